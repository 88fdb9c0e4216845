#!/bin/bash
# Time to solution at equal incompressibility (BENCHMARKS.md): the 128^2 dam break to t = 0.4 s
#   bash benches/equal_volume.sh PEER_COPY K [THREADS]
# PEER_COPY: a copy of ../shared/peers/taichi_mpm_dambreak.py that also takes --track-j (the run's
# extreme J, sampled every 10 steps; not in the repository, see BENCHMARKS.md). K: the bulk
# modulus for the explicit runs of both codes, dt = 2e-4 sqrt(400 / K) (c dt / h = 0.51).
# pmpm's volume error is read from frames every 0.01 s (volume / initial volume of each particle):
# the largest |1 - J| and the extreme 1st and 99th percentiles of J over the frames, as the peer
# copy reports its own J (sampled every 10 steps).
set -eu
cd "$(dirname "$0")/.."
peer=$1; K=$2; t=${3:-2}
cargo build --release --quiet
work=target/bench/equal_volume; mkdir -p "$work"
dt=$(python3 -c "print(2e-4 * (400 / $K) ** 0.5)")
steps=$(python3 -c "print(round(0.4 / $dt))")
python3 "$peer" --n-grid 128 --E "$K" --dt "$dt" --steps "$steps" --warmup 1 --threads "$t" --track-j | grep RESULT
volume_error() {  # max |V/V0 - 1| over the frames, and the front (largest x) at the end
  python3 - "$1" <<'PY'
import csv, glob, sys
files = sorted(glob.glob(sys.argv[1] + "/frames/particles_*.csv"))
v0 = [float(r["volume"]) for r in csv.DictReader(open(files[0]))]
err, p1, p99 = 0.0, 1.0, 1.0
for f in files:
    rows = list(csv.DictReader(open(f)))
    j = sorted(float(r["volume"]) / v for r, v in zip(rows, v0))
    err = max(err, max(abs(a - 1) for a in j))
    p1, p99 = min(p1, j[int(0.01 * len(j))]), max(p99, j[min(len(j) - 1, int(0.99 * len(j)))])
total = sum(float(r["volume"]) for r in rows) / sum(v0) - 1
print("max_abs_1_minus_J=%.4f J_p1_run=%.5f J_p99_run=%.5f total_volume_change_at_end=%.4f "
      "front_x=%.4f frames=%d" % (err, p1, p99, total, max(float(r["x"]) for r in rows), len(files)))
PY
}
for scheme in explicit projection; do
  if [ $scheme = explicit ]; then extra="dt=$dt K=$K"; else extra="cfl=0.5"; fi
  benches/dambreak_deck.sh 2 128 $scheme $extra end=0.4 out="$work/$scheme" \
    | sed 's/^interval = .*/interval = 0.01/' > "$work/$scheme.toml"
  echo "pmpm $scheme $extra"
  target/release/pmpm --threads "$t" bench "$work/$scheme.toml" -o "$work/$scheme" | grep BENCH
  volume_error "$work/$scheme"
done
