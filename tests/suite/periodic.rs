//! Periodic boundaries against exact solutions.

use crate::common;

use common::{deck, drive, in_pool};
use pmpm::scheme::Simulation;

/// Start-up of plane Poiseuille flow (Morris, Fox & Zhu 1997 parameters: channel L = 1e-3 m,
/// nu = 1e-6 m2/s, body force F = 2e-4 m/s2 along x, periodic in x, no-slip walls), here on a
/// coarse grid (h = L/20) to t = 0.1125 s: the particle velocities against the series solution
/// u(y,t) = F/(2 nu) y (L - y) - sum 4 F L^2/(nu pi^3 k^3) sin(k pi y/L) exp(-k^2 pi^2 nu t/L^2),
/// k odd; max error within 2% of the steady centre-line velocity F L^2 / (8 nu).
#[test]
fn poiseuille_start_up_follows_the_series() {
    let d = deck(
        r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.1125
cfl = 0.5
gravity = [2.0e-4, 0.0]
transfer = "apic"
[grid]
size = [3.0e-4, 1.0e-3]
cell_size = 5.0e-5
[grid.boundary]
x_min = "periodic"
x_max = "periodic"
y_min = "no_slip"
y_max = "no_slip"
[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [3.0e-4, 1.0e-3] }
"#,
    );
    let (f, l, nu) = (2e-4, 1e-3, 1e-6);
    let u_max = f * l * l / (8.0 * nu);
    let exact = |y: f64, t: f64| {
        let mut u = f / (2.0 * nu) * y * (l - y);
        for n in 0..200 {
            let k = (2 * n + 1) as f64;
            let pi = std::f64::consts::PI;
            u -= 4.0 * f * l * l / (nu * pi.powi(3) * k.powi(3))
                * (k * pi * y / l).sin()
                * (-k * k * pi * pi * nu * t / (l * l)).exp();
        }
        u
    };
    let err = in_pool(2, || {
        let mut sim = Simulation::<2>::new(&d).unwrap();
        drive(&d, &mut sim, |_, _| true);
        let ps = &sim.particles;
        let mut worst = 0.0f64;
        for p in 0..ps.len() {
            worst = worst.max((ps.v[p][0] - exact(ps.x[p][1], sim.time)).abs());
            assert!(ps.v[p][1].abs() < 1e-12 * u_max, "no cross flow");
        }
        worst / u_max
    });
    println!("Poiseuille start-up, h = L/20, t = 0.1125 s: max error {err:.2e} of u_max");
    assert!(err <= 0.02, "max error {:.3}% of u_max", 100.0 * err);
}
