#!/usr/bin/env python3
"""Volume and flow metrics of pmpm runs, as one markdown table row per run.

Usage:
    python3 validation/scripts/water_metrics.py OUTDIR [OUTDIR ...]
    python3 validation/scripts/water_metrics.py --frames OUTDIR

Each OUTDIR is the output directory of a `pmpm run` (it must hold the CSV frames,
`frames/particles_NNNNNN.csv`, so the deck needs "csv" in `output.formats`), with
`series.csv` and `run.toml`, and `rigid_bodies.csv` when the deck has rigid bodies.
A run that blew up (exit status 3) is read as far as its frames go.

Columns of the table (J = a particle's volume over its volume in frame 0, matched by id):

    run          the directory's name
    scheme       simulation.scheme of run.toml
    frames       CSV frames read; t_last the time of the last one (from series.csv)
    dV max %     max over frames of |sum(volume) / sum(volume at frame 0) - 1|, in %
    dV last %    sum(volume) / sum(volume at frame 0) - 1 at the last frame, in % (signed)
    J ok min %   min over frames of the share of particles with |J - 1| <= 5 %
    J min .. J max   percentiles of J at the last frame: min, 1 %, 50 %, 99 %, max
    steps        the step of the last series.csv row; wall s its wall_seconds
    in body      max over frames of the number of particles inside a rigid body's box (the
                 box of run.toml [[rigid_bodies]], moved by velocity * t), and in brackets of
                 those deeper than h/2 inside it (the contact acts at node resolution, so a
                 skin of h/2 inside the faces is expected to hold some); "-" without bodies
    run-up       max over frames of the highest particle (along the gravity axis: y in 2D,
                 z in 3D, unless run.toml's gravity points along another axis) among the
                 particles within 2 cell sizes of the wall x = x_max of the grid; in brackets
                 the same for the top of the sheet of water in that strip that reaches down
                 to the floor with no gap over 4 cells (single droplets thrown up the wall,
                 or left in the corner under a lid, count in the first figure, not in the
                 second)
    front        the largest particle x at the last frame
    peak |fx|    largest |NAME_fx| over the rows of rigid_bodies.csv (N, per metre in 2D), and
                 in brackets the largest |running mean over 20 steps| (the force is noisy
                 step to step); over all bodies; "-" without rigid_bodies.csv

--frames prints, for one run, a table of the time, volume ratio sum(V)/sum(V0), the J share
(|J - 1| <= 5 %), J min and max, the particles inside rigid bodies (and deeper than h/2), the
run-up (highest particle and top of the sheet) and the front, frame by frame.

Python 3.11 or later (tomllib), standard library only.
"""

import argparse
import csv
import glob
import math
import os
import sys

try:
    import tomllib
except ImportError:  # Python < 3.11
    sys.exit("water_metrics.py needs Python 3.11 or later (tomllib)")

J_BAND = 0.05          # |J - 1| <= 5 % counts as "J ok"
RUNUP_CELLS = 2.0      # run-up: particles within this many cell sizes of the wall x = x_max
FORCE_WINDOW = 20      # steps in the running mean of the rigid-body force
SHEET_GAP_BINS = 2     # run-up sheet: gaps of up to this many empty bins (2 h each) are bridged


def read_csv_rows(path):
    """Header (list of names) and rows (lists of strings) of a CSV file."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = [h.strip() for h in next(reader)]
        rows = [r for r in reader if r]
    return header, rows


def percentile(sorted_values, q):
    """Percentile q (0 to 100) of an ascending list, by linear interpolation."""
    if not sorted_values:
        return float("nan")
    pos = (len(sorted_values) - 1) * q / 100.0
    lo = int(math.floor(pos))
    hi = min(lo + 1, len(sorted_values) - 1)
    return sorted_values[lo] + (sorted_values[hi] - sorted_values[lo]) * (pos - lo)


class Run:
    """One output directory: its deck (run.toml), series and frame list."""

    def __init__(self, outdir):
        self.dir = outdir
        self.name = os.path.basename(os.path.normpath(outdir))
        with open(os.path.join(outdir, "run.toml"), "rb") as f:
            self.deck = tomllib.load(f)
        sim = self.deck["simulation"]
        grid = self.deck["grid"]
        self.dim = int(sim["dimension"])
        self.scheme = sim.get("scheme", "projection")
        self.h = float(grid["cell_size"])
        origin = grid.get("origin", [0.0] * self.dim)
        self.x_max = float(origin[0]) + float(grid["size"][0])
        self.up = self._gravity_axis(sim.get("gravity"))
        self.bodies = []
        for body in self.deck.get("rigid_bodies", []):
            shape = body["shape"]
            self.bodies.append((body["name"], [float(v) for v in shape["min"]],
                                [float(v) for v in shape["max"]],
                                [float(v) for v in body.get("velocity", [0.0] * self.dim)]))
        self.series = self._read_series()
        self.frames = sorted(glob.glob(os.path.join(outdir, "frames", "particles_*.csv")))

    def _gravity_axis(self, gravity):
        """Axis along which gravity acts: its largest numeric component, else the last axis."""
        if isinstance(gravity, list) and all(isinstance(g, (int, float)) for g in gravity):
            if any(g != 0 for g in gravity):
                return max(range(self.dim), key=lambda d: abs(gravity[d]))
        return self.dim - 1

    def _read_series(self):
        path = os.path.join(self.dir, "series.csv")
        if not os.path.exists(path):
            return []
        header, rows = read_csv_rows(path)
        return [dict(zip(header, r)) for r in rows]

    def frame_time(self, path):
        """Time of a frame: series.csv's row for its number, else number * output.interval."""
        number = int(os.path.basename(path)[len("particles_"):-len(".csv")])
        for row in self.series:
            if int(row["frame"]) == number:
                return float(row["time"])
        interval = self.deck.get("output", {}).get("interval")
        return number * float(interval) if interval else float("nan")

    def read_frame(self, path):
        """Positions (tuples), volumes and ids of one CSV frame."""
        header, rows = read_csv_rows(path)
        col = {name: i for i, name in enumerate(header)}
        axes = ["x", "y", "z"][: self.dim]
        pos_cols = [col[a] for a in axes]
        i_id, i_vol = col["id"], col["volume"]
        ids, pos, vol = [], [], []
        for r in rows:
            ids.append(int(r[i_id]))
            pos.append(tuple(float(r[c]) for c in pos_cols))
            vol.append(float(r[i_vol]))
        return ids, pos, vol

    def inside_counts(self, pos, t, inset=0.0):
        """Particles inside each rigid body's box at time t, shrunk by `inset` on every side.

        The contact acts at node resolution, so particles within about h/2 inside a face are
        expected; inset = h/2 counts only those deeper in.
        """
        counts = []
        for _, lo, hi, vel in self.bodies:
            lo_t = [lo[d] + vel[d] * t + inset for d in range(self.dim)]
            hi_t = [hi[d] + vel[d] * t - inset for d in range(self.dim)]
            n = 0
            for p in pos:
                if all(lo_t[d] < p[d] < hi_t[d] for d in range(self.dim)):
                    n += 1
            counts.append(n)
        return counts

    def sheet_top(self, heights):
        """Top of the water in the wall strip that reaches down to the floor.

        The strip's particles are put in bins 2 h tall from the bottom of the grid; the sheet
        ends below the first run of more than SHEET_GAP_BINS empty bins. Unlike the highest
        particle, this ignores droplets that a splash throws up the wall or leaves stuck in
        the corner under the lid.
        """
        if not heights:
            return float("nan")
        bottom = float(self.deck["grid"].get("origin", [0.0] * self.dim)[self.up])
        size = 2.0 * self.h
        filled = {}
        for z in heights:
            k = int((z - bottom) // size)
            filled[k] = max(filled.get(k, z), z)
        k, gap = 0, 0
        top = float("nan")
        while gap <= SHEET_GAP_BINS and k <= max(filled):
            if k in filled:
                top, gap = filled[k], 0
            else:
                gap += 1
            k += 1
        return top

    def frame_metrics(self):
        """Per-frame figures: a list of dicts, and the J values of the last frame (sorted)."""
        out = []
        v0_by_id = None
        total0 = None
        last_j = []
        wall_band = self.x_max - RUNUP_CELLS * self.h
        for index, path in enumerate(self.frames):
            t = self.frame_time(path)
            ids, pos, vol = self.read_frame(path)
            total = sum(vol)
            if v0_by_id is None:
                v0_by_id = dict(zip(ids, vol))
                total0 = total
            js = [v / v0_by_id[i] for i, v in zip(ids, vol) if i in v0_by_id and v0_by_id[i] > 0]
            ok = sum(1 for j in js if abs(j - 1.0) <= J_BAND)
            near_wall = [p[self.up] for p in pos if p[0] >= wall_band]
            sheet = self.sheet_top(near_wall)
            out.append({
                "frame": index,
                "time": t,
                "ratio": total / total0 if total0 else float("nan"),
                "j_ok": ok / len(js) if js else float("nan"),
                "j_min": min(js) if js else float("nan"),
                "j_max": max(js) if js else float("nan"),
                "inside": self.inside_counts(pos, t),
                "deep": self.inside_counts(pos, t, 0.5 * self.h),
                "runup": max(near_wall) if near_wall else float("nan"),
                "sheet": sheet,
                "front": max(p[0] for p in pos) if pos else float("nan"),
            })
            last_j = js
        return out, sorted(last_j)

    def force_peaks(self):
        """Largest |fx| over rigid_bodies.csv, raw and as a running mean over FORCE_WINDOW rows."""
        path = os.path.join(self.dir, "rigid_bodies.csv")
        if not os.path.exists(path):
            return None
        header, rows = read_csv_rows(path)
        fx_cols = [i for i, name in enumerate(header) if name.endswith("_fx")]
        if not fx_cols or not rows:
            return None
        peak, peak_mean = 0.0, 0.0
        for c in fx_cols:
            values = [float(r[c]) for r in rows if len(r) > c]
            peak = max(peak, max(abs(v) for v in values))
            acc = 0.0
            for k, v in enumerate(values):
                acc += v
                if k >= FORCE_WINDOW:
                    acc -= values[k - FORCE_WINDOW]
                if k >= FORCE_WINDOW - 1:
                    peak_mean = max(peak_mean, abs(acc / FORCE_WINDOW))
        return peak, peak_mean


def fmt(x, spec):
    """Format a number; nan as "nan", and in exponent form when it is huge (a blown-up frame)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "nan"
    if abs(x) >= 1e5:
        return format(x, ".2e")
    return format(x, spec)


def summary_row(run):
    frames, last_j = run.frame_metrics()
    if not frames:
        return f"| {run.name} | {run.scheme} | 0 (no CSV frames) |"
    dv_max = max(abs(f["ratio"] - 1.0) for f in frames) * 100.0
    dv_last = (frames[-1]["ratio"] - 1.0) * 100.0
    j_ok_min = min(f["j_ok"] for f in frames) * 100.0
    pct = [percentile(last_j, q) for q in (0, 1, 50, 99, 100)]
    last = run.series[-1] if run.series else {}
    steps = last.get("step", "-")
    wall = fmt(float(last["wall_seconds"]), ".1f") if "wall_seconds" in last else "-"
    if run.bodies:
        inside = "%d (%d)" % (max(max(f["inside"]) for f in frames),
                              max(max(f["deep"]) for f in frames))
    else:
        inside = "-"
    runups = [f["runup"] for f in frames if not math.isnan(f["runup"])]
    sheets = [f["sheet"] for f in frames if not math.isnan(f["sheet"])]
    runup = fmt(max(runups), ".4f") if runups else "-"
    if sheets:
        runup += " (" + fmt(max(sheets), ".4f") + ")"
    forces = run.force_peaks()
    force = f"{forces[0]:.4g} ({forces[1]:.4g})" if forces else "-"
    cells = [
        run.name, run.scheme, str(len(frames)), fmt(frames[-1]["time"], ".3f"),
        fmt(dv_max, ".2f"), fmt(dv_last, "+.2f"), fmt(j_ok_min, ".1f"),
        *(fmt(p, ".3g") for p in pct),
        str(steps), wall, inside, runup, fmt(frames[-1]["front"], ".4f"), force,
    ]
    return "| " + " | ".join(cells) + " |"


HEADER = ("| run | scheme | frames | t_last s | dV max % | dV last % | J ok min % | J min | J 1% "
          "| J 50% | J 99% | J max | steps | wall s | in body (deep) | run-up m (sheet) | front m "
          "| peak abs fx N (20-step mean) |")


def print_frames(run):
    frames, _ = run.frame_metrics()
    names = [b[0] for b in run.bodies]
    head = ["frame", "time", "V/V0", "J ok %", "J min", "J max"] + \
        [f"in {n} (deep)" for n in names] + ["run-up", "sheet", "front"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for f in frames:
        cells = [str(f["frame"]), fmt(f["time"], ".4f"), fmt(f["ratio"], ".5f"),
                 fmt(f["j_ok"] * 100.0, ".1f"), fmt(f["j_min"], ".3g"), fmt(f["j_max"], ".3g")]
        cells += [f"{n} ({m})" for n, m in zip(f["inside"], f["deep"])]
        cells += [fmt(f["runup"], ".4f"), fmt(f["sheet"], ".4f"), fmt(f["front"], ".4f")]
        print("| " + " | ".join(cells) + " |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("outdirs", nargs="+", help="pmpm run output directories")
    parser.add_argument("--frames", action="store_true",
                        help="print the per-frame volume ratio and J share of one run")
    args = parser.parse_args()
    if args.frames:
        if len(args.outdirs) != 1:
            parser.error("--frames takes one output directory")
        print_frames(Run(args.outdirs[0]))
        return
    print(HEADER)
    print("|" + "---|" * HEADER.count(" | ") + "---|")
    for outdir in args.outdirs:
        try:
            print(summary_row(Run(outdir)))
        except (OSError, KeyError, ValueError) as e:
            print(f"| {os.path.basename(os.path.normpath(outdir))} | error: {e} |")


if __name__ == "__main__":
    main()
