#!/bin/bash
# Per-phase cost of the projection step, one or more pmpm binaries side by side on the same
# decks (BENCHMARKS.md, "The projection step, phase by phase"):
#   bash benches/phases.sh THREADS STEPS PMPM [PMPM ...]
# Decks: the shipped 2D dam break example (Martin & Moyce, linear shapes, 3,200 particles) and
# the unit-square dam break of the peer comparison at 128^2 and 256^2 cells (quadratic
# B-splines, APIC, USL, about 2e4 and 8e4 particles), each STEPS steps from rest. Copy the
# binary to compare against out of target/ first (a build overwrites it). Prints one line per
# binary and deck: ms per step and the seconds of each phase (pmpm's BENCH line).
set -eu
cd "$(dirname "$0")/.."
threads=$1; steps=$2; shift 2
work=target/bench/phases; mkdir -p "$work"
benches/dambreak_deck.sh 2 128 projection out="$work/out" > "$work/square_128.toml"
benches/dambreak_deck.sh 2 256 projection out="$work/out" > "$work/square_256.toml"
sed "s#^directory = .*#directory = \"$work/out\"#" examples/dam_break_2d.toml > "$work/dam_break_2d.toml"
for deck in dam_break_2d square_128 square_256; do
  for bin in "$@"; do
    line=$("$bin" --threads "$threads" bench "$work/$deck.toml" --steps "$steps" | grep BENCH)
    echo "$deck $bin: $(echo "$line" | tr ' ' '\n' | grep -E '^(ms_per_step|pressure_iterations|p2g|free-surface|assembly|pressure|corrector|density|g2p|constitutive|output)=' | tr '\n' ' ')"
  done
done
