//! The validation suite: `pmpm validate` runs the cases under `validation/decks/`, compares them
//! with published data and exact solutions, and writes `REPORT.md` with a pass/fail table and
//! one PNG figure (or a few) per case.
//!
//! Each case states its set-up, its metric, its bound and where the bound comes from. A case that
//! does not meet its bound stays in the report as failed. `--quick` runs coarse versions of the
//! same cases in a few minutes; where a coarse case cannot be expected to meet the full bound the
//! row says "report only (quick)", and the full-mode bounds are never changed.

pub mod bingham;
mod cavity;
mod dam_break;
mod elastic;
mod footing;
mod hydrostatic;
mod lobovsky;
pub mod periodic;
pub mod plot;
mod prose;

use pmpm::deck::Deck;
use pmpm::driver::Driver;
use pmpm::error::Error;
use pmpm::scheme::Simulation;
use std::cell::RefCell;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::time::Instant;

/// What `pmpm validate` was asked to do.
#[derive(Debug, Clone)]
pub struct Options {
    /// Coarse versions of the cases (CI).
    pub quick: bool,
    /// Where the unpublished reference series live (Lobovsky et al. 2014).
    pub reference: PathBuf,
    /// Where REPORT.md and the figures go.
    pub out: PathBuf,
    /// Only these cases (all when empty).
    pub cases: Vec<String>,
}

/// A row's verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Within its bound.
    Pass,
    /// Outside its bound.
    Fail,
    /// Measured and reported, no bound applies.
    ReportOnly,
    /// Measured in quick mode, where the coarse case is not held to the full bound.
    ReportOnlyQuick,
    /// Not run (reason in the measured column).
    Skipped,
    /// Not run: needs a feature this version lacks.
    NotRun,
}

impl Verdict {
    fn text(self) -> &'static str {
        match self {
            Verdict::Pass => "**pass**",
            Verdict::Fail => "**FAIL**",
            Verdict::ReportOnly => "report only",
            Verdict::ReportOnlyQuick => "report only (quick)",
            Verdict::Skipped => "skipped",
            Verdict::NotRun => "not run",
        }
    }
}

/// One line of the table.
#[derive(Debug, Clone)]
pub struct Row {
    /// What is measured (names the run: scheme, resolution).
    pub metric: String,
    /// The bound, in words ("<= 0.01"), or "-".
    pub bound: String,
    /// The measured value, formatted.
    pub measured: String,
    /// Pass, fail, report only...
    pub verdict: Verdict,
}

impl Row {
    /// A row held to `value <= limit` when `applies`, report only otherwise (`quick` says why).
    pub fn bounded(
        metric: impl Into<String>,
        value: f64,
        limit: f64,
        fmt: impl Fn(f64) -> String,
        applies: bool,
        quick: bool,
    ) -> Row {
        let verdict = if !applies {
            if quick {
                Verdict::ReportOnlyQuick
            } else {
                Verdict::ReportOnly
            }
        } else if value <= limit {
            Verdict::Pass
        } else {
            Verdict::Fail
        };
        Row {
            metric: metric.into(),
            bound: format!("<= {}", fmt(limit)),
            measured: if value.is_finite() {
                fmt(value)
            } else {
                format!("{value}")
            },
            verdict,
        }
    }

    /// A row held to `value >= limit` when `applies`, report only otherwise (`quick` says why).
    pub fn at_least(
        metric: impl Into<String>,
        value: f64,
        limit: f64,
        fmt: impl Fn(f64) -> String,
        applies: bool,
        quick: bool,
    ) -> Row {
        // -value <= -limit, with the signs put back in the words
        let mut row = Row::bounded(metric, -value, -limit, |v| fmt(-v), applies, quick);
        row.bound = format!(">= {}", fmt(limit));
        row
    }

    /// A row with no bound.
    pub fn report(metric: impl Into<String>, measured: impl Into<String>) -> Row {
        Row {
            metric: metric.into(),
            bound: "-".into(),
            measured: measured.into(),
            verdict: Verdict::ReportOnly,
        }
    }
}

/// A case's part of the report.
#[derive(Debug, Clone, Default)]
pub struct Section {
    /// Registry name (`--case`).
    pub name: String,
    /// Heading.
    pub title: String,
    /// Set-up in words (decks named).
    pub setup: String,
    /// The metric in words.
    pub metric: String,
    /// The bound and where it comes from.
    pub bound: String,
    /// Table rows.
    pub rows: Vec<Row>,
    /// Findings, one paragraph each.
    pub notes: Vec<String>,
    /// PNG file names, relative to the report.
    pub figures: Vec<String>,
    /// Wall time of the case (s).
    pub wall_s: f64,
}

#[cfg(test)]
impl Section {
    /// Title, set-up, metric and bound (the prose files' test).
    fn texts(self) -> Vec<String> {
        vec![self.title, self.setup, self.metric, self.bound]
    }
}

/// Every text the cases fill from their prose files (`validation/prose/`), in `quick` or full
/// mode: the prose files' test runs them all.
#[cfg(test)]
fn prose_texts(quick: bool) -> Vec<String> {
    [
        hydrostatic::prose_texts(quick),
        dam_break::prose_texts(quick),
        lobovsky::prose_texts(quick),
        cavity::prose_texts(quick),
        periodic::prose_texts(quick),
        bingham::prose_texts(quick),
        footing::prose_texts(quick),
        elastic::prose_texts(quick),
    ]
    .concat()
}

/// Shared state of one `validate` run.
pub struct Ctx {
    /// The options.
    pub opts: Options,
    /// Dam-break runs by (scheme, a / h), shared by the Martin & Moyce and conservation cases.
    dam_breaks: RefCell<HashMap<(String, u32), Rc<dam_break::DamBreakRun>>>,
}

type CaseFn = fn(&Ctx) -> Result<Section, String>;

/// The registry: name, what it is, the function that runs it.
const CASES: &[(&str, &str, CaseFn)] = &[
    (
        "hydrostatic",
        "columns at rest, 2D and 3D, both schemes",
        hydrostatic::run,
    ),
    (
        "martin_moyce",
        "Martin & Moyce (1952) dam break, 3 resolutions, both schemes",
        dam_break::martin_moyce,
    ),
    (
        "conservation",
        "mass and volume over the dam break, both schemes",
        dam_break::conservation,
    ),
    (
        "lobovsky",
        "Lobovsky et al. (2014) dam break: wall pressure and water levels",
        lobovsky::run,
    ),
    (
        "cavity",
        "lid-driven cavity, Re = 100 and 1000 (Ghia et al. 1982)",
        cavity::run,
    ),
    (
        "poiseuille",
        "start-up of plane Poiseuille flow (Morris et al. 1997)",
        periodic::poiseuille,
    ),
    (
        "couette",
        "start-up of plane Couette flow (Morris et al. 1997)",
        periodic::couette,
    ),
    (
        "taylor_green",
        "Taylor-Green vortex decay and convergence",
        periodic::taylor_green,
    ),
    (
        "bingham_poiseuille",
        "Bingham plane Poiseuille flow: plug and profile (Bird, Dai & Yarusso 1983)",
        bingham::poiseuille,
    ),
    (
        "strip_footing",
        "strip footing on undrained clay against Prandtl's (2 + pi) c_u, both schemes",
        footing::run,
    ),
    (
        "elastic",
        "elastic column under its own weight and a spinning block, both schemes",
        elastic::run,
    ),
];

/// Names of the registered cases.
pub fn case_names() -> Vec<&'static str> {
    CASES.iter().map(|c| c.0).collect()
}

/// Runs the selected cases and writes REPORT.md and the figures into `opts.out`. Returns the
/// number of rows that failed their bound.
pub fn validate(opts: Options) -> Result<usize, Error> {
    for c in &opts.cases {
        if !CASES.iter().any(|k| k.0 == c) {
            return Err(Error::Usage(format!(
                "unknown validation case {c:?}; the cases are: {}",
                case_names().join(", ")
            )));
        }
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    let start = Instant::now();
    let ctx = Ctx {
        opts: opts.clone(),
        dam_breaks: RefCell::new(HashMap::new()),
    };
    let mut sections = Vec::new();
    for &(name, what, f) in CASES {
        if !opts.cases.is_empty() && !opts.cases.iter().any(|c| c == name) {
            continue;
        }
        eprintln!("validate: {name}: {what}");
        let t0 = Instant::now();
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(&ctx)));
        let mut s = match result {
            Ok(Ok(s)) => s,
            Ok(Err(e)) => failed_section(name, what, &e),
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "panic".into());
                failed_section(name, what, &format!("panicked: {msg}"))
            }
        };
        s.name = name.to_string();
        s.wall_s = t0.elapsed().as_secs_f64();
        eprintln!("validate: {name}: done in {:.1} s", s.wall_s);
        for r in &s.rows {
            eprintln!(
                "  {:<60} {:>14} {:>12}  {}",
                r.metric,
                r.bound,
                r.measured,
                r.verdict.text()
            );
        }
        sections.push(s);
    }
    let wall = start.elapsed().as_secs_f64();
    let report = render(&opts, &sections, wall);
    let path = opts.out.join("REPORT.md");
    std::fs::write(&path, report).map_err(|e| Error::io(&path, e))?;
    let failed = sections
        .iter()
        .flat_map(|s| &s.rows)
        .filter(|r| r.verdict == Verdict::Fail)
        .count();
    eprintln!(
        "validate: wrote {} ({failed} failed rows, {wall:.0} s)",
        path.display()
    );
    Ok(failed)
}

fn failed_section(name: &str, what: &str, e: &str) -> Section {
    Section {
        name: name.into(),
        title: what.into(),
        rows: vec![Row {
            metric: "the case runs".into(),
            bound: "-".into(),
            measured: format!("error: {e}"),
            verdict: Verdict::Fail,
        }],
        notes: vec![format!("The case stopped with an error: {e}")],
        ..Default::default()
    }
}

fn command_output(cmd: &str, args: &[&str]) -> Option<String> {
    let out = std::process::Command::new(cmd).args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// The machine: CPU model, cores, threads used, OS.
fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(0);
    let os = std::fs::read_to_string("/etc/os-release")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("PRETTY_NAME=")).map(|l| {
                l.trim_start_matches("PRETTY_NAME=")
                    .trim_matches('"')
                    .into()
            })
        })
        .unwrap_or_else(|| std::env::consts::OS.to_string());
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines().next().and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|k| k.parse::<f64>().ok())
            })
        })
        .map(|kb| format!(", {:.0} GiB memory", kb / 1024.0 / 1024.0))
        .unwrap_or_default();
    format!(
        "{cpu}, {cores} cores available, {} worker threads{mem}, {os}",
        rayon::current_num_threads()
    )
}

/// A table cell: `|` escaped, one line.
fn cell(text: &str) -> String {
    text.replace('|', "\\|").replace('\n', " ")
}

fn render(opts: &Options, sections: &[Section], wall: f64) -> String {
    let mut s = String::new();
    let mode = if opts.quick {
        "quick (coarse versions of the cases, for CI)"
    } else {
        "full"
    };
    let date = command_output("date", &["-u", "+%Y-%m-%d %H:%M UTC"]).unwrap_or_default();
    let commit = command_output("git", &["rev-parse", "--short", "HEAD"]).map(|c| {
        // the report's own files, written before this line, do not count
        let mut args = vec!["status", "--porcelain", "--untracked-files=no"];
        let out = opts
            .out
            .strip_prefix(".")
            .unwrap_or(&opts.out)
            .to_string_lossy();
        let exclude = format!(":(exclude){}", out.trim_end_matches('/'));
        if opts.out.is_relative() {
            args.extend(["--", ".", &exclude]);
        }
        let dirty = command_output("git", &args)
            .map(|s| !s.is_empty())
            .unwrap_or(false);
        if dirty {
            format!("{c} (with uncommitted changes)")
        } else {
            c
        }
    });
    let _ = writeln!(s, "# pmpm validation report\n");
    let _ = writeln!(
        s,
        "Mode: {mode}. Machine: {}. Wall time of the run: {:.1} min ({:.0} s). pmpm {}{}{}.\n",
        machine(),
        wall / 60.0,
        wall,
        env!("CARGO_PKG_VERSION"),
        commit.map(|c| format!(", commit {c}")).unwrap_or_default(),
        if date.is_empty() {
            String::new()
        } else {
            format!(", run {date}")
        }
    );
    let _ = writeln!(
        s,
        "Command: `pmpm validate{}` (reference directory `{}`). \"report only\": measured, no bound applies (the case text says why); \"report only (quick)\": the full-mode bound is not applied to the coarse quick-mode run.\n",
        if opts.quick { " --quick" } else { "" },
        opts.reference.display()
    );
    let _ = writeln!(s, "| case | metric | bound | measured | pass |");
    let _ = writeln!(s, "|---|---|---|---|---|");
    for sec in sections {
        for r in &sec.rows {
            let _ = writeln!(
                s,
                "| [{}](#{}) | {} | {} | {} | {} |",
                sec.name,
                sec.name.replace('_', "-"),
                cell(&r.metric),
                cell(&r.bound),
                cell(&r.measured),
                r.verdict.text()
            );
        }
    }
    let _ = writeln!(s, "\nWall time per case:");
    for sec in sections {
        let _ = writeln!(s, "- {}: {:.0} s", sec.name, sec.wall_s);
    }
    for sec in sections {
        let _ = writeln!(s, "\n## {}\n", sec.name);
        let _ = writeln!(s, "*{}*\n", sec.title);
        if !sec.setup.is_empty() {
            let _ = writeln!(s, "**Set-up.** {}\n", sec.setup);
        }
        if !sec.metric.is_empty() {
            let _ = writeln!(s, "**Metric.** {}\n", sec.metric);
        }
        if !sec.bound.is_empty() {
            let _ = writeln!(s, "**Bound.** {}\n", sec.bound);
        }
        let _ = writeln!(s, "| metric | bound | measured | pass |");
        let _ = writeln!(s, "|---|---|---|---|");
        for r in &sec.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} |",
                cell(&r.metric),
                cell(&r.bound),
                cell(&r.measured),
                r.verdict.text()
            );
        }
        let _ = writeln!(s);
        for n in &sec.notes {
            let _ = writeln!(s, "{n}\n");
        }
        for f in &sec.figures {
            let _ = writeln!(s, "![{f}]({f})\n");
        }
    }
    s
}

/// The text of a deck under `validation/decks/` (compiled in).
fn deck_text(name: &str) -> &'static str {
    macro_rules! decks {
        ($($n:literal),*) => {
            match name {
                $($n => include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/validation/decks/", $n, ".toml")),)*
                _ => panic!("no validation deck {name}"),
            }
        };
    }
    decks!(
        "hydrostatic_2d_projection",
        "hydrostatic_2d_explicit",
        "hydrostatic_3d_projection",
        "hydrostatic_3d_explicit",
        "martin_moyce_projection",
        "martin_moyce_explicit",
        "lobovsky_projection",
        "lobovsky_explicit",
        "lobovsky_3d",
        "cavity_re100",
        "cavity_re1000",
        "poiseuille",
        "couette",
        "taylor_green",
        "strip_footing",
        "elastic_column_projection",
        "elastic_column_explicit",
        "elastic_spin_projection",
        "elastic_spin_explicit",
        "bingham_poiseuille"
    )
}

/// Parses the deck `validation/decks/NAME.toml`, lets `edit` change it (resolution, probes),
/// then validates it.
pub(crate) fn load_deck(name: &str, edit: impl FnOnce(&mut Deck)) -> Result<Deck, String> {
    let file = format!("validation/decks/{name}.toml");
    let mut d = Deck::parse(deck_text(name), &file).map_err(|e| e.to_string())?;
    edit(&mut d);
    d.validate(&file).map_err(|e| e.to_string())?;
    Ok(d)
}

/// Runs a deck to its end time through the driver `pmpm run` uses ([`Driver`]: the deck's
/// fixed `dt` or its adaptive step, landing on frame times as the deck says). After every
/// step `each(sim, t0)` sees the state (`t0`: the step's start time, when the probes
/// sampled); it returns `false` to end the run early.
pub(crate) fn run_deck<const D: usize>(
    d: &Deck,
    mut each: impl FnMut(&Simulation<D>, f64) -> bool,
) -> Result<Simulation<D>, String> {
    let mut sim = Simulation::<D>::new(d).map_err(|e: Error| e.to_string())?;
    Driver::new(pmpm::build::clock(d))
        .run(&mut sim, |sim, step| each(sim, step.t0))
        .map_err(|e| e.to_string())?;
    Ok(sim)
}

/// Reads a reference CSV: `#` lines skipped, one header row, then numeric columns.
pub(crate) fn read_csv(path: &Path) -> Result<Vec<Vec<f64>>, String> {
    Ok(crate::table::Table::read(path)?.rows)
}

/// A reference table compiled in from `validation/reference/` (published tables only).
pub(crate) fn reference_table(name: &str) -> Vec<Vec<f64>> {
    macro_rules! tables {
        ($($n:literal),*) => {
            match name {
                $($n => include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/validation/reference/", $n, ".csv")),)*
                _ => panic!("no reference table {name}"),
            }
        };
    }
    let text = tables!(
        "martin_moyce_1952_n2_2_table2_surge_front",
        "martin_moyce_1952_n2_2_table6_height",
        "ghia_1982_re100_u_vertical_centerline",
        "ghia_1982_re100_v_horizontal_centerline",
        "ghia_1982_re1000_u_vertical_centerline",
        "ghia_1982_re1000_v_horizontal_centerline"
    );
    crate::table::Table::parse(text)
        .expect("compiled-in table is numeric")
        .rows
}

/// Linear interpolation of (xs, ys) at x (xs increasing; clamped to the ends).
pub(crate) fn interp(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    if xs.len() == 1 || x <= xs[0] {
        return ys[0];
    }
    if x >= xs[xs.len() - 1] {
        return ys[ys.len() - 1];
    }
    let k = xs.partition_point(|&v| v < x).clamp(1, xs.len() - 1);
    let (x0, x1, y0, y1) = (xs[k - 1], xs[k], ys[k - 1], ys[k]);
    if x1 == x0 {
        return y1;
    }
    y0 + (y1 - y0) * (x - x0) / (x1 - x0)
}

/// "12.3%"-style formatting of a fraction.
pub(crate) fn pct(v: f64) -> String {
    if v != 0.0 && v.abs() < 1e-3 {
        format!("{:.2e}%", 100.0 * v)
    } else {
        format!("{:.2}%", 100.0 * v)
    }
}

/// Three significant digits, scientific when small or large.
pub(crate) fn sci(v: f64) -> String {
    if v != 0.0 && (v.abs() < 1e-2 || v.abs() >= 1e4) {
        format!("{v:.2e}")
    } else {
        format!("{v:.3}")
    }
}

/// The sorted names, without extension, of the files `DIR/*.EXT` of the repository (tests).
#[cfg(test)]
pub(crate) fn file_stems(dir: &str, ext: &str) -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| {
            let p = e.unwrap().path();
            (p.extension()? == ext).then(|| p.file_stem().unwrap().to_string_lossy().into())
        })
        .collect();
    names.sort();
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_deck_parses_or_needs_a_missing_feature() {
        // every file under validation/decks/, so that a deck added there is registered too
        let names = file_stems("validation/decks", "toml");
        assert!(names.len() >= 13, "decks found: {names:?}");
        for name in &names {
            load_deck(name, |_| {}).unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }

    #[test]
    fn reference_tables_read() {
        assert_eq!(
            reference_table("martin_moyce_1952_n2_2_table2_surge_front").len(),
            16
        );
        assert_eq!(
            reference_table("martin_moyce_1952_n2_2_table6_height").len(),
            14
        );
        assert_eq!(
            reference_table("ghia_1982_re100_u_vertical_centerline").len(),
            17
        );
    }

    #[test]
    fn interpolation_and_bounds() {
        let xs = [0.0, 1.0, 2.0];
        let ys = [0.0, 10.0, 0.0];
        assert_eq!(interp(&xs, &ys, 0.5), 5.0);
        assert_eq!(interp(&xs, &ys, 3.0), 0.0);
        let r = Row::bounded("m", 0.02, 0.01, pct, true, false);
        assert_eq!(r.verdict, Verdict::Fail);
        let r = Row::bounded("m", 0.02, 0.01, pct, false, true);
        assert_eq!(r.verdict, Verdict::ReportOnlyQuick);
    }
}
