//! Martin & Moyce (1952) dam break, n^2 = 2, against Tables 2 and 6; mass and volume over it.

use super::plot::{colors, save, Panel, Series};
use super::{interp, load_deck, pct, reference_table, run_deck, Ctx, Row, Section};
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
    /// Whether the total mass kept its bits at every step.
    pub mass_exact: bool,
    /// Total mass.
    pub mass: f64,
    /// Steps.
    pub steps: u64,
    /// Wall time (s).
    pub wall_s: f64,
}

/// Runs (or reuses) the dam break with `scheme` at h = a / `per_a`.
fn dam_break(ctx: &Ctx, scheme: &str, per_a: u32) -> Result<Rc<DamBreakRun>, String> {
    let key = (scheme.to_string(), per_a);
    if let Some(r) = ctx.dam_breaks.borrow().get(&key) {
        return Ok(r.clone());
    }
    let h = A / per_a as f64;
    let d = load_deck(&format!("martin_moyce_{scheme}"), |d| {
        d.grid.cell_size = h;
        d.output.probes[0].position = vec![h / 2.0, h / 2.0];
    })?;
    let start = std::time::Instant::now();
    let mut out = DamBreakRun {
        t: Vec::new(),
        front: Vec::new(),
        height: Vec::new(),
        volume: Vec::new(),
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

/// The Martin & Moyce case.
pub fn martin_moyce(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let mut s = Section {
        title: "Martin & Moyce (1952) dam break, n^2 = 2: surge front and residual height".into(),
        setup: format!(
            "A water column a = 0.05715 m wide and 2a high at the back wall of a tank 8a x 3a, slip walls all round, 2x2 particles per cell, linear shape functions, to t = 0.25 s (T = 4.6). Projection (`validation/decks/martin_moyce_projection.toml`): APIC, cfl 0.5, Jacobi-PCG to 1e-8. Explicit (`martin_moyce_explicit.toml`): K for c = 10 sqrt(2 g 2a) = 15 m/s, FLIP 0.99, cfl 0.4. Resolutions h = {} (the case sets `cell_size`; the quick mode runs a/10 and a/20 only).",
            resolutions(quick).iter().map(|n| format!("a/{n}")).collect::<Vec<_>>().join(", ")
        ),
        metric: "Surge front Z = (largest particle x + h/4) / a against Table 2 (T = t sqrt(2g/a) <= 3.3) and residual height at the back wall (highest particle within h of the wall + h/4) / 2a against Table 6 (tau = t sqrt(g/a) <= 3.06); largest absolute deviation over the table points, the simulation interpolated linearly in time. The simulated T is shifted by +0.175 for both schemes (the gate's opening time, as the reference data's README and Lethe do); tables in `validation/reference/` with their source lines.".into(),
        bound: "Projection at h = a/40: front within +-0.2 of Table 2 (the issue). Heights and the other resolutions and the explicit scheme: reported.".into(),
        ..Default::default()
    };
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
    s.notes.push("Both schemes' fronts run ahead of Table 2 (figure), the projection's a little more than the explicit's, and more the finer the grid (a/10, a/20, a/40 in the table): the largest deviations sit at the surge's acceleration (T = 1.2 to 1.6) and at its end (T = 3.3). A plausible cause, not tested here: the experiment's front is slowed by the bed and by the gate's lift, which slip walls and a single +0.175 time shift do not model. The bound (+-0.2 at a/40, from the issue) is kept; where the projection at a/40 exceeds it the case fails.".into());
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

/// Mass and volume over the h = a/20 dam breaks.
pub fn conservation(ctx: &Ctx) -> Result<Section, String> {
    let mut s = Section {
        title: "Conservation over the Martin & Moyce dam break (h = a/20, both schemes)".into(),
        setup: "The h = a/20 runs of the `martin_moyce` case (shared when both cases run), to t = 0.25 s.".into(),
        metric: "Total particle mass sum m_p after every step against its initial value, compared bit for bit (the particles' masses are never changed, so it is exact by construction); total volume sum V0_p J_p after every step against its initial value: largest |V / V(0) - 1|.".into(),
        bound: "Mass: exactly constant (bitwise). Volume: within 1% of the initial at all frames (the issue); checked at every step, which includes every frame.".into(),
        ..Default::default()
    };
    let mut series = Vec::new();
    for scheme in ["projection", "explicit"] {
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
            s.notes.push(format!(
                "{scheme}: the total volume leaves its 1% band (largest deviation {}, {} at the end). The mass is exact, so this is the particles' J, which is integrated from the velocity gradient at the particle (F <- (I + dt L_p) F). {}",
                pct(dev),
                pct(last),
                if scheme == "projection" {
                    "The projection makes the grid velocity divergence-free in the weak, nodal sense (docs/method.md), and only on the rows of interior nodes: a node next to a cell below the volume-fraction tolerance holds p = 0 and no incompressibility condition. Where the flow is at most two cells thick, as in the surge tip, every node is such a node and the particles compress freely. Measured on the example dam_break_2d.toml (h = a/20) at t = 0.1 s (T = 1.85): 136 of 3,200 particles have J < 0.9, all within about one cell of the surface in the last 10 cells of the tip, the lowest at J = 0.45; the volume loss grows steadily once the surge spreads (T > 0.5). The scheme's pressure does not depend on J, so nothing pushes it back. Tried and not kept: a volume-correction source alpha (V0/V - 1)/dt in the Poisson right-hand side (the cell's particles' volume error) held the total within 0.3% until the impact on the far wall (t = 0.34 s), then blew the run up at the splash for every alpha from 0.1 to 1 (with the error clipped at 0.1, 0.5 or 1 the runs reach the end, but the largest volume error over the run ranged from 1.5% to 30 times the initial volume, with no monotone trend in alpha or the clip). It cannot act where the loss is, in the p = 0 layer; a sub-cell free-surface condition (ghost-fluid p = 0 at the interface rather than at the nodes) is the remedy to try."
                } else {
                    ""
                }
            ));
        }
        s.rows.push(Row::bounded(
            format!("{scheme}: max |V/V0 - 1| over the run"),
            dev,
            0.01,
            pct,
            true,
            false,
        ));
        series.push(Series::line(
            scheme,
            r.t.iter()
                .zip(&r.volume)
                .map(|(t, v)| (big_t(*t) - T_SHIFT, 100.0 * (v - 1.0)))
                .collect(),
            if scheme == "projection" {
                colors::PROJ
            } else {
                colors::EXPL
            },
        ));
    }
    save(
        &ctx.opts.out.join("conservation.png"),
        &[Panel {
            title: "Total volume sum V0 J over the dam break, h = a/20".into(),
            x_label: "T = t sqrt(2g/a) (unshifted)".into(),
            y_label: "V / V(0) - 1 (%)".into(),
            series,
            legend_left: true,
            legend_low: true,
            ..Default::default()
        }],
        1,
        900,
        500,
    )?;
    s.figures = vec!["conservation.png".into()];
    Ok(s)
}
