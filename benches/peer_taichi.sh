#!/bin/bash
# Side-by-side speed of pmpm's explicit scheme and the Taichi MLS-MPM peer on the same dam break
# (BENCHMARKS.md, "Against Taichi"). Needs python3 with taichi and numpy, and the peer script:
#   bash benches/peer_taichi.sh [PEER_SCRIPT] [STEPS_3D]
# PEER_SCRIPT defaults to ../shared/peers/taichi_mpm_dambreak.py. Prints the peer's RESULT lines
# and pmpm's BENCH lines (particle updates per second = particles x steps / wall seconds of the
# step loop, for both), for 2D 128^2 and 256^2 (2000 steps) and 3D 64^3, on 1 and 2 threads.
# CASES="dim,n,dt,steps ..." picks other cases.
set -eu
cd "$(dirname "$0")/.."
peer=${1:-../shared/peers/taichi_mpm_dambreak.py}
steps3d=${2:-2000}
cargo build --release --quiet
work=target/bench/taichi; mkdir -p "$work"
cases=${CASES:-"2,128,2e-4,2000 2,256,1e-4,2000 3,64,2e-4,$steps3d"}
for case in $cases; do
  IFS=, read -r dim n dt steps <<< "$case"
  end=$(python3 -c "print($dt * $steps)")
  for update in usl musl; do
    benches/dambreak_deck.sh "$dim" "$n" explicit dt="$dt" end="$end" update=$update \
      out="$work/out" > "$work/deck_${dim}_${n}_$update.toml"
  done
  for t in 1 2; do
    python3 "$peer" --dim "$dim" --n-grid "$n" --steps "$steps" --dt "$dt" --threads "$t" | grep RESULT
    for update in usl musl; do
      if [ $update = musl ] && [ "$t" = 1 ]; then continue; fi
      echo "pmpm stress_update=$update"
      target/release/pmpm --threads "$t" bench "$work/deck_${dim}_${n}_$update.toml" 2>&1 \
        | grep -E "^(BENCH|error)" || true
    done
  done
done
