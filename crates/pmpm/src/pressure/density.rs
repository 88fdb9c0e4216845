//! Density correction: the particles are moved so that each one's volume J V0 returns to its
//! rest volume V0, after the step (`pressure.density_correction = "positions"`).
//!
//! The projection makes the grid velocity divergence free in the weak sense only, so the
//! particles' J, which integrates the divergence at each particle, drifts, most where the
//! flow thins, splashes or turns against a wall. A velocity source aiming at div v = (1 - J) /
//! dt feeds that drift back into the momentum and blows up at an impact. This stage acts on
//! positions instead, as the implicit density projection of Kugelstadt, Longva, Thuerey &
//! Bender (IEEE TVCG 27, 2021) does, with J as the measure of density (Zhang, Zhang, Sze, Lian
//! & Liu, JCP 330, 2017, correct density the same way in incompressible MPM): a displacement
//! u = -grad q with div u = 1/J - 1, from
//!
//! ```text
//! sum_j K_ij q_j = b_i,   K_ij = int grad N_i . grad N_j,   b_i = sum_p V0_p (1 - J_p) N_ip
//! ```
//!
//! with the projection's free surface (q = 0 there, ghost-fluid) and walls (u . n = 0). The
//! nodes' displacement u_i = -sum_p V_p N_ip (grad q)_p / sum_p V_p N_ip moves each particle by
//! sum_i N_ip u_i and deforms it by H_p = sum_i u_i (x) G_ip: F <- (I + H) F, J <- J det(I + H).
//! So J keeps measuring the particle's deformation, and the particles spread where they were
//! packed and close up where they were spread. Velocities are not touched: the correction adds
//! no momentum and no energy.
//!
//! The solve sees J only through its nodal sums. Before it, J is evened out between
//! neighbouring particles of a material, the share `rate` of the way to its nodal average
//! ([`crate::averaging::NodalAveraging::smooth_jacobian`], which keeps sum V0 J): differences
//! below the grid's resolution, which each particle carries along its own path, are not ones
//! the correction could ever give back.

use super::free_surface::{self, NodeKind};
use super::ranks::Ranks;
use super::{describe_layout, FluidDomain, Shared};
use super::{DensityCorrection, PressureSettings};
use crate::boundary::Boundary;
use crate::comm::Comm;
use crate::grid::{CellBins, GridGeometry, Vector};
use crate::linalg::{LinearSolver, Slots, SolveError, SolveParams, SolveStats, System};
use crate::particles::{Matrix, Particles};
use crate::shape::{ShapeFunction, Stencil};
use crate::transfer::{scatter_to_nodes, Band, Points};
use rayon::prelude::*;
use std::sync::Arc;

/// Largest displacement of a node in one correction, in cells: a particle whose volume is far
/// off (after an impact) is brought back over several steps, not thrown across the grid.
const MAX_SHIFT: f64 = 0.25;

/// Largest share of a particle's volume one correction gives back or takes.
const MAX_RATE: f64 = 0.2;

/// The slope of the level set phi = h (1 - 2 f) below which the measured nodes' gradient
/// takes over from it as a surface particle's outward direction ([`own_shift`]): 0.1, a fill
/// that changes by 5 % across a cell.
const NORMAL_SLOPE: f64 = 0.1;

/// How many times the projection's packing share ([`PACE`]) the explicit scheme's packing
/// takes each step ([`Packing::share`]): its particles follow a velocity with the sound's
/// ringing in it, and bunch again faster than the projection's do (docs/method.md).
pub const EXPLICIT_PACKS: f64 = 4.0;

/// Corrections per cell crossing: the volume error is given back over the time
/// h / (PACE max |v|), a third of the time a particle takes to cross a cell (see
/// [`PositionCorrection::rate`]).
pub const PACE: f64 = 3.0;

/// How far one correction goes ([`PositionCorrection::pace`]), each a share from 0 to 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pace {
    /// The share of the volume error 1 - J given back.
    pub volume: f64,
    /// The share of the way the packing goes: of the fill's excess its solve gives back,
    /// and the strength of the pairs' pushes ([`super::spacing`]).
    pub packing: f64,
}

impl Pace {
    /// The same share for both (the explicit scheme's packing, whole when it is due).
    pub fn whole(share: f64) -> Self {
        Self {
            volume: share,
            packing: share,
        }
    }

    /// Each share within 0 to 1.
    fn clamped(self) -> Self {
        Self {
            volume: self.volume.clamp(0.0, 1.0),
            packing: self.packing.clamp(0.0, 1.0),
        }
    }
}

/// The explicit scheme's density correction (`density_correction = "particles"` there): the
/// packing alone (`PositionCorrection::packing_only`) with a solver and stage buffers of its
/// own, the explicit scheme having no projection to share them with.
pub struct Packing<const D: usize> {
    correction: PositionCorrection<D>,
    solver: LinearSolver,
    shared: Shared<D>,
    /// The window past its slab a rank sees over ranks, the projection's
    /// ([`crate::slabs::window_of`]): the packing finds the same free surface.
    window: usize,
}

impl<const D: usize> Packing<D> {
    /// The packing with the `[pressure]` solver settings, on a grid of `cells` cells (the
    /// preconditioner's default follows it), under the body force `gravity` at the origin
    /// (the free surface's ceilings).
    pub fn new(
        pd: &PressureSettings,
        shape: ShapeFunction,
        boundary: &Boundary<D>,
        cells: usize,
        gravity: &[f64],
    ) -> Self {
        let mut shared = Shared::new(pd, boundary);
        shared.surface.set_ceilings(gravity);
        Self {
            correction: PositionCorrection::new(pd, shape).packing_only(),
            solver: super::linear_solver(pd, cells),
            shared,
            window: crate::slabs::window_of(pd.bubble_cells, shape),
        }
    }

    /// The window past its slab that a rank of this packing sees over ranks
    /// ([`crate::slabs::Decomposition::window`]).
    pub fn window(&self) -> usize {
        self.window
    }

    /// The layers of its window whose stages a rank of this packing runs
    /// ([`crate::slabs::projection_reach`]).
    pub fn reach(&self) -> usize {
        crate::slabs::projection_reach(self.correction.shape)
    }

    /// The deck's key that keeps this packing from running over ranks, as
    /// [`super::Projection::unsupported_over_ranks`]; `None` where it spreads.
    pub fn unsupported_over_ranks(&self) -> Option<&'static str> {
        super::unspread(&self.solver)
    }

    /// Makes this the packing of a rank of `comm`'s, the grid cut at `cuts` along `axis`, as
    /// [`super::Projection::spread_over`].
    pub fn spread_over(&mut self, ranks: Option<(Arc<dyn Comm>, crate::slabs::Decomposition)>) {
        self.shared.spread_over(ranks);
    }

    /// Over ranks, how many of the particles are this rank's own: those after them are the
    /// neighbours' ghosts, lent for the packing ([`crate::slabs::Migration::lend_ghosts`]).
    pub fn own_particles(&mut self, own: usize) {
        if let Some(r) = &mut self.shared.ranks {
            r.own = own;
        }
    }

    /// Over ranks, the ghosts dropped: every particle is this rank's own again.
    pub fn ghosts_gone(&mut self) {
        if let Some(r) = &mut self.shared.ranks {
            r.ghosts_gone();
        }
    }

    /// The share of the way to rest density the packing goes in a step where the projection's
    /// packing would go the share `rate` (`PositionCorrection::crossing_rate`):
    /// `EXPLICIT_PACKS` times that, at most the whole. Every step, not in whole shares every
    /// few steps: between such packs the ringing bunched the particles again (docs/method.md).
    /// It depends only on the step's own figures, so a resumed run packs as one never stopped.
    pub fn share(rate: f64) -> Option<f64> {
        let share = (EXPLICIT_PACKS * rate).min(1.0);
        (share > 0.0).then_some(share)
    }

    /// Packs the particles the share `share` of the way to rest density; returns the solve's
    /// iterations.
    pub fn pack(
        &mut self,
        ps: &mut Particles<D>,
        geo: &GridGeometry<D>,
        boundary: &Boundary<D>,
        share: f64,
    ) -> Result<usize, SolveError> {
        let linear = (&mut self.solver, &mut self.shared);
        Ok(self
            .correction
            .correct(ps, geo, boundary, Pace::whole(share), linear)?
            .iterations)
    }
}

/// State and buffers of the density correction, reused from step to step.
pub struct PositionCorrection<const D: usize> {
    shape: ShapeFunction,
    /// The density from the particles' positions ([`DensityCorrection::Particles`]), not
    /// from J; its moves also carry each particle's velocity to where it goes, v_p += C_p dx
    /// (the first-order Taylor correction of particle shifting in SPH: Xu, Stansby & Laurence
    /// 2009, J. Comput. Phys. 228; Lind et al. 2012, J. Comput. Phys. 231), C_p APIC's affine
    /// matrix, the velocity gradient at the particle (zero under FLIP and PIC, which carry
    /// nothing). Without it a shifted particle brings its old velocity to a new place, a
    /// dissipation (docs/method.md, item 4 of the density correction).
    from_positions: bool,
    /// Whether the volumes J V0 are corrected (the solve on 1 - J and its move, which deform
    /// F): the projection's; the explicit scheme's J is its equation of state's, and its
    /// correction only packs ([`Self::packing_only`]).
    volumes: bool,
    tolerance: f64,
    max_iterations: usize,
    /// sum_p V_p N_ip per node (the particles' volume at the node).
    weight: Vec<f64>,
    /// sum_p V0_p (1 - J_p) N_ip per node.
    excess: Vec<f64>,
    /// The per-thread sums of the two above, and their totals per node.
    bands: Vec<Band<nalgebra::Vector2<f64>>>,
    sums: Vec<nalgebra::Vector2<f64>>,
    /// q per node (the ghost values on free-surface nodes).
    potential: Vec<f64>,
    /// Per particle: tr H_p (averaged at the nodes).
    dilatation: Vec<f64>,
    /// Per particle, whether none of its nodes holds an equation of the correction (spray).
    spray: Vec<bool>,
    /// Per node, bit d set where the walls, a body or an inflow's buffer hold component d of
    /// the displacement (with the density from positions).
    held: Vec<u8>,
    /// The sub-cell spacing's pushes (with the density from positions).
    spacing: super::spacing::Spacing<D>,
    /// Per node, 1 where the packing measures and corrects the fill (with the density from
    /// positions; [`Self::fill_excess`]).
    measured: Vec<u8>,
    averaging: crate::averaging::NodalAveraging<D>,
    /// Statistics of the last solve.
    pub stats: SolveStats,
}

impl<const D: usize> PositionCorrection<D> {
    /// The share r of the volume error given back in a step of `dt`:
    /// r = min(1, max(PACE dt max|v| / h, dt / sqrt(2 h / |g|))), [`PACE`] corrections per
    /// cell crossing, however small the step (where the viscous limit sets a step far below
    /// the crossing time, correcting the whole error every step stirs the correction's own
    /// error that much more often: it threw a Bingham slump apart).
    ///
    /// The error is given back at least over sqrt(2 h / |g|), the time a particle takes to
    /// fall one cell from rest (|g| the body force at the grid's origin at the start): a flow
    /// that creeps under gravity (a slump's front settling at millimetres per second) drifts
    /// at the pace of its stresses, not of its speed, and a pace set by its speed alone let
    /// that drift pile up.
    pub fn rate(dt: f64, max_speed: f64, gravity: f64, h: f64) -> f64 {
        let fall = dt * (gravity.abs() / (2.0 * h)).sqrt();
        Self::crossing_rate(dt, max_speed, h).max(fall).min(1.0)
    }

    /// min(1, PACE dt max|v| / h): [`PACE`] corrections per cell crossing.
    fn crossing_rate(dt: f64, max_speed: f64, h: f64) -> f64 {
        (PACE * dt * max_speed / h).min(1.0)
    }

    /// The pace of a correction in a step of `dt`: the volume's share [`Self::rate`], and the
    /// packing's at the flow's own pace alone, [`PACE`] per cell crossing without the floor
    /// of one fall per cell. J drifts under a creeping flow's stresses, but the particles'
    /// arrangement changes only as they move: the packing undoes what the motion made, and
    /// at the floor's pace it rearranged creeping flows many times faster than they moved
    /// (a viscous current's nose ran ahead of its similarity solution, docs/method.md).
    pub fn pace(dt: f64, max_speed: f64, gravity: f64, h: f64) -> Pace {
        Pace {
            volume: Self::rate(dt, max_speed, gravity, h),
            packing: Self::crossing_rate(dt, max_speed, h),
        }
    }

    /// The correction with the pressure's solver settings.
    pub fn new(pd: &PressureSettings, shape: ShapeFunction) -> Self {
        Self {
            shape,
            from_positions: pd.density_correction == Some(DensityCorrection::Particles),
            volumes: true,
            tolerance: pd.tolerance,
            max_iterations: pd.max_iterations,
            weight: Vec::new(),
            excess: Vec::new(),
            bands: Vec::new(),
            sums: Vec::new(),
            potential: Vec::new(),
            dilatation: Vec::new(),
            spray: Vec::new(),
            held: Vec::new(),
            spacing: Default::default(),
            measured: Vec::new(),
            averaging: crate::averaging::NodalAveraging::new(rayon::current_num_threads(), 0),
            stats: SolveStats {
                iterations: 0,
                relative_residual: 0.0,
            },
        }
    }

    /// The packing alone, for the explicit scheme (`density_correction = "particles"` there):
    /// the particles spread to rest density from where they are ([`Self::pack`]), J, F and the
    /// equation of state's pressure left as they are, as particle shifting leaves them in
    /// weakly compressible SPH (Lind et al. 2012).
    pub fn packing_only(mut self) -> Self {
        self.volumes = false;
        self.from_positions = true;
        self
    }

    /// Moves the particles (positions, F and J) so that their volumes return the share
    /// `pace.volume` (0 to 1) of the way to V0, in the stages of the projection: free surface,
    /// unknowns, assembly, solve, correction; with the density from the particles' positions
    /// ([`DensityCorrection::Particles`]), then spreads them to rest density with a second
    /// solve of the same matrix ([`Self::pack`]). The solver and the stages' buffers are the
    /// projection's: the solves run one after the other, so they share its work vectors,
    /// multigrid levels, free surface, Gauss points and matrix instead of keeping two sets
    /// (each is set up again for this system).
    pub fn correct(
        &mut self,
        ps: &mut Particles<D>,
        geo: &GridGeometry<D>,
        boundary: &Boundary<D>,
        pace: Pace,
        (solver, shared): (&mut LinearSolver, &mut Shared<D>),
    ) -> Result<SolveStats, SolveError> {
        let shape = self.shape;
        let pace = pace.clamped();
        let rate = pace.volume;
        // the particles' volumes evened out below the grid's resolution first: the solve below
        // sees J only through its nodal averages, and cannot give one particle's volume back
        // against its neighbour's in the same cell
        self.average_over(shared.ranks.as_ref());
        if self.volumes {
            self.averaging.smooth_jacobian(ps, geo, shape, rate);
        }
        let Shared {
            bins,
            surface,
            system,
            gauss,
            solution,
            ghost: [scratch, first_layer],
            vector_bands,
            nodal: displacement,
            ranks,
        } = shared;
        bins.sort(geo, &ps.x);
        self.gather_volumes(ps, geo, rate, ranks.as_ref());
        // free surface and unknowns, from where the particles are now
        let epsilon = mass_epsilon(&ps.volume0, ranks.as_ref());
        surface.detect(
            geo,
            bins,
            &ps.volume0,
            &self.weight,
            epsilon,
            &boundary.rigid,
        );
        let free = super::number(geo, &surface.kinds, &mut system.unknowns, ranks);
        let rows = system.unknowns.node_of_row.len();
        self.stats = SolveStats {
            iterations: 0,
            relative_residual: 0.0,
        };
        if rows == 0 {
            return Ok(self.stats);
        }
        // K over whole cells (density 1: the particles' volumes as their masses), and b
        let domain = FluidDomain {
            shape,
            kinds: &surface.kinds,
            solid: surface.solid(),
            cut: boundary.rigid.cuts_cells().then_some(&boundary.rigid),
        };
        let v0 = &ps.volume0;
        let mean = super::ranks::mean_density(v0, v0, ranks.as_ref());
        gauss.build(
            geo,
            (bins, v0, v0, mean),
            &surface.fraction,
            shape,
            (Some(domain), ranks.as_ref()),
        );
        gauss.divergence.fill(0.0);
        gauss.velocity.fill(Vector::<D>::zeros());
        crate::pages::fit(&mut self.potential, geo.node_count());
        crate::pages::reset(&mut self.potential);
        let system_rows = super::assemble::Rows {
            kinds: &surface.kinds,
            phi: surface.level_set(),
            unknowns: &system.unknowns,
            dirichlet: &self.potential,
        };
        let (matrix, rhs) = (&mut system.matrix, &mut system.rhs);
        let quadrature = gauss.quadrature(false);
        super::assemble::assemble(geo, shape, &quadrature, &system_rows, 1.0, matrix, rhs);
        if let Some(r) = ranks.as_mut() {
            let unknowns = &system.unknowns;
            r.order_slots::<D>(matrix, 2 * shape.width() - 1, unknowns.assembled_rows());
            r.swap_beside(geo, unknowns, matrix);
        }
        if self.volumes {
            let (u, excess) = (&system.unknowns, &self.excess);
            for r in u.assembled_rows() {
                rhs[r] += excess[u.node_of_row[r] as usize];
            }
        }
        matrix.pin_empty_rows(rhs);
        let u = &mut system.unknowns;
        describe_layout(&mut u.layout, geo, shape, (&u.node_of_row, ranks.as_ref()));
        let stage = Stage {
            geo,
            kinds: &surface.kinds,
            phi: surface.level_set(),
            free,
            ranks: ranks.as_ref(),
        };
        if self.volumes {
            let linear = (&mut *solver, &*system, &mut *solution);
            self.stats = self.solve(&stage, linear, [scratch, first_layer])?;
            // correction: u on the nodes, then the particles moved and deformed by it
            let nodal = (&mut *vector_bands, &mut *displacement);
            self.node_displacement(ps, geo, (boundary, stage.ranks), nodal);
            self.move_particles(ps, geo, &surface.kinds, displacement);
        }
        if self.from_positions {
            let q = gauss.quadrature(false);
            let points = (q.x, q.half_width, q.volume_over_density);
            let ghost = [scratch, first_layer];
            let linear = (solver, system, solution);
            let moved = (boundary, &mut *bins);
            let packed = self.pack(ps, &stage, moved, points, pace, linear, ghost)?;
            self.stats.iterations += packed.iterations;
        }
        Ok(self.stats)
    }

    /// q from the system's right-hand side, with the free surface's ghost values where the
    /// level set sets them.
    fn solve(
        &mut self,
        stage: &Stage<'_, D>,
        (solver, system, solution): (&mut LinearSolver, &super::Assembled, &mut Slots<f64>),
        [scratch, first_layer]: [&mut Vec<f64>; 2],
    ) -> Result<SolveStats, SolveError> {
        let geo = stage.geo;
        // (over ranks on this rank's rows: the solve reads no other)
        solution.fit(system.unknowns.node_of_row.len());
        solution[system.unknowns.assembled_rows()].fill(0.0);
        let linear = System {
            matrix: &system.matrix,
            layout: &system.unknowns.layout,
            singular: stage.free == 0,
            partition: stage.ranks.map(|r| &r.partition),
        };
        let params = SolveParams {
            tolerance: self.tolerance,
            max_iterations: self.max_iterations,
        };
        let stats = solver.solve(&linear, &system.rhs, solution, params)?;
        if let Some(r) = stage.ranks {
            r.gather(geo, &system.unknowns, solution);
        }
        let potential = &mut self.potential;
        super::ranks::scatter_rows(stage.ranks, geo, &system.unknowns, solution, potential);
        geo.copy_to_images(&mut self.potential);
        if let Some(phi) = stage.phi {
            let kinds = stage.kinds;
            free_surface::ghost_values(geo, kinds, phi, &self.potential, scratch, first_layer);
            std::mem::swap(&mut self.potential, scratch);
            geo.copy_to_images(&mut self.potential);
        }
        Ok(stats)
    }

    /// Spreads the particles to rest density: K q = b with b_i the excess of the rest volume
    /// the particles spread onto node i over the volume its shape function covers
    /// ([`Self::fill_excess`]), the same matrix as the volume correction's, and each particle
    /// shifted by its own -(grad q)(x_p) ([`own_shift`]) and pushed apart from the particles
    /// closer to it than their rest spacing ([`super::spacing`], what the nodes cannot see,
    /// at the same pace; `bins` sorted again for it where the volume correction moved the
    /// particles). Positions only: J and F are not touched. The volume correction before it has given J back its share; what is left is
    /// the particles' arrangement, which J does not see (they bunch at J = 1 where they move
    /// with the velocity interpolated within a cell while J integrates its nodal average), so
    /// a move that only rearranges them must not change J either.
    #[allow(clippy::too_many_arguments)]
    fn pack(
        &mut self,
        ps: &mut Particles<D>,
        stage: &Stage<'_, D>,
        (boundary, bins): (&Boundary<D>, &mut CellBins),
        points: (&[Vector<D>], &[f64], &[f64]),
        pace: Pace,
        (solver, system, solution): (&mut LinearSolver, &mut super::Assembled, &mut Slots<f64>),
        ghost: [&mut Vec<f64>; 2],
    ) -> Result<SolveStats, SolveError> {
        let (geo, shape) = (stage.geo, self.shape);
        self.gather_rest_volumes(ps, geo, stage.ranks);
        self.fill_excess(geo, points, stage.kinds, pace.packing);
        let u = &system.unknowns;
        for r in u.assembled_rows() {
            system.rhs[r] = self.excess[u.node_of_row[r] as usize];
        }
        system.matrix.pin_empty_rows(&mut system.rhs);
        let stats = self.solve(stage, (solver, system, solution), ghost)?;
        crate::pages::fit(&mut self.held, geo.node_count());
        crate::pages::reset(&mut self.held);
        boundary.held_components(&mut self.held);
        boundary.hold_buffers_components(&mut self.held);
        // the pairs' pushes with the linear hat only: with the quadratic B-spline the solve's
        // own moves gather particles into the corners of no-slip walls, and the pushes, which
        // cannot spread such a pile, crowd it until the run stops (docs/method.md)
        let pairs = if shape == ShapeFunction::Linear {
            pace.packing
        } else {
            0.0
        };
        if pairs > 0.0 {
            // binned before the volume correction's move; without it (the explicit scheme's
            // packing) the particles are where they were binned
            if self.volumes {
                bins.sort(geo, &ps.x);
            }
            let particles = (&ps.x[..], &ps.volume0[..], &ps.jacobian[..]);
            self.spacing.pushes(geo, bins, particles, pairs);
        } else {
            self.spacing.clear(ps.len());
        }
        let fields = ShiftFields {
            q: &self.potential,
            held: &self.held,
            measured: &self.measured,
            phi: stage.phi,
        };
        let carry = self.from_positions;
        (
            ps.x.par_iter_mut(),
            ps.half_width.par_iter(),
            ps.v.par_iter_mut(),
            ps.affine.par_iter(),
            self.spacing.push.par_iter(),
        )
            .into_par_iter()
            .for_each(|(x, &lp, v, c, &push)| {
                let d = own_shift(shape, geo, &fields, x, lp, push);
                *x += d;
                // the velocity of where it goes ([`Self::from_positions`])
                if carry {
                    *v += c * d;
                }
            });
        Ok(stats)
    }

    /// Over ranks, the nodal averages add up every rank's own particles, as P2G's sums do.
    fn average_over(&mut self, ranks: Option<&Ranks>) {
        if let Some(r) = ranks {
            self.averaging.comm = crate::comm::Ranks(r.partition.comm.clone());
            self.averaging.own = Some(r.own);
        }
    }

    /// sum_p V0_p N_ip per node, into the excess ([`Self::fill_excess`] takes the covered
    /// volume off); over ranks of every rank's own particles ([`Ranks::add_sums`]).
    fn gather_rest_volumes(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        ranks: Option<&Ranks>,
    ) {
        let v0 = &ps.volume0;
        let own = super::ranks::own_of(ranks, ps.len());
        scatter_to_nodes(
            &mut self.bands,
            Points {
                geo,
                shape: ShapeFunction::Linear,
                x: &ps.x[..own],
                half_width: &ps.half_width[..own],
            },
            nalgebra::Vector2::zeros(),
            |p| nalgebra::Vector2::new(v0[p], 0.0),
            &mut self.sums,
        );
        if let Some(r) = ranks {
            r.add_sums(&mut self.sums);
        }
        crate::pages::fit(&mut self.excess, geo.node_count());
        let sums = &self.sums;
        self.excess
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, e)| crate::pages::store(e, sums[i][0]));
    }

    /// sum_p V_p N_ip and rate sum_p V0_p (1 - J_p) N_ip per node, scattered from the
    /// particles ([`scatter_to_nodes`]; over ranks from every rank's own, [`Ranks::add_sums`]).
    fn gather_volumes(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        rate: f64,
        ranks: Option<&Ranks>,
    ) {
        let shape = self.shape;
        let (v0, jac) = (&ps.volume0, &ps.jacobian);
        let own = super::ranks::own_of(ranks, ps.len());
        scatter_to_nodes(
            &mut self.bands,
            Points {
                geo,
                shape,
                x: &ps.x[..own],
                half_width: &ps.half_width[..own],
            },
            nalgebra::Vector2::zeros(),
            |p| {
                // at most MAX_RATE of a particle's volume per correction
                let excess = v0[p] * (1.0 - jac[p]).clamp(-MAX_RATE, MAX_RATE) * rate;
                nalgebra::Vector2::new(v0[p] * jac[p], excess)
            },
            &mut self.sums,
        );
        if let Some(r) = ranks {
            r.add_sums(&mut self.sums);
        }
        let n = geo.node_count();
        crate::pages::fit(&mut self.weight, n);
        crate::pages::fit(&mut self.excess, n);
        let sums = &self.sums;
        (self.weight.par_iter_mut(), self.excess.par_iter_mut())
            .into_par_iter()
            .enumerate()
            .for_each(|(i, (w, e))| {
                // with GIMP a node behind a wall is no unknown: the tails of the particles'
                // shape functions weigh it, but no quadrature point reaches it (the points lie
                // inside the walls and, of no width, reach a cell as the linear hat does), so
                // its row would be empty (a GIMP dam break's solve broke down at its first
                // step). The B-splines' points reach it.
                let pad = crate::shape::PAD;
                let behind_wall = shape == ShapeFunction::Gimp && {
                    let node = geo.multi(i);
                    (0..D).any(|d| {
                        !geo.periodic[d] && (node[d] < pad || node[d] > pad + geo.cells[d])
                    })
                };
                let (weight, excess) = if behind_wall {
                    (0.0, 0.0)
                } else {
                    (sums[i][0], sums[i][1])
                };
                crate::pages::store(w, weight);
                crate::pages::store(e, excess);
            });
    }

    /// With the density from the particles' positions: the excess at node i is
    /// rate (sum_p V0_p N_ip - int_open N_i), the rest volume the particles spread onto it
    /// less the volume its shape function covers in the open domain (the quadrature's points
    /// `points`: x, half-width and the open volume each weighs, so walls and the open part of
    /// a cut cell count as the matrix counts them), at most [`MAX_RATE`] of the latter.
    /// N_i is the linear hat whatever the transfers' shape functions: a regular lattice of
    /// particles spread with it gives the open volume exactly up to a wall (the hat's kinks
    /// lie on the lattice's cell faces), where the quadratic B-spline's samples miss their
    /// integral by a few per cent and would move a pool at rest.
    ///
    /// Near the free surface the domain's cells are whole, but the fluid fills them only in
    /// part, so a node's fill there does not measure the particles' arrangement: where a node
    /// next to it (the corners of the cells its hat covers) is not an unknown (nor inside a
    /// body), nothing is corrected. A deficit there is no void, and spreading an excess there
    /// pushes particles out through the surface, where the water then loses more of its
    /// summed J V0 (docs/method.md, item 4 of the density correction).
    fn fill_excess(
        &mut self,
        geo: &GridGeometry<D>,
        (x, half_width, open): (&[Vector<D>], &[f64], &[f64]),
        kinds: &[NodeKind],
        rate: f64,
    ) {
        scatter_to_nodes(
            &mut self.bands,
            Points {
                geo,
                shape: ShapeFunction::Linear,
                x,
                half_width,
            },
            nalgebra::Vector2::zeros(),
            |g| nalgebra::Vector2::new(open[g], 0.0),
            &mut self.sums,
        );
        let sums = &self.sums;
        crate::pages::fit(&mut self.measured, geo.node_count());
        (self.excess.par_iter_mut(), self.measured.par_iter_mut())
            .into_par_iter()
            .enumerate()
            .for_each(|(i, (e, measured))| {
                let space = sums[i][0];
                if *e == 0.0 && space == 0.0 {
                    crate::pages::store(measured, 0);
                    return;
                }
                let interior = !near_surface(geo, kinds, i);
                let error = if interior {
                    (*e - space).clamp(-MAX_RATE * space, MAX_RATE * space)
                } else {
                    0.0
                };
                crate::pages::store(e, rate * error);
                crate::pages::store(measured, u8::from(interior));
            });
    }

    /// u_i = -sum_p V_p N_ip (grad q)_p / sum_p V_p N_ip, held at the walls (no normal
    /// displacement) and on rigid bodies, and bounded by [`MAX_SHIFT`] cells; over ranks the
    /// sums of every rank's own particles ([`Ranks::add_sums`]).
    fn node_displacement(
        &mut self,
        ps: &Particles<D>,
        geo: &GridGeometry<D>,
        (b, ranks): (&Boundary<D>, Option<&Ranks>),
        (bands, displacement): (&mut Vec<Band<Vector<D>>>, &mut Vec<Vector<D>>),
    ) {
        let shape = self.shape;
        let q = &self.potential;
        let own = super::ranks::own_of(ranks, ps.len());
        let (x, half_width) = (&ps.x[..own], &ps.half_width[..own]);
        let (v0, jac) = (&ps.volume0, &ps.jacobian);
        // (grad q)_p = sum_i G_ip q_i, taken where the scatter asks for the particle's value
        let grad = |p: usize| {
            let st = Stencil::<D>::new(shape, &geo.to_cells(&x[p]), geo.h, half_width[p]);
            let mut s = Vector::<D>::zeros();
            st.for_each(|nw| s += nw.grad * q[geo.flat(&nw.node)]);
            s
        };
        scatter_to_nodes(
            bands,
            Points {
                geo,
                shape,
                x,
                half_width,
            },
            Vector::<D>::zeros(),
            |p| grad(p) * (v0[p] * jac[p]),
            displacement,
        );
        if let Some(r) = ranks {
            r.add_sums(displacement);
        }
        let weight = &self.weight;
        let limit = MAX_SHIFT * geo.h;
        displacement
            .par_iter_mut()
            .zip(weight.par_iter())
            .for_each(|(u, &w)| {
                if w <= 0.0 {
                    crate::pages::store(u, Vector::<D>::zeros());
                    return;
                }
                *u = -*u / w;
                let norm = u.norm();
                if norm > limit {
                    *u *= limit / norm;
                }
            });
        b.hold_still(displacement);
        b.hold_buffers(displacement);
    }

    /// x_p += sum_i N_ip u_i, F_p <- (I + H_p) F_p, J_p <- J_p det(I + H_p) with
    /// H_p = sum_i u_i (x) G_ip, whose volumetric part is the nodal average of tr H (as the
    /// step's own strain rate under the projection, [`crate::averaging`]): a nodal
    /// displacement cannot correct the volume of one particle against its neighbour in the same
    /// cell, and the raw tr H_p, which varies across a cell, would stir such differences up.
    ///
    /// The shift and H_p are taken twice, for tr H before the averaging and for the move after
    /// it, rather than kept per particle in between (D + D^2 numbers a particle, the largest
    /// of the correction's buffers).
    fn move_particles(
        &mut self,
        ps: &mut Particles<D>,
        geo: &GridGeometry<D>,
        kinds: &[NodeKind],
        u: &[Vector<D>],
    ) {
        let shape = self.shape;
        let carry = self.from_positions;
        let n = ps.len();
        self.dilatation.resize(n, 0.0);
        self.spray.resize(n, false);
        (
            ps.x.par_iter(),
            ps.half_width.par_iter(),
            self.dilatation.par_iter_mut(),
            self.spray.par_iter_mut(),
        )
            .into_par_iter()
            .for_each(|(x, &lp, tr, spray)| {
                let (_, h, reached) = shift_at(shape, geo, (u, kinds), x, lp);
                *tr = h.trace();
                *spray = !reached;
            });
        self.averaging.smooth(ps, geo, shape, &mut self.dilatation);
        let (dilatation, spray) = (&self.dilatation, &self.spray);
        (
            ps.x.par_iter_mut(),
            ps.half_width.par_iter(),
            crate::material::optional_mut(&mut ps.deformation, n),
            ps.jacobian.par_iter_mut(),
            ps.v.par_iter_mut(),
            ps.affine.par_iter(),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(p, (x, &lp, f, j, v, c))| {
                let (shift, strain, _) = shift_at(shape, geo, (u, kinds), x, lp);
                // spray keeps its volume here too, as in the step
                // ([`super::Projection::hold_spray_volumes`]): no equation of the correction
                // reaches it, and its nodes' shifts only carry it with its neighbours (a small
                // droplet's J would grow without bound)
                let volumetric = if spray[p] { 0.0 } else { dilatation[p] };
                let h =
                    strain + Matrix::<D>::identity() * ((volumetric - strain.trace()) / D as f64);
                // a particle whose correction would more than halve or double it (or turn it
                // inside out, det <= 0, where the nodes' shifts cross within its cell) takes the
                // largest part 2^-k of it that does not: shift and deformation alike, so that
                // its position stays consistent with its volume
                let mut s = 1.0;
                let mut inc = Matrix::<D>::identity() + h;
                while !(0.5..=2.0).contains(&crate::material::det(&inc)) && s > 1e-3 {
                    s *= 0.5;
                    inc = Matrix::<D>::identity() + h * s;
                }
                if s <= 1e-3 {
                    return;
                }
                if let Some(f) = f {
                    *f = inc * *f;
                }
                *j *= crate::material::det(&inc);
                *x += shift * s;
                // with the density from the positions, the velocity of where it goes
                if carry {
                    *v += c * (shift * s);
                }
            });
    }
}

/// What the solves of one correction share: the grid, the nodes' kinds, the level set (with
/// the ghost-fluid surface) and the count of free-surface nodes (0: the system is singular).
struct Stage<'a, const D: usize> {
    geo: &'a GridGeometry<D>,
    kinds: &'a [NodeKind],
    phi: Option<&'a [f64]>,
    free: usize,
    /// Over ranks, how the solves are spread.
    ranks: Option<&'a super::ranks::Ranks>,
}

/// The node mass below which the correction's free surface reads a node as empty: 1e-9 of
/// the least particle volume (the volumes are the masses here), over every rank's own.
fn mass_epsilon(volume0: &[f64], ranks: Option<&Ranks>) -> f64 {
    let own = super::ranks::own_of(ranks, volume0.len());
    let least = volume0[..own].iter().copied().fold(f64::INFINITY, f64::min);
    1e-9 * ranks.map_or(least, |r| r.min(least))
}

/// Whether a node within one node of node `i` along every axis (the corners of the cells its
/// hat covers) is neither an unknown nor inside a rigid body: the free surface, or no fluid.
/// Nodes beyond the grid's walls do not count (a wall is no free surface).
fn near_surface<const D: usize>(geo: &GridGeometry<D>, kinds: &[NodeKind], i: usize) -> bool {
    let node = geo.multi(i);
    let span: usize = 3;
    (0..span.pow(D as u32)).any(|k| {
        let mut rem = k;
        let mut at = node;
        for d in 0..D {
            let o = rem % span;
            rem /= span;
            let c = (node[d] + o).checked_sub(1);
            match c {
                Some(c) if c < geo.nodes[d] => at[d] = c,
                _ => return false,
            }
        }
        let pad = crate::shape::PAD;
        let beyond_wall =
            (0..D).any(|d| !geo.periodic[d] && (at[d] < pad || at[d] > pad + geo.cells[d]));
        !beyond_wall
            && !matches!(
                kinds[geo.canonical(geo.flat(&at))],
                NodeKind::Interior | NodeKind::Solid
            )
    })
}

/// The nodal fields a particle's own shift reads ([`own_shift`]).
#[derive(Clone, Copy)]
struct ShiftFields<'a> {
    /// q per node.
    q: &'a [f64],
    /// Per node, bit d set where component d is held.
    held: &'a [u8],
    /// Per node, 1 where the fill is measured.
    measured: &'a [u8],
    /// The free surface's level set, where there is one.
    phi: Option<&'a [f64]>,
}

/// A particle's own shift -(grad q)(x_p), at most [`MAX_SHIFT`] cells long. The nodes'
/// displacement u_i averages grad q over the particles around a node, and is blind to a
/// pattern that alternates from cell to cell (particles packed in one cell, spread in the
/// next: the nodal average of the two gradients is nothing); the particle's own gradient
/// moves it. `push` (the sub-cell spacing's, [`super::spacing`]) is added to it. Towards a
/// node where a wall or a body holds component d (`held`, bit d), the shift along d is at
/// most half the particle's distance from that node: a particle closes a gap against a wall
/// but is never moved through it. On an inflow's buffer nodes (`held` at
/// [`crate::boundary::BUFFER_HELD`]) the shift is nothing: it is scaled by the
/// particle's weight on the other nodes, as the volume correction's nodal displacement,
/// zero there, is interpolated (buffer particles moved back towards the patch let less
/// water in than the patch gives). A particle none of whose nodes has its fill measured
/// (`measured`, [`PositionCorrection::fill_excess`]: a film whose every node reaches the
/// free surface) takes no shift from the solve, only its push: the solve corrects nothing
/// there, and q there is only the ghost values' extrapolation and the tail of the interior's
/// solution, whose gradient moved the films of creeping flows without any measure of their
/// arrangement, and they lost J V0 under it (docs/method.md).
///
/// A particle at the surface of the bulk (some of its nodes measured, some not) keeps no part
/// of its push along the outward normal n, the gradient of the level set `phi` at the
/// particle: its close neighbours are all on the inner side, and pushed out along n it left
/// the surface as a droplet (ahead of a yield-stress block's front). Lind, Xu, Stansby &
/// Rogers (JCP 231, 2012) take the normal part off particle shifting at a free surface the
/// same way; where phi is flatter than [`NORMAL_SLOPE`], the direction in
/// which the measured nodes end takes over. A film's particles keep their whole push: the
/// level set does not resolve a sheet thinner than its cells, and without the normal part
/// their bunching came back into the dam break's interior after the impact (docs/method.md).
#[inline]
fn own_shift<const D: usize>(
    shape: ShapeFunction,
    geo: &GridGeometry<D>,
    fields: &ShiftFields<'_>,
    x: &Vector<D>,
    lp: f64,
    push: Vector<D>,
) -> Vector<D> {
    let ShiftFields {
        q,
        held,
        measured,
        phi,
    } = *fields;
    let st = Stencil::<D>::new(shape, &geo.to_cells(x), geo.h, lp);
    let mut grad = Vector::<D>::zeros();
    // per axis, the distance to the nearest held node below and above the particle
    let mut below = Vector::<D>::repeat(f64::INFINITY);
    let mut above = Vector::<D>::repeat(f64::INFINITY);
    let mut free = 0.0;
    let mut measured_node = false;
    let mut surface_node = false;
    let mut normal = Vector::<D>::zeros();
    let mut inward = Vector::<D>::zeros();
    st.for_each(|nw| {
        let i = geo.flat(&nw.node);
        grad += nw.grad * q[i];
        measured_node |= nw.n > 0.0 && measured[i] != 0;
        surface_node |= nw.n > 0.0 && measured[i] == 0;
        if let Some(phi) = phi {
            normal += nw.grad * phi[i];
        }
        if measured[i] != 0 {
            inward += nw.grad * geo.h;
        }
        if held[i] != crate::boundary::BUFFER_HELD {
            free += nw.n;
        }
        if held[i] != 0 {
            let at = geo.node_position(&nw.node);
            for d in (0..D).filter(|d| held[i] >> d & 1 == 1) {
                let gap = at[d] - x[d];
                if gap >= 0.0 {
                    above[d] = above[d].min(gap);
                } else {
                    below[d] = below[d].min(-gap);
                }
            }
        }
    });
    if !measured_node {
        grad = Vector::<D>::zeros();
    }
    let mut push = push;
    if measured_node && surface_node {
        // phi = h (1 - 2 f) is flat where the cells are full, and a gradient of round-off
        // there, normalised, took a direction at random (a run's particles then hung on the
        // order of its sums). Where it is flatter than NORMAL_SLOPE, -h grad m (m = 1 on the
        // measured nodes, falling towards the surface a node or two further in) takes over
        // in proportion, so that n, and the shift, stay continuous.
        let slope = normal.norm();
        let normal = normal - inward * (1.0 - slope / NORMAL_SLOPE).max(0.0);
        let n = normal / normal.norm().max(NORMAL_SLOPE);
        push -= n * push.dot(&n).max(0.0);
    }
    let limit = MAX_SHIFT * geo.h;
    let norm = grad.norm();
    if norm > limit {
        grad *= limit / norm;
    }
    let shift = (push - grad) * free.min(1.0);
    Vector::<D>::from_fn(|d, _| shift[d].clamp(-0.5 * below[d], 0.5 * above[d]))
}

/// A particle's shift sum_i N_ip u_i and H_p = sum_i u_i (x) G_ip from the nodes'
/// displacements `u`, and whether one of its nodes (of weight > 0) holds an equation (`kinds`).
#[inline]
fn shift_at<const D: usize>(
    shape: ShapeFunction,
    geo: &GridGeometry<D>,
    (u, kinds): (&[Vector<D>], &[NodeKind]),
    x: &Vector<D>,
    lp: f64,
) -> (Vector<D>, Matrix<D>, bool) {
    let st = Stencil::<D>::new(shape, &geo.to_cells(x), geo.h, lp);
    let mut dx = Vector::<D>::zeros();
    let mut h = Matrix::<D>::zeros();
    let mut reached = false;
    st.for_each(|nw| {
        let i = geo.flat(&nw.node);
        let ui = u[i];
        dx += ui * nw.n;
        h += ui * nw.grad.transpose();
        reached |= nw.n > 0.0 && kinds[i] == NodeKind::Interior;
    });
    (dx, h, reached)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deck::Deck;

    /// A density correction of `sim`'s grid with its own solver and stage buffers: each call
    /// corrects the particles once, the whole way (rate 1).
    fn corrector<'a>(
        deck: &Deck,
        sim: &'a crate::scheme::Simulation<2>,
        shape: ShapeFunction,
    ) -> impl FnMut(&mut Particles<2>) + 'a {
        let cells = sim.grid.geo.cells.iter().product();
        let mut solver = super::super::linear_solver(&deck.pressure, cells);
        let mut c = PositionCorrection::<2>::new(&deck.pressure, shape);
        let mut shared = Shared::new(&deck.pressure, &sim.boundary);
        move |ps| {
            let (geo, boundary) = (&sim.grid.geo, &sim.boundary);
            c.correct(
                ps,
                geo,
                boundary,
                Pace::whole(1.0),
                (&mut solver, &mut shared),
            )
            .unwrap();
        }
    }

    /// The largest and the mean |J - 1|.
    fn errors(ps: &Particles<2>) -> (f64, f64) {
        let e = ps.jacobian.iter().map(|j| (j - 1.0).abs());
        (
            e.clone().fold(0.0, f64::max),
            e.sum::<f64>() / ps.len() as f64,
        )
    }

    /// A pool of water at rest, no gravity, with a smooth volume error: the correction brings
    /// every particle's J back towards 1, step after step, without moving the pool's centre.
    #[test]
    fn a_smooth_volume_error_is_corrected() {
        let (deck, sim) = pool("linear");
        let mut ps = sim.particles.clone();
        for p in 0..ps.len() {
            let x = ps.x[p];
            ps.jacobian[p] = 1.0 + 0.03 * (std::f64::consts::PI * x[0]).cos() * (3.0 * x[1]).sin();
        }
        let mut correct = corrector(&deck, &sim, ShapeFunction::Linear);
        let (max0, mean0) = errors(&ps);
        let mut last = max0;
        for pass in 0..5 {
            correct(&mut ps);
            let (max, mean) = errors(&ps);
            assert!(max < last, "pass {pass}: max |J - 1| = {max} after {last}");
            if pass == 0 {
                // one pass removes most of a smooth error, 9.4 parts in 10 (the rest sits at the corners
                // where the surface meets the walls)
                assert!(mean < mean0 / 7.0, "mean |J - 1| = {mean} from {mean0}");
            }
            last = max;
        }
        assert!(
            last < 0.25 * max0,
            "max |J - 1| = {last} from {max0} after 5 passes"
        );
        // and the pool's volume, sum J V0, comes back to sum V0
        let volume = |ps: &Particles<2>| (0..ps.len()).map(|p| ps.volume(p)).sum::<f64>();
        let v0: f64 = ps.volume0.iter().sum();
        let drift = (volume(&ps) / v0 - 1.0).abs();
        assert!(drift < 1e-4, "sum J V0 / sum V0 - 1 = {drift}");
    }

    /// A pool of water 0.5 m deep in a closed 1 m box, h = 0.05 m, no gravity, as seeded, for a
    /// shape function.
    fn pool(shape: &str) -> (Deck, crate::scheme::Simulation<2>) {
        let src = format!(
            r#"
[simulation]
dimension = 2
end_time = 1.0
dt = 1e-3
gravity = [0.0, 0.0]
shape_function = "{shape}"
[grid]
size = [1.0, 1.0]
cell_size = 0.05
[grid.boundary]
x_min = "slip"
x_max = "slip"
y_min = "slip"
y_max = "slip"
[[materials]]
name = "water"
density = 1000.0
[[bodies]]
material = "water"
shape = {{ type = "box", min = [0.0, 0.0], max = [1.0, 0.5] }}
particles_per_cell = 2
"#
        );
        let mut deck = Deck::parse(&src, "pool.toml").unwrap();
        deck.validate("pool.toml").unwrap();
        let sim = crate::scheme::Simulation::<2>::new(&deck).unwrap();
        (deck, sim)
    }

    /// The particles below height `y` (positions and rest volumes).
    fn below(ps: &Particles<2>, y: f64) -> Particles<2> {
        let mut kept = ps.clone();
        let keep: Vec<usize> = (0..ps.len()).filter(|&p| ps.x[p][1] < y).collect();
        kept.x = keep.iter().map(|&p| ps.x[p]).collect();
        kept.volume0 = keep.iter().map(|&p| ps.volume0[p]).collect();
        kept
    }

    /// The interior fill ([`crate::fill`]) of the pool's particles, on nodes of c = h.
    fn fill_of(ps: &Particles<2>, h: f64) -> crate::fill::FillFigures {
        let lattice = crate::fill::FillLattice {
            origin: Vector::<2>::zeros(),
            spacing: h,
        };
        lattice.measure(&ps.x, &ps.volume0)
    }

    /// Particles bunched with J = 1 (a band of columns pushed together, J not told): with the
    /// density from the particles' positions the correction spreads them back to rest
    /// density, where J alone would not see them; in the middle of the pool and against its
    /// wall (where they must close the gap the squeeze left at the wall, not cross it). The
    /// fill is measured two cells below the surface: the solve corrects no node whose hat
    /// reaches a surface node ([`PositionCorrection::fill_excess`]).
    #[test]
    fn a_bunched_band_is_spread_to_rest_density() {
        // (from, to, centre): columns between `from` and `to` pushed a fifth of the way to
        // `centre`
        for (from, to, centre) in [(0.3, 0.7, 0.5), (0.0, 0.2, 0.1)] {
            let (mut deck, sim) = pool("linear");
            deck.pressure.density_correction = Some(DensityCorrection::Particles);
            let mut ps = sim.particles.clone();
            for x in ps.x.iter_mut() {
                if (from..to).contains(&x[0]) {
                    x[0] = centre + 0.8 * (x[0] - centre);
                }
            }
            let before = fill_of(&ps, 0.05);
            let mut correct = corrector(&deck, &sim, ShapeFunction::Linear);
            for _ in 0..20 {
                correct(&mut ps);
            }
            // below the nodes whose hats reach the surface's, which the packing leaves
            let after = fill_of(&below(&ps, 0.4), 0.05);
            assert!(before.p99 > 1.19, "{before:?}");
            assert!(
                after.p99 < 1.001 && after.p1 > 0.999,
                "{before:?} -> {after:?}"
            );
            assert!(ps.x.iter().all(|x| x[0] > 0.0 && x[0] < 1.0));
            // J is not told: the move only rearranges the particles
            assert!(ps.jacobian.iter().all(|j| (j - 1.0).abs() < 1e-12));
        }
    }

    /// The explicit scheme's packing ([`Packing`]): the bunched band of
    /// [`a_bunched_band_is_spread_to_rest_density`] with J off 1 as an equation of state
    /// leaves it (a compressed strip) is spread as well, and J and F, the explicit scheme's
    /// pressure, are not touched at all.
    #[test]
    fn the_explicit_packing_spreads_a_band_and_leaves_j() {
        let (mut deck, sim) = pool("linear");
        deck.simulation.scheme = crate::scheme::Scheme::Explicit;
        deck.pressure.density_correction = Some(DensityCorrection::Particles);
        let mut ps = sim.particles.clone();
        for (x, j) in ps.x.iter_mut().zip(ps.jacobian.iter_mut()) {
            if (0.3..0.7).contains(&x[0]) {
                x[0] = 0.5 + 0.8 * (x[0] - 0.5);
                *j = 0.99;
            }
        }
        let (jacobian, deformation) = (ps.jacobian.clone(), ps.deformation.clone());
        let pressure = ps.pressure.clone();
        let before = fill_of(&ps, 0.05);
        let cells = sim.grid.geo.cells.iter().product();
        let shape = ShapeFunction::Linear;
        let mut packing = Packing::<2>::new(&deck.pressure, shape, &sim.boundary, cells, &[0.0; 2]);
        for _ in 0..20 {
            packing
                .pack(&mut ps, &sim.grid.geo, &sim.boundary, 1.0)
                .unwrap();
        }
        let after = fill_of(&below(&ps, 0.4), 0.05);
        assert!(before.p99 > 1.19, "{before:?}");
        assert!(
            after.p99 < 1.001 && after.p1 > 0.999,
            "{before:?} -> {after:?}"
        );
        assert_eq!(ps.jacobian, jacobian);
        assert_eq!(ps.deformation, deformation);
        assert_eq!(ps.pressure, pressure);
    }

    /// The explicit scheme's share: `EXPLICIT_PACKS` times the projection's, at most the
    /// whole, none when the flow stands still.
    #[test]
    fn the_explicit_packing_comes_at_its_pace() {
        let rate = 0.01 / EXPLICIT_PACKS;
        assert!((Packing::<2>::share(rate).unwrap() - 0.01).abs() < 1e-15);
        assert_eq!(Packing::<2>::share(1.0), Some(1.0));
        assert_eq!(Packing::<2>::share(0.0), None);
    }

    /// Particles as seeded, J = 1, tile the pool: the correction leaves them where they are,
    /// with both the linear and the quadratic B-spline shape functions.
    #[test]
    fn a_pool_as_seeded_is_left_alone() {
        for (name, shape, measure) in [
            (
                "linear",
                ShapeFunction::Linear,
                DensityCorrection::Positions,
            ),
            (
                "bspline2",
                ShapeFunction::Bspline2,
                DensityCorrection::Positions,
            ),
            (
                "linear",
                ShapeFunction::Linear,
                DensityCorrection::Particles,
            ),
            (
                "bspline2",
                ShapeFunction::Bspline2,
                DensityCorrection::Particles,
            ),
        ] {
            let (mut deck, sim) = pool(name);
            deck.pressure.density_correction = Some(measure);
            let mut ps = sim.particles.clone();
            let mut correct = corrector(&deck, &sim, shape);
            for _ in 0..3 {
                correct(&mut ps);
            }
            for p in 0..ps.len() {
                let moved = (ps.x[p] - sim.particles.x[p]).norm();
                assert!(moved < 1e-12, "{name}: particle {p} moved {moved} m");
                assert!(
                    (ps.jacobian[p] - 1.0).abs() < 1e-12,
                    "{name}: J = {}",
                    ps.jacobian[p]
                );
            }
        }
    }
}
