//! Implicit viscosity: the fluids' viscous term taken at the new velocity, so that the time
//! step of a viscous or yield-stress flow is set by the flow speed and not by the explicit
//! limit dt <= rho h^2 / (2 d mu).
//!
//! After the pressure's corrector, the node velocities v (divergence free, the wall conditions
//! applied) become the u that solves
//!
//!   (M + dt K) u = M v,      (K u)_i = sum_q w_q tau_q(u) G_iq,
//!   tau_q(u) = 2 mu_q dev sym L_q(u),      L_q(u) = sum_j u_j (x) G_jq,
//!
//! backward Euler on m_i du_i/dt = -sum_q w_q tau_q G_iq, the viscous force of the weak form
//! integrated at quadrature points q: the Gauss points of the cells deep in the fluid, the
//! particles elsewhere (`ImplicitViscosity::quadrature`). u^T K u = sum_q 2 w_q mu_q
//! |dev sym L_q|^2 >= 0, so M + dt K is symmetric positive definite on the nodes that carry
//! mass, for any mu_q >= 0 and any dt: the solve is unconditionally stable. The free surface
//! needs no condition: it is where the quadrature points end, and the weak form's natural
//! condition there is zero viscous traction (Batty & Bridson, SCA 2008, "Accurate viscous free
//! surfaces", reach the same condition with a variational form on a staggered grid). Walls and
//! rigid bodies hold the components they prescribe (their values from the wall conditions);
//! the other components are the unknowns.
//!
//! mu_p is the material's apparent viscosity at the particle's strain rate of the last step
//! (lagged): a Newtonian fluid's constant, a regularised Bingham or Herschel-Bulkley fluid's
//! mu_eff(gamma). The solve is matrix-free conjugate gradients with a Jacobi preconditioner:
//! one gather of L_q and one scatter of tau_q G_iq per iteration, through the same stencils as
//! the transfers. It is written by hand, as the transfers are, because its operator exists
//! only as sums over points.
//!
//! Over ranks with the grid in slabs ([`crate::slabs`]) each rank integrates over the points
//! of its own cells, and its sums onto the nodes are added up with its neighbours' as P2G's
//! are ([`crate::comm::Comm::add_nodes`]): the operator, the diagonal and the cells' fill that
//! picks the points. The conjugate gradient's updates are node by node, so every node a
//! rank's points read stays the same on the ranks that share it; its dot products are sums
//! over each rank's own node layers, added up over the ranks.

use crate::boundary::Boundary;
use crate::comm::Comm;
use crate::grid::{CellBins, Grid, GridGeometry, Vector};
use crate::linalg::{dot, CgWork, Operator, Precondition, SolveError, SolveParams};
use crate::material::{deviatoric_strain_rate, in_mask, Law, MaterialParams};
use crate::pages::store;
use crate::particles::{Matrix, Particles};
use crate::shape::{ShapeFunction, Stencil};
use crate::transfer::{scatter_weighted, Band, Points};
use rayon::prelude::*;
use std::sync::Arc;

/// No one material: a cell of several, or a point that is a particle.
const MIXED: u16 = u16::MAX;

/// Node vectors summed in fixed chunks, in order: the same bits for any thread count.
const CHUNK: usize = 4096;

/// How the viscous part of the stress is integrated in time (`simulation.viscosity`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViscosityTreatment {
    /// At the new velocity, after the pressure (the projection's default): no viscous step
    /// limit.
    Implicit,
    /// From the last step's strain rate, in the internal force: dt <= rho h^2 / (2 d mu_max).
    Explicit,
}

/// Whether a material's whole deviatoric stress is viscous, tau = 2 mu(gamma) dev D, and so is
/// taken by the implicit solve: the fluids. A solid's elastic or plastic stress (and a
/// neo-Hookean solid's Kelvin-Voigt part) stays explicit.
pub fn is_implicit(law: &Law) -> bool {
    matches!(law, Law::Newtonian(_) | Law::Viscoplastic(_))
}

/// Bit `m` set for each material `m` whose stress the implicit solve takes: the mask with which
/// P2G leaves their stress out of the internal force. Materials from the 64th on are never
/// implicit (the deck's limit on materials under implicit viscosity).
pub fn implicit_mask(materials: &[MaterialParams]) -> u64 {
    materials
        .iter()
        .take(64)
        .enumerate()
        .filter(|(_, m)| is_implicit(&m.law))
        .fold(0, |mask, (k, _)| mask | 1 << k)
}

/// Whether the implicit solve has work with these materials: one of those it takes
/// ([`implicit_mask`]) is viscous. An inviscid Newtonian fluid (viscosity 0, the default) has no
/// stress: its solve would leave v* as it is to the bit and only cost a pass over the grid and
/// a set of node-sized buffers.
pub fn any_viscous(materials: &[MaterialParams]) -> bool {
    materials.iter().take(64).any(|m| match &m.law {
        Law::Newtonian(n) => n.viscosity != 0.0,
        law => is_implicit(law),
    })
}

/// Apparent viscosity of a particle of material `law` whose velocity gradient is `l`.
fn apparent_viscosity<const D: usize>(law: &Law, l: &Matrix<D>) -> f64 {
    match law {
        Law::Newtonian(m) => m.viscosity,
        Law::Viscoplastic(m) => {
            let dev = deviatoric_strain_rate(l);
            m.apparent_viscosity((2.0 * dev.norm_squared()).sqrt())
        }
        _ => 0.0,
    }
}

/// Outcome of a viscous solve.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ViscousStats {
    /// Conjugate-gradient iterations.
    pub iterations: usize,
    /// Final |M v* - (M + dt K) u| / |M v*| over the free components.
    pub relative_residual: f64,
}

/// Why the viscous solve failed.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum ViscousError {
    /// The iteration limit was reached.
    #[error(
        "the viscous solve did not converge: relative residual {residual:.3e} after \
         {iterations} iterations (simulation.viscosity_tolerance = {tolerance:.1e}, \
         simulation.viscosity_max_iterations = {iterations})"
    )]
    NotConverged {
        /// Iterations done.
        iterations: usize,
        /// Relative residual reached.
        residual: f64,
        /// Relative residual asked for.
        tolerance: f64,
    },
    /// A value that is not finite, or a direction of non-positive curvature (which the
    /// operator cannot have with finite positive masses and viscosities).
    #[error("the viscous solve broke down: {0}")]
    Breakdown(String),
}

/// The implicit viscous solve and its work buffers, kept between steps.
#[derive(Debug, Default)]
pub struct ImplicitViscosity<const D: usize> {
    tolerance: f64,
    max_iterations: usize,
    /// The transfers' shape functions, which K is built of.
    shape: ShapeFunction,
    /// Nodes of at most this mass hold no equation.
    mass_epsilon: f64,
    /// Bit m set for each material m whose stress the solve takes ([`implicit_mask`]).
    materials: u64,
    /// Per particle: V_p mu_p (0 for a particle whose stress is explicit).
    particle_weight: Vec<f64>,
    /// The quadrature points of K ([`ImplicitViscosity::quadrature`]): where they are, their
    /// width (a particle's, or 0), and dt w_q mu_q.
    points: Vec<Vector<D>>,
    widths: Vec<f64>,
    coefficient: Vec<f64>,
    /// Per cell (numbered like its lower-corner node): sum_p V_p of the implicit particles in
    /// it, and their material ([`MIXED`] where they are of several; 0 in an empty cell, which
    /// nothing reads). Both are written only where the fluid is ([`crate::pages`]).
    cell_volume: Vec<f64>,
    cell_material: Vec<u16>,
    /// Per point: the material whose law gives a Gauss point's viscosity, [`MIXED`] for a
    /// particle (whose weight is final).
    point_material: Vec<u16>,
    bins: CellBins,
    /// Per point: 2 dt w_q mu_q dev sym L_q of the vector the operator is applied to.
    stress: Vec<Matrix<D>>,
    /// Per node: 1 on the free components, 0 on those the walls and bodies hold or where the
    /// node carries no mass.
    mask: Vec<Vector<D>>,
    /// Inverse of the diagonal of M + dt K on the free components.
    inverse_diagonal: Vec<Vector<D>>,
    bands: Vec<Band<Vector<D>>>,
    /// The conjugate gradient's work vectors.
    cg: CgWork<Vector<D>>,
    /// Over ranks with the grid in slabs, this rank's share; `None` on one process.
    ranks: Option<Slab>,
    /// Over ranks, the cells' material as sums onto the nodes: the ranks with particles in
    /// a cell, and the sums of their codes and squared codes ([`ImplicitViscosity::sum_cells`];
    /// the volume is summed in place).
    cell_ranks: [Vec<f64>; 3],
}

/// A rank's share of the solve: the ranks, and the cell (node) layers along `axis` it owns.
#[derive(Clone)]
pub struct Slab {
    /// The ranks, their sums onto the nodes those of the grid's slabs.
    pub comm: Arc<dyn Comm>,
    /// The axis the grid is cut along.
    pub axis: usize,
    /// This rank's cell layers, and the node layers it counts in the dot products.
    pub layers: std::ops::Range<usize>,
}

impl std::fmt::Debug for Slab {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Slab(axis {}, layers {:?})", self.axis, self.layers)
    }
}

impl Slab {
    /// Whether node (or cell) `i` lies on this rank's layers.
    #[inline]
    fn owns<const D: usize>(&self, geo: &GridGeometry<D>, i: usize) -> bool {
        self.layers.contains(&geo.layer(i, self.axis))
    }

    /// Sums of the ranks' points onto the nodes of `v` ([`Comm::add_nodes`]).
    fn add<const D: usize>(&self, v: &mut [Vector<D>]) {
        self.comm.add_nodes(&mut [bytemuck::cast_slice_mut(v)]);
    }

    /// a . b over the nodes of every rank's own layers.
    fn dot<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        (a, b): (&[Vector<D>], &[Vector<D>]),
        partials: &mut Vec<f64>,
    ) -> f64 {
        let own = if self.axis == D - 1 {
            // a slab along the last axis is one run of nodes
            let s = geo.strides[D - 1];
            let run = (self.layers.start * s).min(a.len())..(self.layers.end * s).min(a.len());
            dot(&a[run.clone()], &b[run], partials)
        } else {
            a.par_chunks(CHUNK)
                .zip(b.par_chunks(CHUNK))
                .enumerate()
                .map(|(c, (a, b))| {
                    (0..a.len())
                        .filter(|&k| self.owns(geo, c * CHUNK + k))
                        .map(|k| a[k].dot(&b[k]))
                        .sum::<f64>()
                })
                .collect_into_vec(partials);
            partials.iter().sum()
        };
        self.comm.sum_scalar(own)
    }
}

impl<const D: usize> ImplicitViscosity<D> {
    /// A solve to relative residual `tolerance` in at most `max_iterations` iterations of the
    /// stress of the materials of bit mask `materials` ([`implicit_mask`], the one P2G leaves
    /// out of the internal force), with the transfers' `shape` functions, on the nodes of mass
    /// above `mass_epsilon`.
    pub fn new(
        tolerance: f64,
        max_iterations: usize,
        materials: u64,
        shape: ShapeFunction,
        mass_epsilon: f64,
    ) -> Self {
        Self {
            tolerance,
            max_iterations,
            materials,
            shape,
            mass_epsilon,
            ..Self::default()
        }
    }

    /// Makes this the solve of a rank whose grid is cut as `slab` says; `None`, one process.
    pub fn spread_over(&mut self, slab: Option<Slab>) {
        self.ranks = slab;
    }

    /// Replaces the node velocities v in `grid.velocity_new` by the solution u of
    /// (M + dt K) u = M v, the components the walls and bodies hold kept at their values; the
    /// wall conditions are applied again after it (the ghost nodes behind a wall mirror the
    /// new velocity inside).
    pub fn solve(
        &mut self,
        ps: &Particles<D>,
        grid: &mut Grid<D>,
        boundary: &Boundary<D>,
        materials: &[MaterialParams],
        dt: f64,
    ) -> Result<ViscousStats, ViscousError> {
        let shape = self.shape;
        boundary.apply(&mut grid.velocity_new);
        self.prepare(ps, grid, boundary, materials, dt);
        let Grid {
            geo,
            mass,
            velocity_new: u,
            ..
        } = grid;
        let n = geo.node_count();
        let Self {
            tolerance,
            max_iterations,
            mask,
            inverse_diagonal,
            points,
            widths,
            coefficient,
            stress,
            bands,
            cg,
            ranks,
            ..
        } = self;
        // |b| = |M v*| and r = b - (M + dt K) v* = -dt K v*, on the free components
        cg.fit_nodes(n);
        u.par_chunks(CHUNK)
            .zip(mass.par_chunks(CHUNK).zip(mask.par_chunks(CHUNK)))
            .map(|(u, (m, k))| {
                (0..u.len())
                    .map(|i| (u[i] * m[i]).component_mul(&k[i]).norm_squared())
                    .sum::<f64>()
            })
            .collect_into_vec(&mut cg.partials);
        let mut b_norm = cg.partials.iter().sum::<f64>().sqrt();
        if let Some(slab) = ranks.as_ref() {
            // (r is written below: here it holds M v on the free components)
            cg.r.par_iter_mut().enumerate().for_each(|(i, r)| {
                store(r, (u[i] * mass[i]).component_mul(&mask[i]));
            });
            b_norm = slab.dot(geo, (&cg.r, &cg.r), &mut cg.partials).sqrt();
        }
        let mut op = ViscousOperator {
            geo,
            shape,
            mass,
            mask,
            points,
            widths,
            coefficient,
            stress,
            bands,
            ranks: ranks.as_ref(),
        };
        op.viscous(u, &mut cg.r);
        cg.r.par_iter_mut().enumerate().for_each(|(i, r)| {
            // (a node held or without mass keeps r = +0, and its page uncommitted; a sum
            // that is not finite stays, for the solve to stop on)
            let held = mask[i] == Vector::<D>::zeros() && r.iter().all(|v| v.is_finite());
            let value = if held {
                Vector::<D>::zeros()
            } else {
                -r.component_mul(&mask[i])
            };
            store(r, value);
        });
        // relative to |M v| on the free components, or to the first residual where the free
        // nodes are at rest and only the held ones (a lid, a body) drive the flow
        let r_norm = op.dot(&cg.r, &cg.r, &mut cg.partials).sqrt();
        let params = SolveParams {
            tolerance: *tolerance,
            max_iterations: *max_iterations,
        };
        let mut diagonal = Diagonal(inverse_diagonal);
        let stats = match cg.solve(&mut op, &mut diagonal, u, b_norm.max(r_norm), params) {
            Ok(s) => ViscousStats {
                iterations: s.iterations,
                relative_residual: s.relative_residual,
            },
            Err(SolveError::NotConverged {
                iterations,
                residual,
                tolerance,
            }) => {
                return Err(ViscousError::NotConverged {
                    iterations,
                    residual,
                    tolerance,
                })
            }
            Err(SolveError::Breakdown(why)) => return Err(ViscousError::Breakdown(why)),
        };
        boundary.apply(u);
        Ok(stats)
    }

    /// The quadrature weights dt w_q mu_q (mu_p at the last step's strain rate), the free
    /// components (not held by a wall or body, on a node with mass) and the preconditioner.
    fn prepare(
        &mut self,
        ps: &Particles<D>,
        grid: &Grid<D>,
        boundary: &Boundary<D>,
        materials: &[MaterialParams],
        dt: f64,
    ) {
        let (shape, mass_epsilon) = (self.shape, self.mass_epsilon);
        self.particle_weight.resize(ps.len(), 0.0);
        let implicit = self.materials;
        self.particle_weight
            .par_iter_mut()
            .enumerate()
            .for_each(|(p, c)| {
                let m = ps.material[p];
                let law = &materials[m as usize].law;
                *c = if in_mask(implicit, m as usize) {
                    ps.volume(p) * apparent_viscosity(law, &ps.velocity_gradient[p])
                } else {
                    0.0
                };
            });
        self.quadrature(ps, grid, boundary, materials, shape, dt);
        // 1 on the nodes with mass, written only there (the air's pages stay uncommitted)
        crate::pages::fit(&mut self.mask, grid.geo.node_count());
        self.mask
            .par_iter_mut()
            .zip(grid.mass.par_iter())
            .for_each(|(m, &mass)| {
                // (a mass that is not a number stays free, as before, for the solve to see)
                let free = if mass <= mass_epsilon { 0.0 } else { 1.0 };
                store(m, Vector::<D>::repeat(free));
            });
        boundary.mask_held(&mut self.mask);
        self.diagonal(&grid.geo, shape, &grid.mass);
    }

    /// The points at which K is integrated. A cell deep in the fluid (it and every cell around
    /// it hold implicit particles, or lie behind a wall, and its own are of one material) takes
    /// the 2^D Gauss points of the whole cell, of weight h^D / 2^D each, with the material's
    /// viscosity at the strain rate of the step's velocity there (v^n, lagged as the particles'
    /// is); the other cells (at the free surface, next to a rigid body, where fluids or a fluid
    /// and a solid meet) take their particles as points, of weight V_p.
    ///
    /// Why: integrated at the particles alone, K weighs each cell by the volume of the
    /// particles in it, at the places they happen to be, so where a flow has stirred them a
    /// film's resistance runs through its least filled cells (docs/method.md, "Implicit
    /// viscosity", has the figures). Inside the fluid the weak form integrates over the cell,
    /// whatever it holds.
    fn quadrature(
        &mut self,
        ps: &Particles<D>,
        grid: &Grid<D>,
        boundary: &Boundary<D>,
        materials: &[MaterialParams],
        shape: ShapeFunction,
        dt: f64,
    ) {
        use crate::shape::PAD;
        let geo = &grid.geo;
        self.bins.sort(geo, &ps.x);
        let n = geo.node_count();
        self.sum_cells(ps, geo);
        let (bins, weight) = (&self.bins, &self.particle_weight);
        let open: [bool; 6] = std::array::from_fn(|f| f < 2 * D && boundary.is_open(f));
        let (volume, material) = (&self.cell_volume, &self.cell_material);
        // whether cell c is of one material, and it and the 3^D cells around it hold the fluid
        let deep = |c: usize| {
            let idx = geo.multi(c);
            material[c] != MIXED
                && (0..3usize.pow(D as u32)).all(|k| {
                    let mut rem = k;
                    let mut cell = [0usize; D];
                    for d in 0..D {
                        let v = idx[d] as isize + (rem % 3) as isize - 1;
                        rem /= 3;
                        let (lo, hi) = (PAD as isize, (PAD + geo.cells[d]) as isize);
                        if !geo.periodic[d] && (v < lo || v >= hi) {
                            // behind a face: a wall holds the fluid in, an open face is air
                            return !open[2 * d + usize::from(v >= hi)];
                        }
                        cell[d] = v as usize;
                    }
                    volume[geo.canonical(geo.flat(&cell))] > 0.0
                })
        };
        self.points.clear();
        self.widths.clear();
        self.coefficient.clear();
        self.point_material.clear();
        let corners = 1usize << D;
        let gauss_weight = geo.h.powi(D as i32) / corners as f64;
        let ranks = self.ranks.as_ref();
        for c in 0..n {
            if volume[c] <= 0.0 {
                continue;
            }
            // over ranks a deep cell's Gauss points are the rank's whose slab holds it; the
            // particles elsewhere are their own rank's
            let owned = ranks.is_none_or(|r| r.owns(geo, c));
            let idx = geo.multi(c);
            if (0..D).any(|d| idx[d] < PAD || idx[d] >= PAD + geo.cells[d]) {
                continue;
            }
            let deep = deep(c);
            if deep && !owned {
                continue;
            }
            if deep {
                let lower = geo.node_position(&idx);
                for k in 0..corners {
                    let s = crate::grid::gauss_point::<D>(k);
                    self.points
                        .push(Vector::<D>::from_fn(|d, _| lower[d] + s[d] * geo.h));
                    self.widths.push(0.0);
                    self.coefficient.push(dt * gauss_weight);
                    self.point_material.push(material[c]);
                }
            } else {
                for &p in bins.particles(c) {
                    let p = p as usize;
                    if weight[p] > 0.0 {
                        self.points.push(ps.x[p]);
                        self.widths.push(ps.half_width[p]);
                        self.coefficient.push(dt * weight[p]);
                        self.point_material.push(MIXED);
                    }
                }
            }
        }
        // the Gauss points' viscosity, at the strain rate of v^n there
        let (points, velocity) = (&self.points, &grid.velocity);
        self.coefficient
            .par_iter_mut()
            .zip(self.point_material.par_iter())
            .enumerate()
            .for_each(|(q, (c, &m))| {
                if m == MIXED {
                    return;
                }
                let st = Stencil::<D>::new(shape, &geo.to_cells(&points[q]), geo.h, 0.0);
                let mut l = Matrix::<D>::zeros();
                st.for_each(|nw| l += velocity[geo.flat(&nw.node)] * nw.grad.transpose());
                *c *= apparent_viscosity(&materials[m as usize].law, &l);
            });
    }

    /// Per cell, the volume of its implicit particles and their material ([`MIXED`] where
    /// they are of several); over ranks added up with the neighbours' cells, as their particles
    /// lie in them.
    fn sum_cells(&mut self, ps: &Particles<D>, geo: &GridGeometry<D>) {
        use crate::pages::{fit, store};
        let n = geo.node_count();
        let (bins, weight) = (&self.bins, &self.particle_weight);
        fit(&mut self.cell_volume, n);
        fit(&mut self.cell_material, n);
        (&mut self.cell_volume, &mut self.cell_material)
            .into_par_iter()
            .enumerate()
            .for_each(|(c, (volume, code))| {
                let mut material = None;
                let mut one = true;
                let mut v = 0.0;
                for &p in bins.particles(c) {
                    let p = p as usize;
                    if weight[p] > 0.0 {
                        v += ps.volume(p);
                        one &= *material.get_or_insert(ps.material[p]) == ps.material[p];
                    }
                }
                let m = material.filter(|_| one).unwrap_or(MIXED);
                store(volume, v);
                store(code, if v > 0.0 { m } else { 0 });
            });
        let Some(slab) = &self.ranks else {
            return;
        };
        // the material as numbers whose sums tell one material from several (a cell near the
        // cut holds particles of both ranks): for each rank with particles in the cell, 1,
        // k = m + 1 and k^2 (MIXED + 1 for several); the ranks agree on one material where
        // n sum k^2 = (sum k)^2
        let [ranks, codes, squares] = &mut self.cell_ranks;
        for a in [&mut *ranks, &mut *codes, &mut *squares] {
            fit(a, n);
        }
        (&mut *ranks, &mut *codes, &mut *squares)
            .into_par_iter()
            .zip(&self.cell_volume)
            .zip(&self.cell_material)
            .for_each(|(((r, k, k2), &v), &m)| {
                let (one, code) = if v > 0.0 {
                    (1.0, f64::from(m) + 1.0)
                } else {
                    (0.0, 0.0)
                };
                store(r, one);
                store(k, code);
                store(k2, code * code);
            });
        let mut arrays = [
            &mut self.cell_volume[..],
            &mut ranks[..],
            &mut codes[..],
            &mut squares[..],
        ];
        slab.comm.add_nodes(&mut arrays);
        self.cell_material
            .par_iter_mut()
            .enumerate()
            .for_each(|(c, code)| {
                let (r, k) = (ranks[c], codes[c]);
                let one = r > 0.0 && r * squares[c] == k * k;
                let m = if one { (k / r - 1.0) as u16 } else { MIXED };
                store(code, if r > 0.0 { m } else { 0 });
            });
    }

    /// The inverse diagonal of M + dt K on the free components (0 elsewhere): component d of
    /// node i has m_i + sum_p dt V_p mu_p (|G_ip|^2 + G_ip,d^2 (1 - 2 / D)), the stress of
    /// a unit velocity of that component alone (|dev sym (e_d (x) G)|^2 = (|G|^2 + G_d^2) / 2
    /// - G_d^2 / D).
    fn diagonal(&mut self, geo: &GridGeometry<D>, shape: ShapeFunction, mass: &[f64]) {
        let coefficient = &self.coefficient;
        let shear = 1.0 - 2.0 / D as f64;
        crate::pages::fit(&mut self.inverse_diagonal, geo.node_count());
        scatter_weighted(
            &mut self.bands,
            Points {
                geo,
                shape,
                x: &self.points,
                half_width: &self.widths,
            },
            Vector::<D>::zeros(),
            |p| coefficient[p],
            |c, nw| {
                let g2 = nw.grad.norm_squared();
                nw.grad.map(|g| *c * (g2 + g * g * shear))
            },
            &mut self.inverse_diagonal,
        );
        if let Some(slab) = &self.ranks {
            slab.add(&mut self.inverse_diagonal);
        }
        let mask = &self.mask;
        self.inverse_diagonal
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, d)| {
                let inverse = Vector::<D>::from_fn(|k, _| {
                    let a = mass[i] + d[k];
                    if mask[i][k] > 0.0 && a > 0.0 {
                        1.0 / a
                    } else {
                        0.0
                    }
                });
                store(d, inverse);
            });
    }
}

/// The solve's operator q = (M + dt K) x on the free components, 0 on the others, over the
/// step's quadrature points.
struct ViscousOperator<'a, const D: usize> {
    geo: &'a GridGeometry<D>,
    shape: ShapeFunction,
    mass: &'a [f64],
    mask: &'a [Vector<D>],
    points: &'a [Vector<D>],
    widths: &'a [f64],
    coefficient: &'a [f64],
    stress: &'a mut Vec<Matrix<D>>,
    bands: &'a mut Vec<Band<Vector<D>>>,
    ranks: Option<&'a Slab>,
}

impl<const D: usize> ViscousOperator<'_, D> {
    /// q = dt K v: the gather of each particle's L_p(v), its viscous stress 2 dt V_p mu_p dev
    /// sym L_p, and the scatter of tau_p G_ip (unmasked).
    fn viscous(&mut self, v: &[Vector<D>], q: &mut [Vector<D>]) {
        let (geo, shape) = (self.geo, self.shape);
        self.stress.resize(self.points.len(), Matrix::<D>::zeros());
        let (points, widths) = (self.points, self.widths);
        crate::with_shape!(shape, S => {
            let shape = ShapeFunction::from_code(S);
            let coefficient = self.coefficient;
            self.stress
                .par_iter_mut()
                .enumerate()
                .for_each(|(p, s)| {
                    let c = coefficient[p];
                    if c == 0.0 {
                        *s = Matrix::<D>::zeros();
                        return;
                    }
                    let st = Stencil::<D>::new(shape, &geo.to_cells(&points[p]), geo.h, widths[p]);
                    let mut l = Matrix::<D>::zeros();
                    st.for_each(|nw| l += v[geo.flat(&nw.node)] * nw.grad.transpose());
                    *s = deviatoric_strain_rate(&l) * (2.0 * c);
                });
        });
        let stress = &*self.stress;
        scatter_weighted(
            self.bands,
            Points {
                geo,
                shape,
                x: points,
                half_width: widths,
            },
            Vector::<D>::zeros(),
            |p| stress[p],
            |s, nw| s * nw.grad,
            q,
        );
        if let Some(slab) = self.ranks {
            slab.add(q);
        }
    }
}

impl<const D: usize> Operator<Vector<D>> for ViscousOperator<'_, D> {
    fn apply(&mut self, x: &[Vector<D>], q: &mut [Vector<D>]) {
        self.viscous(x, q);
        let (mass, mask) = (self.mass, self.mask);
        q.par_iter_mut().enumerate().for_each(|(i, q)| {
            store(q, (*q + x[i] * mass[i]).component_mul(&mask[i]));
        });
    }

    fn dot(&self, a: &[Vector<D>], b: &[Vector<D>], partials: &mut Vec<f64>) -> f64 {
        match self.ranks {
            None => dot(a, b, partials),
            Some(slab) => slab.dot(self.geo, (a, b), partials),
        }
    }
}

/// The diagonal preconditioner z = D^-1 r.
struct Diagonal<'a, const D: usize>(&'a [Vector<D>]);

impl<const D: usize> Precondition<Vector<D>> for Diagonal<'_, D> {
    fn apply(&mut self, r: &[Vector<D>], z: &mut [Vector<D>]) {
        z.par_iter_mut()
            .zip(self.0.par_iter().zip(r.par_iter()))
            .for_each(|(z, (d, r))| store(z, d.component_mul(r)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deck::Deck;
    use crate::scheme::Simulation;

    /// A viscous block (mu = 50 Pa s, h = 0.05) in a box whose faces are `faces`, after P2G,
    /// with particle velocities v = (sin 3y, x^2) so that the strain rates (and a
    /// Bingham fluid's lagged viscosity) vary.
    fn block(model: &str, faces: &str) -> Simulation<2> {
        block_with(model, faces, 50.0)
    }

    /// [`block`] of a mud of viscosity `mu`.
    fn block_with(model: &str, faces: &str, mu: f64) -> Simulation<2> {
        let src = format!(
            r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 1.0
cfl = 0.5
[grid]
size = [1.0, 1.0]
cell_size = 0.05
[grid.boundary]
{faces}
[[materials]]
name = "mud"
{model}
density = 1000.0
viscosity = {mu:?}
[[bodies]]
material = "mud"
shape = {{ type = "box", min = [0.2, 0.0], max = [0.7, 0.45] }}
particles_per_cell = 2
"#
        );
        let mut d = Deck::parse(&src, "t.toml").unwrap();
        d.validate("t.toml").unwrap();
        let mut sim = Simulation::<2>::new(&d).unwrap();
        for p in 0..sim.particles.len() {
            let x = sim.particles.x[p];
            sim.particles.v[p] = Vector::<2>::new((3.0 * x[1]).sin(), x[0] * x[0]);
            sim.particles.velocity_gradient[p] =
                Matrix::<2>::new(0.0, 3.0 * (3.0 * x[1]).cos(), 2.0 * x[0], 0.0);
        }
        sim.particles_to_grid();
        sim
    }

    const WALLS: &str = "x_min = \"slip\"\nx_max = \"slip\"\ny_min = \"no_slip\"\ny_max = \"open\"";

    /// The operator the conjugate gradients need: a . A b = b . A a (symmetric), a . A a > 0
    /// on the free components, and the Jacobi diagonal is A's own, for a Newtonian and a
    /// Bingham fluid (whose viscosity varies from particle to particle) next to a no-slip
    /// floor and slip walls.
    #[test]
    fn the_operator_is_symmetric_positive_and_its_diagonal_is_exact() {
        for model in [
            "model = \"newtonian\"",
            "model = \"bingham\"\nyield_stress = 100.0\npapanastasiou_exponent = 10.0",
        ] {
            let sim = block(model, WALLS);
            let (ps, grid, shape) = (&sim.particles, &sim.grid, sim.settings.shape);
            let implicit = implicit_mask(&sim.materials);
            let eps = sim.settings.mass_epsilon;
            let mut v = ImplicitViscosity::<2>::new(1e-8, 100, implicit, shape, eps);
            v.prepare(ps, grid, &sim.boundary, &sim.materials, 0.01);
            let n = grid.geo.node_count();
            let field = |k: f64| -> Vec<Vector<2>> {
                (0..n)
                    .map(|i| {
                        let f = i as f64;
                        Vector::<2>::new((k * f).sin(), (1.7 * k * f).cos())
                            .component_mul(&v.mask[i])
                    })
                    .collect()
            };
            let (a, b) = (field(0.37), field(1.13));
            let mut q = vec![Vector::<2>::zeros(); n];
            v.operator(&grid.geo, &grid.mass).apply(&b, &mut q);
            let ab: f64 = a.iter().zip(&q).map(|(x, y)| x.dot(y)).sum();
            v.operator(&grid.geo, &grid.mass).apply(&a, &mut q);
            let ba: f64 = b.iter().zip(&q).map(|(x, y)| x.dot(y)).sum();
            let aa: f64 = a.iter().zip(&q).map(|(x, y)| x.dot(y)).sum();
            assert!(
                (ab - ba).abs() <= 1e-12 * ab.abs().max(ba.abs()),
                "{ab} {ba}"
            );
            assert!(aa > 0.0);
            // the viscous part is most of the diagonal at this step: the check has teeth
            let mut free = 0;
            for i in (0..n).filter(|&i| grid.mass[i] > 0.0) {
                for c in 0..2 {
                    if v.mask[i][c] == 0.0 {
                        continue;
                    }
                    let mut e = vec![Vector::<2>::zeros(); n];
                    e[i][c] = 1.0;
                    v.operator(&grid.geo, &grid.mass).apply(&e, &mut q);
                    let diagonal = 1.0 / v.inverse_diagonal[i][c];
                    assert!(
                        (q[i][c] - diagonal).abs() <= 1e-12 * diagonal,
                        "node {i}, component {c}: {} against {diagonal}",
                        q[i][c]
                    );
                    free += 1;
                }
            }
            assert!(free > 50, "{free} free components");
        }
    }

    /// Deep in the fluid K is the cell's integral, not the particles' sum: moving the
    /// particles about within their cells (as a sheared flow stirs them) leaves K applied to a
    /// field unchanged at every node whose cells are all deep, and a Newtonian fluid's K there
    /// is the exact integral of the weak form (for v = (y^2, 0), -2 mu h^2 in x per node).
    #[test]
    fn deep_in_the_fluid_k_does_not_depend_on_where_the_particles_sit() {
        let open = "x_min = \"open\"\nx_max = \"open\"\ny_min = \"open\"\ny_max = \"open\"";
        let sim = block("model = \"newtonian\"", open);
        let h = sim.grid.geo.h;
        let mut stirred = sim.particles.clone();
        for p in 0..stirred.len() {
            // each particle moved within its cell, by up to a third of a cell
            let x = stirred.x[p];
            let cell = (x / h).map(|c| c.floor());
            let shift =
                Vector::<2>::new((7.3 * p as f64).sin(), (3.1 * p as f64).cos()) * (h / 3.0);
            let moved = x + shift;
            stirred.x[p] = Vector::<2>::from_fn(|d, _| {
                moved[d].clamp(cell[d] * h + 1e-6 * h, (cell[d] + 1.0) * h - 1e-6 * h)
            });
        }
        let (grid, shape) = (&sim.grid, sim.settings.shape);
        let n = grid.geo.node_count();
        let field: Vec<Vector<2>> = (0..n)
            .map(|i| {
                let x = grid.geo.node_position(&grid.geo.multi(i));
                Vector::<2>::new(x[1] * x[1], 0.0)
            })
            .collect();
        let mu = 50.0;
        let mut k = Vec::new();
        for ps in [&sim.particles, &stirred] {
            let implicit = implicit_mask(&sim.materials);
            let mut v = ImplicitViscosity::<2>::new(1e-8, 100, implicit, shape, 0.0);
            v.prepare(ps, grid, &sim.boundary, &sim.materials, 1.0);
            let mut q = vec![Vector::<2>::zeros(); n];
            v.operator(&grid.geo, &grid.mass).viscous(&field, &mut q);
            k.push(q);
        }
        // nodes whose four cells are all deep: two cells inside the block's edges
        let mut checked = 0;
        for i in 0..n {
            let x = grid.geo.node_position(&grid.geo.multi(i));
            if !(x[0] > 0.2 + 2.5 * h
                && x[0] < 0.7 - 2.5 * h
                && x[1] > 2.5 * h
                && x[1] < 0.45 - 2.5 * h)
            {
                continue;
            }
            let (a, b) = (k[0][i], k[1][i]);
            assert!(
                (a - b).norm() <= 1e-12 * a.norm().max(1.0),
                "node {i}: {a} against {b}"
            );
            // dev sym grad (y^2, 0) = [[0, y], [y, 0]] (y at the cell's middle, on the grid), so
            // K v is the weak form of -div(2 mu dev sym grad v) = -mu v'' (1, 0) = -2 mu (1, 0)
            // against the node's hat, whose integral is h^2
            let exact = -mu * h * h * 2.0;
            assert!(
                (a[0] - exact).abs() <= 1e-9 * exact.abs(),
                "node {i}: {} against {exact}",
                a[0]
            );
            assert!(a[1].abs() <= 1e-9 * exact.abs(), "node {i}: {}", a[1]);
            checked += 1;
        }
        assert!(checked >= 20, "{checked} nodes checked");
    }

    impl<const D: usize> ImplicitViscosity<D> {
        /// The operator of the last [`ImplicitViscosity::prepare`].
        fn operator<'a>(
            &'a mut self,
            geo: &'a GridGeometry<D>,
            mass: &'a [f64],
        ) -> ViscousOperator<'a, D> {
            ViscousOperator {
                geo,
                shape: self.shape,
                mass,
                mask: &self.mask,
                points: &self.points,
                widths: &self.widths,
                coefficient: &self.coefficient,
                stress: &mut self.stress,
                bands: &mut self.bands,
                ranks: self.ranks.as_ref(),
            }
        }
    }

    /// `sim`'s solve at step `dt` by a solver of `tolerance` and `max_iterations`.
    fn solve(
        sim: &mut Simulation<2>,
        tolerance: f64,
        max_iterations: usize,
        dt: f64,
    ) -> Result<ViscousStats, ViscousError> {
        let implicit = implicit_mask(&sim.materials);
        let (shape, eps) = (sim.settings.shape, sim.settings.mass_epsilon);
        ImplicitViscosity::<2>::new(tolerance, max_iterations, implicit, shape, eps).solve(
            &sim.particles,
            &mut sim.grid,
            &sim.boundary,
            &sim.materials,
            dt,
        )
    }

    /// A rigid translation has no strain rate: the solve leaves it as it is, bit for bit,
    /// without an iteration (the property that keeps water at rest in a tank at rest).
    #[test]
    fn a_uniform_velocity_is_left_as_it_is() {
        let open = "x_min = \"open\"\nx_max = \"open\"\ny_min = \"open\"\ny_max = \"open\"";
        let mut sim = block("model = \"newtonian\"", open);
        let uniform = Vector::<2>::new(0.3, -0.2);
        sim.grid.velocity_new.fill(uniform);
        let stats = solve(&mut sim, 1e-10, 100, 1.0).unwrap();
        assert_eq!(stats.iterations, 0);
        assert!(sim.grid.velocity_new.iter().all(|u| *u == uniform));
    }

    /// An inviscid fluid has no viscous stress: its solve would leave a sheared, stirred v* as
    /// it is, bit for bit, so a run of one takes none (and keeps none of its buffers).
    #[test]
    fn an_inviscid_fluid_takes_no_solve() {
        let mut sim = block("model = \"newtonian\"", WALLS);
        assert!(sim.viscosity.is_some(), "a viscous fluid takes the solve");
        sim.materials[0].law = Law::Newtonian(crate::material::Newtonian { viscosity: 0.0 });
        assert!(!any_viscous(&sim.materials));
        sim.grid.velocity_new.clone_from(&sim.grid.velocity);
        sim.boundary.apply(&mut sim.grid.velocity_new);
        let before = sim.grid.velocity_new.clone();
        let stats = solve(&mut sim, 1e-10, 100, 1.0).unwrap();
        assert_eq!(stats.iterations, 0);
        assert!(sim
            .grid
            .velocity_new
            .iter()
            .zip(&before)
            .all(|(u, v)| u == v));
        assert!(block_with("model = \"newtonian\"", WALLS, 0.0)
            .viscosity
            .is_none());
    }

    /// A solve that cannot reach its tolerance in its iterations says so, with the keys.
    #[test]
    fn a_solve_that_does_not_converge_names_its_keys() {
        let mut sim = block("model = \"newtonian\"", WALLS);
        sim.grid.velocity_new.clone_from(&sim.grid.velocity);
        let e = solve(&mut sim, 1e-12, 2, 1.0).unwrap_err();
        let m = e.to_string();
        assert!(
            matches!(e, ViscousError::NotConverged { iterations: 2, .. }),
            "{m}"
        );
        assert!(m.contains("simulation.viscosity_max_iterations"), "{m}");
        assert!(m.contains("simulation.viscosity_tolerance"), "{m}");
    }
}
