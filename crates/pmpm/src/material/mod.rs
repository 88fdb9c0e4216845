//! Constitutive update at the particles (docs/method.md, step 7): strain rate, deviatoric stress,
//! deformation gradient, volume; and, for the explicit scheme, the equation of state.
//!
//! Every model gives only the deviatoric stress, behind [`Constitutive`]; the pressure is the
//! scheme's. One file per model family; docs/materials.md has their equations.

mod neo_hookean;
mod settings;
mod viscoplastic;
mod von_mises;

pub use neo_hookean::NeoHookean;
pub use settings::{MaterialDeck, MAX_MATERIAL_PARAMETER};
pub use viscoplastic::Viscoplastic;
pub use von_mises::VonMises;

use crate::particles::{Matrix, Particles, Stored};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Constitutive model of a material.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Model {
    /// Newtonian fluid: tau = 2 mu dev D.
    #[default]
    Newtonian,
    /// Bingham fluid (yield stress, plastic viscosity), Papanastasiou-regularised.
    Bingham,
    /// Herschel-Bulkley fluid (yield stress, consistency, flow index), Papanastasiou-regularised.
    HerschelBulkley,
    /// Incompressible neo-Hookean solid (shear modulus).
    NeoHookeanIncompressible,
    /// Undrained clay: elastic-perfectly plastic von Mises (shear modulus, c_u).
    VonMises,
}

impl Model {
    /// The deck's name of the model.
    pub fn name(self) -> &'static str {
        match self {
            Model::Newtonian => "newtonian",
            Model::Bingham => "bingham",
            Model::HerschelBulkley => "herschel_bulkley",
            Model::NeoHookeanIncompressible => "neo_hookean_incompressible",
            Model::VonMises => "von_mises",
        }
    }

    /// The model's own keys: (key, required).
    pub fn keys(self) -> &'static [(&'static str, bool)] {
        match self {
            Model::Newtonian => &[("viscosity", false)],
            Model::Bingham => &[
                ("viscosity", true),
                ("yield_stress", true),
                ("papanastasiou_exponent", true),
            ],
            Model::HerschelBulkley => &[
                ("consistency", true),
                ("flow_index", true),
                ("yield_stress", true),
                ("papanastasiou_exponent", true),
            ],
            Model::NeoHookeanIncompressible => &[("shear_modulus", true), ("viscosity", false)],
            Model::VonMises => &[("shear_modulus", true), ("undrained_shear_strength", true)],
        }
    }
}

/// A constitutive model: the deviatoric stress of a particle from its velocity gradient and its
/// state. The pressure is not the model's: the projection gives it, or the explicit scheme's
/// equation of state p = K (1 - J).
pub trait Constitutive {
    /// Advances the model's state over `dt` and returns the new deviatoric Cauchy stress. `l` is
    /// the velocity gradient, `f` the deformation gradient already advanced by it (a model may
    /// adjust it), `j` the volume ratio, `tau` the stress of the step before.
    fn stress<const D: usize>(
        &self,
        l: &Matrix<D>,
        dt: f64,
        f: &mut Matrix<D>,
        j: f64,
        tau: &Matrix<D>,
    ) -> Matrix<D>;

    /// Largest viscosity the model can show (Pa s): the explicit viscous update's step limit.
    fn max_viscosity(&self) -> f64;

    /// Elastic shear modulus (Pa), 0 for a fluid: the shear wave's step limit.
    fn shear_modulus(&self) -> f64;
}

/// A Newtonian fluid, tau = 2 mu dev D.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Newtonian {
    /// Dynamic viscosity mu (Pa s).
    pub viscosity: f64,
}

impl Constitutive for Newtonian {
    #[inline]
    fn stress<const D: usize>(
        &self,
        l: &Matrix<D>,
        _: f64,
        _: &mut Matrix<D>,
        _: f64,
        _: &Matrix<D>,
    ) -> Matrix<D> {
        deviatoric_strain_rate(l) * (2.0 * self.viscosity)
    }
    fn max_viscosity(&self) -> f64 {
        self.viscosity
    }
    fn shear_modulus(&self) -> f64 {
        0.0
    }
}

/// The neo-Hookean solid with an optional viscous (Kelvin-Voigt) part 2 mu dev D, which damps
/// its waves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViscoElastic {
    /// The elastic part.
    pub elastic: NeoHookean,
    /// mu (Pa s), 0 for none.
    pub viscosity: f64,
}

impl Constitutive for ViscoElastic {
    #[inline]
    fn stress<const D: usize>(
        &self,
        l: &Matrix<D>,
        _: f64,
        f: &mut Matrix<D>,
        j: f64,
        _: &Matrix<D>,
    ) -> Matrix<D> {
        let elastic = self.elastic.update(f, j);
        if self.viscosity > 0.0 {
            elastic + deviatoric_strain_rate(l) * (2.0 * self.viscosity)
        } else {
            elastic
        }
    }
    fn max_viscosity(&self) -> f64 {
        self.viscosity
    }
    fn shear_modulus(&self) -> f64 {
        self.elastic.shear_modulus
    }
}

impl Constitutive for VonMises {
    #[inline]
    fn stress<const D: usize>(
        &self,
        l: &Matrix<D>,
        dt: f64,
        _: &mut Matrix<D>,
        _: f64,
        tau: &Matrix<D>,
    ) -> Matrix<D> {
        self.update(tau, l, dt)
    }
    fn max_viscosity(&self) -> f64 {
        0.0
    }
    fn shear_modulus(&self) -> f64 {
        self.shear_modulus
    }
}

/// The models of the deck, one variant each (an enum, so that the particle loop dispatches
/// with a match that inlines, not through a pointer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Law {
    /// `newtonian`
    Newtonian(Newtonian),
    /// `bingham`, `herschel_bulkley`
    Viscoplastic(Viscoplastic),
    /// `neo_hookean_incompressible`
    NeoHookean(ViscoElastic),
    /// `von_mises`
    VonMises(VonMises),
}

impl Constitutive for Law {
    #[inline]
    fn stress<const D: usize>(
        &self,
        l: &Matrix<D>,
        dt: f64,
        f: &mut Matrix<D>,
        j: f64,
        tau: &Matrix<D>,
    ) -> Matrix<D> {
        match self {
            Law::Newtonian(m) => m.stress(l, dt, f, j, tau),
            Law::Viscoplastic(m) => m.stress(l, dt, f, j, tau),
            Law::NeoHookean(m) => m.stress(l, dt, f, j, tau),
            Law::VonMises(m) => m.stress(l, dt, f, j, tau),
        }
    }
    fn max_viscosity(&self) -> f64 {
        match self {
            Law::Newtonian(m) => m.max_viscosity(),
            Law::Viscoplastic(m) => m.max_viscosity(),
            Law::NeoHookean(m) => m.max_viscosity(),
            Law::VonMises(m) => m.max_viscosity(),
        }
    }
    fn shear_modulus(&self) -> f64 {
        match self {
            Law::Newtonian(m) => m.shear_modulus(),
            Law::Viscoplastic(m) => m.shear_modulus(),
            Law::NeoHookean(m) => m.shear_modulus(),
            Law::VonMises(m) => m.shear_modulus(),
        }
    }
}

impl Law {
    /// Whether a particle of this material, with deviatoric stress `tau` and velocity
    /// gradient `l`, has yielded; None for a model without a yield stress. A von Mises solid
    /// has yielded on its yield surface, |tau| = sqrt(2) c_u. A regularised yield-stress fluid
    /// has no sharp yield surface (below tau_y it creeps); it counts as yielded where its shear
    /// rate is past the regularisation's knee, m gamma >= ln 100, where the yield part of its
    /// stress, tau_y (1 - exp(-m gamma)), is within 1 % of tau_y.
    pub fn yielded<const D: usize>(&self, tau: &Matrix<D>, l: &Matrix<D>) -> Option<bool> {
        match self {
            Law::Viscoplastic(m) => {
                let gamma = (2.0 * deviatoric_strain_rate(l).norm_squared()).sqrt();
                Some(m.exponent * gamma >= 100f64.ln())
            }
            Law::VonMises(m) => {
                Some(tau.norm() >= std::f64::consts::SQRT_2 * m.strength * (1.0 - 1e-9))
            }
            Law::Newtonian(_) | Law::NeoHookean(_) => None,
        }
    }

    /// Whether the model has a yield stress ([`Law::yielded`]).
    pub fn has_yield(&self) -> bool {
        matches!(self, Law::Viscoplastic(_) | Law::VonMises(_))
    }

    /// Whether the deviatoric stress is a function of the velocity gradient alone (a fluid:
    /// Newtonian or viscoplastic), so that a particle need not keep it, nor its F.
    pub fn of_rate_alone(&self) -> bool {
        matches!(self, Law::Newtonian(_) | Law::Viscoplastic(_))
    }

    /// The deviatoric stress of a fluid ([`Law::of_rate_alone`]) at velocity gradient `l`,
    /// the same numbers as [`Constitutive::stress`] gives it; zero for a solid, whose stress
    /// the particles keep.
    #[inline]
    pub fn stress_of_rate<const D: usize>(&self, l: &Matrix<D>) -> Matrix<D> {
        match self {
            Law::Newtonian(m) => m.stress(l, 0.0, &mut Matrix::identity(), 1.0, l),
            Law::Viscoplastic(m) => m.stress(l, 0.0, &mut Matrix::identity(), 1.0, l),
            Law::NeoHookean(_) | Law::VonMises(_) => Matrix::zeros(),
        }
    }
}

/// The optional particle fields a run of these materials stores: F where a neo-Hookean solid
/// reads it, tau where any stress is not a function of the rate alone.
pub fn stored(materials: &[MaterialParams]) -> Stored {
    Stored {
        deformation: materials
            .iter()
            .any(|m| matches!(m.law, Law::NeoHookean(_))),
        stress: materials.iter().any(|m| !m.law.of_rate_alone()),
    }
}

/// The deviatoric stress tau_p of particle `p`: as stored, or, where the run keeps none (only
/// fluids), from its velocity gradient, the L the constitutive update last read.
#[inline]
pub fn deviatoric_stress<const D: usize>(
    ps: &Particles<D>,
    materials: &[MaterialParams],
    p: usize,
) -> Matrix<D> {
    if ps.stored.stress {
        ps.tau[p]
    } else {
        materials[ps.material[p] as usize]
            .law
            .stress_of_rate(&ps.velocity_gradient[p])
    }
}

/// Parameters of one material, as the step needs them.
#[derive(Debug, Clone, Copy)]
pub struct MaterialParams {
    /// Constitutive model, as the deck names it.
    pub model: Model,
    /// Reference density (kg/m3).
    pub density: f64,
    /// Bulk modulus of the equation of state (Pa), 0 if none.
    pub bulk_modulus: f64,
    /// The deviatoric model.
    pub law: Law,
}

impl MaterialParams {
    /// Fastest wave the scheme integrates explicitly: the pressure wave sqrt((K + 4 G / 3) /
    /// rho) with the equation of state, the shear wave sqrt(G / rho) with the projection (which
    /// takes the volumetric part implicitly).
    pub fn wave_speed(&self, equation_of_state: bool) -> f64 {
        let g = self.law.shear_modulus();
        if equation_of_state {
            ((self.bulk_modulus + 4.0 / 3.0 * g) / self.density).sqrt()
        } else {
            (g / self.density).sqrt()
        }
    }

    /// Step limit of the explicit viscous update, h^2 rho / (2 D mu_max); infinite without
    /// viscosity.
    pub fn viscous_dt_limit(&self, h: f64, dim: usize) -> f64 {
        let mu = self.law.max_viscosity();
        if mu > 0.0 {
            h * h * self.density / (2.0 * dim as f64 * mu)
        } else {
            f64::INFINITY
        }
    }
}

/// dev(sym L): the deviatoric strain rate.
#[inline]
pub fn deviatoric_strain_rate<const D: usize>(l: &Matrix<D>) -> Matrix<D> {
    deviator(&((l + l.transpose()) * 0.5))
}

/// a - tr(a) / D I.
#[inline]
pub fn deviator<const D: usize>(a: &Matrix<D>) -> Matrix<D> {
    a - Matrix::<D>::identity() * (a.trace() / D as f64)
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
/// `equation_of_state`, also p = K (1 - J) (the explicit, weakly compressible scheme). F and
/// tau only where the run stores them ([`Particles::stored`]): a fluid's stress is read from
/// its L where it is needed.
pub fn update<const D: usize>(
    ps: &mut Particles<D>,
    materials: &[MaterialParams],
    dt: f64,
    equation_of_state: bool,
) {
    let n = ps.len();
    let material = &ps.material;
    let grad_v = &ps.velocity_gradient;
    (
        optional_mut(&mut ps.deformation, n),
        ps.jacobian.par_iter_mut(),
        optional_mut(&mut ps.tau, n),
        ps.pressure.par_iter_mut(),
    )
        .into_par_iter()
        .enumerate()
        .for_each(|(p, (f, j, tau, pressure))| {
            let mat = &materials[material[p] as usize];
            let l = &grad_v[p];
            let inc = Matrix::<D>::identity() + l * dt;
            let mut unit = Matrix::<D>::identity();
            let f = match f {
                Some(f) => {
                    *f = inc * *f;
                    f
                }
                None => &mut unit,
            };
            // J tracked on its own: for a fluid F grows without bound in shear, and det(F)
            // would lose the volume change in round-off. Its rate is tr L alone, dJ/dt = J tr L,
            // integrated exactly over the step: det(I + dt L) = 1 + dt tr L + O(dt^2 |L|^2)
            // would let a spinning particle grow by (dt omega)^2 per step with no divergence at
            // all (a spinning droplet would swell without bound)
            *j *= (l.trace() * dt).exp();
            if let Some(tau) = tau {
                *tau = mat.law.stress(l, dt, f, *j, tau);
            }
            if equation_of_state {
                *pressure = mat.bulk_modulus * (1.0 - *j);
            }
        });
}

/// An optional particle field, `n` long: its values, or None for each particle where the run
/// does not store it (the array is empty). Zipped with the other fields, an empty array would
/// otherwise cut the whole loop to nothing.
pub fn optional_mut<T: Send>(
    field: &mut [T],
    n: usize,
) -> impl IndexedParallelIterator<Item = Option<&mut T>> {
    if field.is_empty() {
        rayon::iter::Either::Right((0..n).into_par_iter().map(|_| None))
    } else {
        rayon::iter::Either::Left(field.par_iter_mut().map(Some))
    }
}

/// Whether bit `material` of a set of materials held as a bit mask (bit m for material m, as
/// the implicit viscosity's mask) is set: materials from the 64th on never are.
#[inline]
pub fn in_mask(mask: u64, material: usize) -> bool {
    u32::try_from(material)
        .ok()
        .and_then(|m| mask.checked_shr(m))
        .is_some_and(|bits| bits & 1 == 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newtonian_stress_is_deviatoric_and_symmetric() {
        let m = Newtonian { viscosity: 0.5 };
        let l = Matrix::<3>::new(1.0, 2.0, 0.0, -1.0, 0.5, 3.0, 0.0, 0.0, 2.0);
        let t = m.stress(&l, 0.1, &mut Matrix::identity(), 1.0, &Matrix::zeros());
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
