#!/bin/bash
# The memory model of `pmpm check` (crates/pmpm/src/deck/limits.rs): peak resident memory
# = BYTES_BASE + a particles + b nodes, a and b per dimension, scheme and shape function, the
# nodes those `check` counts in the rows the bodies reach (the node arrays hold pages only
# there). For each case the benchmarks' dam break (benches/dambreak_deck.sh, h = 1 / N) runs
# STEPS steps in a tight tank and in one with longer rows, the same particles in both; the pair
# gives a and b. Then the model is checked against a run at another resolution.
#   bash benches/memory_model.sh [STEPS] [THREADS]      (SHAPES="linear bspline2 bspline3" by default)
# Prints one line per case: the two peaks, the particles and nodes, and the fitted a and b.
# (3D with bspline3 takes hundreds of pressure iterations a step at N = 48: STEPS=3 for it.)
set -eu
cd "$(dirname "$0")/.."
steps=${1:-10}; threads=${2:-2}
cargo build --release --quiet
pmpm=target/release/pmpm
work=target/bench/memory_model; mkdir -p "$work"
base=10000000
run() { # DIM N SCHEME SHAPE MU TANK -> "peak particles nodes"
  local deck="$work/deck.toml"
  benches/dambreak_deck.sh "$1" "$2" "$3" shape="$4" mu="$5" "tank=\"$6\"" out="$work/out" > "$deck"
  local peak particles nodes
  peak=$("$pmpm" --threads "$threads" bench "$deck" --steps "$steps" | grep -o 'peak_bytes=[0-9]*' | cut -d= -f2)
  particles=$("$pmpm" check "$deck" | awk '$1 == "particles" {print $2}')
  nodes=$("$pmpm" check "$deck" | grep -o 'for the [0-9]* nodes' | cut -d' ' -f3)
  echo "$peak $particles $nodes"
}
for case in "2 256" "3 48"; do
  set -- $case; dim=$1; n=$2
  if [ "$dim" = 2 ]; then tight="1.0, 0.875"; loose="1.75, 1.5"
  else tight="1.0, 0.875, 0.25"; loose="1.75, 0.875, 0.25"; fi
  # inviscid water, then viscous water under the projection (the implicit viscous solve)
  for scheme_mu in "projection " "explicit " "projection 1e-3"; do
    scheme=${scheme_mu%% *}; mu=${scheme_mu#* }
    for shape in ${SHAPES:-linear bspline2 bspline3}; do
      read -r p1 n1 m1 <<< "$(run "$dim" "$n" "$scheme" "$shape" "$mu" "$tight")"
      read -r p2 n2 m2 <<< "$(run "$dim" "$n" "$scheme" "$shape" "$mu" "$loose")"
      python3 - "$dim" "$scheme" "$shape" "${mu:-0}" "$p1" "$p2" "$n1" "$m1" "$m2" "$base" <<'PY'
import sys
dim, scheme, shape, mu = sys.argv[1:5]
p1, p2, n, m1, m2, base = map(float, sys.argv[5:])
b = (p2 - p1) / (m2 - m1)
a = (p1 - base - b * m1) / n
print(f"MODEL dim={dim} scheme={scheme} shape={shape} viscosity={mu} particles={n:.0f} "
      f"nodes={m1:.0f}/{m2:.0f} peak_MB={p1/1e6:.1f}/{p2/1e6:.1f} "
      f"bytes_per_particle={a:.0f} bytes_per_node={b:.0f}")
PY
    done
  done
done
