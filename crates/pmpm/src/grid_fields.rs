//! Fields on the grid's nodes for a frame (`formats = ["grid"]`, docs/deck.md): what the
//! particles carry, spread to the nodes for ParaView's slices, contours and streamlines.
//!
//! The particles' fields are spread with the linear hat weights N_i(x_p), whatever shape
//! function the run steps with: a node's value is the mass-weighted mean of the particles
//! within a cell of it, sum_p N_ip m_p q_p / sum_p N_ip m_p, and its volume fraction is
//! sum_p N_ip V_p over the node's dual cell (h^D, halved on each wall it lies on). The
//! same spreading for both schemes makes the explicit scheme's particle pressure, a
//! checkerboard from particle to particle, a smooth field. Written by hand: it is one of
//! the transfers, and it runs only when a frame is written (it allocates its arrays then).

use crate::particles::Particles;
use crate::scheme::Simulation;

/// A 3-vector of a D-vector (z = 0 in 2D).
fn pad3<const D: usize>(v: &crate::grid::Vector<D>) -> [f64; 3] {
    std::array::from_fn(|d| if d < D { v[d] } else { 0.0 })
}

/// A 3 x 3 tensor, row by row, of a D x D one (zeros outside it in 2D).
fn pad9<const D: usize>(m: &crate::particles::Matrix<D>) -> [f64; 9] {
    std::array::from_fn(|k| {
        let (r, c) = (k / 3, k % 3);
        if r < D && c < D {
            m[(r, c)]
        } else {
            0.0
        }
    })
}

/// Per particle: its Cauchy stress -p I + tau (Pa), its strain rate sym L (1/s), both as
/// 3 x 3 tensors row by row, and its shear rate sqrt(2 dev D : dev D) (1/s).
pub fn particle_stress<const D: usize>(sim: &Simulation<D>, p: usize) -> [f64; 9] {
    let ps = &sim.particles;
    let mut s = pad9(&crate::material::deviatoric_stress(ps, &sim.materials, p));
    for d in 0..D {
        s[4 * d] -= ps.pressure[p];
    }
    s
}

/// The strain rate D = (L + L^T) / 2 of particle `p`, row by row.
pub fn particle_strain_rate<const D: usize>(ps: &Particles<D>, p: usize) -> [f64; 9] {
    let l = &ps.velocity_gradient[p];
    pad9(&((l + l.transpose()) * 0.5))
}

/// The shear rate sqrt(2 dev D : dev D) of particle `p` (1/s).
pub fn particle_shear_rate<const D: usize>(ps: &Particles<D>, p: usize) -> f64 {
    let dev = crate::material::deviatoric_strain_rate(&ps.velocity_gradient[p]);
    (2.0 * dev.norm_squared()).sqrt()
}

/// Whether particle `p` has yielded (1) or not (0, also for a material without a yield
/// stress). Callers ask only when a material of the run has one ([`Law::has_yield`]).
///
/// [`Law::has_yield`]: crate::material::Law::has_yield
pub fn particle_yielded<const D: usize>(sim: &Simulation<D>, p: usize) -> f64 {
    let ps = &sim.particles;
    let law = &sim.materials[ps.material[p] as usize].law;
    let tau = crate::material::deviatoric_stress(ps, &sim.materials, p);
    match law.yielded(&tau, &ps.velocity_gradient[p]) {
        Some(true) => 1.0,
        _ => 0.0,
    }
}

/// The fields at the grid's nodes, x fastest, then y, then z (VTK ImageData's order).
pub struct NodeFields {
    /// Nodes along each axis (1 along z in 2D).
    pub nodes: [usize; 3],
    /// The first node's position (m).
    pub origin: [f64; 3],
    /// Node spacing (m).
    pub h: f64,
    /// Mass spread to the node, sum_p N_ip m_p (kg; kg per metre of thickness in 2D).
    pub mass: Vec<f64>,
    /// Velocity (m/s).
    pub velocity: Vec<[f64; 3]>,
    /// Pressure (Pa, positive in compression).
    pub pressure: Vec<f64>,
    /// Volume fraction: the material's volume over the node's dual cell (0 to about 1).
    pub volume_fraction: Vec<f64>,
    /// Density of the material at the node, mass over volume (kg/m^3; 0 where none).
    pub density: Vec<f64>,
    /// Strain rate sym L (1/s), row by row.
    pub strain_rate: Vec<[f64; 9]>,
    /// Shear rate sqrt(2 dev D : dev D) (1/s).
    pub shear_rate: Vec<f64>,
    /// Cauchy stress (Pa), row by row.
    pub stress: Vec<[f64; 9]>,
    /// The yielded share of the node's mass (0 to 1), when a material has a yield stress.
    pub yielded: Option<Vec<f64>>,
}

impl NodeFields {
    /// The fields of `sim` now.
    pub fn of<const D: usize>(sim: &Simulation<D>) -> Self {
        let geo = &sim.grid.geo;
        let mut nodes = [1usize; 3];
        let mut origin = [0.0; 3];
        for d in 0..D {
            nodes[d] = geo.cells[d] + 1;
            origin[d] = geo.origin[d];
        }
        let count = nodes.iter().product::<usize>();
        let yields = sim.materials.iter().any(|m| m.law.has_yield());
        let mut f = Self {
            nodes,
            origin,
            h: geo.h,
            mass: vec![0.0; count],
            velocity: vec![[0.0; 3]; count],
            pressure: vec![0.0; count],
            volume_fraction: vec![0.0; count],
            density: vec![0.0; count],
            strain_rate: vec![[0.0; 9]; count],
            shear_rate: vec![0.0; count],
            stress: vec![[0.0; 9]; count],
            yielded: yields.then(|| vec![0.0; count]),
        };
        let ps = &sim.particles;
        let at = |idx: &[usize; D]| -> usize {
            let mut k = 0;
            for d in (0..D).rev() {
                k = k * nodes[d] + idx[d];
            }
            k
        };
        // sums over the particles, in id order (the same bits whatever the sort did)
        for p in ps.places() {
            let xc = geo.to_cells(&ps.x[p]);
            let base: [isize; D] = std::array::from_fn(|d| xc[d].floor() as isize);
            let m = ps.mass[p];
            let (v, pr, vol) = (pad3(&ps.v[p]), ps.pressure[p], ps.volume(p));
            let (rate, sigma) = (particle_strain_rate(ps, p), particle_stress(sim, p));
            let shear = particle_shear_rate(ps, p);
            let yielded = yields.then(|| particle_yielded(sim, p));
            for corner in 0..(1usize << D) {
                let mut idx = [0usize; D];
                let mut w = 1.0;
                let mut inside = true;
                for d in 0..D {
                    let c = base[d] + ((corner >> d) & 1) as isize;
                    if c < 0 || c >= nodes[d] as isize {
                        inside = false;
                        break;
                    }
                    idx[d] = c as usize;
                    w *= (1.0 - (xc[d] - c as f64).abs()).max(0.0);
                }
                if !inside || w == 0.0 {
                    continue;
                }
                let k = at(&idx);
                let wm = w * m;
                f.mass[k] += wm;
                for a in 0..3 {
                    f.velocity[k][a] += wm * v[a];
                }
                f.pressure[k] += wm * pr;
                f.volume_fraction[k] += w * vol;
                for a in 0..9 {
                    f.strain_rate[k][a] += wm * rate[a];
                    f.stress[k][a] += wm * sigma[a];
                }
                f.shear_rate[k] += wm * shear;
                if let (Some(y), Some(py)) = (f.yielded.as_mut(), yielded) {
                    y[k] += wm * py;
                }
            }
        }
        // means, and the volume over the dual cell
        for k in 0..count {
            let mut rest = k;
            let mut cell = 1.0;
            for &n in nodes.iter().take(D) {
                let i = rest % n;
                rest /= n;
                // a node on a face of the grid holds half a cell along that axis (a
                // periodic face's node too: its image holds the other half)
                cell *= if i == 0 || i + 1 == n {
                    0.5 * geo.h
                } else {
                    geo.h
                };
            }
            let volume = f.volume_fraction[k];
            f.density[k] = if volume > 0.0 {
                f.mass[k] / volume
            } else {
                0.0
            };
            f.volume_fraction[k] = volume / cell;
            let m = f.mass[k];
            if m <= 0.0 {
                continue;
            }
            for a in 0..3 {
                f.velocity[k][a] /= m;
            }
            f.pressure[k] /= m;
            for a in 0..9 {
                f.strain_rate[k][a] /= m;
                f.stress[k][a] /= m;
            }
            f.shear_rate[k] /= m;
            if let Some(y) = f.yielded.as_mut() {
                y[k] /= m;
            }
        }
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Water at rest filling a box: the nodes inside read volume fraction 1 (the ones on the
    /// walls too, over their half cells), the density of water, and the hydrostatic
    /// pressure rho g (H - y) to within the spreading's error at a particle spacing.
    #[test]
    fn water_at_rest_reads_full_with_its_density_and_pressure() {
        let text = r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.01
dt = 0.001
gravity = [0.0, -9.81]

[grid]
origin = [0.0, 0.0]
size = [0.2, 0.2]
cell_size = 0.02

[[materials]]
name = "water"
model = "newtonian"
density = 1000.0
viscosity = 1.0e-3

[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [0.2, 0.1] }

[output]
formats = ["grid"]
"#;
        let mut deck = crate::deck::Deck::parse(text, "t.toml").unwrap();
        deck.validate("t.toml").unwrap();
        let mut sim = crate::scheme::Simulation::<2>::new(&deck).unwrap();
        let g = 9.81;
        for p in 0..sim.particles.len() {
            sim.particles.pressure[p] = 1000.0 * g * (0.1 - sim.particles.x[p][1]);
        }
        let f = NodeFields::of(&sim);
        assert_eq!(f.nodes, [11, 11, 1]);
        for j in 0..4 {
            for i in 0..11 {
                let k = j * 11 + i;
                assert!((f.volume_fraction[k] - 1.0).abs() < 1e-12, "{i} {j}");
                assert!((f.density[k] - 1000.0).abs() < 1e-9);
                let y = j as f64 * 0.02;
                let want = 1000.0 * g * (0.1 - y);
                if j > 0 {
                    // the mean of a linear field over weights symmetric about the node
                    assert!(
                        (f.pressure[k] - want).abs() < 1e-6,
                        "{i} {j}: {}",
                        f.pressure[k]
                    );
                } else {
                    // on the floor the weights reach only up, less than half a cell
                    let p = f.pressure[k];
                    assert!(p < want && p > want - 1000.0 * g * 0.01, "{i}: {p}");
                }
            }
        }
        // above the water: nothing
        assert_eq!(f.mass[7 * 11 + 5], 0.0);
        assert!(f.yielded.is_none());
    }
}
