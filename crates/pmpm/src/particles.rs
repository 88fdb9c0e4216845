//! Material points, stored as a struct of arrays, and their creation from the deck's bodies.

use crate::grid::Vector;
use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

/// Initial stress state of a body.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InitialStress {
    /// p = rho |g| (H - y) below the body's top H.
    Hydrostatic,
}

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
