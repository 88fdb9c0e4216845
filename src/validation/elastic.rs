//! Elastic solids (`neo_hookean_incompressible`), both schemes: a free-standing column under its
//! own weight against the small-strain solution, and a spinning block's volume over a full turn.
//!
//! The column: uniaxial stress sigma_yy = -rho g (H - y), sigma_xx = 0. In 2D plane strain the
//! top settles by u = rho g H^2 / (2 E') with E' = E / (1 - nu^2), 4 G when incompressible
//! (nu = 1/2, E = 3 G), so u = rho g H^2 / (8 G) (3D: E = 3 G, u = rho g H^2 / (6 G)). With the
//! explicit scheme's finite K the 2D law is sigma = (K - G) tr(eps) I + 2 G eps (p = K (1 - J)
//! with the in-plane J, tau = G dev2(b)): K acts as the in-plane bulk modulus lambda + mu, and
//! E' = 4 G K / (K + G), which is the plane-strain E / (1 - nu^2) of a 3D solid with
//! K_3D = K - G / 3.

use super::plot::{colors, save, Panel, Series};
use super::{load_deck, pct, prose, run_deck, sci, Ctx, Row, Section, Verdict};
use pmpm::deck::{BoundaryKind, BoundarySpec, Deck, PressureUnknowns};
use pmpm::scheme::Simulation;

const RHO: f64 = 1000.0;
const GRAV: f64 = 9.81;
const H: f64 = 1.0;
/// rho g H / G of the column.
const LOAD: f64 = 0.01;
/// Centre of the column's base (m), moved so that its sides lie on grid lines.
const X0: f64 = 0.25;

/// Small-strain top displacement of the 2D column (m, positive down): rho g H^2 / (2 E'),
/// E' = 4 G K / (K + G), or 4 G when `bulk` is None (incompressible).
pub fn column_top_displacement(shear: f64, bulk: Option<f64>) -> f64 {
    let e = match bulk {
        Some(k) => 4.0 * shear * k / (k + shear),
        None => 4.0 * shear,
    };
    RHO * GRAV * H * H / (2.0 * e)
}

struct Column {
    /// Mean settlement of the top row of particles at the end (m, positive down).
    u: f64,
    /// Its rate over the last quarter of the run (m/s, positive down).
    creep: f64,
    /// sum J V0 / sum V0 - 1 at the end.
    volume: f64,
    /// (t, u / u_incompressible).
    history: Vec<(f64, f64)>,
}

/// The column deck of `scheme` with width `w`, cell size `h`, the floor `no_slip` or slip.
fn column_deck(scheme: &str, w: f64, h: f64, no_slip: bool) -> Result<Deck, String> {
    load_deck(&format!("elastic_column_{scheme}"), |d| {
        d.grid.cell_size = h;
        // the sides on grid lines: with the projection a column whose sides cut its cells in
        // half swelled instead of settling (measured: +1.2% volume in 0.16 s at W = 0.2 m,
        // h = 0.02 m)
        let left = ((X0 - w / 2.0) / h).round() * h;
        d.bodies[0].shape.min = Some(vec![left, 0.0]);
        d.bodies[0].shape.max = Some(vec![left + w, H]);
        if !no_slip {
            d.grid.boundary.y_min = Some(BoundarySpec::Kind(BoundaryKind::Slip));
        }
    })
}

fn column(d: &Deck) -> Result<Column, String> {
    let shear = RHO * GRAV * H / LOAD;
    let exact = column_top_displacement(shear, None);
    let sim0 = Simulation::<2>::new(d).map_err(|e| e.to_string())?;
    let ps = &sim0.particles;
    let top_y = ps.x.iter().map(|x| x[1]).fold(f64::NEG_INFINITY, f64::max);
    // ids of the top row and their starting heights (ids are places before the first sort)
    let top: Vec<(usize, f64)> = (0..ps.len())
        .filter(|&p| (ps.x[p][1] - top_y).abs() < 1e-9)
        .map(|p| (ps.id[p] as usize, ps.x[p][1]))
        .collect();
    drop(sim0);
    let settle = |sim: &Simulation<2>| {
        let at = sim.particles.places();
        top.iter()
            .map(|&(id, y0)| y0 - sim.particles.x[at[id]][1])
            .sum::<f64>()
            / top.len() as f64
    };
    let end = d.simulation.end_time;
    let mut history = vec![(0.0, 0.0)];
    let mut next = 0.0;
    let mut at_three_quarters = None;
    let sim = run_deck::<2>(d, |sim, _| {
        if sim.time >= next - 1e-12 {
            history.push((sim.time, settle(sim) / exact));
            next += end / 200.0;
        }
        if at_three_quarters.is_none() && sim.time >= 0.75 * end {
            at_three_quarters = Some((sim.time, settle(sim)));
        }
        true
    })?;
    let u = settle(&sim);
    let (t1, u1) = at_three_quarters.unwrap_or((sim.time, u));
    let ps = &sim.particles;
    let v0: f64 = ps.volume0.iter().sum();
    let v: f64 = (0..ps.len()).map(|p| ps.volume(p)).sum();
    Ok(Column {
        u,
        creep: if sim.time > t1 {
            (u - u1) / (sim.time - t1)
        } else {
            0.0
        },
        volume: v / v0 - 1.0,
        history,
    })
}

struct Spin {
    /// Largest |sum J V0 / sum V0 - 1| over the run.
    jacobian: f64,
    /// Largest |A / A0 - 1| of the polygon through the boundary particles.
    polygon: f64,
    /// Turns of a boundary particle about the centroid.
    turns: f64,
    /// (turns, sum J V0 / V0 - 1).
    jacobian_series: Vec<(f64, f64)>,
    /// (turns, A / A0 - 1).
    polygon_series: Vec<(f64, f64)>,
}

fn spin(d: &Deck) -> Result<Spin, String> {
    let sim0 = Simulation::<2>::new(d).map_err(|e| e.to_string())?;
    let ps = &sim0.particles;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for x in &ps.x {
        for k in 0..2 {
            lo[k] = lo[k].min(x[k]);
            hi[k] = hi[k].max(x[k]);
        }
    }
    let n = ps.len() as f64;
    let c0 =
        ps.x.iter()
            .fold([0.0; 2], |a, x| [a[0] + x[0] / n, a[1] + x[1] / n]);
    // the outer ring of the particle lattice, by id, in order of angle about the centre
    let mut ring: Vec<(usize, f64)> = (0..ps.len())
        .filter(|&p| {
            (0..2).any(|k| (ps.x[p][k] - lo[k]).abs() < 1e-9 || (ps.x[p][k] - hi[k]).abs() < 1e-9)
        })
        .map(|p| {
            (
                ps.id[p] as usize,
                (ps.x[p][1] - c0[1]).atan2(ps.x[p][0] - c0[0]),
            )
        })
        .collect();
    ring.sort_by(|a, b| a.1.total_cmp(&b.1));
    let ring: Vec<usize> = ring.into_iter().map(|r| r.0).collect();
    let v0: f64 = ps.volume0.iter().sum();
    drop(sim0);
    let measure = |sim: &Simulation<2>| {
        let ps = &sim.particles;
        let at = ps.places();
        let mut area = 0.0;
        for k in 0..ring.len() {
            let a = ps.x[at[ring[k]]];
            let b = ps.x[at[ring[(k + 1) % ring.len()]]];
            area += a[0] * b[1] - b[0] * a[1];
        }
        let n = ps.len() as f64;
        let c =
            ps.x.iter()
                .fold([0.0; 2], |a, x| [a[0] + x[0] / n, a[1] + x[1] / n]);
        let m = ps.x[at[ring[0]]];
        let angle = (m[1] - c[1]).atan2(m[0] - c[0]);
        let v: f64 = (0..ps.len()).map(|p| ps.volume(p)).sum();
        (v / v0 - 1.0, area / 2.0, angle)
    };
    let sim0 = Simulation::<2>::new(d).map_err(|e| e.to_string())?;
    let (_, a0, mut last_angle) = measure(&sim0);
    drop(sim0);
    let mut out = Spin {
        jacobian: 0.0,
        polygon: 0.0,
        turns: 0.0,
        jacobian_series: vec![(0.0, 0.0)],
        polygon_series: vec![(0.0, 0.0)],
    };
    let mut swept = 0.0;
    let mut next = 0.0;
    run_deck::<2>(d, |sim, _| {
        let (dv, area, angle) = measure(sim);
        let mut da = angle - last_angle;
        da -= (da / std::f64::consts::TAU).round() * std::f64::consts::TAU;
        swept += da;
        last_angle = angle;
        let da_rel = area / a0 - 1.0;
        out.jacobian = out.jacobian.max(dv.abs());
        out.polygon = out.polygon.max(da_rel.abs());
        let turns = swept / std::f64::consts::TAU;
        if sim.time >= next - 1e-12 {
            out.jacobian_series.push((turns, dv));
            out.polygon_series.push((turns, da_rel));
            next += d.simulation.end_time / 200.0;
        }
        true
    })?;
    out.turns = swept / std::f64::consts::TAU;
    Ok(out)
}

/// (W, h) of the slender column (H / W = 10) and the stubby one (H / W = 5), 10 cells across;
/// quick mode: the slender one at 5 cells across.
fn columns_wh(quick: bool) -> ((f64, f64), (f64, f64)) {
    let slender = if quick { (0.1, 0.02) } else { (0.1, 0.01) };
    (slender, (0.2, 0.02))
}

/// Title, set-up, metric and bound (`validation/prose/elastic.md`).
fn header(quick: bool) -> Section {
    let quick_note = if quick {
        " Quick mode: the H / W = 10 column at h = 0.02 m (5 cells across)."
    } else {
        ""
    };
    let (slender, _) = columns_wh(quick);
    prose::section("elastic", &[("h", &slender.1), ("quick", &quick_note)])
}

/// The column's notes after the runs' own: the projection with one pressure per cell and
/// with the nodal pressure, the observations of development runs.
fn column_notes() -> [String; 3] {
    ["cells", "nodal", "development"].map(|k| prose::note("elastic", k, &[]))
}

/// Every text of the case's prose the code fills (the prose file's test).
#[cfg(test)]
pub(super) fn prose_texts(quick: bool) -> Vec<String> {
    let mut t = header(quick).texts();
    t.extend(column_notes());
    t.push(prose::note("elastic", "spin", &[]));
    t
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let (slender, stubby) = columns_wh(quick);
    let mut s = header(quick);
    columns(ctx, &mut s, slender, stubby)?;
    spinning_block(ctx, &mut s)?;
    s.figures = vec!["elastic_column.png".into(), "elastic_spin.png".into()];
    Ok(s)
}

/// The column's rows, notes and figure: both schemes at both slendernesses on both floors,
/// then the nodal pressure and its volume correction. `slender` and `stubby` are (W, h).
fn columns(
    ctx: &Ctx,
    s: &mut Section,
    slender: (f64, f64),
    stubby: (f64, f64),
) -> Result<(), String> {
    let quick = ctx.opts.quick;
    let shear = RHO * GRAV * H / LOAD;
    let exact = column_top_displacement(shear, None);
    let mut hist_series = Vec::new();
    for scheme in ["explicit", "projection"] {
        let proj = scheme == "projection";
        let bulk = if proj { None } else { Some(100.0 * shear) };
        let target = column_top_displacement(shear, bulk);
        let mut runs = Vec::new();
        for (label, (w, h), no_slip) in [
            ("H/W = 10, no-slip floor", slender, true),
            ("H/W = 10, slip floor", slender, false),
            ("H/W = 5, no-slip floor", stubby, true),
            ("H/W = 5, slip floor", stubby, false),
        ] {
            let c = column(&column_deck(scheme, w, h, no_slip)?)?;
            let err = c.u / target - 1.0;
            runs.push((label, c, err));
        }
        let (_, main, err) = &runs[0];
        s.rows.push(Row::bounded(
            format!("{scheme}: column H/W = 10, no-slip floor, |u_top / u_analytic - 1|"),
            err.abs(),
            0.05,
            pct,
            // the quick grid holds the projection to the same bound (2.7 % measured); the
            // explicit column there is 5.5 % off, a coarse grid's error, so it is reported
            !quick || scheme == "projection",
            quick,
        ));
        s.rows.push(Row::report(
            format!(
                "{scheme}: column H/W = 10, no-slip floor, u_top (analytic {})",
                sci(target)
            ),
            format!("{} m", sci(main.u)),
        ));
        for (label, _, err) in &runs[1..] {
            s.rows.push(Row::report(
                format!("{scheme}: column {label}, u_top / u_analytic - 1"),
                pct(*err),
            ));
        }
        for (label, c, _) in &runs {
            s.rows.push(Row::report(
                format!(
                    "{scheme}: column {label}, creep over the last quarter (m/s); volume change"
                ),
                format!("{}; {}", sci(c.creep), pct(c.volume)),
            ));
        }
        let floor = runs[0].1.u / runs[1].1.u - 1.0;
        let floor5 = runs[2].1.u / runs[3].1.u - 1.0;
        s.notes.push(format!(
            "{scheme}: the no-slip floor changes the settlement by {} at H/W = 10 and {} at H/W = 5 (no-slip against slip floor, same scheme and resolution){}.",
            pct(floor),
            pct(floor5),
            if proj { "" } else { "; the slip-floor column, whose small-strain solution is the uniaxial one up to terms of order (W / H)^2, measures the solver against the analytic value" }
        ));
        let colour = if proj { colors::PROJ } else { colors::EXPL };
        let colour2 = if proj { colors::PROJ2 } else { colors::EXPL2 };
        let mut runs = runs.into_iter();
        let (l0, c0, _) = runs.next().expect("four runs");
        let (l1, c1, _) = runs.next().expect("four runs");
        hist_series.push(Series::line(format!("{scheme}, {l0}"), c0.history, colour));
        hist_series.push(Series::line(format!("{scheme}, {l1}"), c1.history, colour2));
        if !proj {
            hist_series.push(Series::line(
                "analytic, K = 100 G",
                vec![(0.0, target / exact), (0.16, target / exact)],
                colors::REF,
            ));
        }
    }
    nodal_columns(s, slender, &mut hist_series)?;
    hist_series.push(Series::line(
        "analytic, incompressible",
        vec![(0.0, 1.0), (0.16, 1.0)],
        colors::REF,
    ));
    s.notes.extend(column_notes());
    save(
        &ctx.opts.out.join("elastic_column.png"),
        &[Panel {
            title: "Elastic column: settlement of the top, H/W = 10".into(),
            x_label: "t (s)".into(),
            y_label: "u_top / (rho g H^2 / 8 G)".into(),
            series: hist_series,
            y_range: Some((0.0, 2.5)),
            ..Default::default()
        }],
        1,
        900,
        550,
    )?;
    Ok(())
}

/// The spinning block's rows, note and figure, both schemes.
fn spinning_block(ctx: &Ctx, s: &mut Section) -> Result<(), String> {
    let mut vol_series = Vec::new();
    for scheme in ["explicit", "projection"] {
        let proj = scheme == "projection";
        let r = spin(&load_deck(&format!("elastic_spin_{scheme}"), |_| {})?)?;
        s.rows.push(Row::bounded(
            format!("{scheme}: spinning block, max |sum J V0 / V0 - 1|"),
            r.jacobian,
            0.01,
            pct,
            true,
            false,
        ));
        s.rows.push(Row::bounded(
            format!("{scheme}: spinning block, max |boundary polygon area / A0 - 1|"),
            r.polygon,
            0.01,
            pct,
            true,
            false,
        ));
        s.rows.push(Row {
            metric: format!("{scheme}: spinning block, turns made"),
            bound: ">= 1".into(),
            measured: format!("{:.2}", r.turns),
            verdict: if r.turns >= 1.0 {
                Verdict::Pass
            } else {
                Verdict::Fail
            },
        });
        let (c, c2) = if proj {
            (colors::PROJ, colors::PROJ2)
        } else {
            (colors::EXPL, colors::EXPL2)
        };
        vol_series.push(Series::line(
            format!("{scheme}: sum J V0"),
            r.jacobian_series,
            c,
        ));
        vol_series.push(Series::line(
            format!("{scheme}: boundary polygon"),
            r.polygon_series,
            c2,
        ));
    }
    s.notes.push(prose::note("elastic", "spin", &[]));
    save(
        &ctx.opts.out.join("elastic_spin.png"),
        &[Panel {
            title: "Spinning elastic block: volume against turns".into(),
            x_label: "turns".into(),
            y_label: "V / V0 - 1".into(),
            series: vol_series,
            ..Default::default()
        }],
        1,
        900,
        550,
    )?;
    Ok(())
}

/// The projection's column with the nodal pressure (the default), which never comes to rest,
/// and with its volume correction: rows of `s`, and a line of `hist_series`.
fn nodal_columns(
    s: &mut Section,
    slender: (f64, f64),
    hist_series: &mut Vec<Series>,
) -> Result<(), String> {
    let shear = RHO * GRAV * H / LOAD;
    let exact_u = column_top_displacement(shear, None);
    let mut nodal = column_deck("projection", slender.0, slender.1, true)?;
    nodal.pressure.unknowns = PressureUnknowns::Nodes;
    nodal.simulation.stress_update = pmpm::deck::StressUpdate::Musl;
    // settlement error, creep and volume change of a column run, in one cell
    let summary = |c: &Column| {
        format!(
            "{}; {}; {}",
            pct(c.u / exact_u - 1.0),
            sci(c.creep),
            pct(c.volume)
        )
    };
    let c = column(&nodal)?;
    s.rows.push(Row::report(
        "projection, unknowns = \"nodes\": column H/W = 10, no-slip floor: u_top / u_analytic - 1; creep over the last quarter (m/s); volume change",
        summary(&c),
    ));
    hist_series.push(Series::line(
        "projection, unknowns = \"nodes\", H/W = 10, no-slip floor",
        c.history,
        colors::PROJ3,
    ));
    // the particles' J fed back into the nodal projection (`pressure.volume_correction`, off
    // by default): it stops the creep, but where the column comes to rest depends on alpha
    for alpha in [0.03, 0.1] {
        let mut d = nodal.clone();
        d.pressure.volume_correction = alpha;
        d.simulation.end_time = 0.4;
        let c = column(&d)?;
        s.rows.push(Row::report(
            format!(
                "projection, volume_correction = {alpha}: column H/W = 10, no-slip floor, to t = 0.4 s: u_top / u_analytic - 1; creep over the last quarter (m/s); volume change"
            ),
            summary(&c),
        ));
    }
    Ok(())
}
