//! The projection with one pressure per cell (`pressure.unknowns = "cells"`): the pressure is
//! constant in each cell that holds material, the velocity stays on the nodes, and the
//! corrected velocity is divergence free in each cell's weak sense, exactly (to the solver's
//! tolerance), with no stabilisation. It is the Q1-P0 pair of finite elements (with linear
//! shape functions; the wider kernels keep one pressure per cell too), the discrete form of
//! the B-bar element of nearly incompressible elasticity, written here for the particles'
//! quadrature.
//!
//! Why: the nodal projection of docs/method.md keeps a divergence dt (L - D M^-1 G) p after the
//! correction. That residual is what damps the equal-order checkerboard, and it vanishes for
//! a linear pressure, but under a steady pressure with curvature it drains volume every step:
//! a solid at rest under its own weight creeps (docs/method.md, "Where the volume goes"). Here
//! the constraint is D v^{n+1} = 0 with the same D on both sides of the solve, so a body at
//! rest stays at rest.
//!
//! The discrete equations, with D_cj = sum_{p in c} V_p grad N_j(x_p) (a vector per cell c and
//! node j) and m_j the lumped nodal mass:
//!
//! ```text
//!   m_j v_j^{n+1} = m_j v*_j + dt sum_c p_c D_cj          (the pressure's weak force, corrector)
//!   sum_j D_cj . v_j^{n+1} = 0      for every cell c with material          (the constraint)
//!   =>  A p = -(1/dt) D v*,   A_cd = sum_j D_cj . P_j D_dj / m_j
//! ```
//!
//! P_j keeps the components of node j the walls leave free (a wall's reaction takes the
//! rest). A is symmetric positive semidefinite and is solved by the same conjugate gradient as
//! the nodal form. No free-surface detection is needed: the weak force integrates p over the
//! material only, so p = 0 (with the stress, zero traction) holds weakly at the free surface.
//!
//! The price is the pair's known pressure mode: a checkerboard of cell pressures that D^T does
//! not see (it moves nothing, and the velocity is unique whatever it is). The pressure given to
//! the particles is therefore read from nodal averages of the cell pressures (the classical
//! smoothing of Q1-P0, which removes the checkerboard exactly on a regular grid).
//!
//! Two conditions come with it. The strain rate must be taken from v^{n+1} itself
//! (`stress_update = "usl"`, validated): the musl remap smooths it and the volume drifts
//! again. And a cell whose particles touch no free node (inside a rigid body's reach) is no
//! unknown: its row would be zero and its pressure arbitrary.
//!
//! Written by hand rather than taken from a crate: it is the projection itself, on pmpm's grid
//! and particle bins, like the nodal assembly beside it.

use crate::boundary::Boundary;
use crate::grid::{CellBins, Grid, GridGeometry, Vector};
use crate::linalg::{
    EllMatrix, GridLayout, LinearSolver, SolveError, SolveParams, SolveStats, System,
};
use crate::particles::Particles;
use crate::shape::{ShapeFunction, Stencil};
use rayon::prelude::*;

/// Buffers of the cell projection, reused from step to step.
#[derive(Default)]
pub struct CellProjection<const D: usize> {
    /// The transfers' shape functions.
    shape: ShapeFunction,
    /// The solve's relative residual and iteration limit.
    tolerance: f64,
    max_iterations: usize,
    /// Nodes of at most this mass are empty.
    mass_epsilon: f64,
    /// Nodes per direction a cell's particles reach (2 for linear shape functions, 4 for the
    /// others), from the cell's lower corner less `reach`.
    box_width: usize,
    reach: usize,
    /// Row of each cell (u32::MAX: no material, no unknown).
    row_of: Vec<u32>,
    cell_of_row: Vec<u32>,
    /// Per row, D_cj for the box_width^D nodes of its box.
    coupling: Vec<Vector<D>>,
    /// Per row, sum_{p in c} V_p N_j(x_p) for the nodes of its box (the smoothing's weights).
    weight: Vec<f64>,
    /// Per node, 1 on the components the walls leave free, 0 on the others.
    free: Vec<Vector<D>>,
    matrix: EllMatrix,
    rhs: Vec<f64>,
    solution: Vec<f64>,
    /// Per node, sum_c p_c w_cj / sum_c w_cj: the nodal average of the cell pressures.
    node_pressure: Vec<f64>,
    /// Per node, the weak pressure force sum_c p_c D_cj of the last solve.
    force: Vec<Vector<D>>,
}

impl<const D: usize> CellProjection<D> {
    /// Buffers for the given shape functions, and the solve's relative residual `tolerance`
    /// and iteration limit, on the nodes of mass above `mass_epsilon`.
    pub fn new(
        shape: ShapeFunction,
        tolerance: f64,
        max_iterations: usize,
        mass_epsilon: f64,
    ) -> Self {
        let (box_width, reach) = match shape {
            ShapeFunction::Linear => (2, 0),
            // a particle in cell [a, a+1) reaches nodes a-1 .. a+2 (GIMP with lp <= 1/2,
            // quadratic and cubic B-splines alike: `ShapeFunction::kernel_1d`)
            ShapeFunction::Gimp | ShapeFunction::Bspline2 | ShapeFunction::Bspline3 => (4, 1),
        };
        Self {
            shape,
            tolerance,
            max_iterations,
            mass_epsilon,
            box_width,
            reach,
            ..Default::default()
        }
    }

    /// The weak pressure force sum_c p_c D_cj per node, of the last solve.
    pub fn pressure_force(&self) -> &[Vector<D>] {
        &self.force
    }

    fn box_len(&self) -> usize {
        self.box_width.pow(D as u32)
    }

    /// Offset (per direction, 0..box_width) of multi-index k in a box, flattened.
    fn box_flat(&self, o: &[usize; D]) -> usize {
        let mut k = 0;
        for d in (0..D).rev() {
            k = k * self.box_width + o[d];
        }
        k
    }

    /// One projection on v* (in `grid.velocity_new`): applies the wall conditions, assembles
    /// and solves for the cell pressures, corrects the node velocities and gives the particles
    /// their pressure. `cell_pressure` (one slot per cell, numbered like its lower-corner
    /// node) holds the last step's pressures, the solver's first guess, and receives the new
    /// ones. `bins` holds the particles sorted by cell. The caller re-applies the wall
    /// conditions.
    pub fn project(
        &mut self,
        (ps, bins): (&mut Particles<D>, &CellBins),
        grid: &mut Grid<D>,
        boundary: &Boundary<D>,
        solver: &mut LinearSolver,
        dt: f64,
        cell_pressure: &mut Vec<f64>,
    ) -> Result<SolveStats, SolveError> {
        let (shape, mass_epsilon) = (self.shape, self.mass_epsilon);
        let (tolerance, max_iterations) = (self.tolerance, self.max_iterations);
        let geo = &grid.geo;
        let n_nodes = geo.node_count();
        cell_pressure.resize(n_nodes, 0.0);
        // the components the walls leave free: 1 there, 0 where a wall (or a rigid body)
        // prescribes the velocity
        self.free.clear();
        self.free.resize(n_nodes, Vector::<D>::from_element(1.0));
        boundary.mask_held(&mut self.free);
        boundary.apply(&mut grid.velocity_new);

        self.number_and_couple(ps, geo, bins, shape);

        self.drop_unconstrained(geo, &grid.mass, mass_epsilon);
        let rows = self.cell_of_row.len();
        let bl = self.box_len();
        let (bw, reach) = (self.box_width, self.reach);

        // right-hand side -(1/dt) D v* and the matrix rows
        let span = 2 * bw - 1;
        let width = span.pow(D as u32);
        self.rhs.resize(rows, 0.0);
        self.matrix.reshape(rows, width);
        {
            let mut rhs = std::mem::take(&mut self.rhs);
            let mut matrix = std::mem::take(&mut self.matrix);
            let this = &*self;
            let (v_star, mass) = (&grid.velocity_new, &grid.mass);
            rhs.par_iter_mut().enumerate().for_each(|(r, b)| {
                let c = this.cell_of_row[r] as usize;
                let lo = geo.multi(c).map(|i| i - reach);
                let mut s = 0.0;
                this.for_box(geo, &lo, |k, j, _| {
                    s += this.coupling[r * bl + k].dot(&v_star[j])
                });
                *b = -s / dt;
            });
            let EllMatrix { cols, vals, .. } = &mut matrix;
            cols.par_chunks_mut(width)
                .zip(vals.par_chunks_mut(width))
                .enumerate()
                .for_each(|(r, (cols, vals))| {
                    let c = this.cell_of_row[r] as usize;
                    let cm = geo.multi(c);
                    let dc = &this.coupling[r * bl..(r + 1) * bl];
                    // delta runs over [-(bw-1), bw-1]^D, stored shifted by bw - 1
                    for_each_offset::<D>(span, |slot, delta| {
                        cols[slot] = r as u32;
                        vals[slot] = 0.0;
                        let mut other = [0usize; D];
                        let mut inside = true;
                        for d in 0..D {
                            let o = (cm[d] + delta[d]).wrapping_sub(bw - 1);
                            inside &= o < geo.nodes[d];
                            other[d] = o;
                        }
                        if !inside {
                            return;
                        }
                        let row_d = this.row_of[geo.flat(&other)];
                        if row_d == u32::MAX {
                            return;
                        }
                        let dd = &this.coupling[row_d as usize * bl..(row_d as usize + 1) * bl];
                        // the nodes both boxes hold: k in c's box, k - (delta - (bw - 1)) in d's
                        let lo = cm.map(|i| i - reach);
                        let mut a = 0.0;
                        this.for_box(geo, &lo, |k, j, o| {
                            let m = mass[j];
                            if m <= mass_epsilon {
                                return;
                            }
                            let mut kd = [0usize; D];
                            for d in 0..D {
                                // offset of the node in d's box
                                let od = (o[d] + bw - 1).wrapping_sub(delta[d]);
                                if od >= bw {
                                    return;
                                }
                                kd[d] = od;
                            }
                            let g = dd[this.box_flat(&kd)].component_mul(&this.free[j]);
                            a += dc[k].dot(&g) / m;
                        });
                        cols[slot] = row_d;
                        vals[slot] = a;
                    });
                });
            self.rhs = rhs;
            self.matrix = matrix;
        }

        let stats = self.solve(solver, tolerance, max_iterations, cell_pressure)?;

        self.correct(ps, grid, mass_epsilon, dt, shape);
        Ok(stats)
    }

    /// The unknowns, every cell that holds a particle, and each one's coupling to the nodes of
    /// its box: D_cj = sum_p V_p grad N_jp and the weights sum_p V_p N_jp over its particles.
    fn number_and_couple(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        bins: &CellBins,
        shape: ShapeFunction,
    ) {
        let n_nodes = geo.node_count();
        // the unknowns: every cell that holds a particle
        self.row_of.clear();
        self.row_of.resize(n_nodes, u32::MAX);
        self.cell_of_row.clear();
        for c in 0..n_nodes {
            if !bins.particles(c).is_empty() {
                self.row_of[c] = self.cell_of_row.len() as u32;
                self.cell_of_row.push(c as u32);
            }
        }
        let rows = self.cell_of_row.len();
        let bl = self.box_len();
        let (bw, reach) = (self.box_width, self.reach);
        self.coupling.clear();
        self.coupling.resize(rows * bl, Vector::<D>::zeros());
        self.weight.clear();
        self.weight.resize(rows * bl, 0.0);
        {
            let mut coupling = std::mem::take(&mut self.coupling);
            let mut weight = std::mem::take(&mut self.weight);
            let this = &*self;
            let (xs, hw, vol) = (&ps.x, &ps.half_width, &ps.volume0);
            coupling
                .par_chunks_mut(bl)
                .zip(weight.par_chunks_mut(bl))
                .zip(this.cell_of_row.par_iter())
                .for_each(|((dc, wc), &c)| {
                    let lo = geo.multi(c as usize).map(|i| i - reach);
                    for &p in bins.particles(c as usize) {
                        let p = p as usize;
                        let st = Stencil::<D>::new(shape, &geo.to_cells(&xs[p]), geo.h, hw[p]);
                        st.for_each(|nw| {
                            let mut o = [0usize; D];
                            for d in 0..D {
                                o[d] = nw.node[d].wrapping_sub(lo[d]);
                            }
                            if o.iter().any(|&v| v >= bw) {
                                // a weight of exactly zero at the kernel's edge
                                debug_assert!(nw.n == 0.0 && nw.grad.norm() == 0.0);
                                return;
                            }
                            let k = this.box_flat(&o);
                            dc[k] += nw.grad * vol[p];
                            wc[k] += nw.n * vol[p];
                        });
                    }
                });
            self.coupling = coupling;
            self.weight = weight;
        }
    }

    /// Removes the cells whose particles touch no free node (inside a rigid body or a no-slip
    /// wall's reach): their rows would be zero and their pressure arbitrary.
    fn drop_unconstrained(&mut self, geo: &GridGeometry<D>, mass: &[f64], mass_epsilon: f64) {
        let rows = self.cell_of_row.len();
        let (bl, reach) = (self.box_len(), self.reach);
        {
            let free = &self.free;
            let mut kept = 0usize;
            for r in 0..rows {
                let c = self.cell_of_row[r] as usize;
                let lo = geo.multi(c).map(|i| i - reach);
                let (mut masked, mut whole) = (0.0, 0.0);
                self.for_box(geo, &lo, |k, j, _| {
                    if mass[j] > mass_epsilon {
                        let d = self.coupling[r * bl + k];
                        masked += d.component_mul(&free[j]).norm_squared() / mass[j];
                        whole += d.norm_squared() / mass[j];
                    }
                });
                if masked > 1e-12 * whole {
                    if kept != r {
                        self.coupling.copy_within(r * bl..(r + 1) * bl, kept * bl);
                        self.weight.copy_within(r * bl..(r + 1) * bl, kept * bl);
                        self.cell_of_row[kept] = c as u32;
                    }
                    self.row_of[c] = kept as u32;
                    kept += 1;
                } else {
                    self.row_of[c] = u32::MAX;
                }
            }
            self.cell_of_row.truncate(kept);
            self.coupling.truncate(kept * bl);
            self.weight.truncate(kept * bl);
        }
    }

    /// Solves for the cell pressures, from the last step's (`cell_pressure`, which takes the
    /// new ones).
    fn solve(
        &mut self,
        solver: &mut LinearSolver,
        tolerance: f64,
        max_iterations: usize,
        cell_pressure: &mut [f64],
    ) -> Result<SolveStats, SolveError> {
        let rows = self.cell_of_row.len();
        // solve, from the last step's pressures
        self.solution.resize(rows, 0.0);
        {
            let (prev, cells) = (&*cell_pressure, &self.cell_of_row);
            self.solution
                .par_iter_mut()
                .zip(cells.par_iter())
                .for_each(|(x, &c)| *x = prev[c as usize]);
        }
        // one pressure per cell: the rows sit on no node grid (the multigrid is refused)
        let system = System {
            matrix: &self.matrix,
            layout: &GridLayout::EMPTY,
            singular: false,
            partition: None,
        };
        let params = SolveParams {
            tolerance,
            max_iterations,
        };
        let stats = solver.solve(&system, &self.rhs, &mut self.solution, params)?;
        cell_pressure.par_iter_mut().for_each(|p| *p = 0.0);
        for (r, &c) in self.cell_of_row.iter().enumerate() {
            cell_pressure[c as usize] = self.solution[r];
        }
        Ok(stats)
    }

    /// The corrector v_j += (dt / m_j) sum_c p_c D_cj, gathered per node from the cells whose
    /// boxes hold it; the nodal average of the cell pressures; the particles' pressure from it.
    fn correct(
        &mut self,
        ps: &mut Particles<D>,
        grid: &mut Grid<D>,
        mass_epsilon: f64,
        dt: f64,
        shape: ShapeFunction,
    ) {
        let geo = &grid.geo;
        let n_nodes = geo.node_count();
        let bl = self.box_len();
        let (bw, reach) = (self.box_width, self.reach);
        self.node_pressure.resize(n_nodes, 0.0);
        self.force.resize(n_nodes, Vector::<D>::zeros());
        {
            let mut node_pressure = std::mem::take(&mut self.node_pressure);
            let mut force = std::mem::take(&mut self.force);
            let this = &*self;
            let sol = &self.solution;
            grid.velocity_new
                .par_iter_mut()
                .zip(node_pressure.par_iter_mut())
                .zip(force.par_iter_mut())
                .zip(grid.mass.par_iter())
                .enumerate()
                .for_each(|(j, (((v, np), fj), &m))| {
                    *np = 0.0;
                    *fj = Vector::<D>::zeros();
                    if m <= mass_epsilon {
                        return;
                    }
                    let node = geo.multi(j);
                    let (mut f, mut sp, mut sw) = (Vector::<D>::zeros(), 0.0, 0.0);
                    // cells c with c - reach <= j <= c - reach + bw - 1; o is j's offset in c's
                    // box
                    for_each_offset::<D>(bw, |kb, o| {
                        let mut cell = [0usize; D];
                        let mut inside = true;
                        for d in 0..D {
                            let c = (node[d] + reach).wrapping_sub(o[d]);
                            inside &= c < geo.nodes[d];
                            cell[d] = c;
                        }
                        if inside {
                            let r = this.row_of[geo.flat(&cell)];
                            if r != u32::MAX {
                                let k = r as usize * bl + kb;
                                let p = sol[r as usize];
                                f += this.coupling[k] * p;
                                sp += this.weight[k] * p;
                                sw += this.weight[k];
                            }
                        }
                    });
                    *v += f * (dt / m);
                    *fj = f;
                    if sw > 0.0 {
                        *np = sp / sw;
                    }
                });
            self.node_pressure = node_pressure;
            self.force = force;
        }

        // the particles' pressure from the smoothed nodal field
        let np = &self.node_pressure;
        (
            ps.x.par_iter(),
            ps.half_width.par_iter(),
            ps.pressure.par_iter_mut(),
        )
            .into_par_iter()
            .for_each(|(x, &lp, pp)| *pp = crate::transfer::interpolate(shape, geo, np, x, lp));
    }

    /// Calls `f(k, j, o)` for each node of the box whose first node is `lo` (padded
    /// multi-index): o its offset in the box, k that offset flattened, j its flat index; nodes
    /// past the grid are skipped.
    fn for_box(
        &self,
        geo: &GridGeometry<D>,
        lo: &[usize; D],
        mut f: impl FnMut(usize, usize, &[usize; D]),
    ) {
        for_each_offset::<D>(self.box_width, |k, o| {
            let node: [usize; D] = std::array::from_fn(|d| lo[d] + o[d]);
            if (0..D).all(|d| node[d] < geo.nodes[d]) {
                f(k, geo.flat(&node), o);
            }
        });
    }
}

/// Calls `f(k, o)` for each multi-index o in [0, width)^D, the first direction fastest, k its
/// flattened index (the numbering of [`CellProjection::box_flat`]).
fn for_each_offset<const D: usize>(width: usize, mut f: impl FnMut(usize, &[usize; D])) {
    let mut o = [0usize; D];
    for k in 0..width.pow(D as u32) {
        f(k, &o);
        for d in 0..D {
            o[d] += 1;
            if o[d] < width {
                break;
            }
            o[d] = 0;
        }
    }
}
