//! Implicit viscosity (`simulation.viscosity = "implicit"`, the projection's default): viscous
//! flows at steps far above the explicit limit dt <= rho h^2 / (2 D mu), against exact
//! solutions.

use crate::common;

use common::{deck, drive, in_pool};
use pmpm::scheme::Simulation;
use pmpm_cli::validation::bingham::CASE;
use pmpm_cli::validation::periodic::poiseuille_exact;

/// Body-force-driven plane Poiseuille flow from rest (Morris, Fox & Zhu 1997): channel L =
/// 1e-3 m between no-slip walls, periodic along x, nu = 1e-6 m2/s, body force 2e-4 m/s2
/// (steady centre-line speed 2.5e-5 m/s), h = L/20, projection with implicit viscosity at a
/// fixed step 50 times the explicit limit h^2 / (4 nu) = 6.25e-4 s, to t = 1 s (32 steps).
///
/// Asserted: every particle row's mean x-velocity within 2% of the centre-line speed of the
/// exact series solution at t = 1 s (the validation report's bound for the transient at the
/// explicit step; the slowest mode, decaying over 0.1 s, is gone by then, and the steady
/// profile is the solve's own fixed point whatever the step).
#[test]
fn poiseuille_flow_at_fifty_times_the_viscous_limit_reaches_the_exact_profile() {
    let (l, h): (f64, f64) = (1e-3, 5e-5);
    let dt = 50.0 * h * h / (4.0 * 1e-6);
    let d = deck(&format!(
        r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 1.0
dt = {dt}
gravity = [2.0e-4, 0.0]
[grid]
size = [{w}, {l}]
cell_size = {h}
[grid.boundary]
x_min = "periodic"
x_max = "periodic"
y_min = "no_slip"
y_max = "no_slip"
[pressure]
rhs = "flux"
[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3
[[bodies]]
material = "water"
shape = {{ type = "box", min = [0.0, 0.0], max = [{w}, {l}] }}
particles_per_cell = 2
"#,
        w = 10.0 * h
    ));
    assert_eq!(
        d.simulation.viscosity,
        Some(pmpm::deck::ViscosityTreatment::Implicit),
        "the projection's default"
    );
    let mut sim = Simulation::<2>::new(&d).unwrap();
    let mut steps = 0;
    in_pool(2, || {
        drive(&d, &mut sim, |_, _| {
            steps += 1;
            true
        })
    });
    assert_eq!(steps, 32, "the fixed step was used");
    let rows = (2.0 * l / h).round() as usize;
    let mut sum = vec![(0.0, 0.0, 0usize); rows];
    for (x, v) in sim.particles.x.iter().zip(&sim.particles.v) {
        let k = ((x[1] / (h / 2.0)).floor() as usize).min(rows - 1);
        sum[k] = (sum[k].0 + x[1], sum[k].1 + v[0], sum[k].2 + 1);
        assert!(v[1].abs() < 1e-3 * 2.5e-5, "cross flow {}", v[1]);
    }
    for (y, u, n) in sum {
        let (y, u) = (y / n as f64, u / n as f64);
        let err = (u - poiseuille_exact(y, sim.time)).abs() / 2.5e-5;
        assert!(err < 0.02, "row y = {y:.3e}: error {:.2}%", 100.0 * err);
    }
}

/// Bingham plane Poiseuille flow (the validation case `bingham_poiseuille`: W = 1, rho = 1,
/// mu_p = 1, tau_y = 0.1, m = 250, body force 1; plug 2 y0 = 0.2 wide, peak speed 0.08) under
/// the projection with implicit viscosity and its adaptive step, h = W/16, to t = 0.8.
///
/// Asserted: (1) the run takes at most 1/50 of the 21,300 steps the explicit viscous limit of
/// the plug's viscosity mu_p + tau_y m sets; (2) every particle within 1% of the peak speed
/// of the regularised steady profile (the solve at the lagged viscosity converges to the
/// regularised law's fixed point) and within 3% of the ideal Bingham profile; (3) the plug
/// moves as one body: the particles within y0 - h/2 of the centre within 1% of each other.
#[test]
fn bingham_channel_at_the_projection_step_matches_the_regularised_profile() {
    let d = deck(
        r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.8
cfl = 0.5
gravity = [1.0, 0.0]
[grid]
size = [0.3125, 1.0]
cell_size = 0.0625
[grid.boundary]
x_min = "periodic"
x_max = "periodic"
y_min = "no_slip"
y_max = "no_slip"
[pressure]
rhs = "flux"
[[materials]]
name = "bingham"
model = "bingham"
density = 1.0
viscosity = 1.0
yield_stress = 0.1
papanastasiou_exponent = 250.0
[[bodies]]
material = "bingham"
shape = { type = "box", min = [0.0, 0.0], max = [0.3125, 1.0] }
particles_per_cell = 2
"#,
    );
    let ch = CASE;
    let (h, peak, y0) = (0.0625, ch.peak(), ch.plug_half_width());
    let reg = ch.regularised(400);
    let mut sim = Simulation::<2>::new(&d).unwrap();
    let mut steps = 0usize;
    in_pool(2, || {
        drive(&d, &mut sim, |_, _| {
            steps += 1;
            true
        })
    });
    assert!(steps <= 21_300 / 50, "{steps} steps");
    let (ys, us): (Vec<f64>, Vec<f64>) = reg.iter().copied().unzip();
    let (mut plug_lo, mut plug_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (x, v) in sim.particles.x.iter().zip(&sim.particles.v) {
        let (y, u) = (x[1], v[0]);
        let k = ys.partition_point(|&a| a < y).clamp(1, ys.len() - 1);
        let f = (y - ys[k - 1]) / (ys[k] - ys[k - 1]);
        let u_reg = us[k - 1] + f * (us[k] - us[k - 1]);
        assert!(
            (u - u_reg).abs() < 0.01 * peak,
            "y = {y:.3}: u = {u:.5}, regularised {u_reg:.5}"
        );
        assert!(
            (u - ch.ideal(y)).abs() < 0.03 * peak,
            "y = {y:.3}: u = {u:.5}"
        );
        if (y - 0.5).abs() < y0 - h / 2.0 {
            (plug_lo, plug_hi) = (plug_lo.min(u), plug_hi.max(u));
        }
    }
    assert!(
        plug_hi - plug_lo < 0.01 * peak,
        "plug speeds {plug_lo} to {plug_hi}"
    );
}

/// A Newtonian layer of mu = 100 Pa s spreading on a no-slip floor (a syrup or lava), the
/// block 0.1 m x 0.1 m against a symmetry plane, rho = 1000, h = 0.01 m, to t = 10 s: the
/// explicit viscous limit h^2 rho / (4 mu) = 2.5e-4 s would take 40,000 steps.
///
/// Reference: the viscous gravity current of lubrication theory on a horizontal floor,
/// constant area A per unit width, x_N(t) = 1.411 (rho g A^3 t / (3 mu))^(1/5) (Huppert 1982,
/// J. Fluid Mech. 121, 43-58: h_t = (rho g / 3 mu) (h^3 h_x)_x, the similarity solution
/// h^3 = (3/10) (eta_N^2 - eta^2) with the area fixing eta_N = 1.411). At 10 s the current is
/// 2.8 times its initial length and 9 times longer than deep, and the front (the rightmost
/// particle plus half its spacing) is 4.6% ahead of the similarity solution with the particles
/// packed (the default: the nose's particles pushed apart across a layer thinner than their
/// spacing), 1.0% behind with `density_correction = "positions"` (shallow-water theory's own
/// approach to similarity and the 2-cell-deep nose's no-slip drag).
///
/// Asserted: the front within 5% of the similarity solution at t = 5 and 10 s, the particles'
/// total volume within 1% at every frame, and at most 1,000 steps.
#[test]
fn a_viscous_current_spreads_as_the_similarity_solution_says() {
    let d = deck(include_str!("../../examples/viscous_current_2d.toml"));
    let mut sim = Simulation::<2>::new(&d).unwrap();
    let v0: f64 = sim.particles.volume0.iter().sum();
    let (mu, rho, g) = (100.0, 1000.0, 9.81);
    let front =
        |sim: &Simulation<2>| sim.particles.x.iter().map(|x| x[0]).fold(0.0, f64::max) + 0.0025;
    let similarity = |t: f64| 1.411 * (rho * g * v0.powi(3) * t / (3.0 * mu)).powf(0.2);
    let (mut steps, mut next) = (0usize, 5.0);
    let mut checked = 0;
    in_pool(2, || {
        drive(&d, &mut sim, |sim, _| {
            steps += 1;
            let v: f64 = (0..sim.particles.len())
                .map(|p| sim.particles.volume(p))
                .sum();
            assert!(
                (v / v0 - 1.0).abs() < 0.01,
                "t = {}: volume {}",
                sim.time,
                v / v0
            );
            if sim.time >= next - 1e-9 {
                let (x, x_n) = (front(sim), similarity(sim.time));
                assert!(
                    (x / x_n - 1.0).abs() < 0.05,
                    "t = {}: front {x}, similarity {x_n}",
                    sim.time
                );
                next += 5.0;
                checked += 1;
            }
            true
        })
    });
    assert_eq!(checked, 2);
    assert!(steps <= 1000, "{steps} steps");
}
