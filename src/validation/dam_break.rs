//! Martin & Moyce (1952) dam break, n^2 = 2, against Tables 2 and 6; mass and volume over it.

use super::plot::{colors, save, Panel, Series};
use super::{interp, load_deck, pct, prose, reference_table, run_deck, Ctx, Row, Section};
use pmpm::fill::{FillFigures, FillLattice};
use std::rc::Rc;

const G: f64 = 9.81;
/// Column base a (m).
const A: f64 = 0.05715;
/// The gate of the experiment took a while to open: simulated T is shifted by +0.175 (as Lethe
/// and others do), the same for both schemes.
const T_SHIFT: f64 = 0.175;

/// One dam-break run, per step.
pub struct DamBreakRun {
    /// Time (s), after each step (first entry: t = 0).
    pub t: Vec<f64>,
    /// Surge front x_front / a.
    pub front: Vec<f64>,
    /// Residual height at the back wall / 2a.
    pub height: Vec<f64>,
    /// Total volume sum V0 J / initial.
    pub volume: Vec<f64>,
    /// The particles' interior fill ([`pmpm::fill`]).
    pub fill: Vec<FillFigures>,
    /// Whether the total mass kept its bits at every step.
    pub mass_exact: bool,
    /// Total mass.
    pub mass: f64,
    /// Steps.
    pub steps: u64,
    /// Wall time (s).
    pub wall_s: f64,
}

/// The explicit twin with its particles packed (`density_correction = "particles"`).
const EXPLICIT_PACKED: &str = "explicit, packed";

/// Runs (or reuses) the dam break with `scheme` (the deck `martin_moyce_{scheme}`, or
/// [`EXPLICIT_PACKED`]) at h = a / `per_a`.
fn dam_break(ctx: &Ctx, scheme: &str, per_a: u32) -> Result<Rc<DamBreakRun>, String> {
    let key = (scheme.to_string(), per_a);
    if let Some(r) = ctx.dam_breaks.borrow().get(&key) {
        return Ok(r.clone());
    }
    let h = A / per_a as f64;
    let packed = scheme == EXPLICIT_PACKED;
    let deck = if packed { "explicit" } else { scheme };
    let d = load_deck(&format!("martin_moyce_{deck}"), |d| {
        d.grid.cell_size = h;
        d.output.probes[0].position = vec![h / 2.0, h / 2.0];
        if packed {
            d.pressure.density_correction = Some(pmpm::pressure::DensityCorrection::Particles);
        }
    })?;
    let start = std::time::Instant::now();
    let mut out = DamBreakRun {
        t: Vec::new(),
        front: Vec::new(),
        height: Vec::new(),
        volume: Vec::new(),
        fill: Vec::new(),
        mass_exact: true,
        mass: 0.0,
        steps: 0,
        wall_s: 0.0,
    };
    let total = |sim: &pmpm::scheme::Simulation<2>| -> (f64, f64) {
        let ps = &sim.particles;
        let m: f64 = ps.mass.iter().sum();
        let v: f64 = (0..ps.len()).map(|p| ps.volume(p)).sum();
        (m, v)
    };
    let mut m0 = 0.0;
    let mut v0 = 0.0;
    let fill = FillLattice {
        origin: pmpm::grid::Vector::<2>::from_column_slice(&d.grid.origin),
        spacing: pmpm::fill::spacing(&d),
    };
    let mut record = |sim: &pmpm::scheme::Simulation<2>, out: &mut DamBreakRun| {
        // a particle stands for a sub-cell h / 2 wide: the surface is h / 4 beyond its centre
        let ps = &sim.particles;
        let front = ps.x.iter().map(|x| x[0]).fold(0.0, f64::max) + h / 4.0;
        let height =
            ps.x.iter()
                .filter(|x| x[0] < h)
                .map(|x| x[1])
                .fold(0.0, f64::max)
                + h / 4.0;
        let (m, v) = total(sim);
        if out.t.is_empty() {
            m0 = m;
            v0 = v;
        }
        out.mass_exact &= m.to_bits() == m0.to_bits();
        out.t.push(sim.time);
        out.front.push(front / A);
        out.height.push(height / (2.0 * A));
        out.volume.push(v / v0);
        out.fill.push(fill.measure(&ps.x, &ps.volume0));
    };
    let first = pmpm::scheme::Simulation::<2>::new(&d).map_err(|e| e.to_string())?;
    record(&first, &mut out);
    drop(first);
    let sim = run_deck::<2>(&d, |sim, _| {
        record(sim, &mut out);
        true
    })?;
    out.mass = m0;
    out.steps = sim.steps;
    out.wall_s = start.elapsed().as_secs_f64();
    let r = Rc::new(out);
    ctx.dam_breaks.borrow_mut().insert(key, r.clone());
    Ok(r)
}

fn big_t(t: f64) -> f64 {
    t * (2.0 * G / A).sqrt() + T_SHIFT
}

/// The front's signed deviation from Table 2 where it is largest: (T, Z_sim - Z_table).
fn worst_front(r: &DamBreakRun) -> (f64, f64) {
    let bt: Vec<f64> = r.t.iter().map(|&t| big_t(t)).collect();
    reference_table("martin_moyce_1952_n2_2_table2_surge_front")
        .iter()
        .filter(|row| row[0] >= bt[0] && row[0] <= 3.33)
        .map(|row| (row[0], interp(&bt, &r.front, row[0]) - row[1]))
        .fold((0.0, 0.0), |a, b| if b.1.abs() > a.1.abs() { b } else { a })
}

/// Largest deviations from Table 2 (T <= 3.3) and Table 6 (tau <= 3.06), after the shift.
fn against_tables(r: &DamBreakRun) -> (f64, f64) {
    let bt: Vec<f64> = r.t.iter().map(|&t| big_t(t)).collect();
    let tau: Vec<f64> = bt.iter().map(|t| t / 2f64.sqrt()).collect();
    let front = reference_table("martin_moyce_1952_n2_2_table2_surge_front")
        .iter()
        .filter(|row| row[0] >= bt[0] && row[0] <= 3.33)
        .map(|row| (interp(&bt, &r.front, row[0]) - row[1]).abs())
        .fold(0.0, f64::max);
    let height = reference_table("martin_moyce_1952_n2_2_table6_height")
        .iter()
        .filter(|row| row[0] >= tau[0] && row[0] <= 3.06)
        .map(|row| (interp(&tau, &r.height, row[0]) - row[1]).abs())
        .fold(0.0, f64::max);
    (front, height)
}

fn resolutions(quick: bool) -> &'static [u32] {
    if quick {
        &[10, 20]
    } else {
        &[10, 20, 40]
    }
}

/// Title, set-up, metric and bound of `martin_moyce` (`validation/prose/martin_moyce.md`).
fn martin_moyce_header(quick: bool) -> Section {
    let resolutions = resolutions(quick)
        .iter()
        .map(|n| format!("a/{n}"))
        .collect::<Vec<_>>()
        .join(", ");
    prose::section("martin_moyce", &[("resolutions", &resolutions)])
}

/// The notes of `martin_moyce` after the runs' own.
fn martin_moyce_notes() -> [String; 2] {
    ["deviations", "development"].map(|k| prose::note("martin_moyce", k, &[]))
}

/// The notes of `conservation` when the volume of the `scheme` run leaves its band: `dev` its
/// largest deviation, `last` the deviation at the end; the projection's explains it and points
/// to the observations of development runs.
fn volume_notes(scheme: &str, dev: f64, last: f64) -> Vec<String> {
    let proj = scheme == "projection";
    let why = if proj {
        prose::note("conservation", "projection_volume", &[])
    } else {
        String::new()
    };
    let mut notes = vec![prose::note(
        "conservation",
        "volume_band",
        &[
            ("scheme", &scheme),
            ("dev", &pct(dev)),
            ("last", &pct(last)),
            ("why", &why),
        ],
    )];
    if proj {
        notes.push(prose::note("conservation", "development", &[]));
    }
    notes
}

/// Every text of the two cases' prose the code fills (the prose files' test).
#[cfg(test)]
pub(super) fn prose_texts(quick: bool) -> Vec<String> {
    let mut t = martin_moyce_header(quick).texts();
    t.extend(martin_moyce_notes());
    t.extend(prose::section("conservation", &[]).texts());
    t.extend(volume_notes("projection", 0.05, -0.04));
    t.extend(volume_notes("explicit", 0.02, 0.01));
    t
}

/// The Martin & Moyce case.
pub fn martin_moyce(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let mut s = martin_moyce_header(quick);
    let mut fronts = Vec::new();
    let mut heights = Vec::new();
    let t2 = reference_table("martin_moyce_1952_n2_2_table2_surge_front");
    let t6 = reference_table("martin_moyce_1952_n2_2_table6_height");
    fronts.push(Series::markers(
        "Martin & Moyce Table 2",
        t2.iter().map(|r| (r[0], r[1])).collect(),
        colors::REF,
    ));
    heights.push(Series::markers(
        "Martin & Moyce Table 6",
        t6.iter().map(|r| (r[0], r[1])).collect(),
        colors::REF,
    ));
    for scheme in ["projection", "explicit"] {
        for (k, &n) in resolutions(quick).iter().enumerate().rev() {
            let r = dam_break(ctx, scheme, n)?;
            let (f, hd) = against_tables(&r);
            let proj = scheme == "projection";
            let tag = format!("{scheme}, h = a/{n}");
            let bounded = proj && n == 40;
            s.rows.push(Row::bounded(
                format!("{tag}: max |Z - Table 2|, T <= 3.3"),
                f,
                0.2,
                |v| format!("{v:.3}"),
                bounded,
                quick && proj && n == 20,
            ));
            s.rows.push(Row::report(
                format!("{tag}: max |h/2a - Table 6|, tau <= 3.06"),
                format!("{hd:.3}"),
            ));
            s.notes
                .push(format!(
                    "{tag}: {} steps, {:.1} s wall; the front's largest deviation is at T = {:.2}: Z - Table 2 = {:+.3}.",
                    r.steps, r.wall_s, worst_front(&r).0, worst_front(&r).1
                ));
            let color = match (proj, resolutions(quick).len() - 1 - k) {
                (true, 0) => colors::PROJ,
                (true, 1) => colors::PROJ2,
                (true, _) => colors::PROJ3,
                (false, 0) => colors::EXPL,
                (false, 1) => colors::EXPL2,
                (false, _) => colors::EXPL3,
            };
            let bt: Vec<f64> = r.t.iter().map(|&t| big_t(t)).collect();
            fronts.push(Series::line(
                tag.clone(),
                bt.iter().zip(&r.front).map(|(a, b)| (*a, *b)).collect(),
                color,
            ));
            heights.push(Series::line(
                tag,
                bt.iter()
                    .zip(&r.height)
                    .map(|(a, b)| (a / 2f64.sqrt(), *b))
                    .collect(),
                color,
            ));
        }
    }
    s.notes.extend(martin_moyce_notes());
    if quick {
        s.rows.push(Row {
            metric: "projection, h = a/40: max |Z - Table 2|, T <= 3.3".into(),
            bound: "<= 0.200".into(),
            measured: "not run in quick mode".into(),
            verdict: super::Verdict::Skipped,
        });
    }
    save(
        &ctx.opts.out.join("martin_moyce.png"),
        &[
            Panel {
                title: "Surge front (simulated T shifted by +0.175)".into(),
                x_label: "T = t sqrt(2g/a)".into(),
                y_label: "Z = x_front / a".into(),
                series: fronts,
                x_range: Some((0.0, 3.5)),
                y_range: Some((1.0, 4.5)),
                legend_left: true,
                ..Default::default()
            },
            Panel {
                title: "Residual height at the back wall (same shift)".into(),
                x_label: "tau = t sqrt(g/a)".into(),
                y_label: "h / 2a".into(),
                series: heights,
                x_range: Some((0.0, 3.2)),
                y_range: Some((0.2, 1.05)),
                legend_low: true,
                legend_left: true,
            },
        ],
        2,
        750,
        600,
    )?;
    s.figures = vec!["martin_moyce.png".into()];
    Ok(s)
}

/// The rows of the particles' interior fill over a run: its worst step's 99th percentile
/// (<= 1.03) and share of interior nodes within 5 % of 1 (>= 95 %), issue 56's targets, held
/// in the full report where the run corrects its particles (`held`); the worst 1st percentile
/// is reported.
fn fill_rows(s: &mut Section, scheme: &str, r: &DamBreakRun, quick: bool, held: bool) {
    let measured = r.fill.iter().filter(|f| f.nodes > 0);
    let p99 = measured.clone().map(|f| f.p99).fold(f64::NAN, f64::max);
    let p1 = measured.clone().map(|f| f.p1).fold(f64::NAN, f64::min);
    let within = measured.map(|f| f.within).fold(f64::NAN, f64::min);
    let p99_metric = format!("{scheme}: interior fill p99, worst step");
    let within_metric = format!("{scheme}: interior nodes with fill within 5 % of 1, worst step");
    let share = |v: f64| format!("{:.1}%", 100.0 * v);
    if held {
        let fmt = |v: f64| format!("{v:.3}");
        s.rows
            .push(Row::bounded(p99_metric, p99, 1.03, fmt, !quick, quick));
        s.rows.push(Row::at_least(
            within_metric,
            within,
            0.95,
            share,
            !quick,
            quick,
        ));
    } else {
        s.rows.push(Row::report(p99_metric, format!("{p99:.3}")));
        s.rows.push(Row::report(within_metric, share(within)));
    }
    s.rows.push(Row::report(
        format!("{scheme}: interior fill p1, worst step"),
        format!("{p1:.3}"),
    ));
}

/// A conservation run's colour in the figures.
fn color(scheme: &str) -> plotters::style::RGBColor {
    match scheme {
        "projection" => colors::PROJ,
        "explicit" => colors::EXPL,
        _ => colors::EXPL2,
    }
}

/// Mass and volume over the h = a/20 dam breaks.
pub fn conservation(ctx: &Ctx) -> Result<Section, String> {
    let mut s = prose::section("conservation", &[]);
    let mut series = Vec::new();
    let mut fills = Vec::new();
    // the explicit scheme's default packs nothing: its fill is reported, the packed twin's held
    for scheme in ["projection", "explicit", EXPLICIT_PACKED] {
        let r = dam_break(ctx, scheme, 20)?;
        s.rows.push(Row {
            metric: format!("{scheme}: total mass bitwise constant"),
            bound: "exact".into(),
            measured: if r.mass_exact {
                format!("exact ({:.6} kg/m)", r.mass)
            } else {
                "changed".into()
            },
            verdict: if r.mass_exact {
                super::Verdict::Pass
            } else {
                super::Verdict::Fail
            },
        });
        let dev = r.volume.iter().map(|v| (v - 1.0).abs()).fold(0.0, f64::max);
        if dev > 0.01 {
            let last = r.volume.last().copied().unwrap_or(1.0) - 1.0;
            s.notes.extend(volume_notes(scheme, dev, last));
        }
        s.rows.push(Row::bounded(
            format!("{scheme}: max |V/V0 - 1| over the run"),
            dev,
            0.01,
            pct,
            true,
            false,
        ));
        fill_rows(&mut s, scheme, &r, ctx.opts.quick, scheme != "explicit");
        fills.push(Series::line(
            scheme,
            r.t.iter()
                .zip(&r.fill)
                .filter(|(_, f)| f.nodes > 0)
                .map(|(t, f)| (big_t(*t) - T_SHIFT, f.p99))
                .collect(),
            color(scheme),
        ));
        series.push(Series::line(
            scheme,
            r.t.iter()
                .zip(&r.volume)
                .map(|(t, v)| (big_t(*t) - T_SHIFT, 100.0 * (v - 1.0)))
                .collect(),
            color(scheme),
        ));
    }
    save(
        &ctx.opts.out.join("conservation.png"),
        &[
            Panel {
                title: "Total volume sum V0 J over the dam break, h = a/20".into(),
                x_label: "T = t sqrt(2g/a) (unshifted)".into(),
                y_label: "V / V(0) - 1 (%)".into(),
                series,
                legend_left: true,
                legend_low: true,
                ..Default::default()
            },
            Panel {
                title: "Interior fill, 99th percentile (positions alone, not J)".into(),
                x_label: "T = t sqrt(2g/a) (unshifted)".into(),
                y_label: "fill p99".into(),
                series: fills,
                legend_left: true,
                ..Default::default()
            },
        ],
        2,
        900,
        500,
    )?;
    s.figures = vec!["conservation.png".into()];
    Ok(s)
}
