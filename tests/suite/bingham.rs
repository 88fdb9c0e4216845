//! Yield-stress fluid in a channel against the analytic Bingham solution.

use crate::common;

use common::{deck, drive, in_pool};
use pmpm::scheme::Simulation;
use pmpm_cli::validation::bingham::CASE;

/// The channel of the tests below, W = 1, h = W/16, periodic along the flow, no-slip walls,
/// body force 1 along x, explicit (bulk modulus 1e4), to t = 0.8, filled with the material
/// whose `[[materials]]` keys (a `name` among them) are `material`.
fn channel(material: &str) -> pmpm::Deck {
    let name = material
        .lines()
        .find_map(|l| l.strip_prefix("name = "))
        .expect("the material has a name");
    deck(&format!(
        r#"
[simulation]
dimension = 2
scheme = "explicit"
end_time = 0.8
cfl = 0.5
gravity = [1.0, 0.0]
transfer = "apic"
[grid]
size = [0.3125, 1.0]
cell_size = 0.0625
[grid.boundary]
x_min = "periodic"
x_max = "periodic"
y_min = "no_slip"
y_max = "no_slip"
[[materials]]{material}bulk_modulus = 1.0e4
[[bodies]]
material = {name}
shape = {{ type = "box", min = [0.0, 0.0], max = [0.3125, 1.0] }}
"#
    ))
}

/// Runs `d` to its end time through the driver.
fn run_to_end(d: &pmpm::Deck) -> Simulation<2> {
    let mut sim = Simulation::<2>::new(d).unwrap();
    drive(d, &mut sim, |_, _| true);
    sim
}

/// Bingham plane Poiseuille flow, the parameters of the validation case `bingham_poiseuille`
/// (W = 1, rho = 1, mu_p = 1, tau_y = 0.1, body force 1, m = 250: plug 2 y0 = 0.2 wide, peak
/// speed 0.08) on a coarse grid, h = W/16, explicit scheme (the cheaper step; the flow is
/// incompressible and 1D, and the projection gives the same rows), from rest to t = 0.8 (about
/// 21,000 steps, the explicit viscous limit of the plug's viscosity mu_p + tau_y m).
///
/// Asserted: (1) the profile is within 3% of the peak speed of the ideal Bingham profile at
/// every particle (the issue's bound, here at half its resolution; the regularisation alone
/// accounts for y0 / (m u_p) = 0.5% of it, the transient left at t = 0.8 for about 0.1%);
/// (2) a plug exists: the particles in |y - 1/2| < y0 - h/2 are unyielded (sqrt(J2) of their
/// stress below tau_y) and move as one body (speeds within 1% of the peak; the regularised law
/// itself lets them creep by y0 / (2 m) = 0.25%), while those in the sheared layers more than
/// a cell from the plug edge have yielded; (3) no cross flow.
#[test]
fn bingham_channel_has_its_plug_and_the_analytic_profile() {
    let d = channel(
        r#"
name = "bingham"
model = "bingham"
density = 1.0
viscosity = 1.0
yield_stress = 0.1
papanastasiou_exponent = 250.0
"#,
    );
    let ch = CASE;
    let (h, peak, y0, ty) = (0.0625, ch.peak(), ch.plug_half_width(), ch.yield_stress);
    let sim = in_pool(2, || run_to_end(&d));
    let ps = &sim.particles;
    let mut worst = 0.0f64;
    let (mut plug_lo, mut plug_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut plug_particles = 0;
    for p in 0..ps.len() {
        let (y, u) = (ps.x[p][1], ps.v[p][0]);
        worst = worst.max((u - ch.ideal(y)).abs() / peak);
        assert!(ps.v[p][1].abs() < 1e-9 * peak, "cross flow {}", ps.v[p][1]);
        let tau = pmpm::material::deviatoric_stress(ps, &sim.materials, p);
        let sqrt_j2 = (0.5 * tau.norm_squared()).sqrt();
        let r = (y - 0.5).abs();
        if r < y0 - 0.5 * h {
            assert!(sqrt_j2 < ty, "y = {y}: sqrt(J2) = {sqrt_j2} in the plug");
            plug_lo = plug_lo.min(u);
            plug_hi = plug_hi.max(u);
            plug_particles += 1;
        } else if r > y0 + h {
            assert!(
                sqrt_j2 > ty,
                "y = {y}: sqrt(J2) = {sqrt_j2} in the sheared layer"
            );
        }
    }
    println!(
        "Bingham channel, h = W/16, t = 0.8: max error {:.3}% of the peak, plug speeds {:.5}..{:.5} (ideal {:.5})",
        100.0 * worst,
        plug_lo,
        plug_hi,
        peak
    );
    assert!(
        plug_particles >= 10,
        "{plug_particles} particles in the plug"
    );
    assert!(
        (plug_hi - plug_lo) / peak < 0.01,
        "the plug shears: {plug_lo}..{plug_hi}"
    );
    assert!(worst <= 0.03, "max error {:.3}% of the peak", 100.0 * worst);
}

/// Herschel-Bulkley plane Poiseuille flow (the channel above, shear-thinning: K = 1, n = 0.5,
/// tau_y = 0.1, m = 250, body force G = 1, W = 1). Where |y - W/2| = s exceeds the plug's half
/// width y0 = tau_y / G, K gamma^n = G s - tau_y, so
///
///   u(s) = (K / G) n / (n + 1) [X(W/2)^((n + 1) / n) - X(s)^((n + 1) / n)], X(s) = (G s - tau_y) / K,
///
/// and the plug moves at u(y0) = 0.0213. Asserted as for Bingham: every particle within 3 % of
/// the peak speed at t = 0.8 (measured 1.4 %, the same at t = 1.6: steady; the regularisation
/// and the power law's shear-rate floor 1/m account for part of it), and no cross flow.
#[test]
fn herschel_bulkley_channel_follows_the_analytic_profile() {
    let d = channel(
        r#"
name = "slurry"
model = "herschel_bulkley"
density = 1.0
consistency = 1.0
flow_index = 0.5
yield_stress = 0.1
papanastasiou_exponent = 250.0
"#,
    );
    let (k, n, ty, g) = (1.0f64, 0.5f64, 0.1, 1.0);
    let x = |s: f64| ((g * s - ty) / k).max(0.0);
    let e = (n + 1.0) / n;
    let exact = |y: f64| k / g * n / (n + 1.0) * (x(0.5).powf(e) - x((y - 0.5).abs()).powf(e));
    let peak = exact(0.5);
    let sim = in_pool(2, || run_to_end(&d));
    let ps = &sim.particles;
    let mut worst = 0.0f64;
    for p in 0..ps.len() {
        let (y, u) = (ps.x[p][1], ps.v[p][0]);
        worst = worst.max((u - exact(y)).abs() / peak);
        assert!(ps.v[p][1].abs() < 1e-9 * peak, "cross flow {}", ps.v[p][1]);
    }
    println!(
        "Herschel-Bulkley channel, h = W/16, t = 0.8: max error {:.3}% of the peak {peak:.5}",
        100.0 * worst
    );
    assert!(worst <= 0.03, "max error {:.3}% of the peak", 100.0 * worst);
}
