//! Lobovsky et al. (2014) dam break, H = 0.3 m: wall pressure at sensor 1 and water levels at
//! four gauges, against the experiment, in 2D and in 3D (the tank's 0.15 m width and side
//! walls). The series are read from the reference directory (never copied into the
//! repository); the case is skipped when they are absent.

use super::plot::{colors, save, Panel, Series};
use super::{interp, load_deck, pct, prose, read_csv, run_deck, Ctx, Row, Section, Verdict};
use std::path::{Path, PathBuf};

const G: f64 = 9.81;
const H: f64 = 0.3;
const RHO: f64 = 1000.0;
/// The tank's length (m): sensor 1 is on its downstream wall.
const TANK: f64 = 1.61;
/// The tank's width (m), the 3D run's.
const WIDTH: f64 = 0.15;
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

/// Runs the deck `lobovsky_{name}` (2D or 3D) at cell size `h`.
fn simulate<const D: usize>(name: &str, h: f64) -> Result<Run, String> {
    // the probe stays 1 mm in front of the downstream wall where the grid puts it
    let wall = tank_length(h);
    let d = load_deck(&format!("lobovsky_{name}"), |d| {
        d.grid.cell_size = h;
        d.simulation.end_time = T_END * (H / G).sqrt() + 1e-3;
        d.output.probes[0].position[0] = wall - 1e-3;
    })?;
    // the levels' strip: its width 4h along x, and in 3D the tank's width
    let strip = 4.0 * h * if D == 3 { d.grid.size[1] } else { 1.0 };
    let start = std::time::Instant::now();
    let ts = (G / H).sqrt();
    let mut run = Run {
        pressure: Vec::new(),
        levels: vec![Vec::new(); GAUGES.len()],
        steps: 0,
        wall_s: 0.0,
    };
    let sim = run_deck::<D>(&d, |sim, t0| {
        run.pressure
            .push((t0 * ts, sim.probes.values[0] / (RHO * G * H)));
        // per gauge: the equivalent depth, the particles' initial volumes (areas in 2D)
        // within 2h of its x over the strip (a narrower strip counts particles in and out of
        // it from step to step: noise of +-0.1 H at h)
        let ps = &sim.particles;
        let mut top = [0.0f64; 4];
        for p in 0..ps.len() {
            for (g, gauge) in GAUGES.iter().enumerate() {
                if (ps.x[p][0] - gauge.1).abs() <= 2.0 * h {
                    top[g] += ps.volume0[p] / strip;
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

/// The tank's length on a grid of cell size `h`: a length that is not a whole number of
/// cells is rounded up to the next (the quick 3D run's), as the deck's validation does.
fn tank_length(h: f64) -> f64 {
    (TANK / h - 1e-6).ceil() * h
}

/// Cell size (m), 2D.
fn cell_size(quick: bool) -> f64 {
    if quick {
        0.01
    } else {
        0.005
    }
}

/// Cell size (m), 3D: 5 cells across the tank's width in quick mode, 12 in the full report.
fn cell_size_3d(quick: bool) -> f64 {
    if quick {
        0.03
    } else {
        0.0125
    }
}

/// Title, set-up, metric and bound (`validation/prose/lobovsky.md`), the experimental series
/// read from `dir`.
fn header(quick: bool, dir: &Path) -> Section {
    let h = cell_size(quick);
    let h3 = cell_size_3d(quick);
    let (quick_note, quick_3d) = if quick {
        (
            ", quick mode; the full run uses 0.005 m",
            format!(
                ", quick mode, the tank's length rounded up to {:.3} m; the full run uses 0.0125 m",
                tank_length(h3)
            ),
        )
    } else {
        ("", String::new())
    };
    prose::section(
        "lobovsky",
        &[
            ("h", &h),
            ("h_over", &format!("{:.0}", H / h)),
            ("quick", &quick_note),
            ("h3", &h3),
            ("h3_over", &format!("{:.0}", H / h3)),
            ("across", &format!("{:.0}", WIDTH / h3)),
            ("quick3", &quick_3d),
            ("dir", &dir.display()),
        ],
    )
}

/// The notes after the runs' own.
fn closing_notes() -> [String; 2] {
    ["figures", "development"].map(|k| prose::note("lobovsky", k, &[]))
}

/// Every text of the case's prose the code fills (the prose file's test).
#[cfg(test)]
pub(super) fn prose_texts(quick: bool) -> Vec<String> {
    let mut t = header(quick, Path::new("reference/lobovsky2014")).texts();
    t.extend(closing_notes());
    t
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let h = cell_size(quick);
    let dir: PathBuf = ctx.opts.reference.join("lobovsky2014");
    let mut s = header(quick, &dir);
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
        s.notes.push(prose::note("lobovsky", "development", &[]));
        return Ok(s);
    }
    let exp_p = load(&dir, SENSOR1)?;
    let exp_levels: Vec<Vec<(f64, f64)>> = GAUGES
        .iter()
        .map(|g| load(&dir, g.2))
        .collect::<Result<_, _>>()?;
    let runs = [
        ("projection", simulate::<2>("projection", h)?),
        ("explicit", simulate::<2>("explicit", h)?),
        ("projection, 3D", simulate::<3>("3d", cell_size_3d(quick))?),
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
            let proj = scheme.starts_with("projection");
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
        [&runs[0].1, &runs[1].1, &runs[2].1],
        ept,
    )?;
    s.notes.extend(closing_notes());
    s.figures = vec!["lobovsky_pressure.png".into(), "lobovsky_levels.png".into()];
    Ok(s)
}

/// The pressure and level figures: the experiment's series against the runs' (`runs`:
/// projection, explicit, projection in 3D); `ept` the experiment's first peak time, where the
/// zoom centres.
fn figures(
    ctx: &Ctx,
    dir: &Path,
    exp_p: &[(f64, f64)],
    exp_levels: &[Vec<(f64, f64)>],
    runs: [&Run; 3],
    ept: f64,
) -> Result<(), String> {
    let [proj, expl, proj3] = runs;
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
            Series::thin("projection, 3D", proj3.pressure.clone(), colors::PROJ2),
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
        series.push(Series::line(
            "projection, 3D",
            proj3.levels[g].clone(),
            colors::PROJ2,
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
