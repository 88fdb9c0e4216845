#!/bin/bash
# Writes the unit-square dam-break deck of the benchmarks to stdout:
#   dambreak_deck.sh DIM N SCHEME [key=value ...]
# The problem of ../shared/peers/taichi_mpm_dambreak.py: unit square (cube), N cells per axis,
# the block 0.4 x 0.8 (x 0.25 in 3D) at the lower corner with 2 x 2 particles per cell, density 1,
# gravity 9.8, slip walls, quadratic B-splines and APIC. The block's sides are rounded down to
# whole particle rows as the script does, so both codes hold the same particles.
# Keys: K (bulk modulus, default 400), dt (fixed step; default none), cfl, end (end time, s),
# update (musl|usl), pc (multigrid|jacobi), shape (bspline2|linear), sort (steps between particle
# sorts, 0 = never; default 20), out (output directory), tank (the tank's size, default "1.0, 1.0"
# or "1.0, 1.0, 1.0"; the cell size stays 1 / N), mu (the water's viscosity, Pa s; default none:
# inviscid).
set -eu
dim=$1; n=$2; scheme=$3; shift 3
K=400; dt=""; cfl=0.5; end=0.4; update=usl; pc=multigrid; shape=bspline2; sort=20; out=out/bench
tank=""; mu=""
for kv in "$@"; do eval "$kv"; done
side() { python3 -c "print(int($1 * $n * 2) / (2 * $n))"; }
h=$(python3 -c "print(1 / $n)")
if [ "$dim" = 2 ]; then
  g="[0.0, -9.8]"; size="[${tank:-1.0, 1.0}]"; lo="[0.0, 0.0]"; hi="[$(side 0.4), $(side 0.8)]"
  faces="x_min = \"slip\"\nx_max = \"slip\"\ny_min = \"slip\"\ny_max = \"slip\""
else
  g="[0.0, -9.8, 0.0]"; size="[${tank:-1.0, 1.0, 1.0}]"; lo="[0.0, 0.0, 0.0]"
  hi="[$(side 0.4), $(side 0.8), $(side 0.25)]"
  faces="x_min = \"slip\"\nx_max = \"slip\"\ny_min = \"slip\"\ny_max = \"slip\"\nz_min = \"slip\"\nz_max = \"slip\""
fi
step="cfl = $cfl"
[ -n "$dt" ] && step="dt = $dt"
cat <<EOT
[simulation]
dimension = $dim
scheme = "$scheme"
end_time = $end
$step
gravity = $g
transfer = "apic"
shape_function = "$shape"
stress_update = "$update"
sort_interval = $sort

[grid]
size = $size
cell_size = $h

[grid.boundary]
$(printf "$faces")

[pressure]
preconditioner = "$pc"

[[materials]]
name = "water"
density = 1.0
bulk_modulus = $K
${mu:+viscosity = $mu}

[[bodies]]
material = "water"
shape = { type = "box", min = $lo, max = $hi }
particles_per_cell = 2

[output]
directory = "$out"
interval = $end
formats = ["csv"]
EOT
