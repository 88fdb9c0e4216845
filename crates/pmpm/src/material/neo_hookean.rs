//! An incompressible neo-Hookean solid (rubber, a soft elastic soil at large strain).
//!
//! Only the isochoric part of the deformation carries stress: F is kept isochoric,
//! F <- det(F)^(-1/D) F after each update, and with the left Cauchy-Green tensor b = F F^T the
//! deviatoric Kirchhoff stress is
//!
//!   tau_K = G dev(b),
//!
//! the deviatoric Cauchy stress tau_K / J. The pressure is the projection's (or, with the
//! explicit scheme, K (1 - J), J tracked apart from F). In 2D this is the plane-strain model:
//! with F_zz = 1 and an isochoric in-plane F, the in-plane stress differences are those of the
//! 3D model and the rest is isotropic, which the pressure takes up.

use crate::particles::Matrix;

/// Shear modulus G (Pa) of the solid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeoHookean {
    /// G (Pa).
    pub shear_modulus: f64,
}

impl NeoHookean {
    /// Makes `f` isochoric and returns the deviatoric Cauchy stress for the volume ratio `j`.
    #[inline]
    pub fn update<const D: usize>(&self, f: &mut Matrix<D>, j: f64) -> Matrix<D> {
        let det = super::det(f);
        *f *= det.powf(-1.0 / D as f64);
        let b = *f * f.transpose();
        super::deviator(&b) * (self.shear_modulus / j)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_shear_gives_g_gamma_and_large_rotation_no_stress() {
        let m = NeoHookean { shear_modulus: 5.0 };
        let gamma = 1e-6;
        let mut f = Matrix::<3>::new(1.0, gamma, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        let t = m.update(&mut f, 1.0);
        assert!((t[(0, 1)] - 5.0 * gamma).abs() < 1e-15);
        // a rigid rotation by 60 degrees of a stretched state: the stress rotates with it
        let (c, s) = (0.5f64, 0.75f64.sqrt());
        let r = Matrix::<2>::new(c, -s, s, c);
        let mut u = Matrix::<2>::new(1.2, 0.0, 0.0, 1.0);
        let mut ru = r * u;
        let t0 = m.update(&mut u, 1.0);
        let t1 = m.update(&mut ru, 1.0);
        assert!((r * t0 * r.transpose() - t1).norm() < 1e-12);
        // and the rotation alone: none
        let mut rr = r;
        assert!(m.update(&mut rr, 1.0).norm() < 1e-12);
    }

    #[test]
    fn the_deformation_gradient_is_kept_isochoric() {
        let m = NeoHookean { shear_modulus: 1.0 };
        let mut f = Matrix::<2>::new(1.1, 0.3, -0.2, 0.95);
        m.update(&mut f, 1.0);
        assert!((super::super::det(&f) - 1.0).abs() < 1e-14);
    }
}
