//! Lid-driven cavity at Re = 100 and 1000 against Ghia, Ghia & Shin (1982), Tables I and II.

use super::plot::{colors, save, Panel, Series};
use super::{load_deck, reference_table, run_deck, Ctx, Row, Section};
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

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let (h, end100, end1000) = if quick {
        (1.0 / 32.0, 10.0, 10.0)
    } else {
        (1.0 / 64.0, 20.0, 40.0)
    };
    let mut s = Section {
        title: "Lid-driven cavity, Re = 100 and 1000 (Ghia, Ghia & Shin 1982)".into(),
        setup: format!(
            "Unit square completely filled with fluid (density 1, viscosity 1/Re), no gravity; lid y = 1 a no-slip wall moving at u = 1, the other walls no-slip; a closed, filled box, so the projection projects out the constant of the singular Poisson system. Projection, APIC, quadratic B-splines (`bspline2`), `free_surface = \"none\"` (the fluid fills the box), `rhs = \"divergence\"` (see below), cfl 0.5 with dt <= 0.5 h / U (the lid speed does not enter the adaptive step; the viscous limit caps it too), 2x2 particles per cell, h = 1/{:.0}{} (`validation/decks/cavity_re100.toml`, `cavity_re1000.toml`). Run until the kinetic energy changes by less than 1e-6 relative over one unit of time, or to t = {end100} (Re = 100) / {end1000} (Re = 1000), whichever comes first.",
            1.0 / h,
            if quick { ", quick mode (the full run uses h = 1/64)" } else { "" }
        ),
        metric: "u on the vertical centre line x = 0.5 and v on the horizontal one y = 0.5, sampled from the grid velocity (mass-weighted P2G of the particle velocities) by probes at Ghia's points at the last step; max |sim - Ghia| / U over Ghia's interior points (the wall points are boundary values). Tables in `validation/reference/` with their source lines.".into(),
        bound: "Re = 100: max deviation <= 0.05 U (the issue). Re = 1000: reported only.".into(),
        ..Default::default()
    };
    s.notes.push("Shape functions and free surface: with linear shape functions and the default volume-fraction detection the h = 1/64 run stopped at t = 6.5 s (2 threads; a particle pushed out through the right wall near its top at u = 10.9, eleven times the lid speed; on 1 thread the same deck reached t = 10). The stretching flow opens particle-free cells inside the fluid; they read as free surface, and a node next to one takes its mass from a particle with a small weight but a full linear gradient, so the viscous force over that mass kicks it (the Taylor-Green case shows the same, with figures). The decks use quadratic B-splines, whose gradient vanishes with the weight, and `free_surface = \"none\"`. Right-hand side: they keep `rhs = \"divergence\"` (the paper's form; there is no gravity here, the reason for the default flux form). With `rhs = \"flux\"` the Re = 100 run, with linear shape functions at h = 1/32, stopped every time (t = 2.6 s with APIC, 0.5 s with PIC, 7.7 s with FLIP 0.99, 0.5 s with APIC at cfl 0.2), a particle near the top-left corner pushed up through the moving lid at 4 to 12 m/s; with the quadratic B-splines and no free surface it reaches t = 10 at h = 1/32 (largest speed 0.96) but stops at t = 8.6 s at h = 1/64, again a particle near the top-left corner (x = 0.03) pushed up through the lid at 6.8 m/s. The flux form's wall-flux term at the moving lid's corners looks wrong: an issue for the solver, recorded here, not worked around in the default.".into());
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
