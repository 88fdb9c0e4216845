//! Constitutive update at the particles (METHOD.md step 6): strain rate, deviatoric stress,
//! deformation gradient, volume; and, for the explicit scheme, the equation of state.

use crate::deck::{Deck, Model};
use crate::particles::{Matrix, Particles};
use rayon::prelude::*;

/// Parameters of one material, as the step needs them.
#[derive(Debug, Clone, Copy)]
pub struct MaterialParams {
    /// Constitutive model.
    pub model: Model,
    /// Reference density (kg/m3).
    pub density: f64,
    /// Dynamic viscosity (Pa s).
    pub viscosity: f64,
    /// Bulk modulus of the equation of state (Pa), 0 if none.
    pub bulk_modulus: f64,
}

impl MaterialParams {
    /// The deck's materials, in order.
    pub fn from_deck(deck: &Deck) -> Vec<Self> {
        deck.materials
            .iter()
            .map(|m| MaterialParams {
                model: m.model,
                density: m.density,
                viscosity: m.viscosity,
                bulk_modulus: m.bulk_modulus.unwrap_or(0.0),
            })
            .collect()
    }

    /// Sound speed sqrt(K / rho) of the equation of state.
    pub fn sound_speed(&self) -> f64 {
        (self.bulk_modulus / self.density).sqrt()
    }

    /// Deviatoric Cauchy stress from the velocity gradient.
    #[inline]
    pub fn deviatoric_stress<const D: usize>(&self, l: &Matrix<D>) -> Matrix<D> {
        match self.model {
            // tau = 2 mu dev(D), D = sym(L)
            Model::Newtonian => {
                let d = (l + l.transpose()) * 0.5;
                let dev = d - Matrix::<D>::identity() * (d.trace() / D as f64);
                dev * (2.0 * self.viscosity)
            }
        }
    }
}

/// Determinant of a 2x2 or 3x3 matrix (nalgebra's needs extra bounds for a generic D).
#[inline]
pub fn det<const D: usize>(m: &Matrix<D>) -> f64 {
    match D {
        1 => m[(0, 0)],
        2 => m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)],
        3 => {
            m[(0, 0)] * (m[(1, 1)] * m[(2, 2)] - m[(1, 2)] * m[(2, 1)])
                - m[(0, 1)] * (m[(1, 0)] * m[(2, 2)] - m[(1, 2)] * m[(2, 0)])
                + m[(0, 2)] * (m[(1, 0)] * m[(2, 1)] - m[(1, 1)] * m[(2, 0)])
        }
        _ => unreachable!("pmpm is 2D or 3D"),
    }
}

/// Updates F, J and the deviatoric stress of every particle from its velocity gradient; with
/// `equation_of_state`, also p = K (1 - J) (the explicit, weakly compressible scheme).
pub fn update<const D: usize>(
    ps: &mut Particles<D>,
    materials: &[MaterialParams],
    dt: f64,
    equation_of_state: bool,
) {
    let material = &ps.material;
    let grad_v = &ps.velocity_gradient;
    (
        ps.deformation.par_iter_mut(),
        ps.jacobian.par_iter_mut(),
        ps.tau.par_iter_mut(),
        ps.pressure.par_iter_mut(),
    )
        .into_par_iter()
        .enumerate()
        .for_each(|(p, (f, j, tau, pressure))| {
            let mat = &materials[material[p] as usize];
            let l = &grad_v[p];
            let inc = Matrix::<D>::identity() + l * dt;
            *f = inc * *f;
            // J tracked on its own: for a fluid F grows without bound in shear, and det(F)
            // would lose the volume change in round-off.
            *j *= det(&inc);
            *tau = mat.deviatoric_stress(l);
            if equation_of_state {
                *pressure = mat.bulk_modulus * (1.0 - *j);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newtonian_stress_is_deviatoric_and_symmetric() {
        let m = MaterialParams {
            model: Model::Newtonian,
            density: 1000.0,
            viscosity: 0.5,
            bulk_modulus: 0.0,
        };
        let l = Matrix::<3>::new(1.0, 2.0, 0.0, -1.0, 0.5, 3.0, 0.0, 0.0, 2.0);
        let t = m.deviatoric_stress(&l);
        assert!(t.trace().abs() < 1e-14);
        assert!((t - t.transpose()).norm() < 1e-14);
        // shear component: 2 mu * (L01 + L10)/2
        assert!((t[(0, 1)] - 0.5 * (2.0 - 1.0)).abs() < 1e-14);
    }

    #[test]
    fn determinants() {
        let a = Matrix::<2>::new(2.0, 1.0, 0.5, 3.0);
        assert!((det(&a) - 5.5).abs() < 1e-14);
        let b = Matrix::<3>::new(2.0, 0.0, 1.0, 1.0, 3.0, 0.0, 0.0, 1.0, 4.0);
        assert!((det(&b) - 25.0).abs() < 1e-12);
    }
}
