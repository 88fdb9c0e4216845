#!/bin/bash
# Strong and weak scaling of a run over MPI ranks against threads (BENCHMARKS.md, "Over MPI
# ranks"): a 3D explicit dam break (a water block 0.4 m long, 0.3 m high, across the tank's
# width, in a tank 1 m long and 0.5 m high, slip walls, h = H, 2^3 particles a cell), STEPS
# steps' worth of time, frames only at the start and the end.
#   bash benches/mpi_scaling.sh PMPM H END_TIME "RANKS..."
# SCHEME=projection runs the projection (its defaults) in place of the explicit scheme.
# PMPM: a binary built with --features mpi (mpirun on the PATH). Strong: width 0.4 m on R
# ranks of one thread, and on one process of R threads. Weak: width 0.1 R m on R ranks.
# Prints one line per run: kind, ranks or threads, particles, steps, wall seconds of the run
# (series.csv, frames included), the peak resident memory of the largest process (kB, GNU
# time's %M: mpirun's waited-for descendants, the ranks; TIME_BIN, default /usr/bin/time).
set -eu
pmpm=$1; h=$2; end=$3; counts=$4
work=${WORK:-target/bench/mpi}; mkdir -p "$work"
transfer=flip; [ "${SCHEME:-explicit}" = projection ] && transfer=apic
deck() { # width -> deck on stdout
  cat <<EOF
[simulation]
dimension = 3
scheme = "${SCHEME:-explicit}"
end_time = $end
cfl = 0.4
gravity = [0.0, 0.0, -9.81]
transfer = "$transfer"
shape_function = "linear"
[grid]
origin = [0.0, 0.0, 0.0]
size = [1.0, $1, 0.5]
cell_size = $h
[grid.boundary]
x_min = "slip"
x_max = "slip"
y_min = "slip"
y_max = "slip"
z_min = "slip"
z_max = "slip"
[[materials]]
name = "water"
model = "newtonian"
density = 1000.0
viscosity = 1.0e-3
bulk_modulus = 2.0e6
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0, 0.0], max = [0.4, $1, 0.3] }
particles_per_cell = 2
[output]
directory = "$work/out"
interval = $end
formats = ["csv"]
EOF
}
one() { # kind count deck launcher...
  local kind=$1 n=$2 d=$3; shift 3
  local out="$work/out-$kind-$n"
  rm -rf "$out"
  local mem=""
  local timebin=${TIME_BIN:-/usr/bin/time}
  if [ -x "$timebin" ]; then
    "$timebin" -f %M -o "$work/mem" "$@" run "$d" -o "$out" -q --force
    mem=$(cat "$work/mem")
  else
    "$@" run "$d" -o "$out" -q --force
  fi
  local last; last=$(tail -n 1 "$out/series.csv")
  local parts; parts=$(( $(wc -l < "$(ls "$out"/frames/*.csv | tail -n 1)") - 1 ))
  echo "$kind $n particles=$parts steps=$(echo "$last" | cut -d, -f3) wall=$(echo "$last" | cut -d, -f8) mem_kB=$mem"
}
deck 0.4 > "$work/strong.toml"
for n in $counts; do
  one threads "$n" "$work/strong.toml" "$pmpm" --threads "$n"
  one ranks "$n" "$work/strong.toml" mpirun -n "$n" "$pmpm" --threads 1
  deck "$(awk "BEGIN { print 0.1 * $n }")" > "$work/weak-$n.toml"
  one weak "$n" "$work/weak-$n.toml" mpirun -n "$n" "$pmpm" --threads 1
done
