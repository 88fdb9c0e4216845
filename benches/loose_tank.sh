#!/bin/bash
# The cost of empty tank (BENCHMARKS.md, "Time and memory against the tank's size"; issue 55's
# must-show 2): the benchmarks' dam break (water 0.4 x 0.8, x 0.25 in 3D, h = 1 / N) in a
# tight tank and in one 8x the water's area (2D) or volume (3D), STEPS steps from rest each:
#   bash benches/loose_tank.sh [STEPS] [THREADS]
# 2D: tight 1.0 x 0.875 (2.7x the water's area), loose 1.75 x 1.5 (8.2x).
# 3D: tight 1.0 x 0.875 x 0.25 (2.7x the water's volume), loose 1.0 x 0.875 x 0.75 (8.2x).
# (Sizes that are whole numbers of cells at N = 64 and 256.)
# Prints pmpm's BENCH lines (one process per run, so that each peak memory is its own).
set -eu
cd "$(dirname "$0")/.."
steps=${1:-20}; threads=${2:-2}
cargo build --release --quiet
work=target/bench/loose_tank; mkdir -p "$work"
for case in "2 256 1.0,0.875 tight" "2 256 1.75,1.5 loose" "3 64 1.0,0.875,0.25 tight" \
  "3 64 1.0,0.875,0.75 loose"; do
  set -- $case; dim=$1; n=$2; tank=${3//,/, }; name=$4
  benches/dambreak_deck.sh "$dim" "$n" projection shape=linear update=musl "tank=\"$tank\"" \
    out="$work/out" > "$work/deck_${dim}_$name.toml"
  echo "case dim=$dim n=$n tank=[$tank] $name"
  target/release/pmpm --threads "$threads" bench "$work/deck_${dim}_$name.toml" --steps "$steps" | grep BENCH
done
