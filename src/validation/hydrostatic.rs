//! Columns of water at rest, 2D and 3D, both schemes, against p = rho g (H - y).

use super::plot::{colors, save, Panel, Series};
use super::{load_deck, pct, prose, run_deck, sci, Ctx, Row, Section};
use pmpm::deck::Deck;

const RHO: f64 = 1000.0;
const G: f64 = 9.81;
const H: f64 = 0.4;

struct Rest {
    rms: f64,
    max: f64,
    probe_variation: f64,
    max_speed: f64,
    /// (t, base probe p / rho g H), t the step's start.
    base: Vec<(f64, f64)>,
    /// (p / rho g H, y / H) of the particles in the centre column.
    profile: Vec<(f64, f64)>,
    steps: u64,
}

fn rest<const D: usize>(d: &Deck) -> Result<Rest, String> {
    let scale = RHO * G * H;
    let mut base = Vec::new();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let sim = run_deck::<D>(d, |sim, t0| {
        let p = sim.probes.values[0];
        base.push((t0, p / scale));
        if t0 >= 0.05 - 1e-12 {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        true
    })?;
    let ps = &sim.particles;
    let h = sim.grid.geo.h;
    let centre: Vec<f64> = (0..D - 1)
        .map(|k| d.bodies[0].shape.max.as_ref().unwrap()[k] / 2.0)
        .collect();
    let (mut sum2, mut max) = (0.0f64, 0.0f64);
    let mut profile = Vec::new();
    for p in 0..ps.len() {
        let y = ps.x[p][D - 1];
        let e = (ps.pressure[p] - RHO * G * (H - y)) / scale;
        sum2 += e * e;
        max = max.max(e.abs());
        if (0..D - 1).all(|k| (ps.x[p][k] - centre[k]).abs() < h / 2.0) {
            profile.push((ps.pressure[p] / scale, y / H));
        }
    }
    Ok(Rest {
        rms: (sum2 / ps.len() as f64).sqrt(),
        max,
        probe_variation: (hi - lo) / scale,
        max_speed: sim.max_speed(),
        base,
        profile,
        steps: sim.steps,
    })
}

/// End time of the runs (s).
fn end_time(quick: bool) -> f64 {
    if quick {
        0.5
    } else {
        2.0
    }
}

/// Title, set-up, metric and bound (`validation/prose/hydrostatic.md`).
fn header(quick: bool) -> Section {
    let quick_note = if quick {
        " (quick mode; the full run goes to 2 s)"
    } else {
        ""
    };
    prose::section(
        "hydrostatic",
        &[("end", &end_time(quick)), ("quick", &quick_note)],
    )
}

/// The note on the scattered particle pressures of the explicit column `tag`.
fn scatter_note(tag: &str, rms: f64) -> String {
    prose::note(
        "hydrostatic",
        "scatter",
        &[("tag", &tag), ("rms", &pct(rms))],
    )
}

/// The notes after the runs' own; `scattered`: whether a scatter note was given, which the
/// observations of development runs go with.
fn closing_notes(scattered: bool) -> Vec<String> {
    let mut notes = vec![prose::note("hydrostatic", "ringing", &[])];
    if scattered {
        notes.push(prose::note("hydrostatic", "development", &[]));
    }
    notes
}

/// Every text of the case's prose the code fills (the prose file's test).
#[cfg(test)]
pub(super) fn prose_texts(quick: bool) -> Vec<String> {
    let mut t = header(quick).texts();
    t.push(scatter_note("2D explicit", 0.18));
    t.extend(closing_notes(true));
    t
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let end = end_time(quick);
    let mut s = header(quick);
    let mut base_series = Vec::new();
    let mut profile_series = Vec::new();
    let mut scattered = false;
    for dim in [2usize, 3] {
        for scheme in ["projection", "explicit"] {
            let name = format!("hydrostatic_{dim}d_{scheme}");
            let d = load_deck(&name, |d| d.simulation.end_time = end)?;
            let r = if dim == 2 {
                rest::<2>(&d)?
            } else {
                rest::<3>(&d)?
            };
            let proj = scheme == "projection";
            let tag = format!("{dim}D {scheme}");
            s.rows.push(Row::bounded(
                format!("{tag}: RMS p error / rho g H"),
                r.rms,
                0.01,
                pct,
                proj,
                false,
            ));
            s.rows.push(Row::bounded(
                format!("{tag}: max p error / rho g H"),
                r.max,
                0.03,
                pct,
                proj,
                false,
            ));
            s.rows.push(Row::bounded(
                format!("{tag}: base probe variation, t in [0.05, {end}] s / rho g H"),
                r.probe_variation,
                0.01,
                pct,
                proj,
                false,
            ));
            s.rows.push(Row::bounded(
                format!("{tag}: max speed (m/s)"),
                r.max_speed,
                1e-3,
                sci,
                proj,
                false,
            ));
            s.notes.push(format!("{tag}: {} steps.", r.steps));
            if !proj && r.rms > 0.01 {
                scattered = true;
                s.notes.push(scatter_note(&tag, r.rms));
            }
            let color = match (dim, proj) {
                (2, true) => colors::PROJ,
                (2, false) => colors::EXPL,
                (_, true) => colors::PROJ2,
                (_, false) => colors::EXPL2,
            };
            base_series.push(Series::line(tag.clone(), r.base, color));
            profile_series.push(Series::markers(tag, r.profile, color));
        }
    }
    s.notes.extend(closing_notes(scattered));
    let exact = vec![(1.0, 0.0), (0.0, 1.0)];
    profile_series.insert(0, Series::line("exact rho g (H - y)", exact, colors::REF));
    let out = &ctx.opts.out;
    save(
        &out.join("hydrostatic_base.png"),
        &[Panel {
            title: "Base pressure (probe at the floor, centre)".into(),
            x_label: "t (s)".into(),
            y_label: "p / (rho g H)".into(),
            series: base_series,
            y_range: Some((0.0, 2.0)),
            ..Default::default()
        }],
        1,
        900,
        500,
    )?;
    save(
        &out.join("hydrostatic_profile.png"),
        &[Panel {
            title: format!("Pressure profile at t = {end} s (centre column of particles)"),
            x_label: "p / (rho g H)".into(),
            y_label: "y / H".into(),
            series: profile_series,
            x_range: Some((-0.05, 1.1)),
            y_range: Some((0.0, 1.05)),
            ..Default::default()
        }],
        1,
        700,
        600,
    )?;
    s.figures = vec![
        "hydrostatic_base.png".into(),
        "hydrostatic_profile.png".into(),
    ];
    Ok(s)
}
