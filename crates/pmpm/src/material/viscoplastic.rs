//! Yield-stress fluids (mud, debris, fresh concrete): Bingham and Herschel-Bulkley, with
//! Papanastasiou's regularisation.
//!
//! tau = 2 mu_eff(gamma) dev D, gamma = sqrt(2 dev D : dev D), and
//!
//!   mu_eff = K gamma^(n - 1) + tau_y (1 - exp(-m gamma)) / gamma
//!
//! (Papanastasiou, J. Rheol. 31 (1987) 385). Bingham is n = 1 with K the plastic viscosity. The
//! regularised fluid has no true plug: below the yield stress it creeps with viscosity about
//! K + tau_y m, so m sets how rigid the unyielded zones are, and (with the explicit viscous
//! update) how small the time step must be: its `max_viscosity`.

use crate::particles::Matrix;

/// A regularised yield-stress fluid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Viscoplastic {
    /// Consistency K (Pa s^n); the plastic viscosity for Bingham.
    pub consistency: f64,
    /// Flow index n (1 for Bingham).
    pub flow_index: f64,
    /// Yield stress tau_y (Pa).
    pub yield_stress: f64,
    /// Papanastasiou exponent m (s).
    pub exponent: f64,
}

impl Viscoplastic {
    /// Shear rate below which the power-law part of a shear-thinning fluid (n < 1) stops
    /// growing: 1 / m. Without it K gamma^(n - 1) is unbounded at rest.
    fn floor(&self) -> f64 {
        1.0 / self.exponent
    }

    /// Apparent viscosity mu_eff at shear rate `gamma` (1/s).
    #[inline]
    pub fn apparent_viscosity(&self, gamma: f64) -> f64 {
        let power = if self.flow_index == 1.0 {
            self.consistency
        } else if self.flow_index < 1.0 {
            self.consistency * gamma.max(self.floor()).powf(self.flow_index - 1.0)
        } else {
            self.consistency * gamma.powf(self.flow_index - 1.0)
        };
        // (1 - exp(-m gamma)) / gamma, with its limit m at rest
        let x = self.exponent * gamma;
        let yield_part = if x > 1e-8 {
            -(-x).exp_m1() / gamma
        } else {
            self.exponent * (1.0 - 0.5 * x)
        };
        power + self.yield_stress * yield_part
    }
}

impl super::Constitutive for Viscoplastic {
    /// Deviatoric Cauchy stress from the strain rate alone (the fluid keeps no state).
    #[inline]
    fn stress<const D: usize>(
        &self,
        l: &Matrix<D>,
        _: f64,
        _: &mut Matrix<D>,
        _: f64,
        _: &Matrix<D>,
    ) -> Matrix<D> {
        let dev = super::deviatoric_strain_rate(l);
        let gamma = (2.0 * dev.norm_squared()).sqrt();
        dev * (2.0 * self.apparent_viscosity(gamma))
    }

    /// Largest apparent viscosity (at rest, or at the shear-rate floor): what bounds the
    /// explicit viscous update's step. A shear-thickening fluid (n > 1) is bounded only by its
    /// shear rate; its bound here is the yield part alone.
    fn max_viscosity(&self) -> f64 {
        let power = if self.flow_index == 1.0 {
            self.consistency
        } else if self.flow_index < 1.0 {
            self.consistency * self.floor().powf(self.flow_index - 1.0)
        } else {
            0.0
        };
        power + self.yield_stress * self.exponent
    }

    fn shear_modulus(&self) -> f64 {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::super::Constitutive;
    use super::*;

    /// The stress of a state-free fluid: only the velocity gradient matters.
    fn stress(m: &Viscoplastic, l: &Matrix<2>) -> Matrix<2> {
        m.stress(l, 0.0, &mut Matrix::identity(), 1.0, &Matrix::zeros())
    }

    fn bingham() -> Viscoplastic {
        Viscoplastic {
            consistency: 2.0,
            flow_index: 1.0,
            yield_stress: 10.0,
            exponent: 1000.0,
        }
    }

    #[test]
    fn a_yielded_bingham_fluid_has_stress_tau_y_plus_mu_gamma() {
        // simple shear u = gamma y: |tau_xy| = tau_y (1 - e^(-m gamma)) + mu_p gamma
        let b = bingham();
        for gamma in [0.1, 1.0, 50.0] {
            let l = Matrix::<2>::new(0.0, gamma, 0.0, 0.0);
            let t = stress(&b, &l);
            let exact = 10.0 * (1.0 - (-1000.0 * gamma).exp()) + 2.0 * gamma;
            assert!((t[(0, 1)] - exact).abs() < 1e-12 * exact, "{gamma}");
            assert!(t.trace().abs() < 1e-12);
        }
    }

    #[test]
    fn at_rest_the_viscosity_is_finite_and_continuous() {
        let b = bingham();
        assert_eq!(b.apparent_viscosity(0.0), 2.0 + 10.0 * 1000.0);
        let small = b.apparent_viscosity(1e-12);
        assert!((small - b.max_viscosity()).abs() < 1e-6 * small);
        // across the switch to the series
        let (a, c) = (
            b.apparent_viscosity(0.99e-11),
            b.apparent_viscosity(1.01e-11),
        );
        assert!((a - c).abs() < 1e-6 * a);
    }

    #[test]
    fn herschel_bulkley_reduces_to_a_power_law_well_above_yield() {
        let hb = Viscoplastic {
            consistency: 3.0,
            flow_index: 0.5,
            yield_stress: 1.0,
            exponent: 100.0,
        };
        let gamma = 400.0;
        // tau = K gamma^n + tau_y (1 - e^(-m gamma)) = 3 * 20 + 1
        let tau = hb.apparent_viscosity(gamma) * gamma;
        assert!((tau - 61.0).abs() < 1e-9);
        // at rest: K (1/m)^(n-1) + tau_y m = 3 * 10 + 100
        assert!((hb.max_viscosity() - 130.0).abs() < 1e-9);
        assert!((hb.apparent_viscosity(0.0) - 130.0).abs() < 1e-9);
    }
}
