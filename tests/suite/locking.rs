//! Volumetric locking of the explicit scheme and the nodal averaging of the volumetric strain
//! rate (`simulation.volumetric_averaging = "nodal"`, crates/pmpm/src/averaging.rs).

use crate::common;

use common::{drive, in_pool};
use pmpm::deck::VolumetricAveraging;
use pmpm::scheme::Simulation;
use pmpm::Deck;
use std::f64::consts::PI;

/// An elastic square [0, 1]^2 between slip walls, set swinging in its isochoric mode
/// u = A(t) (sin(pi x) cos(pi y), -cos(pi x) sin(pi y)): div u = 0, Delta u = -2 pi^2 u, and
/// the walls' normal displacement and shear traction vanish, so it is an exact mode of the
/// linear elastic square for any bulk modulus, with omega = pi sqrt(2 G / rho). Every
/// particle's volume is kept in the continuum, so a scheme that penalises each particle's
/// own volume change makes the mode stiffer as K / G grows: that is volumetric locking, seen
/// without boundary layers, contact or plasticity. G = rho = 1, velocity amplitude 1e-3 (the
/// strain stays below 1e-3: linear), 2 x 2 particles per cell, APIC, bspline2, cfl 0.5.
const SQUARE: &str = r#"
[simulation]
dimension = 2
scheme = "explicit"
end_time = 0.6
cfl = 0.5
gravity = [0.0, 0.0]
transfer = "apic"
shape_function = "bspline2"

[grid]
size = [1.0, 1.0]
cell_size = 0.0625

# the mode's walls are slip walls held both ways: its normal stress at a wall turns to tension
# every half period, which a separating wall would not hold
[grid.boundary]
contact = "bonded"

[[materials]]
name = "rubber"
model = "neo_hookean_incompressible"
density = 1.0
shear_modulus = 1.0
bulk_modulus = 100.0

[[bodies]]
material = "rubber"
shape = { type = "box", min = [0.0, 0.0], max = [1.0, 1.0] }
particles_per_cell = 2
velocity = ["1.0e-3*sin(pi*x)*cos(pi*y)", "-1.0e-3*cos(pi*x)*sin(pi*y)"]
"#;

/// omega of the mode, from the time of the kinetic energy's first minimum (a quarter period
/// after the start from the undeformed state), refined by a parabola through the three steps
/// around it.
fn mode_frequency(bulk_over_shear: f64, averaging: VolumetricAveraging, h: f64) -> f64 {
    mode_frequency_of(h, |d| {
        d.materials[0].bulk_modulus = Some(bulk_over_shear);
        d.simulation.volumetric_averaging = averaging;
    })
}

/// omega of the mode for the square edited by `edit`, at cell size `h`.
fn mode_frequency_of(h: f64, edit: impl FnOnce(&mut Deck)) -> f64 {
    let mut d = Deck::parse(SQUARE, "square.toml").expect("deck parses");
    edit(&mut d);
    d.grid.cell_size = h;
    d.validate("square.toml").expect("deck is valid");
    in_pool(2, || {
        let mut sim = Simulation::<2>::new(&d).unwrap();
        let mut series = vec![(0.0, sim.kinetic_energy())];
        let mut omega = None;
        drive(&d, &mut sim, |sim, _| {
            series.push((sim.time, sim.kinetic_energy()));
            let n = series.len();
            if n >= 3 && series[n - 2].1 < series[n - 3].1 && series[n - 2].1 <= series[n - 1].1 {
                let [(t0, e0), (t1, e1), (t2, e2)] = [series[n - 3], series[n - 2], series[n - 1]];
                // vertex of the parabola through the three points
                let num = (t1 - t0).powi(2) * (e1 - e2) - (t1 - t2).powi(2) * (e1 - e0);
                let den = (t1 - t0) * (e1 - e2) - (t1 - t2) * (e1 - e0);
                let t_min = t1 - 0.5 * num / den;
                omega = Some(PI / (2.0 * t_min));
            }
            omega.is_none()
        });
        omega.unwrap_or_else(|| panic!("no kinetic energy minimum before t = {}", sim.time))
    })
}

/// With each particle's own volume change penalised, the mode of a nearly incompressible
/// square (K / G = 1000, 2D Poisson's ratio (K - G) / (2 K) = 0.4995) comes out 38% too stiff at
/// h = 1/16 and still 27% at h = 1/32: locking, an error that grows with K / G and does not go
/// away with the grid. With the nodal averaging the same square is as accurate as a
/// compressible one (K = G, Poisson's ratio 0) on the same grid. The figures of the run that
/// set the bounds are in the comments; the stiffening is omega(K = 1000 G) / omega(K = G) - 1
/// on one grid, which takes out the discretisation error that does not depend on K (the
/// compressible square's omega is 4.8% low at h = 1/16, 2.9% at h = 1/32).
#[test]
fn nodal_averaging_removes_the_locking_of_an_isochoric_mode() {
    use VolumetricAveraging::{Nodal, None};
    let exact = PI * 2f64.sqrt();
    let err = |w: f64| w / exact - 1.0;
    // omega[grid][K = G, K = 1000 G][none, nodal]
    let mut omega = [[[0.0; 2]; 2]; 2];
    for (g, h) in [1.0 / 16.0, 1.0 / 32.0].into_iter().enumerate() {
        for (k, bulk) in [1.0, 1000.0].into_iter().enumerate() {
            for (a, avg) in [None, Nodal].into_iter().enumerate() {
                omega[g][k][a] = mode_frequency(bulk, avg, h);
            }
        }
        let w = &omega[g];
        eprintln!(
            "h = 1/{:.0}: omega / exact - 1 at K = G: {:.4} (none), {:.4} (nodal); at K = 1000 G: {:.4} (none), {:.4} (nodal)",
            1.0 / h,
            err(w[0][0]),
            err(w[0][1]),
            err(w[1][0]),
            err(w[1][1])
        );
        // a compressible square hardly notices the averaging (measured: 0.10%, 0.09%)
        assert!((w[0][1] / w[0][0] - 1.0).abs() < 0.005, "h = {h}: {w:?}");
    }
    let stiffening = |g: usize, a: usize| omega[g][1][a] / omega[g][0][a] - 1.0;
    // without averaging it locks (measured: 38%, 27%)
    assert!(
        stiffening(0, 0) > 0.3 && stiffening(1, 0) > 0.2,
        "{omega:?}"
    );
    // with it, a residual stiffening that the grid refinement removes (measured: 5.0%, 2.0%)
    assert!(stiffening(0, 1) < 0.1, "{omega:?}");
    assert!(stiffening(1, 1) < 0.5 * stiffening(0, 1), "{omega:?}");
    // against the exact omega on the finer grid: within the compressible square's error
    // (measured: -1.0% against -2.9%), where without averaging it is 23% off
    assert!(
        err(omega[1][1][1]).abs() <= err(omega[1][0][1]).abs(),
        "{omega:?}"
    );
    assert!(err(omega[1][1][0]) > 0.2, "{omega:?}");
}

/// The projection on the same mode (no bulk modulus: the material is incompressible), with
/// the pressure on the nodes and with one pressure per cell (`pressure.unknowns = "cells"`,
/// whose per-cell constraint could lock if the velocity space were too poor for it): on both
/// grids each is within half a percent of the error of the compressible explicit square
/// (K = G, which cannot lock) on the same grid, and below it in the measured runs:
///
/// | h | explicit, K = G | projection, nodes | projection, cells |
/// |---|---|---|---|
/// | 1/16 | -7.0% | -6.4% | -5.3% |
/// | 1/32 | -3.5% | -2.9% | -3.6% |
///
/// (the cells with `stress_update = "usl"`, which they require).
#[test]
fn projection_isochoric_mode_does_not_lock() {
    use pmpm::deck::{PressureUnknowns, Scheme};
    let exact = PI * 2f64.sqrt();
    let err = |w: f64| w / exact - 1.0;
    for h in [1.0 / 16.0, 1.0 / 32.0] {
        let compressible = err(mode_frequency(1.0, VolumetricAveraging::None, h));
        for unknowns in [PressureUnknowns::Nodes, PressureUnknowns::Cells] {
            let e = err(mode_frequency_of(h, |d| {
                d.simulation.scheme = Scheme::Projection;
                d.materials[0].bulk_modulus = None;
                d.pressure.unknowns = unknowns;
                if unknowns == PressureUnknowns::Cells {
                    d.simulation.stress_update = pmpm::deck::StressUpdate::Usl;
                }
            }));
            eprintln!(
                "h = 1/{:.0}, {unknowns:?}: omega / exact - 1 = {e:.4} (compressible explicit: {compressible:.4})",
                1.0 / h
            );
            assert!(
                e.abs() <= compressible.abs() + 0.005,
                "h = {h}, {unknowns:?}: {e}"
            );
        }
    }
}
