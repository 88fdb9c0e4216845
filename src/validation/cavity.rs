//! Lid-driven cavity at Re = 100 and 1000 against Ghia, Ghia & Shin (1982), Tables I and II.

use super::plot::{colors, save, Panel, Series};
use super::{load_deck, prose, reference_table, run_deck, Ctx, Row, Section};
use pmpm::deck::ProbeDeck;

struct Run {
    /// Ghia points used (interior only): (y, u_ghia, u_sim) and (x, v_ghia, v_sim).
    u: Vec<(f64, f64, f64)>,
    v: Vec<(f64, f64, f64)>,
    /// Dense lines: (y, u) and (x, v).
    u_line: Vec<(f64, f64)>,
    v_line: Vec<(f64, f64)>,
    /// Relative change of the kinetic energy over the last unit of time.
    ke_rate: f64,
    t_end: f64,
    steady_at: Option<f64>,
    steps: u64,
    wall_s: f64,
}

/// Ghia's interior points of `table` (the wall points are boundary values, not results).
fn interior(table: &[Vec<f64>]) -> Vec<(f64, f64)> {
    table
        .iter()
        .filter(|r| r[1] > 1e-9 && r[1] < 1.0 - 1e-9)
        .map(|r| (r[1], r[2]))
        .collect()
}

fn simulate(re: u32, h: f64, end: f64) -> Result<Run, String> {
    let gu = interior(&reference_table(&format!(
        "ghia_1982_re{re}_u_vertical_centerline"
    )));
    let gv = interior(&reference_table(&format!(
        "ghia_1982_re{re}_v_horizontal_centerline"
    )));
    let dense: Vec<f64> = (1..50).map(|i| i as f64 / 50.0).collect();
    let d = load_deck(&format!("cavity_re{re}"), |d| {
        d.grid.cell_size = h;
        d.simulation.end_time = end;
        // the lid's speed (U = 1) does not enter the adaptive step: cap it at cfl h / U
        d.simulation.max_dt = Some(0.5 * h);
        let mut add = |name: String, x: f64, y: f64| {
            d.output.probes.push(ProbeDeck {
                name,
                position: vec![x, y],
                sample: Default::default(),
                radius: None,
            })
        };
        for (i, (y, _)) in gu.iter().enumerate() {
            add(format!("gu{i}"), 0.5, *y);
        }
        for (i, (x, _)) in gv.iter().enumerate() {
            add(format!("gv{i}"), *x, 0.5);
        }
        for (i, s) in dense.iter().enumerate() {
            add(format!("lu{i}"), 0.5, *s);
            add(format!("lv{i}"), *s, 0.5);
        }
    })?;
    let start = std::time::Instant::now();
    // kinetic energy at whole units of time, to test for a steady state
    let mut ke_marks: Vec<f64> = Vec::new();
    let mut steady_at = None;
    let mut last_values = Vec::new();
    let sim = run_deck::<2>(&d, |sim, _| {
        last_values.clone_from(&sim.probes.values);
        if sim.time >= ke_marks.len() as f64 {
            ke_marks.push(sim.kinetic_energy());
            let n = ke_marks.len();
            if n >= 3 {
                let rate = (ke_marks[n - 1] - ke_marks[n - 2]).abs() / ke_marks[n - 1];
                if rate < 1e-6 {
                    steady_at = Some(sim.time);
                    return false;
                }
            }
        }
        true
    })?;
    let n = ke_marks.len();
    let ke_rate = if n >= 2 {
        (ke_marks[n - 1] - ke_marks[n - 2]).abs() / ke_marks[n - 1]
    } else {
        f64::NAN
    };
    // probe layout: per probe pressure, vx, vy
    let val = |k: usize, c: usize| last_values[3 * k + c];
    let u: Vec<(f64, f64, f64)> = gu
        .iter()
        .enumerate()
        .map(|(i, &(y, g))| (y, g, val(i, 1)))
        .collect();
    let off = gu.len();
    let v: Vec<(f64, f64, f64)> = gv
        .iter()
        .enumerate()
        .map(|(i, &(x, g))| (x, g, val(off + i, 2)))
        .collect();
    let off = gu.len() + gv.len();
    let u_line = dense
        .iter()
        .enumerate()
        .map(|(i, &s)| (val(off + 2 * i, 1), s))
        .collect();
    let v_line = dense
        .iter()
        .enumerate()
        .map(|(i, &s)| (s, val(off + 2 * i + 1, 2)))
        .collect();
    Ok(Run {
        u,
        v,
        u_line,
        v_line,
        ke_rate,
        t_end: sim.time,
        steady_at,
        steps: sim.steps,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// Cell size and the end times of the Re = 100 and 1000 runs.
fn resolution(quick: bool) -> (f64, f64, f64) {
    if quick {
        (1.0 / 32.0, 10.0, 10.0)
    } else {
        (1.0 / 64.0, 20.0, 40.0)
    }
}

/// Title, set-up, metric and bound (`validation/prose/cavity.md`).
fn header(quick: bool) -> Section {
    let (h, end100, end1000) = resolution(quick);
    let quick_note = if quick {
        ", quick mode (the full run uses h = 1/64)"
    } else {
        ""
    };
    prose::section(
        "cavity",
        &[
            ("h_inv", &format!("{:.0}", 1.0 / h)),
            ("quick", &quick_note),
            ("end100", &end100),
            ("end1000", &end1000),
        ],
    )
}

/// The notes before the runs' own.
fn opening_notes() -> [String; 2] {
    ["shape_functions", "development"].map(|k| prose::note("cavity", k, &[]))
}

/// Every text of the case's prose the code fills (the prose file's test).
#[cfg(test)]
pub(super) fn prose_texts(quick: bool) -> Vec<String> {
    let mut t = header(quick).texts();
    t.extend(opening_notes());
    t
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let (h, end100, end1000) = resolution(quick);
    let mut s = header(quick);
    s.notes.extend(opening_notes());
    let mut panels = Vec::new();
    for (re, end) in [(100u32, end100), (1000, end1000)] {
        let r = simulate(re, h, end)?;
        let dev =
            r.u.iter()
                .chain(&r.v)
                .map(|(_, g, v)| (v - g).abs())
                .fold(0.0, f64::max);
        s.rows.push(Row::bounded(
            format!(
                "Re = {re}, h = 1/{:.0}: max |u - Ghia|, |v - Ghia| / U",
                1.0 / h
            ),
            dev,
            0.05,
            |v| format!("{v:.3}"),
            re == 100 && !quick,
            quick && re == 100,
        ));
        s.rows.push(Row::report(
            format!("Re = {re}: relative change of kinetic energy over the last unit of time"),
            format!("{:.1e} (t = {:.1})", r.ke_rate, r.t_end),
        ));
        let worst =
            r.u.iter()
                .map(|&(c, g, v)| ("u at y", c, g, v))
                .chain(r.v.iter().map(|&(c, g, v)| ("v at x", c, g, v)))
                .fold(("", 0.0f64, 0.0f64, 0.0f64), |w, q| {
                    if (q.3 - q.2).abs() > (w.3 - w.2).abs() {
                        q
                    } else {
                        w
                    }
                });
        s.notes.push(format!(
            "Re = {re}: {} steps, {:.0} s wall; {}. Largest deviation: {} = {:.4}, {:.3} against Ghia's {:.3}.",
            r.steps,
            r.wall_s,
            match r.steady_at {
                Some(t) => format!("steady (kinetic energy change < 1e-6 per unit time) at t = {t:.1}"),
                None => format!("not steady by that test at t = {:.1}; the last relative change per unit time was {:.1e}", r.t_end, r.ke_rate),
            },
            worst.0,
            worst.1,
            worst.3,
            worst.2,
        ));
        let gu = reference_table(&format!("ghia_1982_re{re}_u_vertical_centerline"));
        let gv = reference_table(&format!("ghia_1982_re{re}_v_horizontal_centerline"));
        panels.push(Panel {
            title: format!("Re = {re}: u on x = 0.5"),
            x_label: "u / U".into(),
            y_label: "y".into(),
            series: vec![
                Series::markers(
                    "Ghia et al. (1982)",
                    gu.iter().map(|r| (r[2], r[1])).collect(),
                    colors::REF,
                ),
                Series::line(
                    format!("pmpm projection, h = 1/{:.0}", 1.0 / h),
                    r.u_line,
                    colors::PROJ,
                ),
            ],
            x_range: Some((-0.6, 1.05)),
            y_range: Some((0.0, 1.0)),
            legend_low: true,
            ..Default::default()
        });
        panels.push(Panel {
            title: format!("Re = {re}: v on y = 0.5"),
            x_label: "x".into(),
            y_label: "v / U".into(),
            series: vec![
                Series::markers(
                    "Ghia et al. (1982)",
                    gv.iter().map(|r| (r[1], r[2])).collect(),
                    colors::REF,
                ),
                Series::line(
                    format!("pmpm projection, h = 1/{:.0}", 1.0 / h),
                    r.v_line,
                    colors::PROJ,
                ),
            ],
            x_range: Some((0.0, 1.0)),
            y_range: Some((-0.6, 0.45)),
            legend_low: true,
            legend_left: true,
        });
    }
    save(&ctx.opts.out.join("cavity.png"), &panels, 2, 650, 550)?;
    s.figures = vec!["cavity.png".into()];
    Ok(s)
}
