#!/bin/bash
# Growth of the projection step with the particle count, memory per particle and parallel
# efficiency (BENCHMARKS.md, "Growth, memory, threads"):
#   bash benches/growth.sh [STEPS] [THREADS...]
# Runs the unit-square (cube) dam break with the projection scheme and the multigrid
# preconditioner (linear shapes, APIC, MUSL: the shipped examples' choice) at 4 resolutions per dimension (about 2e4 to 1.3e6 particles), STEPS steps
# each (default 20) from rest, and prints pmpm's BENCH lines (one process per run, so that each
# peak memory is its own). Time per step without output = (wall_s - output) / steps.
set -eu
cd "$(dirname "$0")/.."
steps=${1:-20}; shift || true
threads=${*:-2}
cargo build --release --quiet
work=target/bench/growth; mkdir -p "$work"
for case in "2 128" "2 256" "2 512" "2 1024" "3 32" "3 64" "3 96" "3 128"; do
  set -- $case; dim=$1; n=$2
  benches/dambreak_deck.sh "$dim" "$n" projection shape=linear update=musl out="$work/out" > "$work/deck_${dim}_$n.toml"
  for t in $threads; do
    target/release/pmpm --threads "$t" bench "$work/deck_${dim}_$n.toml" --steps "$steps" | grep BENCH
  done
done
