//! The simulation state and its time step, read top to bottom in [`Simulation::step`].
//!
//! The two schemes share everything but the pressure: `explicit` takes it from the equation of
//! state p = K (1 - J) inside the particle stress, `projection` (docs/method.md) from a Poisson solve
//! between the predictor and the corrector.

use crate::averaging::NodalAveraging;
use crate::boundary::{Boundary, Leaving};
use crate::comm::Comm;
use crate::error::Error;
use crate::flow::{has_left, Ledger};
use crate::grid::CellBins;
use crate::grid::{Grid, GridGeometry, Vector};
use crate::linalg::SolveError;
use crate::material::{self, in_mask, MaterialParams};
use crate::particles::{Particles, PermuteScratch};
use crate::pressure::Packing;
use crate::pressure::Projection;
use crate::shape::Stencil;
use crate::timing::{Phase, PhaseTimers};
use crate::transfer::{self, P2gScratch, StressUpdate, TransferSettings};
use crate::viscosity::{ImplicitViscosity, ViscousError};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Time-integration scheme: the paper's projection or the weakly compressible baseline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Scheme {
    /// Implicit pressure by Chorin's projection (docs/method.md).
    #[default]
    Projection,
    /// Explicit, weakly compressible: p = K (1 - J).
    Explicit,
}

/// The scheme a simulation steps with, and the state it keeps between steps.
pub enum Stepper<const D: usize> {
    /// Weakly compressible: the pressure is the particles' equation of state, p = K (1 - J);
    /// with `density_correction = "particles"`, the particles' packing (boxed: without it the
    /// explicit scheme keeps nothing).
    Explicit(Option<Box<Packing<D>>>),
    /// Chorin's projection with its solves and their work.
    Projection(Box<Projection<D>>),
}

impl<const D: usize> Stepper<D> {
    /// Which scheme.
    pub fn scheme(&self) -> Scheme {
        match self {
            Stepper::Explicit(_) => Scheme::Explicit,
            Stepper::Projection(_) => Scheme::Projection,
        }
    }

    /// The projection's state, under the projection.
    pub fn projection(&self) -> Option<&Projection<D>> {
        match self {
            Stepper::Explicit(_) => None,
            Stepper::Projection(p) => Some(p),
        }
    }

    /// The projection's state to change, under the projection.
    pub fn projection_mut(&mut self) -> Option<&mut Projection<D>> {
        match self {
            Stepper::Explicit(_) => None,
            Stepper::Projection(p) => Some(p),
        }
    }

    /// The window past its slab that a rank sees over ranks
    /// ([`crate::slabs::Decomposition::window`]): the projection's and the explicit packing's
    /// (their free surface and solves), 0 for the explicit scheme without packing.
    pub fn window(&self) -> usize {
        match self {
            Stepper::Explicit(packing) => packing.as_ref().map_or(0, |p| p.window()),
            Stepper::Projection(p) => p.window(),
        }
    }

    /// The layers of the window whose stages a rank runs ([`crate::slabs::projection_reach`]):
    /// the projection's and the explicit packing's, 0 for the explicit scheme without packing.
    pub fn reach(&self) -> usize {
        match self {
            Stepper::Explicit(packing) => packing.as_ref().map_or(0, |p| p.reach()),
            Stepper::Projection(p) => p.reach(),
        }
    }

    /// The cell layers past its slab whose particles a rank is lent as ghosts
    /// ([`crate::slabs::GHOST_LAYERS`]): the projection's, the explicit packing's (its points
    /// are the cells' Gauss points), 0 for the explicit scheme without packing.
    fn ghost_layers(&self) -> usize {
        match self {
            Stepper::Explicit(packing) => {
                packing.as_ref().map_or(0, |_| crate::slabs::GHOST_LAYERS)
            }
            Stepper::Projection(p) => p.ghost_layers(),
        }
    }

    /// The deck's key that keeps the pressure's or the packing's solver from running over
    /// ranks; `None` where it spreads.
    fn unsupported_over_ranks(&self) -> Option<&'static str> {
        match self {
            Stepper::Explicit(packing) => packing.as_ref().and_then(|p| p.unsupported_over_ranks()),
            Stepper::Projection(p) => p.unsupported_over_ranks(),
        }
    }

    /// Makes the projection's or the packing's stages a rank's, the grid cut at `cuts` along
    /// `axis` ([`Projection::spread_over`]); `None`: one process's.
    fn spread_over(&mut self, ranks: Option<(Arc<dyn Comm>, crate::slabs::Decomposition)>) {
        match self {
            Stepper::Projection(p) => p.spread_over(ranks),
            Stepper::Explicit(Some(p)) => p.spread_over(ranks),
            Stepper::Explicit(None) => {}
        }
    }

    /// Over ranks, the neighbours' particles from `own` on in `ps` are lent as ghosts for
    /// the stages that need them ([`Projection::ghosts_from`]).
    fn ghosts_lent(&mut self, ps: &Particles<D>, own: usize) {
        match self {
            Stepper::Projection(p) => p.ghosts_from(ps, own),
            Stepper::Explicit(Some(p)) => p.own_particles(own),
            Stepper::Explicit(None) => {}
        }
    }

    /// The ghosts dropped: `own` particles again ([`Projection::ghosts_gone`]).
    fn ghosts_dropped(&mut self, own: usize) {
        match self {
            Stepper::Projection(p) => p.ghosts_gone(own),
            Stepper::Explicit(Some(p)) => p.ghosts_gone(),
            Stepper::Explicit(None) => {}
        }
    }
}

/// The most cells a particle's volume may cover before the run stops: a particle that large
/// has lost touch with the grid's resolution (a volume that grew without bound).
pub const MAX_PARTICLE_CELLS: f64 = 4.0;

/// Particles that [`Simulation::check_particles`] caught leaving the grid or going non-finite.
#[derive(Debug, Clone)]
pub struct Escape<const D: usize> {
    /// Particle id.
    pub particle: usize,
    /// Its position.
    pub x: Vector<D>,
    /// Its velocity.
    pub v: Vector<D>,
}

/// The deck's settings the step and its time-step bound read, taken once from the deck: the
/// simulation keeps these, not the deck.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepPolicy {
    /// Steps between sorts of the particles into cell order (0: never).
    pub sort_interval: usize,
    /// Velocity damping (1/s).
    pub damping: f64,
    /// MUSL or USL.
    pub stress_update: StressUpdate,
    /// The particle volume ratios J outside which the run stops.
    pub volume_limits: Option<[f64; 2]>,
    /// Largest adaptive step (s).
    pub max_dt: Option<f64>,
    /// Fixed step (s).
    pub dt: Option<f64>,
}

/// What a probe reads about its point.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProbeSample {
    /// The grid nodes that carry material, weighted by the shape functions (after P2G).
    #[default]
    Nodes,
    /// The mass-weighted mean of the particles within a cell (linear hat weights), as the
    /// pressure and velocity gauges read.
    Particles,
}

/// Points where the grid's pressure and velocity are sampled at every step.
#[derive(Debug, Clone)]
pub struct Probes<const D: usize> {
    /// Probe positions.
    pub positions: Vec<Vector<D>>,
    /// Per probe, the half-width of the hat over which it averages the particles
    /// (`sample = "particles"`), or None where it reads the grid's nodes.
    pub radius: Vec<Option<f64>>,
    /// Samples of the last step's P2G (the state at the step's start): per probe, pressure
    /// then D velocity components.
    pub values: Vec<f64>,
}

/// The step's work buffers, reused from step to step.
struct Work<const D: usize> {
    /// Per-thread node accumulators of P2G.
    p2g: P2gScratch<D>,
    /// Per-particle velocity that moves it this step (interpolated v^{n+1}).
    advect: Vec<Vector<D>>,
    /// Cells of the particles, for the periodic sort.
    sort_bins: CellBins,
    sort_scratch: PermuteScratch<D>,
    /// Places of the particles an outflow face leaves in the run.
    kept: Vec<u32>,
    /// The particles the inflows emit this step, before they join the others.
    entering: Particles<D>,
}

/// What a simulation is made of at t = 0, each part built from its settings.
pub struct Parts<const D: usize> {
    /// The step's own settings.
    pub policy: StepPolicy,
    /// Material points.
    pub particles: Particles<D>,
    /// The grid's geometry.
    pub geo: GridGeometry<D>,
    /// Per-material parameters.
    pub materials: Vec<MaterialParams>,
    /// Transfer settings.
    pub settings: TransferSettings<D>,
    /// Wall conditions and rigid bodies.
    pub boundary: Boundary<D>,
    /// Probe positions, and the radius of the particles' mean of those that read it.
    pub probes: Vec<(Vector<D>, Option<f64>)>,
    /// The scheme, with the projection's state under the projection.
    pub stepper: Stepper<D>,
    /// The nodal averaging of the volumetric strain rate, where it applies.
    pub averaging: Option<NodalAveraging<D>>,
    /// A body force given by expressions that vary in space or time.
    pub body_force: Option<crate::field::CompiledField>,
    /// The implicit viscous solve (`simulation.viscosity = "implicit"`).
    pub viscosity: Option<ImplicitViscosity<D>>,
    /// The damping zones' rate at each node (empty: none).
    pub damping: Vec<f64>,
}

/// The whole state of a run: particles, grid, settings, time.
pub struct Simulation<const D: usize> {
    /// What the step reads besides its parts: the deck's time-step and update settings.
    pub policy: StepPolicy,
    /// Material points.
    pub particles: Particles<D>,
    /// Background grid and its node fields.
    pub grid: Grid<D>,
    /// Per-material parameters.
    pub materials: Vec<MaterialParams>,
    /// Transfer settings.
    pub settings: TransferSettings<D>,
    /// Wall conditions.
    pub boundary: Boundary<D>,
    /// Simulated time (s).
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    /// The probes and what they sampled.
    pub probes: Probes<D>,
    /// A body force given by expressions in x, y, z, t, and its value at each particle now.
    body_force: Option<(crate::field::CompiledField, Vec<Vector<D>>)>,
    /// The scheme, with the projection's state under the projection.
    pub stepper: Stepper<D>,
    /// The nodal averaging of the volumetric strain rate (`volumetric_averaging = "nodal"`).
    averaging: Option<NodalAveraging<D>>,
    /// The implicit viscous solve (`simulation.viscosity = "implicit"`).
    pub viscosity: Option<ImplicitViscosity<D>>,
    work: Work<D>,
    /// What entered and left through the open boundaries ([`crate::flow`]).
    pub ledger: Ledger,
    /// Wall-clock seconds per phase of the step.
    pub timers: PhaseTimers,
    /// The ranks the run is spread over ([`crate::comm`]); one, [`crate::comm::Serial`],
    /// unless [`Simulation::set_comm`] gave it others.
    pub comm: crate::comm::Ranks,
    /// Where the grid is cut into slabs over the ranks ([`crate::slabs`]), kept in the
    /// checkpoint; `None` on one process, or where every rank holds the whole grid.
    pub decomposition: Option<crate::slabs::Decomposition>,
    /// The particles the deck seeds, over every rank (a checkpoint of as many fits).
    pub seeded: usize,
    /// The slabs' work between steps: the ranks without the slabs' exchange, the particles'
    /// counts per layer and the migration's buffers.
    slabs: Option<SlabWork>,
}

/// What a run cut into slabs keeps from step to step ([`crate::slabs`]).
struct SlabWork {
    world: Arc<dyn Comm>,
    counts: crate::slabs::Counts,
    migration: crate::slabs::Migration,
    /// While the neighbours' particles are lent to this rank (the projection's window:
    /// [`crate::slabs::Decomposition::window`]), how many of the particles are its own.
    own: Option<usize>,
}

impl<const D: usize> Simulation<D> {
    /// A simulation at t = 0 from its parts (the `build` module makes them from a deck).
    pub fn from_parts(parts: Parts<D>) -> Self {
        let (n, stored) = (parts.particles.len(), parts.particles.stored);
        let mass0 = parts.particles.mass.iter().sum();
        let body_force = parts.body_force.map(|f| {
            let at = parts.particles.x.iter().map(|x| f.eval(x, 0.0)).collect();
            (f, at)
        });
        let mut sim = Self {
            body_force,
            stepper: parts.stepper,
            averaging: parts.averaging,
            viscosity: parts.viscosity,
            policy: parts.policy,
            particles: parts.particles,
            grid: Grid {
                damping: parts.damping,
                ..Grid::new(parts.geo)
            },
            materials: parts.materials,
            settings: parts.settings,
            boundary: parts.boundary,
            time: 0.0,
            steps: 0,
            probes: Probes {
                values: vec![0.0; parts.probes.len() * (D + 1)],
                positions: parts.probes.iter().map(|p| p.0).collect(),
                radius: parts.probes.iter().map(|p| p.1).collect(),
            },
            work: Work {
                p2g: P2gScratch::new(rayon::current_num_threads()),
                advect: vec![Vector::<D>::zeros(); n],
                sort_bins: CellBins::default(),
                sort_scratch: PermuteScratch::default(),
                kept: Vec::new(),
                entering: Particles {
                    stored,
                    ..Particles::default()
                },
            },
            ledger: Ledger {
                mass0,
                next_id: n as u32,
                ..Ledger::default()
            },
            timers: PhaseTimers::default(),
            comm: crate::comm::Ranks::default(),
            seeded: n,
            decomposition: None,
            slabs: None,
        };
        sim.fit_live();
        sim
    }

    /// Which nodes P2G's gather visits ([`crate::grid::Live`]): under the explicit scheme on
    /// a grid without a periodic axis, those the particles reach, and over ranks cut along the
    /// last axis (the slowest of the node numbering, so a slab is one run of nodes) the slab's
    /// with three layers either side, where a neighbour's sums land (the packing's window,
    /// where it is wider); every node otherwise (the projection reads and writes v^n on the
    /// walls; a periodic grid folds its images; the whole grid on every rank, or slabs along
    /// another axis, take sums from everywhere).
    fn fit_live(&mut self) {
        let geo = &self.grid.geo;
        let n = geo.node_count();
        let slab = match (&self.decomposition, self.comm.is_distributed()) {
            (_, false) => Some(0..0),
            (Some(d), true) if d.axis == D - 1 => {
                // (with the packing's window, its layers too: the neighbours copy their sums
                // there)
                let (r, s) = (self.comm.rank(), geo.strides[D - 1]);
                let reach = d.window.max(3);
                let lo = d.cuts[r].saturating_sub(reach);
                let hi = (d.cuts[r + 1] + reach).min(geo.nodes[D - 1]);
                Some(lo * s..hi * s)
            }
            _ => None,
        };
        let explicit = self.stepper.scheme() == Scheme::Explicit && !geo.has_periodic();
        // (the first gather visits every node: whatever it held before is zeroed)
        self.grid.live = slab.filter(|_| explicit).map(|slab| crate::grid::Live {
            slab,
            previous: 0..n,
        });
    }

    /// One time step of size `dt`, as docs/method.md sets it out.
    pub fn step(&mut self, dt: f64) -> Result<(), Error> {
        self.timers.lap(Phase::Other);
        // 0. every sort_interval steps, particles in cell order (the transfers then walk the
        //    grid in order); a particle keeps its id
        let interval = self.policy.sort_interval;
        if interval > 0 && self.steps % interval as u64 == 0 {
            self.sort_particles();
        }
        // 0b. over ranks, the slabs cut again where the particles' shares drifted apart
        self.rebalance()?;
        self.timers.lap(Phase::Sort);
        // 1. particles -> grid: mass, momentum, internal and body forces (and probe samples)
        self.particles_to_grid();
        self.boundary.rigid.begin_step(&self.grid, dt);
        self.timers.lap(Phase::P2g);
        // 3a. the projection's free surface, from where the particles are (over ranks with
        //     the neighbours' particles next to the cut lent to it until the corrector)
        if self.stepper.scheme() == Scheme::Projection {
            self.lend_ghosts()?;
        }
        if let Stepper::Projection(projection) = &mut self.stepper {
            projection.find_free_surface(&self.particles, &self.grid, &self.boundary);
            self.timers.lap(Phase::FreeSurface);
        }
        // 2. predictor: v* = v^n + dt f / m (with the explicit scheme f holds the EOS pressure),
        //    and the walls that hold this step
        self.predict(dt);
        // 3. boundary conditions on v*; the projection's pressure
        self.pressure(dt)?;
        // 3b. the fluids' viscous stress at the new velocity (implicit viscosity)
        self.solve_viscosity(dt)?;
        // 4. grid -> particles (PIC / FLIP / APIC) and move
        self.grid_to_particles(dt)?;
        // 4b. over ranks, the particles the move took into another rank's slab go to it
        self.migrate()?;
        self.timers.lap(Phase::G2p);
        // 5. strain rate, deviatoric stress, F, J (and p = K (1 - J) for the explicit scheme)
        self.update_materials(dt);
        self.timers.lap(Phase::Constitutive);
        // 6. the particles moved back towards their rest volumes (projection), or packed
        //    (explicit, where the deck asks)
        self.correct_density(dt)?;
        self.time += dt;
        self.steps += 1;
        // 7. the inflows emit the material that entered over the step
        self.emit_inflow()?;
        self.check_particles()?;
        self.check_bodies()?;
        self.check_volumes()
    }

    /// Makes this simulation a rank of `comm`'s: its sums of particles onto the grid (P2G, the
    /// nodal averaging, the bodies' pushes) are added up over the ranks from now on.
    pub fn set_comm(&mut self, comm: Arc<dyn Comm>) {
        if let Some(averaging) = &mut self.averaging {
            averaging.comm = crate::comm::Ranks(comm.clone());
        }
        self.boundary.rigid.comm = crate::comm::Ranks(comm.clone());
        self.comm = crate::comm::Ranks(comm);
        self.fit_live();
    }

    /// Makes this simulation a rank of `world`'s with the grid cut into slabs as `d` says
    /// ([`crate::slabs`]): its sums onto the nodes are exchanged with its neighbours, and its
    /// particles are those of its slab from the next migration on.
    pub fn cut_into_slabs(&mut self, world: Arc<dyn Comm>, d: crate::slabs::Decomposition) {
        let sliced: Arc<dyn Comm> =
            Arc::new(crate::slabs::Sliced::new(world.clone(), &self.grid.geo, &d));
        let rank = world.rank();
        self.boundary.rigid.owned_layers = Some((d.axis, d.cuts[rank]..d.cuts[rank + 1]));
        // (the stages' comm is the slabs': its sums onto the nodes copy the window's layers)
        let ranks = (d.window > 0).then(|| (sliced.clone(), d.clone()));
        self.stepper.spread_over(ranks);
        self.decomposition = Some(d);
        match &mut self.slabs {
            Some(s) => s.world = world,
            None => {
                self.slabs = Some(SlabWork {
                    world,
                    counts: Default::default(),
                    migration: Default::default(),
                    own: None,
                })
            }
        }
        self.set_comm(sliced);
        if let Some(v) = &mut self.viscosity {
            let d = self.decomposition.as_ref().expect("just cut");
            v.spread_over(Some(crate::viscosity::Slab {
                comm: self.comm.0.clone(),
                axis: d.axis,
                layers: d.cuts[rank]..d.cuts[rank + 1],
            }));
        }
    }

    /// Step 4b: the particles outside this rank's slab sent to the ranks whose slabs hold them.
    pub fn migrate(&mut self) -> Result<(), Error> {
        let (Some(d), Some(s)) = (&self.decomposition, &mut self.slabs) else {
            return Ok(());
        };
        let moved = s
            .migration
            .run(&*self.comm, &self.grid.geo, d, &mut self.particles)
            .map_err(|why| Error::Usage(format!("run stopped at step {}: {why}", self.steps)))?;
        if moved {
            if let Some(p) = self.stepper.projection_mut() {
                p.particles_moved(&self.particles);
            }
            self.fit_particle_arrays();
        }
        Ok(())
    }

    /// Over ranks under the projection or the explicit packing, the neighbours' particles
    /// next to the cut appended to its own as ghosts, as deep as the stages read them one by
    /// one ([`Stepper::ghost_layers`], [`crate::slabs::Migration::lend_ghosts`]); nothing on
    /// one process.
    fn lend_ghosts(&mut self) -> Result<(), Error> {
        let (Some(d), Some(s)) = (&self.decomposition, &mut self.slabs) else {
            return Ok(());
        };
        if d.window == 0 || s.own.is_some() {
            return Ok(());
        }
        let own = s
            .migration
            .lend_ghosts(
                &*self.comm,
                &self.grid.geo,
                (d, self.stepper.ghost_layers()),
                &mut self.particles,
            )
            .map_err(|why| Error::Usage(format!("run stopped at step {}: {why}", self.steps)))?;
        s.own = Some(own);
        self.stepper.ghosts_lent(&self.particles, own);
        Ok(())
    }

    /// The ghosts of [`Simulation::lend_ghosts`] dropped; the count of this rank's own
    /// particles, for the projection's state ([`Projection::ghosts_gone`]), where there were
    /// ghosts.
    fn drop_ghosts(&mut self) -> Option<usize> {
        let own = self.slabs.as_mut()?.own.take()?;
        self.particles.truncate(own);
        Some(own)
    }

    /// Step 0b: every [`crate::slabs::REBALANCE_EVERY`] steps, new cuts where the largest
    /// share of the particles drifted above the mean ([`crate::slabs::Decomposition::rebalanced`]).
    fn rebalance(&mut self) -> Result<(), Error> {
        if self.steps % crate::slabs::REBALANCE_EVERY != 0 {
            return Ok(());
        }
        let (Some(d), Some(s)) = (&self.decomposition, &mut self.slabs) else {
            return Ok(());
        };
        s.counts.of(&*self.comm, &self.grid.geo, &self.particles.x);
        if let Some(new) = d.rebalanced(&self.grid.geo, &s.counts) {
            let world = s.world.clone();
            if let Some(p) = self.stepper.projection_mut() {
                p.share_pressure(&self.grid.geo, &new);
            }
            self.cut_into_slabs(world, new);
            self.migrate()?;
        }
        Ok(())
    }

    /// The window past its slab a rank of this run sees over ranks
    /// ([`crate::slabs::Decomposition::window`]): the projection's and the explicit packing's,
    /// 0 for the explicit scheme without packing.
    pub fn window(&self) -> usize {
        self.stepper.window()
    }

    /// The layers of its window whose stages a rank of this run runs
    /// ([`crate::slabs::projection_reach`]).
    pub fn reach(&self) -> usize {
        self.stepper.reach()
    }

    /// The first setting that a run over several ranks does not
    /// support yet (the distributed module asks it), as the deck's key.
    pub(crate) fn unsupported_distributed(&self) -> Option<&'static str> {
        let outflow = (0..2 * D).any(|f| self.boundary.is_outflow(f));
        if let Some(key) = self.stepper.unsupported_over_ranks() {
            return Some(key);
        }
        [
            (self.body_force.is_some(), "simulation.body_force"),
            (outflow, "grid.boundary = \"outflow\""),
            (!self.boundary.inflows.is_empty(), "inflows"),
        ]
        .into_iter()
        .find_map(|(set, key)| set.then_some(key))
    }

    /// Stops the run if a free rigid body's position or velocity is no longer a number.
    fn check_bodies(&self) -> Result<(), Error> {
        let Some(b) = self.boundary.rigid.runaway() else {
            return Ok(());
        };
        Err(Error::BlowUp(format!(
            "run stopped at step {}, t = {:.6} s: free rigid body {} (rigid_bodies[{b}]) has a \
             non-finite position or velocity. Likely cause: a step too large for the force on \
             it; lower simulation.cfl",
            self.steps,
            self.time,
            b + 1
        )))
    }

    /// Step 2: v* = v^n + dt f / m. The projection takes v^n on the walls from the wall
    /// conditions: P2G extrapolates the particles' velocity onto wall nodes, and the flux form
    /// of the Poisson equation would read that as flow through the wall.
    fn predict(&mut self, dt: f64) {
        if self.stepper.scheme() == Scheme::Projection {
            // v^n's motion into the walls removed (the contacts by v^n itself)
            self.settle_contacts(false, dt);
            self.boundary.apply(&mut self.grid.velocity);
        }
        self.grid.predict(
            dt,
            self.policy.damping,
            self.settings.mass_epsilon,
            self.settings.mass_floor,
        );
        // the walls this step holds: those v* presses on, and the slip walls' shear on them
        self.settle_contacts(true, dt);
        let g = &mut self.grid;
        self.boundary
            .rub(&mut g.velocity_new, &g.velocity, &g.mass, dt);
    }

    /// The largest body force per unit mass on a particle, |g| or the field's.
    fn body_acceleration(&self) -> f64 {
        match &self.body_force {
            Some((_, f)) => self
                .comm
                .max_scalar(f.iter().map(|f| f.norm()).fold(0.0, f64::max)),
            None => self.settings.gravity.norm(),
        }
    }

    /// The walls' contacts for the step ([`Boundary::settle_contacts`]) on v^n (which also
    /// marks the material already leaving faster than a step of the body force), or on v* with
    /// `predicted`: under the projection by the last solve's pressure as well, or held where it
    /// sets no level ([`Projection::wall_pressure`]).
    fn settle_contacts(&mut self, predicted: bool, dt: f64) {
        if !self.boundary.separates() {
            return;
        }
        let (v, leaving) = if predicted {
            (&self.grid.velocity_new, None)
        } else {
            let g = self.body_acceleration();
            let rho = self.materials.iter().map(|m| m.density).fold(0.0, f64::max);
            let leaving = Leaving {
                speed: g * dt,
                weight: rho * g * self.grid.geo.h,
            };
            (&self.grid.velocity, Some(leaving))
        };
        // (over ranks the fastest on any: a node no particle of a rank reaches reads 0 there)
        let speed = self.comm.max_scalar(self.boundary.face_speed(v));
        match &self.stepper {
            Stepper::Explicit(_) => self.boundary.settle_contacts(v, speed, None, None),
            Stepper::Projection(p) => match p.wall_pressure(self.grid.geo.node_count()) {
                Some(pressure) => self
                    .boundary
                    .settle_contacts(v, speed, Some(pressure), leaving),
                None => self.boundary.hold_all(),
            },
        }
    }

    /// Step 3b: the projected velocity v <- u, the solution of (M + dt K) u = M v, K the
    /// fluids' viscous operator (docs/method.md, "Implicit viscosity"). After the pressure, not
    /// before: before it, the solve would diffuse the predictor's gravity increment, which the
    /// pressure is about to cancel, into the walls' boundary layers (water at rest in a tank
    /// moved at 3 mm/s). A solve that fails stops the run with its residual and the keys to
    /// change.
    fn solve_viscosity(&mut self, dt: f64) -> Result<(), Error> {
        let Some(viscosity) = self.viscosity.as_mut() else {
            return Ok(());
        };
        self.timers.lap(Phase::Other);
        viscosity
            .solve(
                &self.particles,
                &mut self.grid,
                &self.boundary,
                &self.materials,
                dt,
            )
            .map_err(|e| {
                let hint = match e {
                    ViscousError::NotConverged { .. } => {
                        "raise simulation.viscosity_max_iterations, or lower simulation.cfl \
                         (a smaller step makes the viscous system better conditioned)"
                    }
                    ViscousError::Breakdown(_) => {
                        "the flow had blown up before the solve; lower simulation.cfl or \
                         simulation.dt"
                    }
                };
                Error::BlowUp(format!(
                    "run stopped at step {}, t = {:.6} s: {e}. {hint}",
                    self.steps + 1,
                    self.time
                ))
            })?;
        self.timers.lap(Phase::Viscosity);
        Ok(())
    }

    /// Step 3 of the explicit scheme: the boundary conditions on v* (the pressure came from
    /// the equation of state in the particle stress) and the rigid bodies' force.
    fn hold_walls(&mut self, dt: f64) {
        self.boundary
            .rigid
            .end_step(&self.grid, dt, crate::rigid::PressureForce::None);
        self.boundary.apply(&mut self.grid.velocity_new);
        self.timers.lap(Phase::Predictor);
    }

    /// Step 3 by the scheme: the walls' conditions on v* (explicit), or the projection. The
    /// projection's state is taken out of the simulation for the stage and put back.
    fn pressure(&mut self, dt: f64) -> Result<(), Error> {
        match std::mem::replace(&mut self.stepper, Stepper::Explicit(None)) {
            explicit @ Stepper::Explicit(_) => {
                self.stepper = explicit;
                self.hold_walls(dt);
                Ok(())
            }
            Stepper::Projection(mut projection) => {
                let projected = self.project(&mut projection, dt);
                self.stepper = Stepper::Projection(projection);
                projected
            }
        }
    }

    /// Step 3 of the projection: boundary conditions on v* (applied by the projection, after
    /// it has taken the walls' flux of v* into the Poisson equation), free surface, Poisson
    /// equation, corrector, pressure to particles; then the rigid bodies' force with the new
    /// pressure, and the wall conditions again (the corrector changed the wall nodes' normal
    /// velocity).
    fn project(&mut self, projection: &mut Projection<D>, dt: f64) -> Result<(), Error> {
        self.timers.lap(Phase::Predictor);
        let projected = projection.project(
            &mut self.particles,
            &mut self.grid,
            &self.boundary,
            dt,
            &mut self.timers,
        );
        // the ghosts go before the sums over the particles below
        if let Some(own) = self.drop_ghosts() {
            projection.ghosts_gone(own);
        }
        projected.map_err(|e| {
            let hint = match e {
                SolveError::NotConverged { .. } => {
                    "raise pressure.max_iterations, or use preconditioner = \"multigrid\" \
                         on a large grid"
                }
                SolveError::Breakdown(_) => {
                    "likely a time step too large for the flow (lower simulation.cfl or \
                         simulation.dt); next to a rigid body, pressure.rigid_faces = \"nodes\" \
                         is the other way to hold its faces"
                }
            };
            Error::BlowUp(format!(
                "run stopped at step {}, t = {:.6} s: {e}. {hint}",
                self.steps + 1,
                self.time
            ))
        })?;
        let pressure = match projection.cell_pressure_force() {
            Some(f) => crate::rigid::PressureForce::Nodal(f),
            None => crate::rigid::PressureForce::Particles {
                particles: &self.particles,
                shape: self.settings.shape,
                pressure: &projection.previous,
                level_set: projection.shared.surface.level_set(),
                kinds: &projection.shared.surface.kinds,
            },
        };
        self.boundary.rigid.end_step(&self.grid, dt, pressure);
        self.boundary.apply(&mut self.grid.velocity_new);
        Ok(())
    }

    /// Step 4: grid -> particles (PIC / FLIP / APIC) and move; the strain rate and APIC's C_p
    /// from node velocities remapped from the particles (MUSL) or from v^{n+1} (USL). A
    /// particle that left the grid stops the run here, before a transfer reads it.
    fn grid_to_particles(&mut self, dt: f64) -> Result<(), Error> {
        // the particles in the inflows' buffers, before the move
        let h = self.grid.geo.h;
        for q in &mut self.boundary.inflows {
            q.mark_buffer(&self.particles, h);
        }
        match self.policy.stress_update {
            StressUpdate::Musl => {
                transfer::grid_to_particles(
                    &mut self.particles,
                    &self.grid,
                    &self.settings,
                    &mut self.work.advect,
                );
                transfer::remap_velocity(
                    &self.particles,
                    &mut self.grid,
                    &mut self.work.p2g,
                    &self.settings,
                    &*self.comm,
                );
                self.boundary.apply(&mut self.grid.velocity_new);
                transfer::gradient_and_move(
                    &mut self.particles,
                    &self.grid,
                    &self.settings,
                    &self.work.advect,
                    dt,
                );
            }
            StressUpdate::Usl => {
                transfer::grid_to_particles_usl(&mut self.particles, &self.grid, &self.settings, dt)
            }
        }
        // the inflows' buffers move at the inflows' velocity
        for q in &self.boundary.inflows {
            q.hold_buffer(&mut self.particles, self.time + dt, dt);
        }
        self.boundary
            .confine(&self.grid.geo, dt, &mut self.particles);
        // the particles the move carried past an outflow face leave the run
        self.drain_outflow();
        self.check_particles()
    }

    /// Step 5: the constitutive update. With volumetric_averaging = "nodal", against locking,
    /// the strain rate's volumetric part before and the pressure after are averaged at the
    /// nodes; under the projection the spray's volumes are held.
    fn update_materials(&mut self, dt: f64) {
        let (geo, shape) = (&self.grid.geo, self.settings.shape);
        if let Some(averaging) = &mut self.averaging {
            averaging.average_strain_rate(&mut self.particles, geo, shape);
        }
        if let Some(projection) = self.stepper.projection() {
            projection.hold_spray_volumes(&mut self.particles, geo);
        }
        material::update(
            &mut self.particles,
            &self.materials,
            dt,
            self.stepper.scheme() == Scheme::Explicit,
        );
        if let Some(averaging) = &mut self.averaging {
            if self.stepper.scheme() == Scheme::Explicit {
                averaging.average_pressure(&mut self.particles, geo, shape);
            }
        }
    }

    /// Step 6: the particles moved back towards their rest volumes (projection), or packed to
    /// rest density (explicit, with `density_correction = "particles"`), at the pace of the
    /// flow (a few corrections per cell crossing).
    fn correct_density(&mut self, dt: f64) -> Result<(), Error> {
        let corrects = match &self.stepper {
            Stepper::Projection(p) => p.corrects_density(),
            Stepper::Explicit(packing) => packing.is_some(),
        };
        let pace = if corrects {
            crate::pressure::density::PositionCorrection::<D>::pace(
                dt,
                self.max_speed(),
                self.settings.gravity.norm(),
                self.grid.geo.h,
            )
        } else {
            crate::pressure::density::Pace::whole(0.0)
        };
        // over ranks, the neighbours' particles next to the cut lent for it, as for the
        // projection
        let explicit = self.stepper.scheme() == Scheme::Explicit;
        if corrects && !(explicit && Packing::<D>::share(pace.packing).is_none()) {
            self.lend_ghosts()?;
        }
        let (ps, geo, boundary) = (&mut self.particles, &self.grid.geo, &self.boundary);
        // the explicit scheme packs a share of the way each step ([`Packing::share`])
        let moved = match &mut self.stepper {
            Stepper::Projection(projection) => projection
                .correct_density(ps, geo, boundary, pace)
                .map(|_| true),
            Stepper::Explicit(Some(packing)) => match Packing::<D>::share(pace.packing) {
                Some(share) => packing.pack(ps, geo, boundary, share).map(|_| true),
                None => Ok(false),
            },
            Stepper::Explicit(None) => Ok(false),
        };
        if let Some(own) = self.drop_ghosts() {
            self.stepper.ghosts_dropped(own);
        }
        let moved = moved.map_err(|e| {
            Error::BlowUp(format!(
                "run stopped at step {}, t = {:.6} s: the density correction: {e}",
                self.steps + 1,
                self.time
            ))
        })?;
        if moved {
            self.boundary
                .confine(&self.grid.geo, dt, &mut self.particles);
            self.drain_outflow();
            // over ranks, a particle moved past its slab's edge goes to the rank that owns
            // it now: the next sums onto the grid reach only the shared layers past the edge
            if corrects {
                self.migrate()?;
            }
            self.timers.lap(Phase::Density);
        }
        Ok(())
    }

    /// Stops the run if a particle's volume ratio J is not positive, left
    /// `simulation.volume_limits` where the deck gives them, or its volume grew past
    /// [`MAX_PARTICLE_CELLS`] cells: its state no longer says anything about the
    /// material, and its volume would go on into the output and the transfers.
    pub fn check_volumes(&self) -> Result<(), Error> {
        match self.comm.agree(self.volume_fault()) {
            Some(message) => Err(Error::BlowUp(message)),
            None => Ok(()),
        }
    }

    /// What [`Simulation::check_volumes`] finds wrong with this rank's particles.
    fn volume_fault(&self) -> Option<String> {
        let limits = self.policy.volume_limits;
        let [lo, hi] = limits.unwrap_or([0.0, f64::INFINITY]);
        let cell = self.grid.geo.h.powi(D as i32);
        let largest = MAX_PARTICLE_CELLS * cell;
        let ps = &self.particles;
        let bad = ps
            .jacobian
            .par_iter()
            .zip(ps.volume0.par_iter())
            .position_first(|(&j, &v0)| !(j > lo && j <= hi && j * v0 <= largest));
        let p = bad?;
        let (j, v0) = (ps.jacobian[p], ps.volume0[p]);
        let parts: Vec<String> = ps.x[p].iter().map(|c| format!("{c:.6}")).collect();
        let what = if j * v0 > largest && j <= hi {
            format!(
                "its volume {:.3e} covers {:.1} cells (at most {} allowed)",
                j * v0,
                j * v0 / cell,
                MAX_PARTICLE_CELLS
            )
        } else if let Some([lo, hi]) = limits {
            format!("J is outside simulation.volume_limits = [{lo}, {hi}]")
        } else {
            "a volume ratio must be positive".to_string()
        };
        let verb = if j < 1.0 { "compressed" } else { "expanded" };
        let cause = match self.stepper.scheme() {
            Scheme::Explicit => format!(
                "the equation of state let it be {verb} that far: a bulk_modulus too low for \
                 the flow's speed, or a step above the stability limit"
            ),
            Scheme::Projection => format!(
                "the projection {verb} it where no pressure equation holds it (against a wall \
                 at an impact, in spray, in a sheet thinner than a cell): refine \
                 grid.cell_size or lower simulation.cfl"
            ),
        };
        Some(format!(
            "run stopped at step {}, t = {:.6} s: particle {} at x = ({}) has a volume ratio \
             J = V / V0 = {j:.4e}; {what}. Likely cause: {cause}",
            self.steps,
            self.time,
            ps.id[p],
            parts.join(", ")
        ))
    }

    /// The body force at each particle, where it varies in space or time.
    pub fn body_force_values(&self) -> Option<&[Vector<D>]> {
        self.body_force.as_ref().map(|(_, f)| &f[..])
    }

    /// The same, to restore it from a checkpoint.
    pub fn body_force_values_mut(&mut self) -> Option<&mut Vec<Vector<D>>> {
        self.body_force.as_mut().map(|(_, f)| f)
    }

    /// Takes out the particles that crossed an outflow face, with every per-particle array of
    /// the step, and counts them out in the ledger.
    fn drain_outflow(&mut self) {
        let outflow: [bool; 6] = std::array::from_fn(|f| f < 2 * D && self.boundary.is_outflow(f));
        let geo = &self.grid.geo;
        if outflow.iter().any(|&o| o)
            && self
                .particles
                .x
                .par_iter()
                .any(|x| has_left(geo, &outflow, x))
        {
            let ps = &self.particles;
            let kept = &mut self.work.kept;
            kept.clear();
            for p in 0..ps.len() {
                if has_left(geo, &outflow, &ps.x[p]) {
                    self.ledger.mass_out += ps.mass[p];
                    self.ledger.volume_out += ps.volume(p);
                } else {
                    kept.push(p as u32);
                }
            }
            let kept = &self.work.kept;
            self.particles.keep(kept);
            crate::particles::keep(&mut self.work.advect, kept);
            if let Some((_, f)) = &mut self.body_force {
                crate::particles::keep(f, kept);
            }
            if let Some(projection) = self.stepper.projection_mut() {
                projection.keep_particles(kept);
            }
        }
    }

    /// Step 7: adds the particles the inflows have room for now.
    fn emit_inflow(&mut self) -> Result<(), Error> {
        if self.boundary.inflows.is_empty() {
            return Ok(());
        }
        let mut entering = std::mem::take(&mut self.work.entering);
        for q in &mut self.boundary.inflows {
            q.emit(&self.particles, self.time, &mut self.ledger, &mut entering);
        }
        if !entering.is_empty() {
            if let Some(projection) = self.stepper.projection_mut() {
                projection.add_particles(&entering);
            }
            self.particles.append(&mut entering);
            self.fit_particle_arrays();
        }
        self.work.entering = entering;
        if self.ledger.next_id == u32::MAX {
            return Err(Error::BlowUp(format!(
                "run stopped at t = {:.6} s: the inflows have given out {} particle ids, the most pmpm numbers; use a larger cell_size or fewer particles_per_cell",
                self.time,
                u32::MAX
            )));
        }
        Ok(())
    }

    /// Sizes the step's per-particle arrays to the particles (after particles entered, or a
    /// resume from a checkpoint with another count): the body force evaluated at the new ones.
    pub fn fit_particle_arrays(&mut self) {
        let n = self.particles.len();
        self.work.advect.resize(n, Vector::<D>::zeros());
        if let Some((field, f)) = &mut self.body_force {
            let (from, t) = (f.len().min(n), self.time);
            f.truncate(n);
            f.extend(self.particles.x[from..].iter().map(|x| field.eval(x, t)));
        }
        if let Some(projection) = self.stepper.projection_mut() {
            projection.fit_particles(n);
        }
    }

    /// Reorders the particles and every per-particle array of the step by cell (a stable
    /// counting sort, so the order depends only on the positions, not on the threads).
    pub fn sort_particles(&mut self) {
        self.work.sort_bins.sort(&self.grid.geo, &self.particles.x);
        let order = &self.work.sort_bins.order;
        let scratch = &mut self.work.sort_scratch;
        self.particles.permute(order, scratch);
        crate::particles::permute(&mut self.work.advect, order, scratch);
        if let Some((_, f)) = &mut self.body_force {
            crate::particles::permute(f, order, scratch);
        }
        if let Some(projection) = self.stepper.projection_mut() {
            projection.permute_particles(order, scratch);
        }
    }

    /// P2G of the current particles, and the probes sampled from it (also used without a step,
    /// for the final state's probe row).
    pub fn particles_to_grid(&mut self) {
        if let Some((field, f)) = &mut self.body_force {
            let t = self.time;
            f.par_iter_mut()
                .zip(self.particles.x.par_iter())
                .for_each(|(f, x)| *f = field.eval(x, t));
        }
        // wall velocities given by expressions, at the step's time
        self.boundary.set_time(self.time, &self.grid.geo);
        transfer::particles_to_grid(
            &self.particles,
            &mut self.grid,
            &mut self.work.p2g,
            &self.settings,
            (
                &self.materials,
                self.body_force.as_ref().map(|(_, f)| &f[..]),
            ),
            &*self.comm,
        );
        self.sample_probes();
    }

    /// Grid fields at the probes: pressure and velocity interpolated from the nodes that have
    /// mass, normalised by their weight (so a probe on a wall or at the surface reads the fluid).
    fn sample_probes(&mut self) {
        let geo = &self.grid.geo;
        for (k, x) in self.probes.positions.iter().enumerate() {
            if let Some(r) = self.probes.radius[k] {
                let ps = &self.particles;
                let (m, q) = ps.hat_mean(x, r, |p| {
                    let mut q = Vector::<D>::zeros();
                    q[0] = ps.pressure[p];
                    q
                });
                let (_, v) = ps.hat_mean(x, r, |p| ps.v[p]);
                let (m, [q, v]) = global_means(&*self.comm, m, [q, v]);
                let out = &mut self.probes.values[k * (D + 1)..(k + 1) * (D + 1)];
                out[0] = if m > 0.0 { q[0] } else { 0.0 };
                for d in 0..D {
                    out[1 + d] = if m > 0.0 { v[d] } else { 0.0 };
                }
                continue;
            }
            let st = Stencil::<D>::new(self.settings.shape, &geo.to_cells(x), geo.h, 0.25);
            let (mut wsum, mut p, mut v) = (0.0, 0.0, Vector::<D>::zeros());
            st.for_each(|nw| {
                let i = geo.flat(&nw.node);
                if self.grid.mass[i] > self.settings.mass_epsilon {
                    wsum += nw.n;
                    p += nw.n * self.grid.pressure[i];
                    v += self.grid.velocity[i] * nw.n;
                }
            });
            let out = &mut self.probes.values[k * (D + 1)..(k + 1) * (D + 1)];
            if wsum > 0.0 {
                out[0] = p / wsum;
                for d in 0..D {
                    out[1 + d] = v[d] / wsum;
                }
            } else {
                out.fill(0.0);
            }
        }
        self.share_probes();
    }

    /// Over ranks with the grid in slabs, each probe as the rank that holds its slab sampled
    /// it (the nodes about it are whole there), and rank 0's means of the particles (the same
    /// on every rank), on every rank.
    fn share_probes(&mut self) {
        let Some(d) = self
            .decomposition
            .as_ref()
            .filter(|_| self.comm.is_distributed())
        else {
            return;
        };
        let (rank, geo) = (self.comm.rank(), &self.grid.geo);
        for (k, x) in self.probes.positions.iter().enumerate() {
            let mine = match self.probes.radius[k] {
                Some(_) => rank == 0,
                None => d.owner_of(geo, x) == rank,
            };
            if !mine {
                self.probes.values[k * (D + 1)..(k + 1) * (D + 1)].fill(0.0);
            }
        }
        self.comm.sum(&mut self.probes.values);
    }

    /// Largest stable step now: cfl h / max(|v| + c), with c the sound speed (explicit) or a
    /// solid's shear wave speed (projection, 0 for a fluid), bounded by cfl sqrt(h / |g|), the
    /// viscous limit and `max_dt`.
    pub fn stable_dt(&self, cfl: f64) -> f64 {
        let explicit = self.stepper.scheme() == Scheme::Explicit;
        let mats = &self.materials;
        let ps = &self.particles;
        let speed =
            ps.v.par_iter()
                .zip(ps.material.par_iter())
                .map(|(v, &m)| v.norm() + mats[m as usize].wave_speed(explicit))
                .reduce(|| 0.0, f64::max);
        let speed = self.comm.max_scalar(speed);
        // a moving wall or body sets the speed of the flow it drives from the first step
        let speed = speed.max(self.boundary.max_wall_speed());
        let h = self.grid.geo.h;
        let mut dt = if speed > 0.0 {
            cfl * h / speed
        } else {
            f64::INFINITY
        };
        // body-force limit: a particle starting from rest moves at most cfl h in a step
        // (|g| dt^2 <= cfl^2 h); it sets the first steps of a flow starting at rest
        let g = self.body_acceleration();
        if g > 0.0 {
            dt = dt.min(cfl * (h / g).sqrt());
        }
        let implicit = self.settings.implicit_stress;
        for (k, m) in mats.iter().enumerate() {
            if !in_mask(implicit, k) {
                dt = dt.min(m.viscous_dt_limit(h, D));
            }
        }
        if implicit != 0 {
            dt = dt.min(self.strain_limit(cfl, dt));
        }
        if let Some(max) = self.policy.max_dt {
            dt = dt.min(max);
        }
        dt
    }

    /// The step limit that replaces the viscous one where the implicit solve lifted it: a
    /// particle is sheared by at most `cfl` in a step, cfl / max gamma_p with gamma =
    /// sqrt(2 dev D : dev D), over the particles of the materials whose explicit viscous limit
    /// is below `dt`. The viscosity is lagged from the last step's strain rate, so a step that
    /// strains a particle by more than that lets a yield-stress fluid yield or stop a step late,
    /// and the particles' volume ratios drift with the square of the strain per step
    /// (docs/method.md, "The time step"). Water's viscous limit is seconds long and never
    /// reaches this.
    fn strain_limit(&self, cfl: f64, dt: f64) -> f64 {
        let h = self.grid.geo.h;
        let implicit = self.settings.implicit_stress;
        let stiff = self
            .materials
            .iter()
            .enumerate()
            .take(64)
            .filter(|(k, m)| in_mask(implicit, *k) && m.viscous_dt_limit(h, D) < dt)
            .fold(0u64, |mask, (k, _)| mask | 1 << k);
        if stiff == 0 {
            return f64::INFINITY;
        }
        let ps = &self.particles;
        let gamma = ps
            .velocity_gradient
            .par_iter()
            .zip(ps.material.par_iter())
            .filter(|(_, &m)| in_mask(stiff, m.into()))
            .map(|(l, _)| {
                let dev = material::deviatoric_strain_rate(l);
                (2.0 * dev.norm_squared()).sqrt()
            })
            .reduce(|| 0.0, f64::max);
        let gamma = self.comm.max_scalar(gamma);
        if gamma > 0.0 {
            cfl / gamma
        } else {
            f64::INFINITY
        }
    }

    /// Pressure iterations of the last step, summed over its passes (0 for the explicit
    /// scheme).
    pub fn pressure_iterations(&self) -> usize {
        self.stepper
            .projection()
            .map_or(0, |p| p.last.stats.iterations)
    }

    /// Stops the run if a particle left the grid or has a non-finite position or velocity
    /// (on any rank; every rank stops with the message of the first rank that found one).
    pub fn check_particles(&self) -> Result<(), Error> {
        match self.comm.agree(self.particle_fault()) {
            Some(message) => Err(Error::BlowUp(message)),
            None => Ok(()),
        }
    }

    /// What [`Simulation::check_particles`] finds wrong with this rank's particles.
    fn particle_fault(&self) -> Option<String> {
        let geo = &self.grid.geo;
        let bad = self
            .particles
            .x
            .par_iter()
            .zip(self.particles.v.par_iter())
            .position_first(|(x, v)| {
                !(geo.contains(x) && x.iter().chain(v.iter()).all(|c| c.is_finite()))
            });
        let p = bad?;
        let x = self.particles.x[p];
        let v = self.particles.v[p];
        let fmt = |a: &Vector<D>| {
            let parts: Vec<String> = a.iter().map(|c| format!("{c:.6}")).collect();
            format!("({})", parts.join(", "))
        };
        let what = if x.iter().chain(v.iter()).all(|c| c.is_finite()) {
            format!(
                "particle {} left the grid [{}, {}] at x = {}, v = {} m/s",
                self.particles.id[p],
                fmt(&geo.origin),
                fmt(&geo.upper()),
                fmt(&x),
                fmt(&v)
            )
        } else {
            format!(
                "particle {} has a non-finite state (x = {}, v = {})",
                self.particles.id[p],
                fmt(&x),
                fmt(&v)
            )
        };
        let mut cause = String::from(
            "likely causes: a time step above the stability limit, an \"open\" face material can \
             flow through, or a body pushed out by its initial velocity",
        );
        // (the limit is a collective: not where only this rank has found the particle)
        if let Some(dt) = self.policy.dt.filter(|_| !self.comm.is_distributed()) {
            let limit = match self.stepper.scheme() {
                Scheme::Explicit => "h / max(|v| + c)",
                Scheme::Projection => "h / max |v|",
            };
            cause = format!(
                "{cause}; the fixed dt = {dt:.3e} s against the limit now {limit} = {:.3e} s \
                 (or give simulation.cfl instead of dt)",
                self.stable_dt(1.0)
            );
        }
        Some(format!(
            "run stopped at step {}, t = {:.6} s: {what}. {cause}",
            self.steps, self.time
        ))
    }

    /// Total kinetic energy sum m v^2 / 2, summed in a fixed order (over every rank).
    pub fn kinetic_energy(&self) -> f64 {
        let e = self
            .particles
            .v
            .iter()
            .zip(&self.particles.mass)
            .map(|(v, m)| 0.5 * m * v.norm_squared())
            .sum();
        self.comm.sum_scalar(e)
    }

    /// Largest particle speed (over every rank).
    pub fn max_speed(&self) -> f64 {
        let v = self
            .particles
            .v
            .par_iter()
            .map(|v| v.norm())
            .reduce(|| 0.0, f64::max);
        self.comm.max_scalar(v)
    }
}

/// The share of a full node's mass (the lightest material's density times h^D) below which
/// the projection's predictor divides a node's internal force by that share instead of by
/// the node's own mass ([`Grid::predict`]).
pub(crate) const LIGHT_NODE: f64 = 0.1;

/// Means from a rank's weight sum `m` and its means `q` over its particles (as
/// [`Particles::hat_mean`] gives them), over every rank's particles: the mass-weighted sums
/// added up, then divided.
fn global_means<const D: usize, const K: usize>(
    comm: &dyn Comm,
    m: f64,
    q: [Vector<D>; K],
) -> (f64, [Vector<D>; K]) {
    if !comm.is_distributed() {
        return (m, q);
    }
    // on the stack: no allocation in the step (K D <= 6: a value and a velocity in 3D)
    let mut all = [0.0; 1 + 2 * 3];
    let sums = &mut all[..1 + K * D];
    sums[0] = m;
    for (k, q) in q.iter().enumerate() {
        for d in 0..D {
            sums[1 + k * D + d] = q[d] * m;
        }
    }
    comm.sum(sums);
    let m = sums[0];
    let means = std::array::from_fn(|k| {
        let s = Vector::<D>::from_fn(|d, _| sums[1 + k * D + d]);
        if m > 0.0 {
            s / m
        } else {
            s
        }
    });
    (m, means)
}

/// The least density m_p / V0_p of the particles.
pub(crate) fn least_density<const D: usize>(ps: &Particles<D>) -> f64 {
    ps.mass
        .iter()
        .zip(&ps.volume0)
        .map(|(m, v)| m / v)
        .fold(f64::INFINITY, f64::min)
}

impl<const D: usize> Grid<D> {
    /// Predictor on the nodes: v* = v^n / (1 + dt c_i) + dt f / m, zero on empty nodes, with
    /// c_i = damping + the damping zones' rate at the node (the `damping` module).
    /// The damping acts on the velocity the node has (implicitly, so it is stable for any
    /// coefficient), not on the step's force: damping the force too, (v^n + dt f / m) /
    /// (1 + dt damping), made a column at rest under the projection carry only
    /// 1 / (1 + dt damping) of its weight, since the
    /// projection balances v*, not a force.
    ///
    /// A node lighter than `mass_floor` takes its internal force over `mass_floor`:
    /// v* = v^n / (1 + dt damping) + dt (f_body / m + f_int / mass_floor). A node that a
    /// particle reaches only with the edge of its shape function has m_i = m_p N_ip, however
    /// small, while the linear shape's gradient in f_int = -sum_p V_p tau_p grad N_ip is whole:
    /// f_int / m_i grows as 1 / N_ip. The projection reads v* at the cells' quadrature points,
    /// by geometry and not by mass, so such a node's v* enters the Poisson equation in full
    /// (in a two-fluid column a node of 1e-4 of a full node's mass took 4.7 m/s, the solve
    /// answered with 3.6 kPa a quarter of a cell below the surface, and a particle left at
    /// 4 m/s). The body force is a force per unit mass and stays whole.
    pub fn predict(&mut self, dt: f64, damping: f64, mass_epsilon: f64, mass_floor: f64) {
        let zones = &self.damping;
        (
            self.velocity_new.par_iter_mut(),
            self.velocity.par_iter(),
            self.force.par_iter(),
            self.body.par_iter(),
            self.mass.par_iter(),
        )
            .into_par_iter()
            .enumerate()
            .for_each(|(i, (vn, v, f, b, &m))| {
                let rate = damping + zones.get(i).copied().unwrap_or(0.0);
                let scale = 1.0 / (1.0 + dt * rate);
                let v_star = if m >= mass_floor && m > mass_epsilon {
                    v * scale + f * (dt / m)
                } else if m > mass_epsilon {
                    v * scale + b * (dt / m) + (f - b) * (dt / mass_floor)
                } else {
                    Vector::<D>::zeros()
                };
                crate::pages::store(vn, v_star);
            });
    }
}
