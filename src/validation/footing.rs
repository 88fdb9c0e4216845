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

/// What the runs outside the case measured (q / c_u over s / B in [0.09, 0.10]).
const CONVERGENCE: &str = "Which projection is bounded, and why: the nodal pressure's result depends on the time step. At cfl 0.5 it reads 5.08 (a pass, per-step standard deviation 1.5), at cfl 0.1 6.45 (the rows above): its stabilisation residual lets the clay lose volume in proportion to dt, a numerical compliance that lowers the load. One pressure per cell has no such residual: 5.70 at cfl 0.5 and 5.84 at cfl 0.1, per-step standard deviation 0.03. The bounded projection row is therefore the cells'. Grid convergence of the cells (runs outside this case, cfl 0.5): 5.94 at h = B/10, 5.70 at B/20, 5.62 at B/40; the differences (0.24, 0.08) shrink by a third per halving, which extrapolates to about 5.58, 8.6% above 2 + pi: the gap is not the grid. Nor is it the start of the curve: at B/40 the mean over s/B in [0.02, 0.03] is 5.21 (+1.4%), and the load then rises with the settlement (5.47 at 0.03 to 0.04, 5.57 at 0.05 to 0.07). The explicit scheme converges alike (6.29 at B/10, 5.97 at B/20). The 7% bound at s/B = 0.1 is not met; the next note locates the excess.";

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

/// The footing deck at cell size `h`, in the variant `v`, with the footing's half-width `w`
/// (m; the deck's is B / 2).
fn push(v: Variant, h: f64, w: f64) -> Result<Curve, String> {
    use crate::deck::{PressureUnknowns, Scheme, StressUpdate, VolumetricAveraging};
    let d = load_deck("strip_footing", |d| {
        match v {
            Variant::Explicit => {
                // K = 100 G locks each particle's volume: the volumetric strain rate is
                // averaged at the nodes (src/averaging.rs)
                d.simulation.scheme = Scheme::Explicit;
                d.simulation.volumetric_averaging = VolumetricAveraging::Nodal;
            }
            Variant::Cells => {
                d.simulation.scheme = Scheme::Projection;
                d.pressure.unknowns = PressureUnknowns::Cells;
                d.simulation.stress_update = StressUpdate::Usl;
            }
            Variant::Nodes { cfl } => {
                d.simulation.scheme = Scheme::Projection;
                d.simulation.cfl = Some(cfl);
            }
        }
        d.grid.cell_size = h;
        if let Some(max) = d.rigid_bodies[0].shape.max.as_mut() {
            max[0] = w;
        }
    })?;
    let mut points = Vec::new();
    let sim = run_deck::<2>(&d, |sim, _| {
        let r = &sim.boundary.rigid;
        let s = -r.displacement(0, sim.time)[1] / B;
        // half model: the force is on half the footing, per metre
        let q = r.force(0)[1] / w;
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

/// The runs of the case.
#[derive(Clone, Copy)]
enum Variant {
    /// Projection, one pressure per cell (`pressure.unknowns = "cells"`, usl).
    Cells,
    /// Projection, nodal pressure, at this cfl.
    Nodes { cfl: f64 },
    /// Explicit, K = 100 G, nodal averaging.
    Explicit,
}

/// The case.
pub fn run(ctx: &Ctx) -> Result<Section, String> {
    let quick = ctx.opts.quick;
    let h = if quick { 0.1 } else { 0.05 };
    let mut s = Section {
        title: "Strip footing on undrained clay (Prandtl)".into(),
        setup: format!(
            "A rigid, rough strip footing of width B = 1 m on the surface of a weightless clay layer 2 m deep (von Mises, c_u = 10 kPa, G = 1 MPa, rho = 1800 kg/m3), pushed down at 0.05 m/s (rho v^2 / c_u = 5e-4: quasi-static) to a settlement of 0.1 B. Half model, 3 m wide: the slip wall x = 0 is the footing's centre line; slip wall x = 3 m, no-slip base, open top. The footing is a `[[rigid_bodies]]` box; its force is the momentum its nodes need (`src/rigid.rs`). APIC, quadratic B-splines (`bspline2`), cfl 0.5, 2x2 particles per cell, h = {h} m = B / {:.0} (`validation/decks/strip_footing.toml`{}). Projection with one pressure per cell (`pressure.unknowns = \"cells\"`, `stress_update = \"usl\"`), the bounded run; the projection with the nodal pressure, reported (at cfl 0.5 and, in full mode, 0.1); and the explicit scheme with K = 100 G and `volumetric_averaging = \"nodal\"`: the volumetric strain rate averaged at the nodes (`src/averaging.rs`), against the locking of the nearly incompressible clay (without it the explicit footing's load keeps rising, q / c_u = 7.08 at s / B = 0.1 at h = B / 20).",
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
    let mut runs = vec![
        (Variant::Cells, "projection, cells", colors::PROJ, true),
        (
            Variant::Nodes { cfl: 0.5 },
            "projection, nodes",
            colors::PROJ2,
            false,
        ),
    ];
    if !quick {
        runs.push((
            Variant::Nodes { cfl: 0.1 },
            "projection, nodes, cfl 0.1",
            colors::PROJ3,
            false,
        ));
    }
    runs.push((
        Variant::Explicit,
        "explicit, nodal averaging",
        colors::EXPL,
        true,
    ));
    let mut cells_at_10 = f64::NAN;
    for (variant, label, color, bounded) in runs {
        let c = push(variant, h, B / 2.0)?;
        if matches!(variant, Variant::Cells) {
            cells_at_10 = c.at_10;
        }
        let err = (c.at_10 - NC).abs() / NC;
        let metric = format!(
            "{label}, h = B/{:.0}: |q/c_u - (2+pi)| / (2+pi) at s/B = 0.1 (q/c_u = {:.3})",
            B / h,
            c.at_10
        );
        s.rows.push(if bounded {
            Row::bounded(metric, err, 0.07, pct, !quick, quick)
        } else {
            Row::report(metric, pct(err))
        });
        s.rows.push(Row::report(
            format!("{label}, h = B/{:.0}: q/c_u at s/B = 0.05", B / h),
            format!("{:.3}", c.at_5),
        ));
        s.notes.push(format!("{label}: {} steps.", c.steps));
        // one point in ten keeps the figure light
        let pts = c.points.iter().step_by(10).copied().collect();
        series.push(Series::thin(label, pts, color));
    }
    s.notes.push("With the nodal averaging the explicit curve levels off (without it, it keeps rising: locking). What is left is not locking: without averaging, a compressible clay (K = 2 G) gives q / c_u = 5.90 at s / B = 0.1 and h = B / 20 (a run outside this case), against 5.97 for K = 100 G with averaging.".into());
    s.notes.push(CONVERGENCE.into());
    // the force's derivative with respect to the footing's width: the bearing pressure with
    // whatever is attached to the footing's edge taken out
    let (w0, w1) = (B / 2.0 - 2.0 * h, B / 2.0 + 2.0 * h);
    let f = |w: f64| -> Result<(f64, f64), String> {
        let c = push(Variant::Cells, h, w)?;
        Ok((c.at_10 * w, c.at_5 * w))
    };
    let (lo, hi) = (f(w0)?, f(w1)?);
    let slope = ((hi.0 - lo.0) / (w1 - w0), (hi.1 - lo.1) / (w1 - w0));
    let edge = cells_at_10 * B / 2.0 / slope.0 - B / 2.0;
    s.rows.push(Row::report(
        format!(
            "projection, cells, h = B/{:.0}: d(F/c_u)/dw, the footing's half-width w = B/2 -+ 2h, at s = 0.09 to 0.10 m; at 0.045 to 0.055 m",
            B / h
        ),
        format!("{:.3}; {:.3}", slope.0, slope.1),
    ));
    s.rows.push(Row::report(
        format!(
            "projection, cells, h = B/{:.0}: edge term F / q' - B/2 at s = 0.09 to 0.10 m (m, and in cells)",
            B / h
        ),
        format!("{:.4} m, {:.2} h", edge, edge / h),
    ));
    s.notes.push(format!("Where the excess sits: the force grows with the footing's half-width w at the rate d(F/c_u)/dw = {:.3} at s = 0.09 to 0.10 m (runs with w = B/2 -+ 2h, one pressure per cell, the rows above), {:+.1}% from 2 + pi: the bearing pressure away from the footing's edge is Prandtl's. The excess of q = F / (B/2) is an edge term, a force equal to that pressure on {:.3} m more of width, about one cell ({:.2} h): the rigid body's contact is at node resolution, its face's nodes take its velocity and their shape functions reach past the face. (Measured outside the case: the same at h = B/10 gives 5.22 and 0.069 m, 0.69 h.) Prandtl's bound is therefore met by the pressure under the footing, not by the force on its nodes divided by its nominal width; the bounded row keeps the latter, the issue's measure.", slope.0, (slope.0 / NC - 1.0) * 100.0, edge, edge / h));
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
