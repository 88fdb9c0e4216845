//! Lobovsky et al. (2014) dam break, H = 0.3 m: wall pressure at sensor 1 and water levels at
//! four gauges, against the experiment. The series are read from the reference directory
//! (never copied into the repository); the case is skipped when they are absent.

use super::plot::{colors, save, Panel, Series};
use super::{interp, load_deck, pct, read_csv, run_deck, Ctx, Row, Section, Verdict};
use std::path::{Path, PathBuf};

const G: f64 = 9.81;
const H: f64 = 0.3;
const RHO: f64 = 1000.0;
/// Non-dimensional end time t sqrt(g/H) of the water-level window.
const T_END: f64 = 6.0;
/// Gauges: name, x (m) from the back wall, experimental file (ETSIN 01 series), second file.
const GAUGES: [(&str, f64, &str, Option<&str>); 4] = [
    (
        "H1",
        0.300,
        "lobovsky2014_H300_water_level_Fig16_WaterLevels_H1_2.csv",
        None,
    ),
    (
        "H2",
        0.865,
        "lobovsky2014_H300_water_level_Fig16_WaterLevels_H2_4.csv",
        Some("lobovsky2014_H300_water_level_Fig16_WaterLevels_H2_3.csv"),
    ),
    (
        "H3",
        1.114,
        "lobovsky2014_H300_water_level_Fig16_WaterLevels_H3_4.csv",
        Some("lobovsky2014_H300_water_level_Fig16_WaterLevels_H3_3.csv"),
    ),
    (
        "H4",
        1.3625,
        "lobovsky2014_H300_water_level_Fig16_WaterLevels_H4_5.csv",
        Some("lobovsky2014_H300_water_level_Fig16_WaterLevels_H4_4.csv"),
    ),
];
const SENSOR1: &str = "lobovsky2014_H300_pressure_sensor_1_Fig18_peak_event_5_sensors_5.csv";

struct Run {
    /// (T, p / rho g H) at sensor 1, T at the step's start.
    pressure: Vec<(f64, f64)>,
    /// Per gauge: (T, level / H) after each step.
    levels: Vec<Vec<(f64, f64)>>,
    steps: u64,
    wall_s: f64,
}

fn simulate(scheme: &str, h: f64) -> Result<Run, String> {
    let d = load_deck(&format!("lobovsky_{scheme}"), |d| {
        d.grid.cell_size = h;
        d.simulation.end_time = T_END * (H / G).sqrt() + 1e-3;
    })?;
    let start = std::time::Instant::now();
    let ts = (G / H).sqrt();
    let mut run = Run {
        pressure: Vec::new(),
        levels: vec![Vec::new(); GAUGES.len()],
        steps: 0,
        wall_s: 0.0,
    };
    let sim = run_deck::<2>(&d, |sim, t0| {
        run.pressure
            .push((t0 * ts, sim.probes.values[0] / (RHO * G * H)));
        // per gauge: the equivalent depth, the particles' initial volumes (areas in 2D)
        // within 2h of its x over the strip's width 4h (a narrower strip counts particles in
        // and out of it from step to step: noise of +-0.1 H at h)
        let ps = &sim.particles;
        let mut top = [0.0f64; 4];
        for p in 0..ps.len() {
            for (g, gauge) in GAUGES.iter().enumerate() {
                if (ps.x[p][0] - gauge.1).abs() <= 2.0 * h {
                    top[g] += ps.volume0[p] / (4.0 * h);
                }
            }
        }
        for g in 0..GAUGES.len() {
            run.levels[g].push((sim.time * ts, top[g] / H));
        }
        true
    })?;
    run.steps = sim.steps;
    run.wall_s = start.elapsed().as_secs_f64();
    Ok(run)
}

/// First impact: the first time P exceeds 0.1, then the largest P within 1 time unit.
fn first_peak(series: &[(f64, f64)]) -> Option<(f64, f64)> {
    let k = series.iter().position(|p| p.1 > 0.1)?;
    let t0 = series[k].0;
    series[k..]
        .iter()
        .take_while(|p| p.0 <= t0 + 1.0)
        .copied()
        .fold(None, |best: Option<(f64, f64)>, p| match best {
            Some(b) if b.1 >= p.1 => Some(b),
            _ => Some(p),
        })
}

fn load(dir: &Path, file: &str) -> Result<Vec<(f64, f64)>, String> {
    Ok(read_csv(&dir.join(file))?
        .into_iter()
        .map(|r| (r[0], r[1]))
        .collect())
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let h = if quick { 0.01 } else { 0.005 };
    let dir: PathBuf = ctx.opts.reference.join("lobovsky2014");
    let mut s = Section {
        title: "Lobovsky et al. (2014) dam break, H = 0.3 m: wall pressure and water levels".into(),
        setup: format!(
            "2D. A water column 0.6 m long and H = 0.3 m high at the back wall of a tank 1.61 m long (the grid is 0.8 m high, slip walls all round), h = {h} m (H/{:.0}{}), 2x2 particles per cell, linear shape functions, to t sqrt(g/H) = 6. Projection (`validation/decks/lobovsky_projection.toml`): APIC, cfl 0.5; explicit (`lobovsky_explicit.toml`): c = 10 sqrt(2 g H) = 24 m/s, FLIP 0.99, cfl 0.4. Geometry, sensor and gauge positions from the `#` lines of the reference CSVs: sensor 1 on the downstream wall 3 mm above the floor, sampled every step by the deck's probe `s1` (grid pressure, 1 mm in front of the wall); gauges at x = 0.300, 0.865, 1.114, 1.3625 m from the back wall. The experimental series are read from `{}` and are not in the repository.",
            H / h,
            if quick { ", quick mode; the full run uses 0.005 m" } else { "" },
            dir.display()
        ),
        metric: "Sensor 1: the first impact's peak p / (rho g H) and its time T = t sqrt(g/H) (first time P > 0.1, then the largest P within 1 time unit), simulation against the experiment (one repetition, 'peak event 5'). Water level at a gauge: the equivalent depth, the sum of the initial particle volumes (areas, 2D) V0_p of the particles within 2h of the gauge's x divided by the strip's width 4h, over H (a strip h wide was noisy, +-0.1 H, as particles cross its edges; robust to the voids the flow opens and to spray; V0 rather than V0 J because the projection's J drifts, see `conservation`; the first full run took the highest particle in the strip and read the plunging jet's spray at H3 and H4 as levels of 2.7 H, and the top of the water connected to the floor was broken by voids near the floor in the projection run); error: max |sim - exp| over the experiment's samples with T <= 6 (simulation interpolated linearly in time) divided by (max - min) of the experimental curve over the window. For H2-H4 the reference directory holds two curves (file headers 'ETSIN 01' and 'ETSIN 02'; the meaning of the index is not documented): the ETSIN 01 curve is the reference (H1 has only that one), the other is plotted in grey.".into(),
        bound: "Water levels of the projection run within 15% of the experimental curve's range (the issue). The impact peak and its time are reported only (a single repetition; the paper reports a large run-to-run scatter of peaks).".into(),
        ..Default::default()
    };
    let missing: Vec<String> = std::iter::once(SENSOR1)
        .chain(GAUGES.iter().map(|g| g.2))
        .filter(|f| !dir.join(f).is_file())
        .map(|f| f.to_string())
        .collect();
    if !missing.is_empty() {
        let why = format!(
            "reference series not found in {} ({} missing); pass --reference DIR",
            dir.display(),
            missing.len()
        );
        s.rows.push(Row {
            metric: "sensor 1 peak; water levels H1-H4".into(),
            bound: "levels <= 15%".into(),
            measured: why.clone(),
            verdict: Verdict::Skipped,
        });
        s.notes.push(format!("Skipped: {why}."));
        return Ok(s);
    }
    let exp_p = load(&dir, SENSOR1)?;
    let exp_levels: Vec<Vec<(f64, f64)>> = GAUGES
        .iter()
        .map(|g| load(&dir, g.2))
        .collect::<Result<_, _>>()?;
    let runs = [
        ("projection", simulate("projection", h)?),
        ("explicit", simulate("explicit", h)?),
    ];
    let (ept, epp) = first_peak(&exp_p).unwrap_or((f64::NAN, f64::NAN));
    s.rows.push(Row::report(
        "experiment: sensor 1 first peak P at T",
        format!("{epp:.2} at {ept:.2}"),
    ));
    for (scheme, r) in &runs {
        let (pt, pp) = first_peak(&r.pressure).unwrap_or((f64::NAN, f64::NAN));
        s.rows.push(Row::report(
            format!("{scheme}: sensor 1 first peak P at T"),
            format!("{pp:.2} at {pt:.2}"),
        ));
        for (g, gauge) in GAUGES.iter().enumerate() {
            let exp: Vec<&(f64, f64)> = exp_levels[g].iter().filter(|p| p.0 <= T_END).collect();
            let ts: Vec<f64> = r.levels[g].iter().map(|p| p.0).collect();
            let ls: Vec<f64> = r.levels[g].iter().map(|p| p.1).collect();
            let (lo, hi) = exp.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
                (a.0.min(p.1), a.1.max(p.1))
            });
            let err = exp
                .iter()
                .map(|p| (interp(&ts, &ls, p.0) - p.1).abs())
                .fold(0.0, f64::max)
                / (hi - lo);
            let proj = *scheme == "projection";
            s.rows.push(Row::bounded(
                format!(
                    "{scheme}: water level {} (x = {} m), max error / range",
                    gauge.0, gauge.1
                ),
                err,
                0.15,
                pct,
                proj && !quick,
                quick && proj,
            ));
        }
        s.notes.push(format!(
            "{scheme}: {} steps, {:.0} s wall.",
            r.steps, r.wall_s
        ));
    }
    figures(
        ctx,
        &dir,
        &exp_p,
        &exp_levels,
        (&runs[0].1, &runs[1].1),
        ept,
    )?;
    s.notes.push("The two figures draw the experiment's series, which may not be committed: they are written beside this report and kept out of the repository (`.gitignore`).".into());
    s.notes.push("Why H2 to H4 miss (read from the levels figure of the full run of 2026-11-23, h = H/60): both schemes agree with each other within the noise and miss alike, so this is not the projection. (1) The surge reaches the gauges early: the level first passes 0.05 H at T = 0.95 against 1.0 at H2, 1.5 against 1.65 at H3 and 1.95 against 2.15 at H4; the simulation starts from a column released at once, the experiment from a gate lifted in a finite time (Martin & Moyce needed +0.175 in T for the same reason, see `martin_moyce`). On the steep front a shift of 0.15 in T is an error of 0.1 H, 40% of H3's range: the max-error metric reads the arrival time. (2) Behind the front the simulated layer is 0.02 to 0.04 H deeper at H2 and H3 (T = 2 to 5). (3) At H4, 0.25 m from the downstream wall, the run-up reflected from that wall returns at T = 5.6 in both schemes as in the experiment, but the simulated level reaches 0.75 H (projection) and 0.58 H (explicit) against 0.40 H: the equivalent depth counts every particle in the strip, including the water of the collapsing run-up jet above the layer. Not tuned away: no time shift is applied here (the issue gives none), and the bound stays.".into());
    s.figures = vec!["lobovsky_pressure.png".into(), "lobovsky_levels.png".into()];
    Ok(s)
}

/// The pressure and level figures: the experiment's series against both schemes' (`runs`:
/// projection, explicit); `ept` the experiment's first peak time, where the zoom centres.
fn figures(
    ctx: &Ctx,
    dir: &Path,
    exp_p: &[(f64, f64)],
    exp_levels: &[Vec<(f64, f64)>],
    runs: (&Run, &Run),
    ept: f64,
) -> Result<(), String> {
    let (proj, expl) = runs;
    let p_panel = Panel {
        title: "Pressure at sensor 1 (downstream wall, 3 mm)".into(),
        x_label: "T = t sqrt(g/H)".into(),
        y_label: "p / (rho g H)".into(),
        series: vec![
            Series::thin(
                "experiment (Lobovsky et al. 2014, one run)",
                exp_p.iter().copied().filter(|p| p.0 <= T_END).collect(),
                colors::REF2,
            ),
            Series::line("projection", proj.pressure.clone(), colors::PROJ),
            Series::thin("explicit", expl.pressure.clone(), colors::EXPL),
        ],
        x_range: Some((0.0, T_END)),
        legend_left: true,
        ..Default::default()
    };
    let mut p_zoom = p_panel.clone();
    p_zoom.title = "Sensor 1, first impact".into();
    p_zoom.x_range = Some((ept - 0.5, ept + 1.5));
    p_zoom.legend_left = false;
    save(
        &ctx.opts.out.join("lobovsky_pressure.png"),
        &[p_panel, p_zoom],
        2,
        750,
        550,
    )?;
    let mut panels = Vec::new();
    for (g, gauge) in GAUGES.iter().enumerate() {
        let mut series = vec![Series::line(
            "experiment (ETSIN 01)",
            exp_levels[g]
                .iter()
                .copied()
                .filter(|p| p.0 <= T_END)
                .collect(),
            colors::REF,
        )];
        if let Some(second) = gauge.3 {
            if let Ok(e2) = load(dir, second) {
                series.push(Series::line(
                    "experiment (ETSIN 02)",
                    e2.into_iter().filter(|p| p.0 <= T_END).collect(),
                    colors::REF2,
                ));
            }
        }
        series.push(Series::line(
            "projection",
            proj.levels[g].clone(),
            colors::PROJ,
        ));
        series.push(Series::line(
            "explicit",
            expl.levels[g].clone(),
            colors::EXPL,
        ));
        panels.push(Panel {
            title: format!("Water level at {} (x = {} m)", gauge.0, gauge.1),
            x_label: "T = t sqrt(g/H)".into(),
            y_label: "level / H".into(),
            series,
            x_range: Some((0.0, T_END)),
            legend_left: g != 0,
            legend_low: g == 0,
            ..Default::default()
        });
    }
    save(
        &ctx.opts.out.join("lobovsky_levels.png"),
        &panels,
        2,
        750,
        500,
    )?;
    Ok(())
}
