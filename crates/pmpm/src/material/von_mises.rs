//! Undrained clay: elastic-perfectly plastic von Mises (J2) with the undrained shear strength
//! c_u, the total-stress model of undrained (phi = 0) analysis.
//!
//! The deviatoric Cauchy stress s is a state: a trial stress from the Jaumann rate,
//!
//!   s_trial = s + dt (2 G dev D + W s - s W),   W = (L - L^T) / 2,
//!
//! is returned radially onto the yield surface sqrt(J2) = c_u (J2 = s : s / 2), that is
//! q = sqrt(3 J2) = sqrt(3) c_u: s = s_trial min(1, sqrt(2) c_u / |s_trial|). The volume is the
//! pressure's (projection, or K (1 - J) with the explicit scheme). In 2D, plane strain: the
//! deviator is the in-plane one and s_zz = 0 (an incompressible plane flow has D_zz = 0 and
//! keeps it so), and sqrt(J2) is the largest shear stress, the Tresca radius, so the model's
//! limit loads are Tresca's: Prandtl's (2 + pi) c_u for a strip footing.

use crate::particles::Matrix;

/// Shear modulus and undrained shear strength.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VonMises {
    /// G (Pa).
    pub shear_modulus: f64,
    /// c_u (Pa).
    pub strength: f64,
}

impl VonMises {
    /// The new deviatoric stress from the old one `s` and the velocity gradient `l`.
    #[inline]
    pub fn update<const D: usize>(&self, s: &Matrix<D>, l: &Matrix<D>, dt: f64) -> Matrix<D> {
        let w = (l - l.transpose()) * 0.5;
        let d = super::deviatoric_strain_rate(l);
        let trial = s + (d * (2.0 * self.shear_modulus) + w * s - s * w) * dt;
        // W s - s W is trace free and keeps s symmetric; round-off is removed with the trace
        let trial = super::deviator(&((trial + trial.transpose()) * 0.5));
        let norm = trial.norm();
        let radius = std::f64::consts::SQRT_2 * self.strength;
        if norm > radius {
            trial * (radius / norm)
        } else {
            trial
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simple_shear_is_elastic_then_flows_at_c_u() {
        let m = VonMises {
            shear_modulus: 100.0,
            strength: 2.0,
        };
        // shear rate 1, dt 1e-3: elastic tau = G gamma until tau = c_u at gamma = 0.02
        let l = Matrix::<2>::new(0.0, 1.0, 0.0, 0.0);
        let mut s = Matrix::<2>::zeros();
        for _ in 0..10 {
            s = m.update(&s, &l, 1e-3);
        }
        // after gamma = 0.01, small rotation: s_xy = G gamma to first order
        assert!((s[(0, 1)] - 1.0).abs() < 1e-3, "{}", s[(0, 1)]);
        for _ in 0..1000 {
            s = m.update(&s, &l, 1e-3);
        }
        let j2 = 0.5 * s.norm_squared();
        assert!((j2.sqrt() - 2.0).abs() < 1e-12);
        assert!(s.trace().abs() < 1e-14 && (s - s.transpose()).norm() < 1e-14);
    }

    #[test]
    fn a_rigid_spin_rotates_the_stress_without_changing_its_size() {
        let m = VonMises {
            shear_modulus: 100.0,
            strength: 10.0,
        };
        let spin = Matrix::<3>::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut s = Matrix::<3>::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0);
        let n0 = s.norm();
        for _ in 0..100 {
            s = m.update(&s, &spin, 1e-4);
        }
        assert!((s.norm() - n0).abs() < 1e-5);
        assert!(s[(0, 1)].abs() > 1e-3, "rotated: {s}");
    }
}
