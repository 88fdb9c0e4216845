//! The projection step of docs/method.md (steps 3 to 6): free surface, pressure Poisson equation,
//! solve, corrector, pressure to the particles.
//!
//! [`Projection::project`] runs between the predictor (v* on the nodes, wall conditions
//! applied) and the grid-to-particle transfer. With `beta > 0` (incremental projection) the
//! predictor has already applied beta p^n from the particle stress, and the solve is for the
//! increment.
//!
//! The material is incompressible, so the quadrature volume of a particle is its initial
//! volume V_p^0 (rho_p = m_p / V_p^0), not V_p^0 J: J drifts with the discrete divergence, and
//! feeding the drift back into L and into the free-surface volume fractions would compound it.

pub(crate) mod assemble;
pub(crate) mod cell;
pub(crate) mod density;
pub use density::Packing;
pub mod free_surface;
mod ranks;
mod settings;
mod spacing;

pub use settings::{DensityCorrection, Preconditioner, PressureSettings, Solver, MULTIGRID_CELLS};

use crate::boundary::Boundary;
use crate::comm::Comm;
use crate::grid::{CellBins, Grid, Vector};
use crate::linalg::{
    Direct, EllMatrix, GridLayout, IncompleteCholesky, Jacobi, LinearSolver, Multigrid, Pcg, Slots,
    SolveError, SolveParams, SolveStats, System,
};
use crate::pages;
use crate::particles::Particles;
use crate::shape::{ShapeFunction, Stencil};
use crate::timing::{Phase, PhaseTimers};
use crate::transfer::{scatter_to_nodes, Band, Points};
use assemble::ParticleQuadrature;
use free_surface::NodeKind;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Right-hand side of the pressure Poisson equation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PoissonRhs {
    /// The divergence form plus the wall flux (1/dt) sum_p V_p G_ip . w_p, w the part of v*
    /// the wall conditions removed: the discrete form of the Neumann condition
    /// dp/dn = rho (v* - v_wall) . n / dt, exact under gravity.
    #[default]
    Flux,
    /// docs/method.md's -(1/dt) sum_p V_p N_ip (div v*)_p with v* after the wall conditions
    /// (dp/dn = 0 on walls), the paper's form.
    Divergence,
}

/// Where the projection's pressure unknowns sit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PressureUnknowns {
    /// One pressure per node, the velocity's own shape functions (docs/method.md): a free-surface
    /// detection gives p = 0, and the projection's residual dt (L - D M^-1 G) p damps the
    /// equal-order checkerboard.
    #[default]
    Nodes,
    /// One pressure per cell that holds material, constant in the cell (the Q1-P0 pair,
    /// `crates/pmpm/src/pressure/cell.rs`): each cell's weak divergence is zero after the correction, with
    /// no stabilisation residual, so a solid at rest under a steady load stays at rest. No
    /// free-surface detection (p = 0 holds weakly at the material's boundary).
    Cells,
}

/// Quadrature of the Poisson matrix L and its right-hand side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Quadrature {
    /// The particles are the quadrature points (the paper): L_ij = sum_p (V_p / rho_p)
    /// G_ip . G_jp.
    Particle,
    /// 2^D Gauss points per cell, weighted by the cell's volume fraction min(phi_c, 1), with the
    /// cell's density (docs/method.md's alternative): L and the right-hand side do not see where the
    /// particles sit inside the fluid, only how full each cell is.
    #[default]
    Cell,
}

/// How the nodal projection sees the rigid bodies' faces (`pressure.rigid_faces`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RigidFaces {
    /// The body's nodes hold its velocity: the face acts at node resolution.
    Nodes,
    /// Cut cells: a face acts where it lies ([`crate::rigid`]). Needs linear or GIMP shape
    /// functions, the level-set free surface and nodal unknowns.
    Cut,
}

/// The projection's settings, read once from [`PressureSettings`].
#[derive(Debug, Clone, Copy)]
struct Settings {
    tolerance: f64,
    max_iterations: usize,
    /// Most solves per step (`pressure.passes`, [`Projection::pass`]).
    passes: usize,
    /// Share of p^n in the predictor (0: Chorin, 1: incremental).
    beta: f64,
    shape: ShapeFunction,
    rhs_form: PoissonRhs,
    quadrature: Quadrature,
    /// alpha of `pressure.volume_correction`.
    volume_correction: f64,
    /// A material is a solid (shear modulus > 0): the free surface carries p = n . tau . n
    /// instead of 0 ([`free_surface::surface_normal_stress`]).
    traction_free: bool,
    /// Nodes of at most this mass are empty.
    mass_epsilon: f64,
    /// The window past its slab a rank sees over ranks ([`crate::slabs::window_of`]).
    window: usize,
}

/// The projection's work buffers, sized as the particles and the grid need them.
#[derive(Default)]
struct Work<const D: usize> {
    /// V_p^0 V_p^0 / m_p = V_p / rho_p per particle (permuted with the particles).
    volume_over_density: Vec<f64>,
    /// The particle quadrature's (div v*)_p and w_p (the cell quadrature keeps them at its
    /// Gauss points).
    divergence: Vec<f64>,
    velocity_star: Vec<Vector<D>>,
    /// v* before the wall conditions.
    unconstrained: Vec<Vector<D>>,
    /// Per cell, 1 - J, with J the particles' volume ratio averaged with the weights V_p^0.
    cell_deficit: Vec<f64>,
    /// Per node, bit d set where the walls or rigid bodies hold velocity component d (a byte,
    /// and zero off the walls, so that it commits little memory: [`crate::pages`]).
    held: Vec<u8>,
    extended: Vec<Vector<D>>,
    pressure_gradient: Vec<Vector<D>>,
    /// p^{n+1} on the free-surface nodes when `traction_free` (0 elsewhere; empty, all 0,
    /// without it).
    surface_pressure: Vec<f64>,
}

/// The buffers of the stages the pressure solve and the density correction both run: the
/// particles binned by cell, the free surface, the Gauss points, the linear system and its
/// solution, a scatter's sums. The correction runs after the projection in the step and each
/// rebuilds them from the particles, so the two keep one set (a second cost as much memory as
/// the first).
pub struct Shared<const D: usize> {
    /// The particles (or, in the quadrature, the Gauss points) binned by cell.
    bins: CellBins,
    /// The free surface of the last solve (the density correction's after a step that ran
    /// it): volume fractions, level set, each node's role.
    pub surface: free_surface::Surface,
    /// The last solve's linear system (the density correction's after a step that ran it).
    pub system: Assembled,
    gauss: GaussPoints<D>,
    /// The solution of the last solve ([`Slots`]: over ranks a rank writes only its own rows
    /// and those beside them).
    solution: Slots<f64>,
    /// Scratch for the ghost values (the second and the first layer).
    ghost: [Vec<f64>; 2],
    /// A scatter's per-thread sums and their total per node: the corrector's
    /// sum_p V_p N_ip (grad p)_p, the density correction's displacements.
    vector_bands: Vec<Band<Vector<D>>>,
    nodal: Vec<Vector<D>>,
    /// Over ranks, how the stages share their work ([`ranks`]); `None` on one process.
    ranks: Option<ranks::Ranks>,
}

impl<const D: usize> Shared<D> {
    /// Makes these the stages of a rank of `comm`'s (the slabs' comm,
    /// [`crate::slabs::Sliced`]), the grid cut as `d` cuts it; `None`: one process's.
    pub fn spread_over(&mut self, ranks: Option<(Arc<dyn Comm>, crate::slabs::Decomposition)>) {
        let ranks = ranks.map(|(comm, d)| ranks::Ranks::new(comm, d.axis, d.cuts, d.reach));
        let owners = ranks.as_ref().map(|r| free_surface::Owners {
            comm: r.partition.comm.clone(),
            axis: r.axis,
            layers: r.layers(),
            reach: r.reach(),
        });
        self.surface.spread_over(owners);
        self.ranks = ranks;
    }

    /// Empty buffers, with the free surface of `[pressure]` and the boundary's open faces.
    pub fn new(pd: &PressureSettings, boundary: &Boundary<D>) -> Self {
        Self {
            bins: CellBins::default(),
            surface: free_surface::Surface::new(pd, boundary),
            system: Assembled::default(),
            gauss: GaussPoints::default(),
            solution: Slots::default(),
            ghost: Default::default(),
            vector_bands: Vec::new(),
            nodal: Vec::new(),
            ranks: None,
        }
    }
}

/// The linear system of the last pass: the numbering of its unknowns, its matrix and its
/// right-hand side.
#[derive(Debug, Default)]
pub struct Assembled {
    /// The numbering of the unknowns.
    unknowns: Unknowns,
    /// The assembled matrix L (interior rows and columns).
    pub matrix: EllMatrix,
    /// The right-hand side ([`Slots`]: over ranks a rank writes only the rows it assembles).
    pub rhs: Slots<f64>,
}

/// What the last step's solves did.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Statistics of the last solve (iterations summed over the passes).
    pub stats: SolveStats,
    /// The right-hand-side norm per pass, solved or not: what divergence each pass started
    /// from.
    pub pass_norms: Vec<f64>,
    /// Whether the system had no free-surface node (pressure fixed up to a constant).
    pub singular: bool,
    /// Whether the last solve's pressure had a level set by a free surface (not singular);
    /// taken as true on resuming, which does not record it.
    pub level: bool,
}

/// State and work buffers of the projection, reused from step to step.
pub struct Projection<const D: usize> {
    settings: Settings,
    solver: LinearSolver,
    /// The stages' buffers, shared with the density correction.
    pub shared: Shared<D>,
    /// The last pass's solved pressure increment per node: p^{n+1} - beta p^n after the first
    /// (the Dirichlet values on the free surface, 0 on empty nodes), the increment of a further
    /// one (0 on the free surface).
    pub node_pressure: Vec<f64>,
    /// Node pressure p^{n+1} of the last solve (the free-surface value on free-surface nodes, 0
    /// on empty ones).
    pub previous: Vec<f64>,
    work: Work<D>,
    /// What the last step's solves did.
    pub last: Outcome,
    /// With `pressure.unknowns = "cells"`, the cell projection (then `previous` holds the
    /// cell pressures, numbered like their cells' lower-corner nodes).
    cells: Option<cell::CellProjection<D>>,
    /// The density correction after the step (`pressure.density_correction = "positions"`,
    /// nodal unknowns).
    density: Option<density::PositionCorrection<D>>,
}

impl<const D: usize> Projection<D> {
    /// The projection with validated settings, for the given particles and shape functions;
    /// `traction_free` where a material is a solid (its free surface bears no pressure of its
    /// own), on a grid of `cells` cells (the default preconditioner depends on it).
    pub fn new(
        pd: &PressureSettings,
        shape: ShapeFunction,
        traction_free: bool,
        ps: &Particles<D>,
        boundary: &Boundary<D>,
        cells: usize,
        mass_epsilon: f64,
    ) -> Self {
        let solver = linear_solver(pd, cells);
        let particle_quadrature = usize::from(pd.quadrature == Quadrature::Particle);
        let volume_over_density = ps
            .volume0
            .iter()
            .zip(&ps.mass)
            .map(|(v, m)| v * v / m)
            .collect();
        Self {
            settings: Settings {
                tolerance: pd.tolerance,
                max_iterations: pd.max_iterations,
                passes: pd.passes,
                beta: pd.beta,
                shape,
                rhs_form: pd.rhs,
                quadrature: pd.quadrature,
                volume_correction: pd.volume_correction,
                traction_free,
                mass_epsilon,
                window: crate::slabs::window_of(pd.bubble_cells, shape),
            },
            solver,
            shared: Shared::new(pd, boundary),
            node_pressure: Vec::new(),
            previous: Vec::new(),
            work: Work {
                volume_over_density,
                // the particle quadrature's values at the particles (the cell quadrature
                // keeps them at its Gauss points)
                divergence: vec![0.0; particle_quadrature * ps.len()],
                velocity_star: vec![Vector::<D>::zeros(); particle_quadrature * ps.len()],
                pressure_gradient: vec![Vector::<D>::zeros(); ps.len()],
                ..Default::default()
            },
            last: Outcome {
                stats: SolveStats {
                    iterations: 0,
                    relative_residual: 0.0,
                },
                pass_norms: Vec::with_capacity(pd.passes),
                singular: false,
                level: true,
            },
            cells: (pd.unknowns == PressureUnknowns::Cells).then(|| {
                cell::CellProjection::new(shape, pd.tolerance, pd.max_iterations, mass_epsilon)
            }),
            density: (pd.unknowns == PressureUnknowns::Nodes
                && matches!(
                    pd.density_correction,
                    Some(DensityCorrection::Positions | DensityCorrection::Particles)
                ))
            .then(|| density::PositionCorrection::new(pd, shape)),
        }
    }

    /// Spray keeps its volume: a particle none of whose nodes held a pressure equation this
    /// step (a droplet thrown off the flow, a splash breaking up) loses the trace of its
    /// velocity gradient before J is updated.
    ///
    /// Around such a particle the grid velocity is the particles' own, unprojected, and its
    /// divergence measures how the droplets fly apart or together, which the grid cannot
    /// resolve below a cell, not a change of the fluid's volume: integrated into J it blows a
    /// splash up into particles of several cells. Droplets
    /// that come together fill their cells again, their nodes take equations, and J measures
    /// them as before.
    pub fn hold_spray_volumes(&self, ps: &mut Particles<D>, geo: &crate::grid::GridGeometry<D>) {
        let kinds = &self.shared.surface.kinds;
        if self.cells.is_some() || kinds.is_empty() {
            return;
        }
        let shape = self.settings.shape;
        (
            ps.x.par_iter(),
            ps.half_width.par_iter(),
            ps.velocity_gradient.par_iter_mut(),
        )
            .into_par_iter()
            .for_each(|(x, &lp, l)| {
                let st = Stencil::<D>::new(shape, &geo.to_cells(x), geo.h, lp);
                let mut reached = false;
                st.for_each(|nw| {
                    reached |= nw.n > 0.0 && kinds[geo.flat(&nw.node)] == NodeKind::Interior;
                });
                if !reached {
                    *l -= crate::particles::Matrix::<D>::identity() * (l.trace() / D as f64);
                }
            });
    }

    /// Whether this projection has a density correction.
    pub fn corrects_density(&self) -> bool {
        self.density.is_some()
    }

    /// After the step: moves the particles so that their volumes return towards V0, the
    /// share `pace.volume` of the way (nothing without the density correction). Returns the
    /// solves' iterations.
    pub fn correct_density(
        &mut self,
        ps: &mut Particles<D>,
        geo: &crate::grid::GridGeometry<D>,
        boundary: &Boundary<D>,
        pace: density::Pace,
    ) -> Result<usize, SolveError> {
        match &mut self.density {
            Some(d) => Ok(d
                .correct(
                    ps,
                    geo,
                    boundary,
                    pace,
                    (&mut self.solver, &mut self.shared),
                )?
                .iterations),
            None => Ok(0),
        }
    }

    /// With `pressure.unknowns = "cells"`, the last solve's weak pressure force
    /// sum_c p_c D_cj per node.
    pub fn cell_pressure_force(&self) -> Option<&[Vector<D>]> {
        self.cells.as_ref().map(|c| c.pressure_force())
    }

    /// V_p / rho_p per particle (for checkpoints).
    pub fn volume_over_density(&self) -> &[f64] {
        &self.work.volume_over_density
    }

    /// Restores V_p / rho_p per particle from a checkpoint.
    pub fn restore_volume_over_density(&mut self, v: Vec<f64>) {
        self.work.volume_over_density = v;
    }

    /// Keeps the per-particle state of the particles at `kept` ([`Particles::keep`]).
    pub fn keep_particles(&mut self, kept: &[u32]) {
        crate::particles::keep(&mut self.work.volume_over_density, kept);
        self.fit_particles(kept.len());
    }

    /// Appends the per-particle state of particles joining the run.
    pub fn add_particles(&mut self, ps: &Particles<D>) {
        self.work
            .volume_over_density
            .extend(ps.volume0.iter().zip(&ps.mass).map(|(v, m)| v * v / m));
    }

    /// Sizes the per-particle scratch to `n` particles.
    pub fn fit_particles(&mut self, n: usize) {
        self.work.pressure_gradient.resize(n, Vector::<D>::zeros());
        if self.settings.quadrature == Quadrature::Particle {
            self.work.divergence.resize(n, 0.0);
            self.work.velocity_star.resize(n, Vector::<D>::zeros());
        }
    }

    /// Follows a reordering of the particles ([`Particles::permute`]): the arrays that live
    /// from step to step move with them (the others are refilled every step).
    pub fn permute_particles(
        &mut self,
        order: &[u32],
        scratch: &mut crate::particles::PermuteScratch<D>,
    ) {
        crate::particles::permute(&mut self.work.volume_over_density, order, scratch);
    }

    /// Step 3's first stage, before the predictor: the particles binned by cell and, under the
    /// nodal projection, the free surface (each node's role, and the level set where the
    /// surface lies) and the unknowns numbered. It reads only where the particles are, so the
    /// walls can settle their contacts on it before v* is formed ([`Projection::wall_pressure`]);
    /// the cell projection finds its own surface in [`Projection::project`].
    pub fn find_free_surface(&mut self, ps: &Particles<D>, grid: &Grid<D>, boundary: &Boundary<D>) {
        self.shared.bins.sort(&grid.geo, &ps.x);
        if self.cells.is_some() {
            return;
        }
        let geo = &grid.geo;
        self.shared.surface.detect(
            geo,
            &self.shared.bins,
            &ps.volume0,
            &grid.mass,
            self.settings.mass_epsilon,
            &boundary.rigid,
        );
        let shared = &mut self.shared;
        let free = number(
            geo,
            &shared.surface.kinds,
            &mut shared.system.unknowns,
            &mut shared.ranks,
        );
        self.last.singular = free == 0 && !self.shared.system.unknowns.node_of_row.is_empty();
    }

    /// The first of its settings that a run over ranks does not support yet, as the deck's
    /// key and value: the cell unknowns, and a solver that is not spread (the direct solver,
    /// the incomplete Cholesky).
    pub fn unsupported_over_ranks(&self) -> Option<&'static str> {
        if self.cells.is_some() {
            Some("pressure.unknowns = \"cells\"")
        } else {
            unspread(&self.solver)
        }
    }

    /// The window past its slab that a rank of this projection sees over ranks
    /// ([`crate::slabs::Decomposition::window`]).
    pub fn window(&self) -> usize {
        self.settings.window
    }

    /// The layers of its window whose nodes' sums a rank of this projection takes and whose
    /// stages it runs ([`crate::slabs::projection_reach`]).
    pub fn reach(&self) -> usize {
        crate::slabs::projection_reach(self.settings.shape)
    }

    /// The cell layers past its slab whose particles a rank is lent as ghosts: a layer or two
    /// ([`crate::slabs::GHOST_LAYERS`]) where the stages read the window's cells only through
    /// the owners' sums; the whole window where the particles are the quadrature's points or a
    /// solid's surface stress is averaged from them.
    pub fn ghost_layers(&self) -> usize {
        if self.cell_quadrature() && !self.settings.traction_free {
            crate::slabs::GHOST_LAYERS
        } else {
            self.settings.window
        }
    }

    /// Makes this the projection of a rank of `comm`'s, the grid cut as the
    /// [`crate::slabs::Decomposition`] cuts it; `None` makes it one process's again.
    pub fn spread_over(&mut self, ranks: Option<(Arc<dyn Comm>, crate::slabs::Decomposition)>) {
        self.shared.spread_over(ranks);
    }

    /// Over ranks, the neighbours' particles from `own` on in `ps` are ghosts
    /// ([`crate::slabs::Migration::lend_ghosts`]) until [`Projection::ghosts_gone`]: the
    /// per-particle state follows them, and no sum that is added up over the ranks counts
    /// them (the particle quadrature's rows and a solid's surface stress, summed on this
    /// rank alone, read them).
    pub fn ghosts_from(&mut self, ps: &Particles<D>, own: usize) {
        if let Some(r) = &mut self.shared.ranks {
            r.own = own;
        }
        self.particles_moved(ps);
    }

    /// Over ranks, after particles left or joined this rank (a migration, ghosts): V_p / rho_p
    /// = V_p^0 V_p^0 / m_p of every particle again (what it is from the start: the same bits),
    /// and the per-particle scratch sized.
    pub fn particles_moved(&mut self, ps: &Particles<D>) {
        let vod = &mut self.work.volume_over_density;
        vod.clear();
        vod.extend(ps.volume0.iter().zip(&ps.mass).map(|(v, m)| v * v / m));
        self.fit_particles(ps.len());
    }

    /// Over ranks, before the grid is cut anew at `new`: p^n on the nodes of this rank's new
    /// slab and window, from the ranks whose slabs hold them now (each rank's is exact only on
    /// its slab and window, and a new cut gives it another slab; `Ranks::hand_over`).
    pub fn share_pressure(
        &mut self,
        geo: &crate::grid::GridGeometry<D>,
        new: &crate::slabs::Decomposition,
    ) {
        let Some(r) = &self.shared.ranks else {
            return;
        };
        pages::fit(&mut self.previous, geo.node_count());
        r.hand_over(geo, new, &mut self.previous);
    }

    /// The ghosts of [`Projection::ghosts_from`] dropped: `own` particles again.
    pub fn ghosts_gone(&mut self, own: usize) {
        self.work.volume_over_density.truncate(own);
        self.fit_particles(own);
        if let Some(r) = &mut self.shared.ranks {
            r.ghosts_gone();
        }
    }

    /// The node pressure that decides which walls hold this step
    /// ([`Boundary::settle_contacts`]): the last solve's, where it has a level. None where the
    /// walls hold both ways: before the first solve, under the cell projection, and where no
    /// free surface sets the pressure's level, this step or at the last solve (a filled, closed
    /// box, whose water cannot leave a wall without leaving a void; a singular solve's
    /// pressure has its mean taken out, so half its nodes read below zero).
    pub fn wall_pressure(&self, nodes: usize) -> Option<&[f64]> {
        let level = self.cells.is_none()
            && !self.last.singular
            && self.last.level
            && self.previous.len() == nodes;
        level.then_some(&self.previous[..])
    }

    /// Steps 3 to 6 of docs/method.md on v* (in `grid.velocity_new`, wall conditions applied),
    /// after [`Projection::find_free_surface`]: with beta > 0 applies -beta grad p^n, then
    /// assembles and solves the Poisson equation for the pressure (its increment when
    /// beta > 0), corrects the node velocities and interpolates the new pressure to the
    /// particles. The caller re-applies the wall conditions.
    ///
    /// p^n is the last solve's node pressure (zero on nodes that were not in the fluid), and the
    /// predictor's -beta grad p^n uses the corrector's own operator, so that an exact pressure
    /// is a fixed point: in a column at rest the increment vanishes. (Taking p^n from the
    /// particle stress instead, the weak-form force sum V_p p_p G_ip, mixes two discrete
    /// gradients, and a column at rest blows up within a few steps.)
    pub fn project(
        &mut self,
        ps: &mut Particles<D>,
        grid: &mut Grid<D>,
        boundary: &Boundary<D>,
        dt: f64,
        timers: &mut PhaseTimers,
    ) -> Result<SolveStats, SolveError> {
        let shape = self.settings.shape;
        let beta = self.settings.beta;
        let n_nodes = grid.geo.node_count();
        pages::fit(&mut self.node_pressure, n_nodes);
        pages::fit(&mut self.previous, n_nodes);
        if let Some(cells) = &mut self.cells {
            timers.lap(Phase::FreeSurface);
            self.last.stats = cells.project(
                (ps, &self.shared.bins),
                grid,
                boundary,
                &mut self.solver,
                dt,
                &mut self.previous,
            )?;
            self.last.singular = false;
            timers.lap(Phase::Solve);
            return Ok(self.last.stats);
        }
        if beta > 0.0 {
            // incremental form: v* -= beta (dt / m_i) sum_p V_p N_ip (grad p^n)_p
            self.particle_pressure(ps, &grid.geo, false);
            self.correct(ps, grid, beta * dt);
            timers.lap(Phase::Corrector);
        }
        let geo = &grid.geo;
        // on the free surface p^{n+1} = 0, or n . tau . n where a solid's surface is (a run
        // with a solid stores every particle's tau: `material::stored`)
        if self.settings.traction_free {
            debug_assert!(ps.stored.stress);
            let points = Points {
                geo,
                shape,
                x: &ps.x,
                half_width: &ps.half_width,
            };
            let s = &self.shared.surface;
            free_surface::surface_normal_stress(
                points,
                &self.shared.bins,
                (&ps.volume0, &ps.tau),
                (&s.fraction, &s.open, &s.kinds),
                &mut self.work.surface_pressure,
            );
        }
        timers.lap(Phase::FreeSurface);
        // the unknown is p^{n+1} - beta p^n
        {
            let (kinds, prev, surface) = (
                &self.shared.surface.kinds,
                &self.previous,
                &self.work.surface_pressure,
            );
            self.node_pressure
                .par_iter_mut()
                .enumerate()
                .for_each(|(i, dp)| {
                    let value = match kinds[i] {
                        NodeKind::FreeSurface => {
                            surface.get(i).copied().unwrap_or(0.0) - beta * prev[i]
                        }
                        _ => 0.0,
                    };
                    pages::store(dp, value);
                });
        }
        // 4. and 5. in passes: the first projects v*; each further one projects the
        //    divergence the corrector and the wall conditions left, until it is below the
        //    solver's tolerance relative to the first, stops shrinking, or `passes` are done
        let (mut first_norm, mut last_norm) = (0.0, f64::INFINITY);
        self.last.pass_norms.clear();
        let mut iterations = 0;
        for pass in 0..self.settings.passes {
            let first = pass == 0;
            let further = (!first).then_some((self.settings.tolerance * first_norm, last_norm));
            match self.pass(ps, grid, boundary, dt, further, timers)? {
                Some((norm, stats)) => {
                    if first {
                        first_norm = norm;
                        self.last.stats = stats;
                    }
                    last_norm = norm;
                    iterations += stats.iterations;
                }
                None => break,
            }
        }
        self.last.stats.iterations = iterations;
        self.last.level = !self.last.singular;
        Ok(self.last.stats)
    }

    /// One pass of steps 4 and 5 on the node velocities in `grid.velocity_new`: the
    /// right-hand side from them, the solve and the corrector.
    ///
    /// The first pass assembles L and solves for p^{n+1} - beta p^n. L is the Laplacian
    /// sum_q (V_q / rho_q) G_iq . G_jq, not the operator the corrector and the wall conditions
    /// apply (the divergence of M^-1 times the pressure force, with the walls' components
    /// removed), so the corrected velocity keeps a divergence, largest next to the walls
    /// (docs/method.md, "Passes"). A further pass solves L dq = b(v) for that divergence,
    /// with L and its preconditioner kept and dq = 0 on the free surface, and corrects again:
    /// the fixed-point iteration p <- p + L^-1 (b - A p) towards the operator A the corrector
    /// applies. `further` is None for the first pass; for a further one, the residual r to
    /// solve to and the last pass's right-hand side's norm. Returns the right-hand side's norm
    /// and the solve's statistics, or `None` without solving (never on the first pass) when
    /// that norm is at most r or at least the last pass's: where the iteration would not
    /// converge, it stops.
    fn pass(
        &mut self,
        ps: &mut Particles<D>,
        grid: &mut Grid<D>,
        boundary: &Boundary<D>,
        dt: f64,
        further: Option<(f64, f64)>,
        timers: &mut PhaseTimers,
    ) -> Result<Option<(f64, SolveStats)>, SolveError> {
        let first = further.is_none();
        // 4. (div v*) after the wall conditions, then L and the right-hand side, the solve
        self.sample_divergence(ps, grid, boundary, dt, first);
        self.assemble_pass(ps, grid, boundary, dt, first);
        timers.lap(Phase::Assembly);
        // a sequential sum: the same bits on any number of threads
        let rhs = &self.shared.system.rhs;
        let norm = match &self.shared.ranks {
            None => rhs.iter().map(|b| b * b).sum::<f64>().sqrt(),
            Some(r) => r.norm(rhs),
        };
        self.last.pass_norms.push(norm);
        let mut further_tolerance = 0.0;
        if let Some((residual, last_norm)) = further {
            if norm <= residual || norm >= last_norm {
                return Ok(None);
            }
            further_tolerance = residual / norm;
        }
        let stats = self.solve(&grid.geo, first, further_tolerance)?;
        let level_set = self.shared.surface.level_set().is_some();
        self.store_pressure(&grid.geo, first, level_set);
        timers.lap(Phase::Solve);
        // 5. particle pressure and (grad dp)_p, then the corrector
        self.correct_velocity(ps, grid, boundary, dt, level_set);
        timers.lap(Phase::Corrector);
        Ok(Some((norm, stats)))
    }

    /// Stage 4 of a pass, first half: (div v*) and, for the flux form, w (the part of v* the
    /// walls removed) at the quadrature points, after the wall conditions; on the first pass
    /// with the cell quadrature, its Gauss points from where the particles are.
    fn sample_divergence(
        &mut self,
        ps: &Particles<D>,
        grid: &mut Grid<D>,
        boundary: &Boundary<D>,
        dt: f64,
        first: bool,
    ) {
        let shape = self.settings.shape;
        let flux = self.settings.rhs_form == PoissonRhs::Flux;
        if !first {
            // a further pass measures the divergence of the velocity the particles will take,
            // with the wall conditions: what the walls remove from the corrector's velocity is
            // not flow through them
            boundary.apply(&mut grid.velocity_new);
        }
        pages::copy(&mut self.work.unconstrained, &grid.velocity_new);
        if flux {
            // only the normal part enters the wall flux: a no-slip wall's tangential condition
            // is not flow through it (and the tangential condition is applied below)
            boundary.apply_normal(&mut grid.velocity_new);
        } else {
            boundary.apply(&mut grid.velocity_new);
        }
        let v_star = &grid.velocity_new;
        let v_free = &self.work.unconstrained;
        let geo = &grid.geo;
        let level_set = self.shared.surface.level_set().is_some();
        let cell = self.cell_quadrature();
        if cell && first {
            let domain = level_set.then(|| FluidDomain {
                shape,
                kinds: &self.shared.surface.kinds,
                solid: self.shared.surface.solid(),
                cut: boundary.rigid.cuts_cells().then_some(&boundary.rigid),
            });
            let mean = ranks::mean_density(&ps.mass, &ps.volume0, self.shared.ranks.as_ref());
            self.shared.gauss.build(
                geo,
                (&self.shared.bins, &ps.mass, &ps.volume0, mean),
                &self.shared.surface.fraction,
                shape,
                (domain, self.shared.ranks.as_ref()),
            );
        }
        let (qx, qhw, qdiv, qw, qcell) = if cell {
            let g = &mut self.shared.gauss;
            (
                &g.x,
                &g.half_width,
                &mut g.divergence,
                &mut g.velocity,
                Some(&g.cell[..]),
            )
        } else {
            (
                &ps.x,
                &ps.half_width,
                &mut self.work.divergence,
                &mut self.work.velocity_star,
                None,
            )
        };
        velocity_at_points(geo, shape, (v_star, v_free), (qx, qhw), qdiv, qw);
        if self.settings.volume_correction > 0.0 && first {
            // the discrete projection keeps the grid velocity divergence free in the weak
            // sense, not each particle's: the particles' J drifts, and a solid under a steady
            // load creeps with it. Aim at div v = alpha (1 - J) / dt, which gives back the
            // fraction alpha of the drift per step.
            let rate = self.settings.volume_correction / dt;
            let cj = &mut self.work.cell_deficit;
            let (bins, ranks) = (&self.shared.bins, self.shared.ranks.as_ref());
            aim_at_volume(geo, (bins, ranks), ps, qcell, rate, cj, qdiv);
        }
        if flux {
            boundary.apply(&mut grid.velocity_new);
        }
    }

    /// Whether this step integrates at the cells' Gauss points: asked for, or needed by the
    /// ghost-fluid condition, whose matrix is taken over whole cells.
    fn cell_quadrature(&self) -> bool {
        self.settings.quadrature == Quadrature::Cell || self.shared.surface.level_set().is_some()
    }

    /// Stage 4 of a pass, second half: L (first pass only) and the right-hand side, with the
    /// flux through the rigid bodies' faces where they cut cells.
    fn assemble_pass(
        &mut self,
        ps: &Particles<D>,
        grid: &Grid<D>,
        boundary: &Boundary<D>,
        dt: f64,
        first: bool,
    ) {
        let shape = self.settings.shape;
        let flux = self.settings.rhs_form == PoissonRhs::Flux;
        let geo = &grid.geo;
        let cell = self.cell_quadrature();
        let quadrature = if cell {
            self.shared.gauss.quadrature(flux)
        } else {
            ParticleQuadrature {
                bins: &self.shared.bins,
                x: &ps.x,
                half_width: &ps.half_width,
                volume: &ps.volume0,
                volume_over_density: &self.work.volume_over_density,
                divergence: &self.work.divergence,
                velocity: &self.work.velocity_star,
                flux,
                templates: None,
            }
        };
        if first {
            let rows = assemble::Rows {
                kinds: &self.shared.surface.kinds,
                phi: self.shared.surface.level_set(),
                unknowns: &self.shared.system.unknowns,
                dirichlet: &self.node_pressure,
            };
            let (matrix, rhs) = (&mut self.shared.system.matrix, &mut self.shared.system.rhs);
            assemble::assemble(geo, shape, &quadrature, &rows, dt, matrix, rhs);
            if let Some(r) = &mut self.shared.ranks {
                let unknowns = &self.shared.system.unknowns;
                r.order_slots::<D>(matrix, 2 * shape.width() - 1, unknowns.assembled_rows());
                r.swap_beside(geo, unknowns, matrix);
            }
        } else {
            assemble::right_hand_side(
                geo,
                shape,
                &quadrature,
                &self.shared.system.unknowns,
                dt,
                &mut self.shared.system.rhs,
            );
        }
        if boundary.rigid.cuts_cells() {
            // the rigid bodies' faces where they lie: the jump of the normal velocity across
            // them joins the source
            boundary.rigid.add_face_flux(
                geo,
                shape,
                &grid.velocity_new,
                self.shared.surface.level_set(),
                dt,
                (
                    &self.shared.system.unknowns.row_of,
                    &mut self.shared.system.rhs,
                ),
            );
        }
    }

    /// Stage 4 of a pass: solves L dp = rhs for the unknowns, from the last step's pressure
    /// (Chorin's form, first pass) or from zero (a further pass, to `further_tolerance`
    /// relative to its own right-hand side: the first solve's accuracy).
    fn solve(
        &mut self,
        geo: &crate::grid::GridGeometry<D>,
        first: bool,
        further_tolerance: f64,
    ) -> Result<SolveStats, SolveError> {
        // solve; Chorin's form starts from the last step's pressure at the same nodes, a
        // further pass from zero
        // (over ranks on this rank's rows: the solve reads no other)
        let unknowns = &self.shared.system.unknowns;
        self.shared.solution.fit(unknowns.node_of_row.len());
        {
            let (prev, own) = (&self.previous, unknowns.assembled_rows());
            let warm = first && self.settings.beta == 0.0;
            self.shared.solution[own.clone()]
                .par_iter_mut()
                .zip(unknowns.node_of_row[own].par_iter())
                .for_each(|(x, &i)| *x = if warm { prev[i as usize] } else { 0.0 });
        }
        if !first {
            // the increment vanishes on the free surface and off the fluid
            pages::reset(&mut self.node_pressure);
        }
        if first {
            let u = &mut self.shared.system.unknowns;
            let ranks = self.shared.ranks.as_ref();
            describe_layout(
                &mut u.layout,
                geo,
                self.settings.shape,
                (&u.node_of_row, ranks),
            );
        }
        self.shared
            .system
            .matrix
            .pin_empty_rows(&mut self.shared.system.rhs);
        let system = System {
            matrix: &self.shared.system.matrix,
            layout: &self.shared.system.unknowns.layout,
            singular: self.last.singular,
            partition: self.shared.ranks.as_ref().map(|r| &r.partition),
        };
        let mut params = SolveParams {
            tolerance: self.settings.tolerance,
            max_iterations: self.settings.max_iterations,
        };
        let stats = if first {
            self.solver.solve(
                &system,
                &self.shared.system.rhs,
                &mut self.shared.solution,
                params,
            )?
        } else {
            // to the first solve's accuracy: its tolerance relative to the first right-hand side
            params.tolerance = further_tolerance;
            self.solver.solve_again(
                &system,
                &self.shared.system.rhs,
                &mut self.shared.solution,
                params,
            )?
        };
        if let Some(r) = &self.shared.ranks {
            let unknowns = &self.shared.system.unknowns;
            r.gather(geo, unknowns, &mut self.shared.solution);
        }
        Ok(stats)
    }

    /// Stage 4, after the solve: dp on the nodes (with the free surface's ghost values and the
    /// solids' extension), and p^{n+1} kept for the next step.
    fn store_pressure(&mut self, geo: &crate::grid::GridGeometry<D>, first: bool, level_set: bool) {
        {
            let (sol, unknowns) = (&self.shared.solution, &self.shared.system.unknowns);
            let dp = &mut self.node_pressure;
            ranks::scatter_rows(self.shared.ranks.as_ref(), geo, unknowns, sol, dp);
            geo.copy_to_images(dp);
            if level_set {
                // the free-surface nodes take the ghost values that put p = 0 on the surface
                let (kinds, phi) = (&self.shared.surface.kinds, &self.shared.surface.phi);
                let [out, first] = &mut self.shared.ghost;
                free_surface::ghost_values(geo, kinds, phi, dp, out, first);
                std::mem::swap(dp, out);
                if self.shared.surface.solid().is_some() {
                    free_surface::extend_into_solids(geo, kinds, dp, first);
                }
                geo.copy_to_images(dp);
            }
            // p^{n+1} = beta p^n + dp on the fluid's nodes after the first pass, plus dp after
            // each further one: the memory of the next step (on the free surface its own
            // value, or the ghost value)
            let keep = if first { self.settings.beta } else { 1.0 };
            let kinds = &self.shared.surface.kinds;
            self.previous
                .par_iter_mut()
                .zip(self.node_pressure.par_iter())
                .enumerate()
                .for_each(|(i, (p, &d))| {
                    let value = match kinds[i] {
                        NodeKind::Interior | NodeKind::FreeSurface | NodeKind::Solid => {
                            keep * *p + d
                        }
                        NodeKind::Empty => 0.0,
                    };
                    pages::store(p, value);
                });
        }
    }

    /// Stage 5 of a pass: the particles' pressure and (grad dp)_p, the corrector
    /// v^{n+1} = v* - dt / rho grad dp, and, with the level set, the velocity of the nodes no
    /// pressure reached.
    fn correct_velocity(
        &mut self,
        ps: &mut Particles<D>,
        grid: &mut Grid<D>,
        boundary: &Boundary<D>,
        dt: f64,
        level_set: bool,
    ) {
        // 5. particle pressure and (grad dp)_p, then the corrector
        self.particle_pressure(ps, &grid.geo, true);
        self.correct(ps, grid, dt);
        if level_set {
            // the nodes no pressure reached take the held velocity of the walls around them
            boundary.apply(&mut grid.velocity_new);
            pages::fit(&mut self.work.held, grid.geo.node_count());
            pages::reset(&mut self.work.held);
            boundary.held_components(&mut self.work.held);
            free_surface::extend_velocity(
                &grid.geo,
                &self.shared.surface.kinds,
                &self.work.held,
                &mut grid.velocity_new,
                &mut self.work.extended,
            );
        }
    }

    /// Interpolates to the particles: with `after_solve` the new pressure
    /// p_p = sum_i N_ip p_i^{n+1} and (grad dp)_p of the increment; before the solve,
    /// (grad p^n)_p of the previous pressure only.
    fn particle_pressure(
        &mut self,
        ps: &mut Particles<D>,
        geo: &crate::grid::GridGeometry<D>,
        after_solve: bool,
    ) {
        let shape = self.settings.shape;
        let total = &self.previous;
        let grad_field = if after_solve {
            &self.node_pressure
        } else {
            &self.previous
        };
        let write_pressure = after_solve;
        // over ranks the rank's own particles: the corrector scatters only theirs, and the
        // ghosts go back before any other stage reads a particle's pressure
        let own = ranks::own_of(self.shared.ranks.as_ref(), ps.len());
        (
            ps.x[..own].par_iter(),
            ps.half_width[..own].par_iter(),
            ps.pressure[..own].par_iter_mut(),
            self.work.pressure_gradient[..own].par_iter_mut(),
        )
            .into_par_iter()
            .for_each(|(x, &lp, pp, gp)| {
                let st = Stencil::<D>::new(shape, &geo.to_cells(x), geo.h, lp);
                let (mut p, mut g) = (0.0, Vector::<D>::zeros());
                st.for_each(|nw| {
                    let i = geo.flat(&nw.node);
                    p += nw.n * total[i];
                    g += nw.grad * grad_field[i];
                });
                if write_pressure {
                    *pp = p;
                }
                *gp = g;
            });
    }

    /// v_i -= (scale / m_i) sum_p V_p N_ip (grad p)_p on every node with mass.
    ///
    /// A scatter from the particles, like P2G ([`scatter_to_nodes`]); over ranks from this
    /// rank's own, the sums then added up with the neighbours' as P2G's are.
    fn correct(&mut self, ps: &Particles<D>, grid: &mut Grid<D>, scale: f64) {
        let mass_epsilon = self.settings.mass_epsilon;
        let (vol, gp) = (&ps.volume0, &self.work.pressure_gradient);
        let force = &mut self.shared.nodal;
        let ranks = self.shared.ranks.as_ref();
        let own = ranks::own_of(ranks, ps.len());
        scatter_to_nodes(
            &mut self.shared.vector_bands,
            Points {
                geo: &grid.geo,
                shape: self.settings.shape,
                x: &ps.x[..own],
                half_width: &ps.half_width[..own],
            },
            Vector::<D>::zeros(),
            |p| gp[p] * vol[p],
            force,
        );
        if let Some(r) = ranks {
            r.add_sums(force);
        }
        grid.velocity_new
            .par_iter_mut()
            .zip(grid.mass.par_iter())
            .zip(force.par_iter())
            .for_each(|((v, &m), f)| {
                if m > mass_epsilon {
                    *v -= f * (scale / m);
                }
            });
    }
}

/// The mass and volume of the particles in cell `c` (flat, padded) of `bins`.
fn cell_sums(bins: &CellBins, (mass, volume): (&[f64], &[f64]), c: usize) -> (f64, f64) {
    bins.particles(c).iter().fold((0.0, 0.0), |(m, v), &p| {
        (m + mass[p as usize], v + volume[p as usize])
    })
}

/// The volume correction's source: the divergence at the quadrature points `div` aims at
/// alpha (1 - J) / dt (`rate` = alpha / dt) instead of 0, with J the particle's, or, at cell
/// points (`cells`), the volume-weighted J of the cell's particles.
fn aim_at_volume<const D: usize>(
    geo: &crate::grid::GridGeometry<D>,
    (bins, ranks): (&CellBins, Option<&ranks::Ranks>),
    ps: &Particles<D>,
    cells: Option<&[[u32; D]]>,
    rate: f64,
    cell_deficit: &mut Vec<f64>,
    div: &mut [f64],
) {
    let (v0, jac) = (&ps.volume0, &ps.jacobian);
    if let Some(cells) = cells {
        // 1 - J per cell (zero in an empty cell, which keeps its page uncommitted)
        pages::fit(cell_deficit, geo.node_count());
        cell_deficit
            .par_iter_mut()
            .enumerate()
            .for_each(|(c, deficit)| {
                let (mut sv, mut sj) = (0.0, 0.0);
                for &p in bins.particles(c) {
                    sv += v0[p as usize];
                    sj += v0[p as usize] * jac[p as usize];
                }
                let j = if sv > 0.0 { sj / sv } else { 1.0 };
                pages::store(deficit, 1.0 - j);
            });
        // over ranks, the window's cells as their owners found them (from their particles)
        if let Some(r) = ranks {
            r.take_owners(geo, &mut [cell_deficit]);
        }
        let deficit = &*cell_deficit;
        div.par_iter_mut()
            .zip(cells.par_iter())
            .for_each(|(div, c)| {
                let idx: [usize; D] = std::array::from_fn(|d| c[d] as usize + crate::shape::PAD);
                *div -= rate * deficit[geo.flat(&idx)];
            });
    } else {
        div.par_iter_mut()
            .zip(jac.par_iter())
            .for_each(|(div, j)| *div -= rate * (1.0 - j));
    }
}

/// The deck's key that keeps `solver` from running over ranks (the direct solver and ic0
/// factor the whole matrix on one process); `None` where its solves spread.
fn unspread(solver: &LinearSolver) -> Option<&'static str> {
    if let LinearSolver::Direct(_) = solver {
        Some("pressure.solver = \"direct\"")
    } else if !solver.spreads() {
        Some("pressure.preconditioner = \"ic0\"")
    } else {
        None
    }
}

/// The linear solver `[pressure]` asks for.
fn linear_solver(pd: &PressureSettings, cells: usize) -> LinearSolver {
    match (pd.solver, pd.preconditioner(cells)) {
        (Solver::Direct, _) => LinearSolver::Direct(Direct::default()),
        (Solver::Pcg, Preconditioner::Multigrid) => {
            LinearSolver::Pcg(Pcg::new(Box::<Multigrid>::default()))
        }
        (Solver::Pcg, Preconditioner::Ic0) => {
            LinearSolver::Pcg(Pcg::new(Box::<IncompleteCholesky>::default()))
        }
        (Solver::Pcg, Preconditioner::Jacobi) => {
            LinearSolver::Pcg(Pcg::new(Box::new(Jacobi::default())))
        }
    }
}

/// Where the rows `node_of_row` sit on the grid, for a geometric preconditioner (the
/// multigrid's coarsening).
///
/// The solver spreads its rows over ranks in slabs along the layout's last axis
/// ([`crate::linalg::spread`]); over ranks cut along another axis (`ranks`), that axis is
/// the layout's last and the others keep their order before it, so that the rows, numbered
/// layer by layer along the cut ([`Unknowns::number`]), are in the layout's node order.
fn describe_layout<const D: usize>(
    layout: &mut GridLayout,
    geo: &crate::grid::GridGeometry<D>,
    shape: ShapeFunction,
    (node_of_row, ranks): (&[u32], Option<&ranks::Ranks>),
) {
    let cut = ranks.map_or(D - 1, |r| r.axis);
    let mut order = [0usize; D];
    for (k, d) in (0..D).filter(|&d| d != cut).chain([cut]).enumerate() {
        order[k] = d;
    }
    layout.dim = D;
    layout.reach = shape.width() - 1;
    for (k, &d) in order.iter().enumerate() {
        layout.nodes[k] = geo.nodes[d];
        layout.offset[k] = crate::shape::PAD;
        layout.cells[k] = geo.cells[d];
        layout.periodic[k] = geo.periodic[d];
    }
    layout.index.clear();
    layout.index.extend(node_of_row.iter().map(|&i| {
        let m = geo.multi(i as usize);
        std::array::from_fn(|k| if k < D { m[order[k]] as u32 } else { 0 })
    }));
}

/// The numbering of a solve's unknowns: the interior nodes, a row each.
#[derive(Debug, Default)]
pub struct Unknowns {
    /// Each node's row + 1, 0 where it is not an unknown (zero off the fluid, so that the
    /// array holds memory only where the fluid is: [`crate::pages`]); [`Unknowns::row`]
    /// reads it.
    pub row_of: Vec<u32>,
    /// Each row's node.
    pub node_of_row: Vec<u32>,
    /// Where the rows sit on the grid, for the solver.
    pub layout: GridLayout,
    /// Over ranks, the rows this rank assembles (its own and those the solver reads beside
    /// them, numbered over the ranks); the others are not written. `None`: every row.
    pub assembled: Option<std::ops::Range<usize>>,
}

impl Unknowns {
    /// The rows this rank assembles ([`Unknowns::assembled`]).
    pub fn assembled_rows(&self) -> std::ops::Range<usize> {
        self.assembled.clone().unwrap_or(0..self.node_of_row.len())
    }

    /// Node i's row, or `u32::MAX` where it is not an unknown.
    #[inline]
    pub fn row(&self, i: usize) -> u32 {
        self.row_of[i].wrapping_sub(1)
    }

    /// Numbers the interior nodes (a periodic image shares its node's row) in node order and
    /// returns the number of free-surface nodes; with `layers`, only those of the node layers
    /// `layers.1` along axis `layers.0` (a rank's own, over ranks), layer by layer.
    pub fn number<const D: usize>(
        &mut self,
        geo: &crate::grid::GridGeometry<D>,
        kinds: &[NodeKind],
        layers: Option<(usize, std::ops::Range<usize>)>,
    ) -> usize {
        pages::fit(&mut self.row_of, geo.node_count());
        pages::reset(&mut self.row_of);
        self.node_of_row.clear();
        self.assembled = None;
        let mut free = 0usize;
        let nodes: Box<dyn Iterator<Item = usize> + '_> = match layers {
            Some((axis, l)) => Box::new(l.flat_map(move |l| geo.layer_nodes(axis, l))),
            None => Box::new(0..kinds.len()),
        };
        for i in nodes {
            let k = &kinds[i];
            if geo.canonical(i) != i {
                continue;
            }
            match k {
                NodeKind::Interior => {
                    self.row_of[i] = self.node_of_row.len() as u32 + 1;
                    self.node_of_row.push(i as u32);
                }
                NodeKind::FreeSurface => free += 1,
                NodeKind::Empty | NodeKind::Solid => {}
            }
        }
        free
    }
}

/// Numbers the unknowns of `kinds` ([`Unknowns::number`]) and returns the number of
/// free-surface nodes: on one process every node's; over ranks each rank's own layers', every
/// rank's rows then joined into the numbering of the whole grid on each ([`ranks::Ranks::join`]).
fn number<const D: usize>(
    geo: &crate::grid::GridGeometry<D>,
    kinds: &[NodeKind],
    unknowns: &mut Unknowns,
    ranks: &mut Option<ranks::Ranks>,
) -> usize {
    match ranks {
        None => unknowns.number(geo, kinds, None),
        Some(r) => {
            let free = unknowns.number(geo, kinds, Some((r.axis, r.layers())));
            r.join(geo, unknowns, free)
        }
    }
}

/// (div v*)_q and w_q (the part of v* the walls removed) at the quadrature points at `x`
/// of GIMP half-widths `half_width`, from the nodes' v* after (`v_star`) and before (`v_free`)
/// the wall conditions.
fn velocity_at_points<const D: usize>(
    geo: &crate::grid::GridGeometry<D>,
    shape: ShapeFunction,
    (v_star, v_free): (&[Vector<D>], &[Vector<D>]),
    (x, half_width): (&[Vector<D>], &[f64]),
    divergence: &mut [f64],
    removed: &mut [Vector<D>],
) {
    (
        x.par_iter(),
        half_width.par_iter(),
        divergence.par_iter_mut(),
        removed.par_iter_mut(),
    )
        .into_par_iter()
        .for_each(|(x, &lp, div, vp)| {
            let st = Stencil::<D>::new(shape, &geo.to_cells(x), geo.h, lp);
            let (mut s, mut w) = (0.0, Vector::<D>::zeros());
            st.for_each(|nw| {
                let i = geo.flat(&nw.node);
                s += nw.grad.dot(&v_star[i]);
                // what the walls removed from v* (zero off the wall nodes)
                w += (v_free[i] - v_star[i]) * nw.n;
            });
            *div = s;
            *vp = w;
        });
}

/// The fluid's domain for the level-set free surface: the matrix is integrated over every cell
/// next to an unknown, less what rigid bodies cover.
struct FluidDomain<'a, const D: usize> {
    shape: ShapeFunction,
    kinds: &'a [NodeKind],
    solid: Option<&'a [f64]>,
    /// With cut cells, the rigid bodies: a cell they cut is integrated over its open part.
    cut: Option<&'a crate::rigid::RigidBodies<D>>,
}

impl<const D: usize> FluidDomain<'_, D> {
    /// The share of the open part of cut cell `idx` (padded multi-index) the fluid fills:
    /// w / open, `w` the cell's fluid fraction and `open` the part no body covers, or wholly
    /// where the cell lies inside the fluid (its corners all unknowns). Its particles cannot
    /// fill the last sliver against the face (a lattice seeded under a face stops up to a
    /// particle's spacing short of it), and read as a partial fill the sliver weighed the
    /// divergence less than the face's flux and set still water moving.
    fn cut_cell_fill(
        &self,
        geo: &crate::grid::GridGeometry<D>,
        idx: &[usize; D],
        w: f64,
        open: f64,
    ) -> f64 {
        let inside = (0..1usize << D).all(|k| {
            let node: [usize; D] = std::array::from_fn(|d| idx[d] + ((k >> d) & 1));
            self.kinds[geo.canonical(geo.flat(&node))] == NodeKind::Interior
        });
        if inside {
            1.0
        } else {
            w.clamp(0.0, open) / open
        }
    }

    /// Nodes below and above a cell's lower corner, along each axis, that a point in the cell
    /// reaches: the cell's corners with linear shape functions, up to one more node either
    /// side with the wider ones (as [`assemble::cell_range`] has it).
    fn reach(&self) -> (usize, usize) {
        if self.shape == ShapeFunction::Linear {
            (0, 1)
        } else {
            (1, 2)
        }
    }

    /// Per line of nodes along axis 0 (flat index / `nodes[0]`), whether it holds an unknown,
    /// into `wet`: on a grid without periodic axes (whose images read other lines' kinds),
    /// so that a cell of air is told by a few lines' flags ([`Self::lines_dry`]).
    fn wet_lines(&self, geo: &crate::grid::GridGeometry<D>, wet: &mut Vec<bool>) -> bool {
        if geo.has_periodic() {
            return false;
        }
        let line = geo.nodes[0];
        wet.resize(geo.node_count() / line, false);
        wet.par_iter_mut()
            .zip(self.kinds.par_chunks(line))
            .for_each(|(w, kinds)| {
                // (no early exit: the compiler vectorises the whole line's test)
                *w = kinds
                    .iter()
                    .fold(false, |a, &k| a | (k == NodeKind::Interior));
            });
        true
    }

    /// Whether no node line that a point in cell `idx` reaches holds an unknown (`wet` from
    /// [`Self::wet_lines`]): then [`Self::touches_unknown`] is false. It reads `idx` past
    /// axis 0 only, so it holds for the cell's whole line along axis 0.
    fn lines_dry(
        &self,
        geo: &crate::grid::GridGeometry<D>,
        idx: &[usize; D],
        wet: &[bool],
    ) -> bool {
        let (below, above) = self.reach();
        let span: usize = below + above + 1;
        (0..span.pow(D as u32 - 1)).all(|k| {
            let (mut rem, mut line) = (k, 0);
            for d in 1..D {
                let o = rem % span;
                rem /= span;
                let n = (idx[d] + o).saturating_sub(below).min(geo.nodes[d] - 1);
                line += n * (geo.strides[d] / geo.nodes[0]);
            }
            !wet[line]
        })
    }

    /// Whether a point in cell `idx` (padded multi-index) reaches an unknown ([`Self::reach`]).
    fn touches_unknown(&self, geo: &crate::grid::GridGeometry<D>, idx: &[usize; D]) -> bool {
        let (below, above) = self.reach();
        let span: usize = below + above + 1;
        (0..span.pow(D as u32)).any(|k| {
            let mut rem = k;
            let node: [usize; D] = std::array::from_fn(|d| {
                let o = rem % span;
                rem /= span;
                (idx[d] + o).saturating_sub(below).min(geo.nodes[d] - 1)
            });
            self.kinds[geo.canonical(geo.flat(&node))] == NodeKind::Interior
        })
    }
}

/// Over ranks, the cell layers (along the cut) whose points reach a row this rank assembles,
/// those of its own node layers ([`assemble::cell_range`]): the rest of the window adds to no
/// row here.
fn assembled_cells<const D: usize>(
    geo: &crate::grid::GridGeometry<D>,
    shape: ShapeFunction,
    r: &ranks::Ranks,
) -> (usize, std::ops::RangeInclusive<usize>) {
    let (layers, n) = (r.layers(), geo.nodes[r.axis]);
    let first = assemble::cell_range(shape, layers.start, n).0;
    let last = assemble::cell_range(shape, layers.end.saturating_sub(1), n).1;
    (r.axis, first..=last)
}

/// Gauss points of the cell quadrature: 2^D per cell with fluid, volume min(phi_c, 1) h^D / 2^D,
/// density of the cell (its particles' mass over their volume; cells without particles, filled
/// by hole closing, take the mean density of all particles).
#[derive(Default)]
struct GaussPoints<const D: usize> {
    x: Vec<Vector<D>>,
    half_width: Vec<f64>,
    volume: Vec<f64>,
    volume_over_density: Vec<f64>,
    divergence: Vec<f64>,
    velocity: Vec<Vector<D>>,
    /// The cell of each point (padded multi-index less PAD).
    cell: Vec<[u32; D]>,
    /// The 2^D places in a cell, tabulated.
    templates: assemble::ReferenceCell<D>,
    /// Whether some points are not at the places of the templates (cut cells).
    sub_cells: bool,
    bins: CellBins,
    /// Over ranks, each cell's particles' mass and volume as the cell's owner summed them
    /// (the window's cells past the ghosts have no particles here).
    cell_sums: [Vec<f64>; 2],
    /// Per line of nodes along axis 0, whether it holds an unknown
    /// ([`FluidDomain::wet_lines`]).
    wet_lines: Vec<bool>,
}

impl<const D: usize> GaussPoints<D> {
    /// The points as the assembly reads them.
    fn quadrature(&self, flux: bool) -> ParticleQuadrature<'_, D> {
        ParticleQuadrature {
            bins: &self.bins,
            x: &self.x,
            half_width: &self.half_width,
            volume: &self.volume,
            volume_over_density: &self.volume_over_density,
            divergence: &self.divergence,
            velocity: &self.velocity,
            flux,
            templates: (!self.sub_cells).then_some((&self.templates, &self.cell[..])),
        }
    }

    /// The points of the cells with fluid (volume fractions `fraction`), or with a level set
    /// of the cells next to an unknown (`domain`), each cell's density from the masses and
    /// volumes of the particles `bins` holds in it (`mean_density` in a cell without any);
    /// over ranks (`ranks`) those sums as the cell's owner found them
    /// ([`ranks::Ranks::take_owners`]).
    fn build(
        &mut self,
        geo: &crate::grid::GridGeometry<D>,
        (bins, mass, volume, mean_density): (&CellBins, &[f64], &[f64], f64),
        fraction: &[f64],
        shape: ShapeFunction,
        (domain, ranks): (Option<FluidDomain<'_, D>>, Option<&ranks::Ranks>),
    ) {
        use crate::shape::PAD;
        let sums = |c: usize| cell_sums(bins, (mass, volume), c);
        if let Some(r) = ranks {
            self.sum_cells_over(geo, (bins, mass, volume), r);
        }
        self.sub_cells = false;
        self.x.clear();
        self.volume.clear();
        self.cell.clear();
        self.volume_over_density.clear();
        let corners = 1usize << D;
        let cell_volume = geo.h.powi(D as i32);
        let reach = ranks.map(|r| assembled_cells(geo, shape, r));
        // the lines of nodes that hold an unknown, to pass over the air's cells quickly
        let mut wet = std::mem::take(&mut self.wet_lines);
        let lines = domain
            .as_ref()
            .is_some_and(|fd| fd.wet_lines(geo, &mut wet));
        // (the cells in flat order, their multi-indices kept without a division a cell)
        let (mut next, mut line_dry) = ([0; D], false);
        for (c, &phi) in fraction.iter().enumerate() {
            let w = phi.min(1.0);
            let idx = next;
            geo.advance(&mut next);
            if idx[0] == 0 {
                // a line of cells along axis 0 reaches the same lines of nodes
                line_dry = lines
                    && domain
                        .as_ref()
                        .is_some_and(|fd| fd.lines_dry(geo, &idx, &wet));
            }
            if (0..D).any(|d| idx[d] < PAD || idx[d] >= PAD + geo.cells[d]) {
                continue;
            }
            if let Some((axis, cells)) = &reach {
                if !cells.contains(&idx[*axis]) {
                    continue;
                }
            }
            // the matrix's share of the cell: its fraction of fluid, or with a level set the
            // whole cell less what a rigid body covers (the ghost-fluid condition needs the
            // couplings across the surface, and a solid's face is where the flux is imposed)
            let matrix_share = match &domain {
                Some(fd) => {
                    if line_dry || !fd.touches_unknown(geo, &idx) {
                        continue;
                    }
                    1.0 - fd.solid.map_or(0.0, |s| s[c].clamp(0.0, 1.0))
                }
                None if w <= 0.0 => continue,
                None => w,
            };
            let (m, v) = match ranks {
                Some(_) => (self.cell_sums[0][c], self.cell_sums[1][c]),
                None => sums(c),
            };
            let rho = if v > 0.0 { m / v } else { mean_density };
            let lower = geo.node_position(&idx);
            if let Some(rigid) = domain.as_ref().and_then(|d| d.cut) {
                // (a cell only a shaped body covers takes the Gauss points below: its nodes
                // hold the body where it is)
                if matrix_share > 0.0
                    && matrix_share < 1.0 - 1e-12
                    && rigid.box_meets_cell(&lower, geo.h)
                {
                    // a cell a body cuts: points on its open part
                    self.sub_cells = true;
                    let fill = domain
                        .as_ref()
                        .map_or(1.0, |fd| fd.cut_cell_fill(geo, &idx, w, matrix_share));
                    self.push_cut_cell(geo, rigid, &idx, fill, rho);
                    continue;
                }
            }
            let vol = w.max(0.0) * cell_volume / corners as f64;
            let matrix_vol = matrix_share * cell_volume / corners as f64;
            for k in 0..corners {
                let s = crate::grid::gauss_point::<D>(k);
                let x = Vector::<D>::from_fn(|d, _| lower[d] + s[d] * geo.h);
                self.x.push(x);
                self.volume.push(vol);
                self.volume_over_density.push(matrix_vol / rho);
                self.cell
                    .push(std::array::from_fn(|d| (idx[d] - PAD) as u32));
            }
        }
        self.wet_lines = wet;
        if self.templates.is_empty() {
            let stencils = (0..corners)
                .map(|k| Stencil::<D>::new(shape, &crate::grid::gauss_point::<D>(k), geo.h, 0.0))
                .collect();
            self.templates = assemble::ReferenceCell::new(stencils);
        }
        let n = self.x.len();
        self.half_width.clear();
        self.half_width.resize(n, 0.0);
        self.divergence.resize(n, 0.0);
        self.velocity.resize(n, Vector::<D>::zeros());
        self.bins.sort(geo, &self.x);
    }

    /// Over ranks, each cell's particles' mass and volume into `cell_sums`, every cell's
    /// taken from the rank that owns it ([`ranks::Ranks::take_owners`]).
    fn sum_cells_over(
        &mut self,
        geo: &crate::grid::GridGeometry<D>,
        (bins, mass, volume): (&CellBins, &[f64], &[f64]),
        r: &ranks::Ranks,
    ) {
        let [m, v] = &mut self.cell_sums;
        pages::fit(m, geo.node_count());
        pages::fit(v, geo.node_count());
        (m.par_iter_mut(), v.par_iter_mut())
            .into_par_iter()
            .enumerate()
            .for_each(|(c, (m, v))| {
                let (cm, cv) = cell_sums(bins, (mass, volume), c);
                pages::store(m, cm);
                pages::store(v, cv);
            });
        r.take_owners(geo, &mut [m, v]);
    }

    /// The points of a cell (padded multi-index `idx`) a rigid body cuts: SUB^D sub-cells, each
    /// cut to its open part, a point at the part's centroid weighing its volume (the open
    /// part's volume is exact; the midpoints of the sub-cells in it had it to a sub-cell, and a
    /// box in still water whose face left 0.6 h of its cell open, short of a third midpoint,
    /// stirred the water). The fluid fills the open part in the share `fill`
    /// ([`FluidDomain::cut_cell_fill`]); `rho` is the cell's density.
    fn push_cut_cell(
        &mut self,
        geo: &crate::grid::GridGeometry<D>,
        rigid: &crate::rigid::RigidBodies<D>,
        idx: &[usize; D],
        fill: f64,
        rho: f64,
    ) {
        use crate::shape::PAD;
        /// Sub-cells per direction of a cell a rigid body cuts.
        const SUB: usize = 4;
        let lower = geo.node_position(idx);
        let half = 0.5 * geo.h / SUB as f64;
        for k in 0..SUB.pow(D as u32) {
            let mut rem = k;
            let x = Vector::<D>::from_fn(|d, _| {
                let j = rem % SUB;
                rem /= SUB;
                lower[d] + (j as f64 + 0.5) / SUB as f64 * geo.h
            });
            let (open, x) = rigid.open_part(geo, &x.add_scalar(-half), &x.add_scalar(half));
            if open <= 0.0 {
                continue;
            }
            self.x.push(x);
            self.volume.push(fill * open);
            self.volume_over_density.push(open / rho);
            self.cell
                .push(std::array::from_fn(|d| (idx[d] - PAD) as u32));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridGeometry;

    /// A cell whose node lines hold no unknown ([`FluidDomain::lines_dry`]) reaches none
    /// ([`FluidDomain::touches_unknown`]), with the linear and the wider shape functions,
    /// at the box's edges too: a few unknowns scattered in a 3D box, every cell compared.
    #[test]
    fn a_cell_on_dry_node_lines_touches_no_unknown() {
        let geo = GridGeometry::<3>::new(Vector::<3>::zeros(), 0.5, [7, 5, 6]);
        let mut kinds = vec![NodeKind::Empty; geo.node_count()];
        for (k, node) in [[0, 0, 0], [8, 6, 7], [4, 3, 3], [2, 1, 7], [7, 6, 2]]
            .iter()
            .enumerate()
        {
            let i = geo.flat(&std::array::from_fn(|d| node[d].min(geo.nodes[d] - 1)));
            kinds[i] = if k % 2 == 0 {
                NodeKind::Interior
            } else {
                NodeKind::FreeSurface
            };
        }
        for shape in [ShapeFunction::Linear, ShapeFunction::Bspline2] {
            let fd = FluidDomain {
                shape,
                kinds: &kinds,
                solid: None,
                cut: None,
            };
            let mut wet = Vec::new();
            assert!(fd.wet_lines(&geo, &mut wet));
            let (mut dry, mut touching) = (0, 0);
            for c in 0..geo.node_count() {
                let idx = geo.multi(c);
                let touches = fd.touches_unknown(&geo, &idx);
                if fd.lines_dry(&geo, &idx, &wet) {
                    assert!(!touches, "cell {idx:?}, {shape:?}");
                    dry += 1;
                }
                touching += usize::from(touches);
            }
            assert!(
                dry > 0 && touching > 0,
                "{shape:?}: {dry} dry, {touching} touching"
            );
        }
    }
}
