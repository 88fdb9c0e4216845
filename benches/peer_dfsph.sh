#!/bin/bash
# Side by side with SPlisHSPlasH's DFSPH on the Martin & Moyce (1952) dam break, n^2 = 2, to
# t = 0.25 s at the same particle spacing (BENCHMARKS.md, "Against DFSPH"):
#   bash benches/peer_dfsph.sh PEER_SCRIPT [DIV] [THREADS]
# PEER_SCRIPT: the peer's driver (../shared/peers/splishsplash_dambreak.py beside a checkout);
# it needs python3 with pysplishsplash 2.19.0 and numpy. DIV: particle spacing a/DIV (default
# 64); pmpm runs examples/dam_break_2d.toml with h = a/(DIV/2) (2 x 2 particles per cell, so the
# same spacing and particle count) and the default preconditioner (the example's Jacobi is
# meant for its own small grid). THREADS: both codes' threads (default 2).
# Prints the peer's wall time of its step loop, steps and density error, and pmpm's BENCH line
# with the volume figures read from its frames (every 0.005 s): the total volume change, and
# the 1st and 99th percentiles of the per-particle volume ratio J = V / V0 over all frames.
set -eu
cd "$(dirname "$0")/.."
peer=$1; div=${2:-64}; t=${3:-2}
cargo build --release --quiet
work=target/bench/dfsph; rm -rf "$work"; mkdir -p "$work"
# the peer's wheel bundles a libGLdispatch that crashes without a display; the system's does not
gl=$(ldconfig -p | awk '/libGLdispatch.so.0/ {print $NF; exit}')
LD_PRELOAD=$gl OMP_NUM_THREADS=$t python3 "$peer" --div "$div" --out "$work/peer" --end 0.25 \
  > "$work/peer.log" 2>&1
python3 - "$work/peer/result.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
f = r["frames"]
print("DFSPH particles=%d steps=%d loop_wall_s=%.3f init_s=%.3f dt_mean=%.2e iterations_mean=%.1f"
      % (r["particles"], r["steps"], r["loop_wall_s"], r["init_plus_deferred_s"], r["dt_mean"],
         r["iters_mean"]))
print("DFSPH density: mean compression %.3f %% averaged over frames, %.3f %% at most, "
      "J p1 min %.4f, J p99 max %.4f over frames after the first, front x at the end %.4f m"
      % (sum(x["rho_avg_compression_pct"] for x in f) / len(f),
         max(x["rho_avg_compression_pct"] for x in f), min(x["J_p01"] for x in f[1:]),
         max(x["J_p99"] for x in f[1:]), f[-1]["front_edge"]))
PY
h=$(python3 -c "print(0.05715 / ($div / 2))")
sed -e "s/^cell_size = .*/cell_size = $h/" -e "s/^end_time = .*/end_time = 0.25/" \
    -e "s/^interval = .*/interval = 0.005/" -e 's/^formats = .*/formats = ["csv"]/' \
    -e '/^preconditioner = /d' \
    examples/dam_break_2d.toml > "$work/pmpm.toml"
target/release/pmpm --threads "$t" bench "$work/pmpm.toml" -o "$work/pmpm" | grep BENCH
python3 - "$work/pmpm" <<'PY'
import csv, glob, sys
files = sorted(glob.glob(sys.argv[1] + "/frames/particles_*.csv"))
v0 = [float(r["volume"]) for r in csv.DictReader(open(files[0]))]
ratios, worst = [], 0.0
for f in files[1:]:
    v = [float(r["volume"]) for r in csv.DictReader(open(f))]
    ratios += [a / b for a, b in zip(v, v0)]
    worst = max(worst, abs(sum(v) / sum(v0) - 1))
ratios.sort()
q = lambda p: ratios[min(len(ratios) - 1, int(p * len(ratios)))]
print("pmpm volume: max |V/V0 - 1| %.4f %%, J p1 %.4f, J p99 %.4f over %d frames"
      % (100 * worst, q(0.01), q(0.99), len(files) - 1))
PY
