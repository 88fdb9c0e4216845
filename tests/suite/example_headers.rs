//! Every example states figures in its header; this test runs the example and fails when one
//! has drifted past the tolerance the header gives it.
//!
//! The figures an example's header checks are in a block of lines under `# Figures`:
//!
//! ```text
//! # Figures (the test suite runs this deck and checks them: tests/suite/example_headers.rs):
//! #   steps = 499 +- 2 %
//! #   volume_drift <= 5e-4
//! #   frame_max(x, 0.1) = 0.146 +- 0.002
//! ```
//!
//! Each line is `MEASURE OP VALUE`: OP is `=` (with `+- TOL` or `+- TOL %`), `<=` or `>=`.
//! The measures, read from what the run writes as `pmpm run` writes it:
//!
//! | measure | what |
//! |---|---|
//! | `steps`, `particles` | steps taken; particles at the end |
//! | `volume_drift` | max over frames of \|sum V / sum V(0) - 1\| (CSV frames) |
//! | `volume_change(t)` | sum V / sum V(0) - 1 in the frame nearest time t |
//! | `volume_kept(q)` | min over frames of the share of particles with \|V / V0 - 1\| <= q |
//! | `settlement(t)` | how far the particles of the top row at t = 0 (the highest y) have moved down by time t, on average |
//! | `frame_max(col, t)`, `frame_min(col, t)` | a CSV frame column's max / min in the frame nearest time t |
//! | `frame_mean(col, t[, material])` | its mean, of one material's particles if given |
//! | `depth(x0, x1, t)` | 2D: the particles' volume with x0 <= x < x1 per length x1 - x0, in the frame nearest time t |
//! | `csv_first(file, col)`, `csv_last(file, col)` | first / last row of series, probes, rigid_bodies or gauges |
//! | `csv_at(file, col, t)` | the first row at or after time t |
//! | `csv_max(file, col[, t0, t1])`, `csv_min(...)` | over all rows, or those with t0 <= time <= t1 |
//! | `csv_mean(file, col, t0, t1)` | mean over t0 < time <= t1, each row weighted by the time since the row before |
//! | `csv_period(file, col, t0, t1)` | the mean period of an oscillation: the time between its first and last upward crossings of its mean (as `csv_mean`) over t0 <= time <= t1, over the number of periods between them |
//! | `csv_amplitude(file, col, T, t0, t1)` | the amplitude of its component of period T, \|(2 / span) sum (y - mean) e^(-2 pi i t / T) dt\| over t0 < time <= t1 (a whole number of periods), each row weighted and the mean taken as in `csv_mean` |
//!
//! `cargo test --release` runs every example but the slowest ones (about 2 minutes on 2
//! cores); `cargo test --release --test suite -- --ignored example_headers` runs those
//! (about 20 minutes).

use crate::common;

use pmpm_cli::table::Table;
use std::path::{Path, PathBuf};

/// The examples that take more than about 10 s on 2 cores: checked by the ignored test.
const SLOW: [&str; 21] = [
    "bingham_slump_2d_explicit",
    "dam_break_closed_tank_2d",
    "dam_break_closed_tank_2d_explicit",
    "dam_break_column_3d",
    "dam_break_column_3d_explicit",
    "dam_break_cylinder_3d",
    "dam_break_obstacle_2d",
    "dam_break_obstacle_2d_explicit",
    "dam_break_tall_tank_2d",
    "dam_break_tall_tank_2d_explicit",
    "drop_impact_2d",
    "drop_into_pool_2d",
    "drop_into_pool_2d_explicit",
    "elastic_column_2d",
    "floating_box_2d",
    "lid_driven_cavity_2d",
    "open_channel_2d",
    "sloshing_2d",
    "strip_footing_2d",
    "wave_flume_2d",
    "yield_block_slump_2d_explicit",
];

/// How a stated figure is compared.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Bound {
    /// Within `tol` of `value` (absolute).
    Near {
        value: f64,
        tol: f64,
    },
    AtMost(f64),
    AtLeast(f64),
}

impl Bound {
    fn holds(&self, x: f64) -> bool {
        match *self {
            Bound::Near { value, tol } => (x - value).abs() <= tol,
            Bound::AtMost(v) => x <= v,
            Bound::AtLeast(v) => x >= v,
        }
    }
}

/// One line of a header's figures block.
#[derive(Debug, Clone, PartialEq)]
struct Figure {
    /// The line as written.
    line: String,
    /// The measure's name.
    measure: String,
    /// Its arguments: column and file names, times, a material index.
    args: Vec<String>,
    bound: Bound,
}

/// The figures block of a deck's text: the `#   ` lines after the `# Figures` line.
fn figures(text: &str) -> Result<Vec<Figure>, String> {
    let mut lines = text.lines().skip_while(|l| !l.starts_with("# Figures"));
    if lines.next().is_none() {
        return Err("no `# Figures` block in the header".into());
    }
    let block: Vec<&str> = lines
        .take_while(|l| l.starts_with("#   "))
        .map(|l| l[1..].trim())
        .collect();
    if block.is_empty() {
        return Err("the `# Figures` block is empty".into());
    }
    block.iter().map(|l| figure(l)).collect()
}

/// Parses `MEASURE OP VALUE [+- TOL [%]]`.
fn figure(line: &str) -> Result<Figure, String> {
    let bad = |why: &str| format!("figure `{line}`: {why}");
    let (lhs, op, rhs) = ["<=", ">=", "="]
        .iter()
        .find_map(|op| line.split_once(op).map(|(l, r)| (l.trim(), *op, r.trim())))
        .ok_or_else(|| bad("no `=`, `<=` or `>=`"))?;
    let (measure, args) = match lhs.split_once('(') {
        Some((name, rest)) => {
            let inner = rest
                .strip_suffix(')')
                .ok_or_else(|| bad("no closing `)`"))?;
            let args = inner.split(',').map(|a| a.trim().to_string()).collect();
            (name.trim().to_string(), args)
        }
        None => (lhs.to_string(), Vec::new()),
    };
    let number = |s: &str| {
        s.trim()
            .replace('_', "")
            .parse::<f64>()
            .map_err(|_| bad(&format!("`{s}` is not a number")))
    };
    let bound = match op {
        "<=" => Bound::AtMost(number(rhs)?),
        ">=" => Bound::AtLeast(number(rhs)?),
        _ => {
            let (value, tol) = rhs
                .split_once("+-")
                .ok_or_else(|| bad("`=` needs `+- TOL`"))?;
            let value = number(value)?;
            let tol = match tol.trim().strip_suffix('%') {
                Some(pct) => number(pct)? / 100.0 * value.abs(),
                None => number(tol)?,
            };
            Bound::Near { value, tol }
        }
    };
    Ok(Figure {
        line: line.to_string(),
        measure,
        args,
        bound,
    })
}

/// What a finished run left to measure.
struct Run {
    dir: PathBuf,
    steps: u64,
    particles: usize,
    /// The CSV frames, read once, at the first figure that needs them.
    frames: std::cell::OnceCell<Vec<(f64, Table)>>,
}

impl Run {
    fn table(&self, name: &str) -> Result<Table, String> {
        let file = match name {
            "series" | "probes" | "rigid_bodies" | "gauges" => format!("{name}.csv"),
            _ => return Err(format!("no CSV file `{name}`")),
        };
        Table::read(&self.dir.join(file))
    }

    /// The CSV particle frames in order, with their times.
    fn frames(&self) -> Result<&[(f64, Table)], String> {
        if let Some(f) = self.frames.get() {
            return Ok(f);
        }
        let series = self.table("series")?;
        let (f, t) = (column(&series, "frame")?, column(&series, "time")?);
        let mut out = Vec::new();
        for row in &series.rows {
            let path = self
                .dir
                .join(format!("frames/particles_{:06}.csv", row[f] as usize));
            out.push((row[t], Table::read(&path)?));
        }
        Ok(self.frames.get_or_init(|| out))
    }

    /// The CSV frame nearest time `t`: a run that does not land on frame times writes each
    /// frame at the first step past it. No frame within half the frame interval is an error.
    fn frame_at(&self, t: f64) -> Result<&Table, String> {
        let frames = self.frames()?;
        let gap = frames
            .windows(2)
            .map(|w| w[1].0 - w[0].0)
            .filter(|g| *g > 0.0)
            .fold(f64::INFINITY, f64::min);
        frames
            .iter()
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .filter(|(time, _)| (time - t).abs() <= 0.5 * gap)
            .map(|(_, table)| table)
            .ok_or_else(|| format!("no frame near t = {t}"))
    }

    /// The value of a figure's measure.
    fn measure(&self, fig: &Figure) -> Result<f64, String> {
        let a = &fig.args;
        let num = |i: usize| -> Result<f64, String> {
            a.get(i)
                .ok_or_else(|| format!("argument {} missing", i + 1))?
                .parse::<f64>()
                .map_err(|_| format!("argument {} is not a number", i + 1))
        };
        let arg = |i: usize| -> Result<&str, String> {
            a.get(i)
                .map(|s| s.as_str())
                .ok_or_else(|| format!("argument {} missing", i + 1))
        };
        match fig.measure.as_str() {
            "steps" => Ok(self.steps as f64),
            "particles" => Ok(self.particles as f64),
            "volume_drift" => {
                let frames = self.frames()?;
                let total = |t: &Table| {
                    column(t, "volume").map(|c| t.rows.iter().map(|r| r[c]).sum::<f64>())
                };
                let v0 = total(&frames[0].1)?;
                frames.iter().try_fold(0.0f64, |most, (_, t)| {
                    Ok(most.max((total(t)? / v0 - 1.0).abs()))
                })
            }
            "volume_change" => {
                let (first, now) = (&self.frames()?[0].1, self.frame_at(num(0)?)?);
                let total = |t: &Table| {
                    column(t, "volume").map(|c| t.rows.iter().map(|r| r[c]).sum::<f64>())
                };
                Ok(total(now)? / total(first)? - 1.0)
            }
            "settlement" => {
                let (first, now) = (&self.frames()?[0].1, self.frame_at(num(0)?)?);
                let (id, y) = (column(first, "id")?, column(first, "y")?);
                let top = first
                    .rows
                    .iter()
                    .map(|r| r[y])
                    .fold(f64::NEG_INFINITY, f64::max);
                let row: std::collections::HashMap<u64, f64> = first
                    .rows
                    .iter()
                    .filter(|r| r[y] >= top - 1e-9)
                    .map(|r| (r[id] as u64, r[y]))
                    .collect();
                let moved: Vec<f64> = now
                    .rows
                    .iter()
                    .filter_map(|r| row.get(&(r[id] as u64)).map(|y0| y0 - r[y]))
                    .collect();
                Ok(moved.iter().sum::<f64>() / moved.len() as f64)
            }
            "volume_kept" => {
                let q = num(0)?;
                let frames = self.frames()?;
                let first = &frames[0].1;
                let (id, vol) = (column(first, "id")?, column(first, "volume")?);
                let v0: std::collections::HashMap<u64, f64> =
                    first.rows.iter().map(|r| (r[id] as u64, r[vol])).collect();
                let mut least = 1.0f64;
                for (_, t) in frames {
                    let kept = t
                        .rows
                        .iter()
                        .filter(|r| {
                            v0.get(&(r[id] as u64))
                                .is_some_and(|v| (r[vol] / v - 1.0).abs() <= q)
                        })
                        .count();
                    least = least.min(kept as f64 / t.rows.len() as f64);
                }
                Ok(least)
            }
            "depth" => {
                let (x0, x1) = (num(0)?, num(1)?);
                let t = self.frame_at(num(2)?)?;
                let (x, vol) = (column(t, "x")?, column(t, "volume")?);
                let held: f64 = t
                    .rows
                    .iter()
                    .filter(|r| r[x] >= x0 && r[x] < x1)
                    .map(|r| r[vol])
                    .sum();
                Ok(held / (x1 - x0))
            }
            "frame_max" | "frame_min" | "frame_mean" => {
                let t = self.frame_at(num(1)?)?;
                let c = column(t, arg(0)?)?;
                let rows: Vec<&Vec<f64>> = match a.get(2) {
                    Some(m) => {
                        let m: f64 = m
                            .parse()
                            .map_err(|_| "material is not a number".to_string())?;
                        let mc = column(t, "material")?;
                        t.rows.iter().filter(|r| r[mc] == m).collect()
                    }
                    None => t.rows.iter().collect(),
                };
                let values = rows.iter().map(|r| r[c]);
                Ok(match fig.measure.as_str() {
                    "frame_max" => values.fold(f64::NEG_INFINITY, f64::max),
                    "frame_min" => values.fold(f64::INFINITY, f64::min),
                    _ => values.sum::<f64>() / rows.len() as f64,
                })
            }
            "csv_period" | "csv_amplitude" => {
                let t = self.table(arg(0)?)?;
                let (time, c) = (column(&t, "time")?, column(&t, arg(1)?)?);
                let (period, t0, t1) = if fig.measure == "csv_amplitude" {
                    (num(2)?, num(3)?, num(4)?)
                } else {
                    (0.0, num(2)?, num(3)?)
                };
                // (time, weight, value) of the rows in the window, each weighted by the time
                // since the row before
                let mut rows = Vec::new();
                let mut before = 0.0f64;
                for r in &t.rows {
                    if r[time] > t0 + 1e-9 && r[time] <= t1 + 1e-9 {
                        rows.push((r[time], r[time] - before.max(t0), r[c]));
                    }
                    before = r[time];
                }
                let span: f64 = rows.iter().map(|r| r.1).sum();
                if span <= 0.0 {
                    return Err(format!("no row of {} in the window", arg(0)?));
                }
                let mean = rows.iter().map(|r| r.1 * r.2).sum::<f64>() / span;
                if fig.measure == "csv_amplitude" {
                    // about the mean: a surface 0.3 m up would leak into the transform through
                    // the window's ragged ends (rows a step apart) by several per cent
                    let w = 2.0 * std::f64::consts::PI / period;
                    let (re, im) = rows.iter().fold((0.0, 0.0), |(re, im), &(s, dt, y)| {
                        let y = y - mean;
                        (re + y * (w * s).cos() * dt, im - y * (w * s).sin() * dt)
                    });
                    return Ok(2.0 / span * (re * re + im * im).sqrt());
                }
                let ups: Vec<f64> = rows
                    .windows(2)
                    .filter(|p| p[0].2 < mean && p[1].2 >= mean)
                    .map(|p| p[0].0 + (mean - p[0].2) / (p[1].2 - p[0].2) * (p[1].0 - p[0].0))
                    .collect();
                match (ups.first(), ups.last()) {
                    (Some(a), Some(b)) if ups.len() >= 2 => Ok((b - a) / (ups.len() - 1) as f64),
                    _ => Err(format!(
                        "{} crosses its mean upwards {} times in the window: no period",
                        arg(1)?,
                        ups.len()
                    )),
                }
            }
            "csv_first" | "csv_last" | "csv_at" | "csv_max" | "csv_min" | "csv_mean" => {
                let t = self.table(arg(0)?)?;
                let (time, c) = (column(&t, "time")?, column(&t, arg(1)?)?);
                let window = |r: &&Vec<f64>| -> bool {
                    match (num(2), num(3)) {
                        (Ok(t0), Ok(t1)) => r[time] >= t0 - 1e-9 && r[time] <= t1 + 1e-9,
                        _ => true,
                    }
                };
                let none = || format!("no row of {} in the window", arg(0).unwrap_or(""));
                match fig.measure.as_str() {
                    "csv_first" => t.rows.first().map(|r| r[c]).ok_or_else(none),
                    "csv_last" => t.rows.last().map(|r| r[c]).ok_or_else(none),
                    "csv_at" => {
                        let at = num(2)?;
                        t.rows
                            .iter()
                            .find(|r| r[time] >= at - 1e-9)
                            .map(|r| r[c])
                            .ok_or_else(none)
                    }
                    "csv_max" => t
                        .rows
                        .iter()
                        .filter(window)
                        .map(|r| r[c])
                        .reduce(f64::max)
                        .ok_or_else(none),
                    "csv_min" => t
                        .rows
                        .iter()
                        .filter(window)
                        .map(|r| r[c])
                        .reduce(f64::min)
                        .ok_or_else(none),
                    _ => {
                        let (t0, t1) = (num(2)?, num(3)?);
                        let (mut sum, mut span, mut before) = (0.0, 0.0, 0.0f64);
                        for r in &t.rows {
                            if r[time] > t0 + 1e-9 && r[time] <= t1 + 1e-9 {
                                let w = r[time] - before.max(t0);
                                sum += w * r[c];
                                span += w;
                            }
                            before = r[time];
                        }
                        (span > 0.0).then(|| sum / span).ok_or_else(none)
                    }
                }
            }
            other => Err(format!("no measure `{other}`")),
        }
    }
}

/// The index of column `name` of a table.
fn column(t: &Table, name: &str) -> Result<usize, String> {
    t.header.iter().position(|h| h == name).ok_or_else(|| {
        format!(
            "no column `{name}` (the columns are {})",
            t.header.join(",")
        )
    })
}

/// Runs an example on 2 threads into a scratch directory, as `pmpm run` does.
fn run_example(path: &Path) -> Result<Run, String> {
    let file = path.display().to_string();
    let deck = pmpm::run::load(path).map_err(|e| e.to_string())?;
    let dir = common::scratch_dir(&format!(
        "header-{}",
        path.file_stem().unwrap().to_string_lossy()
    ));
    let summary = common::in_pool(2, || {
        pmpm::run::run(
            &deck,
            &file,
            &dir,
            &pmpm::run::RunOptions {
                force: true,
                ..Default::default()
            },
            &mut pmpm::run::Silent,
        )
    })
    .map_err(|e| e.to_string())?;
    Ok(Run {
        dir,
        steps: summary.steps,
        particles: summary.particles,
        frames: std::cell::OnceCell::new(),
    })
}

/// The examples' paths, by name; `slow` picks those of [`SLOW`] or the others.
fn examples(slow: bool) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let mut out: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("examples/ is there")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .filter(|p| SLOW.contains(&p.file_stem().unwrap().to_str().unwrap()) == slow)
        .collect();
    out.sort();
    out
}

/// Runs each example and checks its figures; panics listing every figure that drifted, with
/// what the run gave. `PMPM_EXAMPLES=a,b` (file stems) checks only those, when working on them.
fn check_examples(slow: bool) {
    let only = std::env::var("PMPM_EXAMPLES").ok();
    let mut failures = Vec::new();
    for path in examples(slow) {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        if only
            .as_ref()
            .is_some_and(|o| !o.split(',').any(|s| s == stem))
        {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let figs = match figures(&text) {
            Ok(f) => f,
            Err(e) => {
                failures.push(format!("{name}: {e}"));
                continue;
            }
        };
        let run = match run_example(&path) {
            Ok(r) => r,
            Err(e) => {
                failures.push(format!("{name}: the run failed: {e}"));
                continue;
            }
        };
        for fig in &figs {
            match run.measure(fig) {
                Ok(x) if fig.bound.holds(x) => eprintln!("{name}: {} (measured {x:.6e})", fig.line),
                Ok(x) => failures.push(format!("{name}: {}: measured {x:.6e}", fig.line)),
                Err(e) => failures.push(format!("{name}: {}: {e}", fig.line)),
            }
        }
        let _ = std::fs::remove_dir_all(&run.dir);
    }
    assert!(
        failures.is_empty(),
        "header figures that do not hold:\n  {}",
        failures.join("\n  ")
    );
}

#[test]
fn the_examples_hold_their_header_figures() {
    check_examples(false);
}

/// The slow examples (about 20 minutes on 2 cores).
#[test]
#[ignore]
fn the_slow_examples_hold_their_header_figures() {
    check_examples(true);
}

#[test]
fn every_example_has_a_figures_block_that_parses() {
    let all: Vec<PathBuf> = examples(false).into_iter().chain(examples(true)).collect();
    assert!(all.len() >= 30, "the examples are found");
    for s in SLOW {
        assert!(
            all.iter().any(|p| p.file_stem().unwrap() == s),
            "{s} is an example"
        );
    }
    for path in all {
        let text = std::fs::read_to_string(&path).unwrap();
        figures(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

#[test]
fn figure_lines_parse() {
    let f = figure("steps = 499 +- 2 %").unwrap();
    assert_eq!(f.measure, "steps");
    assert_eq!(
        f.bound,
        Bound::Near {
            value: 499.0,
            tol: 9.98
        }
    );
    let f = figure("csv_mean(rigid_bodies, obstacle_fx, 0.15, 0.2) = 160 +- 5").unwrap();
    assert_eq!(f.args, ["rigid_bodies", "obstacle_fx", "0.15", "0.2"]);
    assert_eq!(
        f.bound,
        Bound::Near {
            value: 160.0,
            tol: 5.0
        }
    );
    assert_eq!(
        figure("volume_drift <= 5e-4").unwrap().bound,
        Bound::AtMost(5e-4)
    );
    assert_eq!(
        figure("volume_kept(0.05) >= 0.99").unwrap().bound,
        Bound::AtLeast(0.99)
    );
    assert!(figure("steps = 499").is_err());
    assert!(figure("steps 499").is_err());
    assert!(Bound::Near {
        value: 1.0,
        tol: 0.1
    }
    .holds(1.09));
    assert!(!Bound::AtMost(1.0).holds(1.01));
}
