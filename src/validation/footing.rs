//! Strip footing on undrained clay: the bearing pressure of a rigid footing pushed into a
//! weightless von Mises (Tresca) clay, against Prandtl's limit load (2 + pi) c_u.

use super::plot::{colors, save, Panel, Series};
use super::{load_deck, pct, run_deck, Ctx, Row, Section};
use std::f64::consts::PI;

/// Undrained shear strength (Pa) and full footing width (m) of the deck.
const CU: f64 = 1.0e4;
const B: f64 = 1.0;
/// Prandtl's bearing capacity factor N_c = 2 + pi.
const NC: f64 = 2.0 + PI;

struct Curve {
    /// (s / B, q / c_u) every step.
    points: Vec<(f64, f64)>,
    /// Mean q / c_u over s / B in [0.09, 0.10].
    at_10: f64,
    /// Mean q / c_u over s / B in [0.045, 0.055].
    at_5: f64,
    steps: u64,
}

fn mean(points: &[(f64, f64)], lo: f64, hi: f64) -> f64 {
    let sel: Vec<f64> = points
        .iter()
        .filter(|(s, _)| *s >= lo - 1e-12 && *s <= hi + 1e-12)
        .map(|p| p.1)
        .collect();
    if sel.is_empty() {
        f64::NAN
    } else {
        sel.iter().sum::<f64>() / sel.len() as f64
    }
}

fn push(scheme: &str, h: f64) -> Result<Curve, String> {
    let d = load_deck("strip_footing", |d| {
        if scheme == "explicit" {
            // K = 100 G locks each particle's volume: the volumetric strain rate is averaged
            // at the nodes (src/averaging.rs)
            d.simulation.scheme = crate::deck::Scheme::Explicit;
            d.simulation.volumetric_averaging = crate::deck::VolumetricAveraging::Nodal;
        } else {
            d.simulation.scheme = crate::deck::Scheme::Projection;
        }
        d.grid.cell_size = h;
    })?;
    let mut points = Vec::new();
    let sim = run_deck::<2>(&d, |sim, _| {
        let r = &sim.boundary.rigid;
        let s = -r.displacement(0, sim.time)[1] / B;
        // half model: the force is on half the footing, per metre
        let q = r.force(0)[1] / (B / 2.0);
        points.push((s, q / CU));
        true
    })?;
    Ok(Curve {
        at_10: mean(&points, 0.09, 0.10),
        at_5: mean(&points, 0.045, 0.055),
        points,
        steps: sim.steps,
    })
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let h = if quick { 0.1 } else { 0.05 };
    let mut s = Section {
        title: "Strip footing on undrained clay (Prandtl)".into(),
        setup: format!(
            "A rigid, rough strip footing of width B = 1 m on the surface of a weightless clay layer 2 m deep (von Mises, c_u = 10 kPa, G = 1 MPa, rho = 1800 kg/m3), pushed down at 0.05 m/s (rho v^2 / c_u = 5e-4: quasi-static) to a settlement of 0.1 B. Half model, 3 m wide: the slip wall x = 0 is the footing's centre line; slip wall x = 3 m, no-slip base, open top. The footing is a `[[rigid_bodies]]` box; its force is the momentum its nodes need (`src/rigid.rs`). APIC, quadratic B-splines (`bspline2`), cfl 0.5, 2x2 particles per cell, h = {h} m = B / {:.0} (`validation/decks/strip_footing.toml`{}). Projection, and the explicit scheme with K = 100 G and `volumetric_averaging = \"nodal\"`: the volumetric strain rate averaged at the nodes (`src/averaging.rs`), against the locking of the nearly incompressible clay (without it the explicit footing's load keeps rising, q / c_u = 7.08 at s / B = 0.1 at h = B / 20).",
            B / h,
            if quick { "; quick mode, the full case has h = B / 20" } else { "" }
        ),
        metric: "Bearing pressure q = F_y / (B/2) (the force on the half footing per metre) / c_u, every step; its mean over the settlement range s / B in [0.09, 0.10] (about 200 steps with the projection: a step's value carries the noise of particles crossing cells), against N_c = 2 + pi = 5.14. The value near s / B = 0.05 is reported as well.".into(),
        bound: "|q / c_u - (2 + pi)| / (2 + pi) <= 7% at s / B = 0.1 (the issue). Prandtl's solution is the limit load of a weightless rigid-perfectly plastic Tresca material under a strip footing, smooth or rough (Prandtl 1920; e.g. Chen, Limit Analysis and Soil Plasticity, 1975); the von Mises model in plane strain with s_zz = 0 yields at the same largest shear stress c_u (docs/materials.md). The bound holds at h = B/20; quick mode (B/10) is report only.".into(),
        ..Default::default()
    };
    let mut series = vec![Series::line(
        "Prandtl (2 + pi) c_u",
        vec![(0.0, NC), (0.1, NC)],
        colors::REF,
    )];
    for (scheme, label, color) in [
        ("projection", "projection", colors::PROJ),
        ("explicit", "explicit, nodal averaging", colors::EXPL),
    ] {
        let c = push(scheme, h)?;
        let err = (c.at_10 - NC).abs() / NC;
        s.rows.push(Row::bounded(
            format!(
                "{label}, h = B/{:.0}: |q/c_u - (2+pi)| / (2+pi) at s/B = 0.1 (q/c_u = {:.3})",
                B / h,
                c.at_10
            ),
            err,
            0.07,
            pct,
            !quick,
            quick,
        ));
        s.rows.push(Row::report(
            format!("{label}, h = B/{:.0}: q/c_u at s/B = 0.05", B / h),
            format!("{:.3}", c.at_5),
        ));
        s.notes.push(format!("{label}: {} steps.", c.steps));
        if scheme == "explicit" {
            s.notes.push("With the nodal averaging the explicit curve levels off (without it, it keeps rising: locking), but higher than the projection's. What is left is not locking: without averaging, a compressible clay (K = 2 G) gives q / c_u = 5.90 at s / B = 0.1 and h = B / 20 (a run outside this case), against 5.97 for K = 100 G with averaging. The bound stays.".into());
        }
        // one point in ten keeps the figure light
        let pts = c.points.iter().step_by(10).copied().collect();
        series.push(Series::thin(label, pts, color));
    }
    save(
        &ctx.opts.out.join("strip_footing.png"),
        &[Panel {
            title: format!("Strip footing, h = B/{:.0}", B / h),
            x_label: "settlement s / B".into(),
            y_label: "bearing pressure q / c_u".into(),
            series,
            x_range: Some((0.0, 0.1)),
            y_range: Some((0.0, 8.0)),
            ..Default::default()
        }],
        1,
        800,
        500,
    )?;
    s.figures = vec!["strip_footing.png".into()];
    Ok(s)
}
