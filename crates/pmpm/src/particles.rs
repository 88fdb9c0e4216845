//! Material points, stored as a struct of arrays, and their creation from the deck's bodies.

use crate::deck::{Deck, InitialStress};
use crate::grid::{GridGeometry, Vector};
use nalgebra::SMatrix;

/// D x D matrix of f64.
pub type Matrix<const D: usize> = SMatrix<f64, D, D>;

/// All particles, one array per field. The arrays are sorted by cell from time to time
/// ([`Particles::permute`]) so that the transfers walk the grid in order; `id` keeps each
/// particle's number from its creation, and the output lists particles by it.
#[derive(Debug, Clone, Default)]
pub struct Particles<const D: usize> {
    /// Number of the particle at this place, in creation order (0 to n - 1).
    pub id: Vec<u32>,
    /// Position x_p.
    pub x: Vec<Vector<D>>,
    /// Velocity v_p.
    pub v: Vec<Vector<D>>,
    /// Mass m_p.
    pub mass: Vec<f64>,
    /// Initial volume V_p^0.
    pub volume0: Vec<f64>,
    /// Volume ratio J = V_p / V_p^0.
    pub jacobian: Vec<f64>,
    /// Deformation gradient F_p.
    pub deformation: Vec<Matrix<D>>,
    /// Pressure p_p (positive in compression).
    pub pressure: Vec<f64>,
    /// Deviatoric Cauchy stress tau_p.
    pub tau: Vec<Matrix<D>>,
    /// Velocity gradient L_p of the last grid-to-particle transfer.
    pub velocity_gradient: Vec<Matrix<D>>,
    /// APIC affine matrix C_p.
    pub affine: Vec<Matrix<D>>,
    /// Index into the deck's materials.
    pub material: Vec<u16>,
    /// GIMP half-width of the particle domain, in cells.
    pub half_width: Vec<f64>,
}

impl<const D: usize> Particles<D> {
    /// Number of particles.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Current volume V_p = J V_p^0.
    #[inline]
    pub fn volume(&self, p: usize) -> f64 {
        self.jacobian[p] * self.volume0[p]
    }

    /// Places of the particles in id order: `places()[k]` is where particle `k` is stored.
    pub fn places(&self) -> Vec<usize> {
        let mut at = vec![0; self.len()];
        for (p, &id) in self.id.iter().enumerate() {
            at[id as usize] = p;
        }
        at
    }

    /// A copy of a per-particle field in id order.
    pub fn by_id<T: Copy>(&self, field: &[T]) -> Vec<T> {
        self.places().iter().map(|&p| field[p]).collect()
    }

    /// Reorders every array so that the particle at place `order[k]` moves to place k.
    pub fn permute(&mut self, order: &[u32], scratch: &mut PermuteScratch<D>) {
        permute(&mut self.id, order, scratch);
        permute(&mut self.x, order, scratch);
        permute(&mut self.v, order, scratch);
        permute(&mut self.mass, order, scratch);
        permute(&mut self.volume0, order, scratch);
        permute(&mut self.jacobian, order, scratch);
        permute(&mut self.deformation, order, scratch);
        permute(&mut self.pressure, order, scratch);
        permute(&mut self.tau, order, scratch);
        permute(&mut self.velocity_gradient, order, scratch);
        permute(&mut self.affine, order, scratch);
        permute(&mut self.material, order, scratch);
        permute(&mut self.half_width, order, scratch);
    }
}

/// Work space of [`Particles::permute`]: one bit per particle, kept between sorts so that a
/// sort allocates nothing once it has grown. The permutation is applied in place, cycle by
/// cycle, so a sort needs no second copy of the particle arrays (which would cost as much
/// memory as the matrix fields themselves).
#[derive(Debug, Default)]
pub struct PermuteScratch<const D: usize> {
    done: Vec<u64>,
}

/// `field[k] = old field[order[k]]` in place (`order` a permutation of the indices).
///
/// Serial: it runs every `sort_interval` steps and costs a few nanoseconds per particle and
/// field, against microseconds per particle for a step.
pub fn permute<T: Copy, const D: usize>(
    field: &mut [T],
    order: &[u32],
    scratch: &mut PermuteScratch<D>,
) {
    let done = &mut scratch.done;
    done.clear();
    done.resize(field.len().div_ceil(64), 0);
    for start in 0..field.len() {
        if done[start / 64] >> (start % 64) & 1 == 1 {
            continue;
        }
        let first = field[start];
        let mut j = start;
        loop {
            done[j / 64] |= 1 << (j % 64);
            let src = order[j] as usize;
            if src == start {
                field[j] = first;
                break;
            }
            field[j] = field[src];
            j = src;
        }
    }
}

/// APIC's affine matrix C_p at t = 0: the gradient of the body's initial velocity field at `x`
/// (central differences over `eps`; exact for the linear field of a rigid rotation or a shear,
/// zero for a uniform velocity), less its trace under the projection as after every transfer.
/// Left at zero, the first transfer drops the velocity's variation around each particle: a
/// block spinning at one turn per second lost 2 to 3 % of its angular momentum in its first
/// step.
fn initial_affine<const D: usize>(
    velocity: &crate::field::CompiledField,
    x: &Vector<D>,
    eps: f64,
    isochoric: bool,
) -> Matrix<D> {
    let mut c = Matrix::<D>::zeros();
    for d in 0..D {
        let mut e = Vector::<D>::zeros();
        e[d] = eps;
        let dv = (velocity.eval(&(x + e), 0.0) - velocity.eval(&(x - e), 0.0)) / (2.0 * eps);
        c.set_column(d, &dv);
    }
    crate::transfer::affine(c, isochoric)
}

impl<const D: usize> Particles<D> {
    /// Fills every body of the deck with particles on a regular lattice of spacing
    /// h / particles_per_cell, lattice points at the centres of the sub-cells.
    pub fn from_deck(deck: &Deck, geo: &GridGeometry<D>) -> Self {
        let mut ps = Particles::default();
        // the hydrostatic initial stress takes the body force at the origin at t = 0
        let g = deck
            .simulation
            .gravity
            .compile()
            .expect("validated expressions")
            .eval(&geo.origin, 0.0);
        let gnorm = g.norm();
        let apic = deck.simulation.transfer == Some(crate::deck::Transfer::Apic);
        let isochoric = deck.simulation.scheme == crate::deck::Scheme::Projection;
        for body in &deck.bodies {
            let mat = deck
                .materials
                .iter()
                .position(|m| m.name == body.material)
                .expect("validated: body material exists");
            let rho = deck.materials[mat].density;
            let ppc = body.particles_per_cell;
            let spacing = geo.h / ppc as f64;
            let vol = spacing.powi(D as i32);
            let (lo, hi) = body.shape.bounds();
            // lattice index range covering the body's bounding box
            let first: [i64; D] =
                std::array::from_fn(|d| ((lo[d] - geo.origin[d]) / spacing - 0.5).floor() as i64);
            let last: [i64; D] =
                std::array::from_fn(|d| ((hi[d] - geo.origin[d]) / spacing - 0.5).ceil() as i64);
            let start = ps.len();
            let velocity = body.velocity.compile().expect("validated expressions");
            let mut idx = first;
            'lattice: loop {
                let x =
                    Vector::<D>::from_fn(|d, _| geo.origin[d] + (idx[d] as f64 + 0.5) * spacing);
                if geo.contains(&x) && body.shape.contains(x.as_slice()) {
                    ps.x.push(x);
                    ps.v.push(velocity.eval(&x, 0.0));
                    if apic {
                        ps.affine
                            .push(initial_affine(&velocity, &x, 1e-3 * spacing, isochoric));
                    }
                    ps.mass.push(rho * vol);
                    ps.volume0.push(vol);
                    ps.material.push(mat as u16);
                    ps.half_width.push(0.5 / ppc as f64);
                }
                for d in 0..D {
                    idx[d] += 1;
                    if idx[d] <= last[d] {
                        continue 'lattice;
                    }
                    idx[d] = first[d];
                }
                break;
            }
            let n = ps.len();
            ps.jacobian.resize(n, 1.0);
            ps.pressure.resize(n, 0.0);
            if body.stress == Some(InitialStress::Hydrostatic) && gnorm > 0.0 {
                // p = rho |g| (H - y), H the body's top along -g
                let down = g / gnorm;
                let top = ps.x[start..]
                    .iter()
                    .map(|x| -x.dot(&down))
                    .fold(f64::NEG_INFINITY, f64::max)
                    + 0.5 * spacing;
                for p in start..n {
                    ps.pressure[p] = rho * gnorm * (top + ps.x[p].dot(&down));
                    // With an equation of state p = K (1 - J) the particle is compressed: it fills
                    // its lattice volume now, so its reference volume and mass are larger.
                    if let Some(k) = deck.materials[mat].bulk_modulus {
                        let j = 1.0 - ps.pressure[p] / k;
                        ps.jacobian[p] = j;
                        ps.volume0[p] = vol / j;
                        ps.mass[p] = rho * vol / j;
                    }
                }
            }
        }
        let n = ps.len();
        ps.id = (0..n as u32).collect();
        // the lattice loop grew the arrays by doubling: give back the unused half
        ps.x.shrink_to_fit();
        ps.v.shrink_to_fit();
        ps.mass.shrink_to_fit();
        ps.volume0.shrink_to_fit();
        ps.material.shrink_to_fit();
        ps.half_width.shrink_to_fit();
        ps.affine.shrink_to_fit();
        ps.jacobian.shrink_to_fit();
        ps.pressure.shrink_to_fit();
        ps.deformation = vec![Matrix::<D>::identity(); n];
        ps.tau = vec![Matrix::<D>::zeros(); n];
        ps.velocity_gradient = vec![Matrix::<D>::zeros(); n];
        if !apic {
            ps.affine = vec![Matrix::<D>::zeros(); n];
        }
        ps
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permute_moves_each_element_to_its_new_place() {
        // two cycles and a fixed point
        let order = [3u32, 0, 2, 1, 5, 4];
        let mut field = vec![10, 11, 12, 13, 14, 15];
        permute(&mut field, &order, &mut PermuteScratch::<2>::default());
        assert_eq!(field, vec![13, 10, 12, 11, 15, 14]);
    }
}
