//! Nodal averaging of the volumetric strain rate and of the pressure, against the explicit
//! scheme's volumetric locking (`simulation.volumetric_averaging = "nodal"`).
//!
//! With p = K (1 - J) and K >> G every particle's volume change is penalised on its own: one
//! near-incompressibility constraint per particle (four per cell with 2 x 2 particles per cell)
//! against D velocity unknowns per node. There are too few velocity fields that keep every
//! particle's volume, the grid velocities lock up, and a footing pushed into undrained clay
//! meets a bearing pressure far above Prandtl's (2 + pi) c_u.
//!
//! The cure is the MPM form of the B-bar / F-bar methods: fewer volumetric constraints, one per
//! node. The divergence of the velocity, tr L_p, is projected onto the nodal shape functions
//! with a lumped (row-sum) L2 projection over the current volume,
//!
//!   d_i = sum_p N_ip V_p tr(L_p) / sum_p N_ip V_p,
//!
//! and interpolated back; the particle keeps its own deviatoric (and spin) part:
//!
//!   L_p <- L_p + (sum_i N_ip d_i - tr L_p) / D  I.
//!
//! Everything the constitutive update takes from L_p then sees the averaged dilatation: J (and
//! so the equation of state's pressure), F (its volumetric part), and nothing else, since the
//! models' deviatoric stresses read only dev(sym L) and the spin. It is the F-bar idea of
//! Coombs et al. (2018, "Overcoming volumetric locking in material point methods", CMAME 333),
//! who average the volume change over each background cell, with the average taken at the
//! nodes instead (as the "nodal mixed discretisation" of FLAC does for tetrahedra), in rate
//! form: the increment det(I + dt L_p) of J is taken from the averaged L_p. It needs no
//! particle-to-cell bookkeeping and uses the transfers' own shape functions, whichever they
//! are.
//!
//! The pressure goes through the same averaging after the constitutive update: the internal
//! force of the next step takes p_p <- sum_i N_ip p_i, p_i the nodal average of the particles'
//! p. This is the symmetric (B-bar) half. Write A for "project onto the nodes, interpolate
//! back"; it is symmetric in the volume-weighted sum over particles, sum_p V_p a_p (A b)_p =
//! sum_p V_p (A a)_p b_p. J follows the averaged dilatation A tr L, so the pressure's power
//! should be sum_p V_p p_p (A tr L)_p, and that is sum_p V_p (A p)_p tr L_p: the averaged
//! pressure through each particle's own velocity gradient, which is what P2G computes. With
//! the particle's own p instead, the force does work on a dilatation that J does not follow,
//! and J, which each particle carries along, drifts apart from particle to particle where the
//! flow mixes them (docs/materials.md, "Solids with the explicit scheme", has what each half
//! gives on a slump). Each half costs a particle-to-grid and a grid-to-particle pass of a scalar.
//!
//! The weight is the particle's volume V_p = J_p V_p^0, not its mass: with it the averaging
//! keeps the body's total rate of volume change, sum_p V_p tr(L_p), and sum_p V_p p_p (the
//! shape functions are a partition of unity), so it moves volume change between neighbouring
//! particles but makes or loses none. With one material the two weights differ only by the
//! density's variation, a fraction p / K.
//!
//! The shape functions are those of the particles' positions when the averaging runs, after
//! the step's move (L_p was computed before it; a particle moves less than cfl h in a step),
//! which the next step's P2G uses too: the projection and the interpolation use the same
//! weights, so a uniform field comes back exactly.
//!
//! What it gives, measured on the strip footing and on an isochoric mode of an elastic square
//! (`tests/suite/locking.rs`), is in docs/materials.md ("Solids with the explicit scheme").
//!
//! The key is for the explicit scheme (the deck refuses it with `scheme = "projection"`). The
//! projection with nodal pressures averages the strain rate's trace the same way, always: its
//! velocity is divergence free node by node, not at each particle. Its density correction
//! also evens out J itself between neighbours ([`NodalAveraging::smooth_jacobian`]).

use crate::grid::GridGeometry;
use crate::particles::Particles;
use crate::shape::{ShapeFunction, Stencil};
use crate::transfer::{scatter_bands, Band};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Anti-locking treatment of the explicit scheme's volume change (`crate::averaging`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum VolumetricAveraging {
    /// Each particle's own velocity gradient: one volume constraint per particle, which locks
    /// a nearly incompressible solid (K >> G).
    #[default]
    None,
    /// The volumetric part of the velocity gradient averaged at the nodes (one constraint per
    /// node); explicit scheme only.
    Nodal,
}

/// The buffers of the averaging, kept between steps: one band of node sums per rayon thread
/// (as for P2G, so the sum is deterministic for a given thread count) and two node fields.
#[derive(Debug, Clone)]
pub struct NodalAveraging<const D: usize> {
    /// Per thread: at each node of its band, (sum N_ip V_p, sum N_ip V_p tr L_p) (or the
    /// pressure in place of tr L_p).
    bands: Vec<Band<[f64; 2]>>,
    /// sum_p N_ip V_p at each node.
    weight: Vec<f64>,
    /// The nodal average of the field last projected (d_i for tr L, or the pressure), 0 where
    /// no particle reaches.
    average: Vec<f64>,
    /// The ranks whose particles' sums are added up before the average ([`crate::comm`]).
    pub comm: crate::comm::Ranks,
    /// Over ranks while the neighbours' particles are lent as ghosts: how many are this
    /// rank's own, the only ones its sums count (the ghosts' own ranks count them).
    pub own: Option<usize>,
}

impl<const D: usize> NodalAveraging<D> {
    /// Buffers for `threads` threads on a grid of `nodes` nodes.
    pub fn new(threads: usize, nodes: usize) -> Self {
        Self {
            bands: vec![Band::default(); threads.max(1)],
            weight: crate::pages::zeroed(nodes),
            average: crate::pages::zeroed(nodes),
            comm: crate::comm::Ranks::default(),
            own: None,
        }
    }

    /// The nodal averages of the last [`Self::average_strain_rate`] (d_i) or
    /// [`Self::average_pressure`].
    pub fn node_values(&self) -> &[f64] {
        &self.average
    }

    /// Replaces the volumetric part of every particle's velocity gradient by the interpolated
    /// nodal average of tr L; the deviatoric part and the spin are kept. Before the constitutive
    /// update.
    pub fn average_strain_rate(
        &mut self,
        ps: &mut Particles<D>,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
    ) {
        crate::with_shape!(shape, S => {
            self.project::<S>(ps, geo, |p| ps.velocity_gradient[p].trace());
            let average = &self.average;
            (
                ps.x.par_iter(),
                ps.half_width.par_iter(),
                ps.velocity_gradient.par_iter_mut(),
            )
                .into_par_iter()
                .for_each(|(x, &lp, l)| {
                    let avg = interpolate::<D, S>(geo, average, x, lp);
                    let shift = (avg - l.trace()) / D as f64;
                    for d in 0..D {
                        l[(d, d)] += shift;
                    }
                });
        });
    }

    /// Replaces a per-particle field by the interpolated nodal average of it.
    pub fn smooth(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
        values: &mut [f64],
    ) {
        crate::with_shape!(shape, S => {
            self.project::<S>(ps, geo, |p| values[p]);
            let average = &self.average;
            (ps.x.par_iter(), ps.half_width.par_iter(), values.par_iter_mut())
                .into_par_iter()
                .for_each(|(x, &lp, v)| *v = interpolate::<D, S>(geo, average, x, lp));
        });
    }

    /// Moves every particle's volume ratio J_p the share `share` (0 to 1) of the way to the
    /// interpolated nodal average of J over the particles of its own material,
    ///
    ///   J_i = sum_p N_ip V0_p J_p / sum_p N_ip V0_p,   J_p <- J_p + share (sum_i N_ip J_i - J_p),
    ///
    /// and scales F_p's volumetric part to match (det F_p = J_p). The weight V0_p keeps each
    /// material's volume sum_p V0_p J_p (the shape functions are a partition of unity): volume
    /// moves between neighbouring particles of a material, none is made or lost.
    pub fn smooth_jacobian(
        &mut self,
        ps: &mut Particles<D>,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
        share: f64,
    ) {
        if share <= 0.0 {
            return;
        }
        let materials = ps
            .material
            .iter()
            .copied()
            .max()
            .map_or(0, |m| m as usize + 1);
        // the same count on every rank, whose collectives it repeats
        let materials = self.comm.max_scalar(materials as f64) as usize;
        for m in 0..materials {
            let m = m as u16;
            crate::with_shape!(shape, S => {
                let mat = &ps.material;
                self.project_weighted::<S>(
                    ps,
                    geo,
                    |p| if mat[p] == m { ps.volume0[p] } else { 0.0 },
                    |p| ps.jacobian[p],
                );
                let average = &self.average;
                let n = ps.len();
                (
                    ps.x.par_iter(),
                    ps.half_width.par_iter(),
                    ps.material.par_iter(),
                    ps.jacobian.par_iter_mut(),
                    crate::material::optional_mut(&mut ps.deformation, n),
                )
                    .into_par_iter()
                    .for_each(|(x, &lp, &mp, j, f)| {
                        if mp != m {
                            return;
                        }
                        let new = *j + share * (interpolate::<D, S>(geo, average, x, lp) - *j);
                        if new > 0.0 && *j > 0.0 {
                            if let Some(f) = f {
                                *f *= (new / *j).powf(1.0 / D as f64);
                            }
                            *j = new;
                        }
                    });
            });
        }
    }

    /// Replaces every particle's pressure by the interpolated nodal average of the pressure,
    /// the one the next step's internal force takes. After the constitutive update (which
    /// sets p = K (1 - J) afresh from each particle's J every step, so the averages do not
    /// pile up).
    pub fn average_pressure(
        &mut self,
        ps: &mut Particles<D>,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
    ) {
        crate::with_shape!(shape, S => {
            self.project::<S>(ps, geo, |p| ps.pressure[p]);
            let average = &self.average;
            (ps.x.par_iter(), ps.half_width.par_iter(), ps.pressure.par_iter_mut())
                .into_par_iter()
                .for_each(|(x, &lp, p)| *p = interpolate::<D, S>(geo, average, x, lp));
        });
    }

    /// The lumped L2 projection of a particle field onto the nodes, into `self.average`:
    /// sum_p N_ip V_p value(p) / sum_p N_ip V_p, 0 where no particle reaches.
    fn project<const S: u8>(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        value: impl Fn(usize) -> f64 + Sync,
    ) {
        self.project_weighted::<S>(ps, geo, |p| ps.volume(p), value)
    }

    /// The lumped L2 projection with the weight `weight(p)` in place of V_p.
    fn project_weighted<const S: u8>(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        weight: impl Fn(usize) -> f64 + Sync,
        value: impl Fn(usize) -> f64 + Sync,
    ) {
        let shape = ShapeFunction::from_code(S);
        // particles -> nodes: volume-weighted sums, per thread (of this rank's own)
        let own = self.own.map_or(ps.len(), |own| own.min(ps.len()));
        scatter_bands(
            &mut self.bands,
            [0.0; 2],
            geo,
            &ps.x[..own],
            |band, range| {
                let (start, acc) = band.sums_mut();
                for p in range {
                    let vol = weight(p);
                    let v = value(p);
                    let st =
                        Stencil::<D>::new(shape, &geo.to_cells(&ps.x[p]), geo.h, ps.half_width[p]);
                    st.for_each(|nw| {
                        let a = &mut acc[geo.flat(&nw.node) - start];
                        let w = nw.n * vol;
                        a[0] += w;
                        a[1] += w * v;
                    });
                }
            },
        );
        // the threads' sums in a fixed order, then the average; with periodic axes the images
        // are folded onto their nodes first, and over several ranks the ranks' sums added up,
        // so the division waits for that
        crate::pages::fit(&mut self.weight, geo.node_count());
        crate::pages::fit(&mut self.average, geo.node_count());
        let bands = &self.bands;
        let periodic = geo.has_periodic();
        let later = periodic || self.comm.is_distributed();
        // (outside the bands' reach both are zero: `divide` gives 0 where no weight)
        let reach = crate::transfer::reach(bands);
        let first = reach.start;
        let weights = crate::transfer::outside_zeroed(&mut self.weight, reach.clone());
        let averages = crate::transfer::outside_zeroed(&mut self.average, reach);
        (weights.par_iter_mut(), averages.par_iter_mut())
            .into_par_iter()
            .enumerate()
            .for_each(|(k, (w, a))| {
                let (mut weight, mut sum) = (0.0, 0.0);
                for b in bands.iter().filter_map(|b| b.at(first + k)) {
                    weight += b[0];
                    sum += b[1];
                }
                if !later {
                    sum = divide(sum, weight);
                }
                crate::pages::store(w, weight);
                crate::pages::store(a, sum);
            });
        if later {
            if periodic {
                geo.fold(&mut self.weight);
                geo.fold(&mut self.average);
            }
            self.comm
                .add_nodes(&mut [&mut self.weight, &mut self.average]);
            self.average
                .par_iter_mut()
                .zip(self.weight.par_iter())
                .for_each(|(a, &w)| crate::pages::store(a, divide(*a, w)));
        }
    }
}

/// A weighted sum over its weight, 0 at a node no particle reaches.
#[inline]
fn divide(sum: f64, weight: f64) -> f64 {
    if weight > 0.0 {
        sum / weight
    } else {
        0.0
    }
}

/// [`crate::transfer::interpolate`] with the shape `S` of [`crate::with_shape!`].
#[inline]
fn interpolate<const D: usize, const S: u8>(
    geo: &GridGeometry<D>,
    node: &[f64],
    x: &crate::grid::Vector<D>,
    lp: f64,
) -> f64 {
    crate::transfer::interpolate(ShapeFunction::from_code(S), geo, node, x, lp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Vector;
    use crate::material::deviator;
    use crate::particles::Matrix;

    /// Particles scattered (deterministically) inside a grid, each with a velocity gradient
    /// `l(p, x)`, with volumes that differ from particle to particle.
    fn particles<const D: usize>(
        geo: &GridGeometry<D>,
        n: usize,
        mut l: impl FnMut(&mut dyn FnMut() -> f64) -> Matrix<D>,
    ) -> Particles<D> {
        let mut ps = Particles::<D>::default();
        let mut rnd = crate::test_random(987654321);
        for _ in 0..n {
            let x = Vector::<D>::from_fn(|d, _| {
                geo.origin[d] + (0.5 + rnd() * (geo.cells[d] as f64 - 1.0)) * geo.h
            });
            ps.x.push(x);
            ps.v.push(Vector::<D>::zeros());
            ps.mass.push(1.0);
            ps.volume0.push(1e-3 * (0.5 + rnd()));
            ps.jacobian.push(0.9 + 0.2 * rnd());
            ps.pressure.push(0.0);
            ps.material.push(0);
            ps.half_width.push(0.25);
            ps.deformation.push(Matrix::<D>::identity());
            ps.tau.push(Matrix::<D>::zeros());
            ps.velocity_gradient.push(l(&mut rnd));
            ps.affine.push(Matrix::<D>::zeros());
        }
        ps
    }

    const SHAPES: [ShapeFunction; 4] = [
        ShapeFunction::Linear,
        ShapeFunction::Gimp,
        ShapeFunction::Bspline2,
        ShapeFunction::Bspline3,
    ];

    /// A uniform dilatation a I plus any deviatoric part per particle: L_p comes back as it was;
    /// so does a uniform pressure.
    fn keeps_uniform_dilatation<const D: usize>(periodic: bool) {
        let geo = GridGeometry::<D>::new(Vector::<D>::from_element(-0.2), 0.1, [7; D])
            .with_periodic([periodic; D]);
        for shape in SHAPES {
            let a = 0.37;
            let mut ps = particles(&geo, 500, |rnd| {
                deviator(&Matrix::<D>::from_fn(|_, _| rnd() - 0.5)) + Matrix::<D>::identity() * a
            });
            let before = ps.velocity_gradient.clone();
            let mut avg = NodalAveraging::<D>::new(3, geo.node_count());
            avg.average_strain_rate(&mut ps, &geo, shape);
            for (l, l0) in ps.velocity_gradient.iter().zip(&before) {
                assert!((l - l0).norm() < 1e-14, "{shape:?} {D}D: {l} against {l0}");
            }
            ps.pressure.fill(1.5e5);
            avg.average_pressure(&mut ps, &geo, shape);
            for &p in &ps.pressure {
                assert!((p - 1.5e5).abs() < 1e-9, "{shape:?} {D}D: p = {p}");
            }
        }
    }

    #[test]
    fn a_uniform_dilatation_and_a_uniform_pressure_are_kept_exactly() {
        keeps_uniform_dilatation::<2>(false);
        keeps_uniform_dilatation::<3>(false);
        keeps_uniform_dilatation::<2>(true);
    }

    /// A dilatation that varies from particle to particle: the deviatoric part of every L_p and
    /// its antisymmetric part are unchanged, the total rate of volume change sum V_p tr L_p is
    /// kept, and the spread of tr L_p shrinks.
    fn averages_only_the_trace<const D: usize>() {
        let geo = GridGeometry::<D>::new(Vector::<D>::zeros(), 0.1, [6; D]);
        for shape in SHAPES {
            let mut ps = particles(&geo, 400, |rnd| {
                Matrix::<D>::from_fn(|_, _| rnd() - 0.5) * 2.0
            });
            let before = ps.velocity_gradient.clone();
            let volume_rate = |ps: &Particles<D>| -> f64 {
                (0..ps.len())
                    .map(|p| ps.volume(p) * ps.velocity_gradient[p].trace())
                    .sum()
            };
            let spread = |ls: &[Matrix<D>]| -> f64 {
                let mean = ls.iter().map(|l| l.trace()).sum::<f64>() / ls.len() as f64;
                ls.iter().map(|l| (l.trace() - mean).powi(2)).sum::<f64>()
            };
            let total0 = volume_rate(&ps);
            let mut avg = NodalAveraging::<D>::new(2, geo.node_count());
            avg.average_strain_rate(&mut ps, &geo, shape);
            for (l, l0) in ps.velocity_gradient.iter().zip(&before) {
                assert!(
                    (deviator(l) - deviator(l0)).norm() < 1e-14,
                    "{shape:?} {D}D deviator"
                );
                let skew = |m: &Matrix<D>| m - m.transpose();
                assert!((skew(l) - skew(l0)).norm() < 1e-14);
            }
            let total = volume_rate(&ps);
            assert!(
                (total - total0).abs() < 1e-12 * total0.abs().max(1e-3),
                "{shape:?} {D}D: sum V tr L {total} against {total0}"
            );
            // the pressure's average keeps sum V p
            for (p, l) in ps.pressure.iter_mut().zip(&before) {
                *p = 1e4 * l[(0, 1)];
            }
            let integral = |ps: &Particles<D>| -> f64 {
                (0..ps.len()).map(|p| ps.volume(p) * ps.pressure[p]).sum()
            };
            let integral0 = integral(&ps);
            let scale: f64 = (0..ps.len())
                .map(|p| (ps.volume(p) * ps.pressure[p]).abs())
                .sum();
            avg.average_pressure(&mut ps, &geo, shape);
            let total = integral(&ps);
            assert!(
                (total - integral0).abs() < 1e-13 * scale,
                "{shape:?} {D}D: sum V p {total} against {integral0}"
            );
            assert!(
                spread(&ps.velocity_gradient) < 0.5 * spread(&before),
                "{shape:?} {D}D: the averaging smooths tr L"
            );
        }
    }

    #[test]
    fn only_the_volumetric_part_is_averaged_and_the_volume_rate_is_kept() {
        averages_only_the_trace::<2>();
        averages_only_the_trace::<3>();
    }

    #[test]
    fn the_average_is_deterministic_for_a_thread_count() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 0.1, [10; 2]);
        let ps0 = particles(&geo, 2000, |rnd| Matrix::<2>::from_fn(|_, _| rnd() - 0.5));
        let (mut a, mut b) = (ps0.clone(), ps0);
        let mut avg = NodalAveraging::<2>::new(4, geo.node_count());
        avg.average_strain_rate(&mut a, &geo, ShapeFunction::Bspline2);
        let rates = avg.node_values().to_vec();
        avg.average_strain_rate(&mut b, &geo, ShapeFunction::Bspline2);
        assert_eq!(a.velocity_gradient, b.velocity_gradient);
        assert_eq!(rates, avg.node_values());
    }

    /// J evened out between the particles of each material: each material's volume
    /// sum V0 J is kept to round-off, the spread of J shrinks, a share of 0 changes nothing,
    /// a uniform J stays, and det F follows J.
    fn smooths_jacobian<const D: usize>() {
        let geo = GridGeometry::<D>::new(Vector::<D>::zeros(), 0.1, [6; D]);
        for shape in SHAPES {
            let mut ps = particles(&geo, 400, |_| Matrix::<D>::zeros());
            for p in 0..ps.len() {
                ps.material[p] = (p % 3 == 0) as u16;
                ps.deformation[p] = Matrix::<D>::identity() * ps.jacobian[p].powf(1.0 / D as f64);
            }
            let volume = |ps: &Particles<D>, m: u16| -> f64 {
                (0..ps.len())
                    .filter(|&p| ps.material[p] == m)
                    .map(|p| ps.volume0[p] * ps.jacobian[p])
                    .sum()
            };
            let spread = |ps: &Particles<D>| -> f64 {
                ps.jacobian.iter().map(|j| (j - 1.0).powi(2)).sum::<f64>()
            };
            let mut avg = NodalAveraging::<D>::new(2, geo.node_count());
            let before = ps.clone();
            avg.smooth_jacobian(&mut ps, &geo, shape, 0.0);
            assert_eq!(ps.jacobian, before.jacobian, "{shape:?} {D}D: share 0");
            avg.smooth_jacobian(&mut ps, &geo, shape, 1.0);
            for m in 0..2 {
                let (v, v0) = (volume(&ps, m), volume(&before, m));
                assert!(
                    (v - v0).abs() < 1e-13 * v0,
                    "{shape:?} {D}D material {m}: {v} against {v0}"
                );
            }
            assert!(
                spread(&ps) < 0.5 * spread(&before),
                "{shape:?} {D}D: J is evened out"
            );
            for p in 0..ps.len() {
                let det = crate::material::det(&ps.deformation[p]);
                assert!(
                    (det - ps.jacobian[p]).abs() < 1e-12,
                    "{shape:?} {D}D: det F {det}"
                );
            }
            ps.jacobian.fill(0.97);
            avg.smooth_jacobian(&mut ps, &geo, shape, 1.0);
            assert!(
                ps.jacobian.iter().all(|j| (j - 0.97).abs() < 1e-14),
                "{shape:?} {D}D uniform"
            );
        }
    }

    #[test]
    fn smoothing_j_keeps_each_materials_volume() {
        smooths_jacobian::<2>();
        smooths_jacobian::<3>();
    }
}
