//! A run spread over ranks (MPI processes): each rank builds, steps and writes its own share
//! of the particles (docs/distributed.md).
//!
//! The grid is cut into slabs, one a rank ([`crate::slabs`]): each rank holds the particles of
//! its slab and the nodes they reach, and neighbours swap the node layers they share after
//! every sum of particles onto the grid. Where the grid is too short for as many slabs, every
//! rank holds the whole grid instead and every such sum is added up over all of it
//! ([`crate::comm::Comm::sum`]); each rank then holds an equal share of the particles by id,
//! in cell order (the explicit scheme without implicit viscosity only). Under the projection
//! each rank also sees a window of its neighbours' slabs (their particles near the cut, lent
//! as ghosts, and their node sums: [`crate::slabs::Decomposition::window`]), runs the
//! projection's stages on its slab, and the pressure solves are spread
//! (`pressure::ranks`, [`crate::linalg::spread`]).
//!
//! Each rank builds only its own particles ([`build`]), and writes them: its piece of a frame
//! and of a checkpoint (`run`, [`crate::output::write_parts`], [`crate::checkpoint::Pieces`]).
//! Rank 0 writes the rest, with figures and gauges summed over the ranks. Only a frame of the
//! grid's nodes still reads every particle on rank 0, which for that moment is the run on one
//! process ([`gathered`]).

use crate::comm::{self, Comm};
use crate::deck::Deck;
use crate::error::Error;
use crate::particles::{FlatParticles, Particles};
use crate::pressure::DensityCorrection;
use crate::scheme::Simulation;
use crate::slabs::{Counts, Decomposition};
use std::sync::Arc;

/// The first deck setting that this stage of the distributed run does not support, as the
/// deck's key and what it is set to; `None` where the run can be spread over ranks.
pub fn unsupported<const D: usize>(sim: &Simulation<D>) -> Option<&'static str> {
    sim.unsupported_distributed()
}

/// Refuses, with the deck's key, a run over `size` ranks that this stage does not support.
pub fn check<const D: usize>(sim: &Simulation<D>, size: usize) -> Result<(), Error> {
    if let Some(key) = unsupported(sim) {
        let (key, value) = match key.split_once(" = ") {
            Some((key, value)) => (key, format!("{value} is")),
            None => (key, "it is".to_string()),
        };
        return Err(Error::Unsupported {
            file: String::new(),
            key: key.to_string(),
            message: format!(
                "{value} not supported yet in a run over {} MPI ranks (not yet spread: outflow \
                 faces, inflows, body-force fields, the cell pressure unknowns, the direct \
                 solver and the ic0 preconditioner; docs/distributed.md). Run it on one process (without mpirun), or change the \
                 key",
                size
            ),
        });
    }
    Ok(())
}

/// Builds this rank's part of the deck's simulation, and how the grid is cut: the cut is
/// planned from the seeding's particles counted per cell layer (every rank counts them all
/// without keeping them, the same counts on each), and each rank then builds only the
/// particles of its slab ([`Simulation::new_part`]); where the grid is too short for the
/// slabs (`None`), an equal share of the particles by id. No rank holds every particle. On
/// one process, [`Simulation::new`].
pub fn build<const D: usize>(
    deck: &Deck,
    comm: &dyn Comm,
) -> Result<(Simulation<D>, Option<Decomposition>), Error> {
    if !comm.is_distributed() {
        return Ok((Simulation::new(deck)?, None));
    }
    let geo = crate::build::grid_geometry::<D>(deck);
    let mut counts = Counts::default();
    counts.reset(&geo);
    crate::build::part(deck, &geo, &mut |_, x| {
        counts.add(&geo, x);
        false
    })?;
    let plan = Decomposition::plan(&geo, &counts, comm.size(), window_of(deck));
    let rank = comm.rank();
    let share = comm::share(counts.total() as usize, rank, comm.size());
    let sim = Simulation::new_part(deck, comm, &mut |id, x| match &plan {
        Some(d) => d.owner_of(&geo, x) == rank,
        None => share.contains(&(id as usize)),
    })?;
    Ok((sim, plan))
}

/// Which particles a rank holds when the run is spread ([`distribute`]).
pub enum Held {
    /// Its own, as [`build`] built them, and the cut it built them for.
    Fresh(Option<Decomposition>),
    /// Its own, as a checkpoint gave them (its piece, in order, of a run over as many ranks;
    /// or its share of every piece, cut anew, of a run over another number), and their cut.
    Own(Option<Decomposition>),
    /// Every particle of the run, as a checkpoint holds them (rank 0's, then rank 1's, ...).
    Every,
}

/// Makes `sim` a rank of a distributed run over `comm` ([`check`] first), holding the
/// particles of its slab. A fresh run's particles ([`Held::Fresh`]) are put in cell order; a
/// rank resumed from its own piece ([`Held::Own`]) keeps its particles in their order, so
/// that the run goes on bit for bit; of every particle ([`Held::Every`]: a checkpoint of
/// another rank count) each rank keeps those of its slab (`slabs_for`), or without slabs an
/// equal contiguous share.
pub fn distribute<const D: usize>(
    sim: &mut Simulation<D>,
    comm: Arc<dyn Comm>,
    held: Held,
) -> Result<(), Error> {
    if !comm.is_distributed() {
        sim.decomposition = None;
        sim.set_comm(comm);
        return Ok(());
    }
    check(sim, comm.size())?;
    let plan = match held {
        Held::Fresh(plan) => {
            sim.sort_particles();
            plan
        }
        Held::Own(plan) => plan,
        Held::Every => {
            let plan = slabs_for(sim, comm.size());
            let (rank, size) = (comm.rank(), comm.size());
            let kept: Vec<u32> = match &plan {
                Some(d) => {
                    let geo = &sim.grid.geo;
                    (0..sim.particles.len())
                        .filter(|&p| d.owner_of(geo, &sim.particles.x[p]) == rank)
                        .map(|p| p as u32)
                        .collect()
                }
                None => {
                    let range = comm::share(sim.particles.len(), rank, size);
                    (range.start as u32..range.end as u32).collect()
                }
            };
            sim.particles.keep(&kept);
            sim.particles.shrink_to_fit();
            plan
        }
    };
    match plan {
        Some(d) => sim.cut_into_slabs(comm, d),
        None if needs_slabs(sim) => return Err(too_short(sim, comm.size())),
        None => {
            sim.decomposition = None;
            sim.set_comm(comm);
        }
    }
    sim.fit_particle_arrays();
    Ok(())
}

/// Whether a run over ranks needs its grid cut into slabs (the projection's window, the
/// packing's, the implicit viscosity's sums): it cannot fall back on every rank holding the
/// whole grid.
fn needs_slabs<const D: usize>(sim: &Simulation<D>) -> bool {
    sim.window() > 0 || sim.viscosity.is_some()
}

/// Refuses, before anything is written, a fresh run over `size` ranks whose grid is too short
/// for the slabs it needs (`plan`, the cut [`build`] planned).
pub fn check_plan<const D: usize>(
    sim: &Simulation<D>,
    plan: &Option<Decomposition>,
    size: usize,
) -> Result<(), Error> {
    match plan {
        None if size > 1 && needs_slabs(sim) => Err(too_short(sim, size)),
        _ => Ok(()),
    }
}

/// The refusal of a run over `size` ranks on a grid too short for its slabs, with the most
/// ranks it takes.
fn too_short<const D: usize>(sim: &Simulation<D>, size: usize) -> Error {
    let geo = &sim.grid.geo;
    let axes = (0..D).filter(|&a| !geo.periodic[a]);
    let layers = axes.map(|a| geo.nodes[a]).max().unwrap_or(0);
    let least = crate::slabs::least_width(sim.window());
    let explicit = sim.stepper.scheme() == crate::scheme::Scheme::Explicit;
    let wide = format!(
        "(its slabs as wide as the larger of pressure.bubble_cells and {}, with this shape \
         function)",
        sim.reach()
    );
    let (key, what) = match (sim.window() > 0, explicit) {
        (true, false) => ("simulation.scheme", format!("\"projection\" {wide}")),
        (true, true) => (
            "pressure.density_correction",
            format!("\"particles\" {wide}"),
        ),
        (false, _) => ("simulation.viscosity", "\"implicit\"".to_string()),
    };
    Error::Unsupported {
        file: String::new(),
        key: key.into(),
        message: format!(
            "{what} over {size} MPI ranks needs the grid cut into slabs along an axis that is \
             not periodic, at least {least} cell layers each, and this grid's longest has \
             {layers} with its padding: run it on at most {} ranks",
            (layers / least).max(1)
        ),
    }
}

/// The window past its slab that each rank of the deck's run sees
/// ([`Decomposition::window`]), and the reach of its stages within it
/// ([`Decomposition::reach`]): the projection's, and the explicit scheme's where it packs the
/// particles (`density_correction = "particles"`: the same free surface and solve); 0 for
/// the explicit scheme otherwise.
pub fn window_of(deck: &Deck) -> (usize, usize) {
    let packs = deck.pressure.density_correction == Some(DensityCorrection::Particles);
    let shape = deck.simulation.shape_function;
    match deck.simulation.scheme {
        crate::scheme::Scheme::Explicit if !packs => (0, 0),
        _ => (
            crate::slabs::window_of(deck.pressure.bubble_cells, shape),
            crate::slabs::projection_reach(shape),
        ),
    }
}

/// How the grid of `sim` is cut over `size` ranks: the checkpoint's cuts where it was cut
/// for as many ranks (so that each rank takes back its particles, in their order), else the
/// best cut of its particles ([`Decomposition::plan`]); `None` where the grid is too short
/// along every axis that is not periodic for `size` slabs (every rank then holds the whole
/// grid).
fn slabs_for<const D: usize>(sim: &Simulation<D>, size: usize) -> Option<Decomposition> {
    let geo = &sim.grid.geo;
    if let Some(d) = sim.decomposition.as_ref().filter(|d| d.fits(geo, size)) {
        return Some(d.clone());
    }
    let mut counts = Counts::default();
    // (every rank holds every particle here: counted on one)
    counts.of(&comm::Serial, geo, &sim.particles.x);
    Decomposition::plan(geo, &counts, size, (sim.window(), sim.reach()))
}

/// How `sim`'s run is spread over its ranks, in words (for the line a run starts with);
/// `None` on one process.
pub fn describe<const D: usize>(sim: &Simulation<D>) -> Option<String> {
    let ranks = sim.comm.size();
    if ranks < 2 {
        return None;
    }
    Some(match &sim.decomposition {
        Some(d) => {
            let geo = &sim.grid.geo;
            let at: Vec<String> = d.cuts[1..ranks]
                .iter()
                .map(|&c| {
                    let x = geo.origin[d.axis] + (c as f64 - crate::shape::PAD as f64) * geo.h;
                    format!("{x:.4}")
                })
                .collect();
            format!(
                "over {ranks} MPI ranks: the grid in slabs along {}, cut at {} = {} m \
                 (cut again as the particles move)",
                AXES[d.axis],
                AXES[d.axis],
                at.join(", ")
            )
        }
        None => format!(
            "over {ranks} MPI ranks: the whole grid on each (it has fewer than {} cell layers a \
             rank along every axis that is not periodic)",
            crate::slabs::MIN_WIDTH
        ),
    })
}

/// The axes' names.
const AXES: [&str; 3] = ["x", "y", "z"];

/// Runs `write` on rank 0, and where it reads the particles (`due`) with every rank's
/// particles in `sim` (in rank order) and the run on one process ([`comm::Serial`]), then
/// gives rank 0 its own particles and the ranks back; on the other ranks `write` is not run.
/// Each rank sends its particles to rank 0 in one message, and rank 0 appends them to its
/// own one rank at a time, so that beside every particle it holds one rank's bytes at most.
/// Every rank calls it at the same point of the run, with the same `due`. Rank 0's result is
/// every rank's: a write that failed there stops them all.
pub fn gathered<const D: usize>(
    sim: &mut Simulation<D>,
    due: bool,
    write: impl FnOnce(&mut Simulation<D>) -> Result<(), Error>,
) -> Result<(), Error> {
    let comm = sim.comm.0.clone();
    if !comm.is_distributed() {
        return write(sim);
    }
    if !due {
        // (rank 0 alone, on one process too: a collective there would wait for ever)
        let result = if comm.is_root() {
            sim.set_comm(comm::serial());
            let result = write(sim);
            sim.set_comm(comm.clone());
            result
        } else {
            Ok(())
        };
        return agree_on_root(&*comm, result);
    }
    // one message carries at most 2 GiB (MPI's counts are 32-bit): refused on every rank alike
    let mine = (!comm.is_root()).then(|| {
        postcard::to_stdvec(&sim.particles.flat_view())
            .expect("the particles' flat form serialises: plain numbers and vectors")
    });
    let own = sim.particles.len();
    let total = comm.sum_scalar(own as f64) as usize;
    let largest = comm.max_scalar(mine.as_ref().map_or(0, Vec::len) as f64);
    if largest > i32::MAX as f64 {
        return Err(Error::Usage(format!(
            "a rank's particles are {:.1} GB, more than it can send rank 0 in one piece (2 GiB) \
             to write a frame of the grid's nodes in this stage of the distributed run \
             (docs/distributed.md): run them over more ranks",
            largest / 1e9
        )));
    }
    if let Some(mine) = mine {
        comm.send_bytes(0, &mine);
        return agree_on_root(&*comm, Ok(()));
    }
    // rank 0: its own particles first, then each rank's as it arrives (one rank's bytes held
    // at a time), into arrays sized once for all of them
    sim.particles.reserve(total - own);
    for rank in 1..comm.size() {
        let bytes = comm.receive_bytes(rank);
        let flat: FlatParticles<D> = postcard::from_bytes(&bytes)
            .expect("the bytes of a rank's particles, as that rank wrote them");
        drop(bytes);
        let mut piece = Particles::unflatten(&flat);
        drop(flat);
        piece.stored = sim.particles.stored;
        sim.particles.append(&mut piece);
    }
    sim.set_comm(comm::serial());
    let result = write(sim);
    sim.set_comm(comm.clone());
    // the writers read the particles and keep their order: rank 0's own are the first
    debug_assert_eq!(sim.particles.len(), total, "the writers keep the particles");
    sim.particles.truncate(own);
    sim.particles.shrink_to_fit();
    agree_on_root(&*comm, result)
}

/// Rank 0's `result` on every rank, with its exit status (what the others pass is not read:
/// their errors are rank 0's, or they have none).
pub(crate) fn agree_on_root(comm: &dyn Comm, result: Result<(), Error>) -> Result<(), Error> {
    if !comm.is_distributed() {
        return result;
    }
    let mut failed = match (&result, comm.is_root()) {
        (Err(e), true) => error_bytes(e),
        _ => Vec::new(),
    };
    comm.broadcast(&mut failed);
    if comm.is_root() || failed.is_empty() {
        return if comm.is_root() { result } else { Ok(()) };
    }
    Err(error_from_bytes(&failed))
}

/// An error as another rank can rebuild it ([`error_from_bytes`]): its exit status, then its
/// message.
pub(crate) fn error_bytes(e: &Error) -> Vec<u8> {
    let mut bytes = vec![e.exit_code()];
    bytes.extend_from_slice(e.to_string().as_bytes());
    bytes
}

/// The error of [`error_bytes`], of a kind with the same exit status (the other ranks do not
/// print it: rank 0 speaks for the run).
pub(crate) fn error_from_bytes(bytes: &[u8]) -> Error {
    let message = String::from_utf8_lossy(&bytes[1..]).into_owned();
    match bytes[0] {
        1 => Error::Io {
            path: "rank 0".to_string(),
            source: std::io::Error::other(message),
        },
        3 => Error::BlowUp(message),
        130 => Error::Interrupted(message),
        _ => Error::Usage(message),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comm::threads;
    use crate::driver::{Clock, Driver, StepSize};

    /// The run of the deck `text` to `end` over `ranks` ranks (threads): each particle's id
    /// with its position, velocity and pressure, in id order; the pressure iterations of each
    /// step; and the rigid bodies' force.
    type Outcome = (Vec<(u32, Vec<f64>)>, Vec<usize>, Vec<f64>);

    fn run_over<const D: usize>(ranks: usize, text: &str, end: f64) -> Outcome {
        let out = threads::run(ranks, |comm| {
            let mut deck = Deck::parse(text, "deck.toml").unwrap();
            deck.validate("deck.toml").unwrap();
            let (mut sim, plan) = build::<D>(&deck, &*comm).unwrap();
            distribute(&mut sim, comm, Held::Fresh(plan)).unwrap();
            let step = StepSize::Adaptive {
                cfl: deck.simulation.cfl.unwrap(),
                land_on_frames: true,
            };
            let mut driver = Driver::new(Clock {
                end,
                interval: end,
                step,
            });
            let mut iterations = Vec::new();
            while !driver.finished(&sim) {
                driver.step(&mut sim).unwrap();
                iterations.push(sim.pressure_iterations());
            }
            let ps = &sim.particles;
            let state = (0..ps.len()).map(|p| {
                let (x, v) = (ps.x[p].iter(), ps.v[p].iter());
                let fields = x.chain(v).copied().chain([ps.pressure[p]]);
                (ps.id[p], fields.collect::<Vec<f64>>())
            });
            let rigid = &sim.boundary.rigid;
            let force =
                (0..rigid.len()).flat_map(|b| rigid.force(b).iter().copied().collect::<Vec<_>>());
            (
                state.collect::<Vec<_>>(),
                iterations,
                force.collect::<Vec<f64>>(),
            )
        });
        let (steps, force) = (out[0].1.clone(), out[0].2.clone());
        let mut all: Vec<_> = out.into_iter().flat_map(|(s, _, _)| s).collect();
        all.sort_by_key(|a| a.0);
        (all, steps, force)
    }

    /// Runs the deck to `end` on one rank and on `ranks` (threads), and checks that they take
    /// the same steps and that every particle agrees within `bounds` (position, velocity,
    /// pressure), and the rigid bodies' force within `force` (N).
    fn agrees<const D: usize>(text: &str, end: f64, ranks: &[usize], bounds: [f64; 3], force: f64) {
        let (one, steps, f1) = run_over::<D>(1, text, end);
        assert!(steps.len() > 5, "{} steps", steps.len());
        for &r in ranks {
            let (many, s, f) = run_over::<D>(r, text, end);
            // the same steps, each with the same pressure iterations to within 2 (issue 57)
            assert_eq!(
                s.len(),
                steps.len(),
                "{r} ranks took another number of steps"
            );
            for (k, (a, b)) in steps.iter().zip(&s).enumerate() {
                assert!(
                    a.abs_diff(*b) <= 2,
                    "{r} ranks, step {k}: {b} iterations, not {a}"
                );
            }
            let same = steps.iter().zip(&s).filter(|(a, b)| a == b).count();
            eprintln!(
                "{r} ranks: {same} of {} steps with the same iterations",
                s.len()
            );
            assert_eq!(many.len(), one.len());
            let mut worst = [0.0f64; 3];
            for (a, b) in one.iter().zip(&many) {
                assert_eq!(a.0, b.0);
                for (k, (x, y)) in a.1.iter().zip(&b.1).enumerate() {
                    let kind = if k < D {
                        0
                    } else if k < 2 * D {
                        1
                    } else {
                        2
                    };
                    worst[kind] = worst[kind].max((x - y).abs());
                }
            }
            let f_worst = f1
                .iter()
                .zip(&f)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            eprintln!("{r} ranks: largest differences (x, v, p) {worst:?}, force {f_worst:e}");
            for k in 0..3 {
                assert!(
                    worst[k] <= bounds[k],
                    "{r} ranks: {worst:?} past {bounds:?}"
                );
            }
            assert!(f_worst <= force, "{r} ranks: force {f:?} vs {f1:?}");
        }
    }

    // The solves stop at a relative residual of 1e-8, and over ranks their dot products
    // round otherwise: positions to 1e-9 m, velocities to 1e-7 m/s, pressures to 1e-5 Pa
    // (of about 1,000) in the runs below, which agree to round-off (1e-16 m, 1e-12 Pa).

    #[test]
    fn the_projection_dam_break_over_two_and_three_ranks_agrees_with_one() {
        // the shipped deck (the projection, its implicit viscosity and density correction by
        // default), to 0.05 s: the column has started to fall; cut along y
        let text = include_str!("../../../examples/dam_break_2d.toml");
        agrees::<2>(text, 0.05, &[2, 3], [1e-9, 1e-7, 1e-5], 0.0);
    }

    #[test]
    fn a_bingham_slump_cut_along_x_over_two_and_three_ranks_agrees_with_one() {
        // a layer 12 cells deep: the slabs are cut along x
        let text = include_str!("../../../examples/bingham_slump_2d.toml");
        agrees::<2>(text, 0.05, &[2, 3], [1e-9, 1e-7, 1e-5], 0.0);
    }

    #[test]
    fn the_explicit_packing_over_two_and_three_ranks_agrees_with_one() {
        // the explicit dam break with its particles packed (density_correction = "particles"):
        // the packing's free surface and solve run on the window's ghosts, as the projection's
        let plain = include_str!("../../../examples/dam_break_2d_explicit.toml");
        let text = plain.replace(
            "[[materials]]",
            "[pressure]\ndensity_correction = \"particles\"\n\n[[materials]]",
        );
        agrees::<2>(&text, 0.02, &[2, 3], [1e-9, 1e-7, 1e-5], 0.0);
        // (the packing moved the particles: the run without it ends elsewhere)
        let (packed, unpacked) = (
            run_over::<2>(1, &text, 0.02).0,
            run_over::<2>(1, plain, 0.02).0,
        );
        let moved = packed
            .iter()
            .zip(&unpacked)
            .map(|(a, b)| (a.1[0] - b.1[0]).abs());
        assert!(moved.fold(0.0, f64::max) > 1e-5);
    }

    #[test]
    fn the_dam_break_past_its_impact_over_three_ranks_agrees_with_one() {
        // to 0.3 s: the surge has hit the far wall and risen up it, gaps open and close
        // inside the water, and the window (8 layers) is narrower than a gap plus the
        // stages' reach
        let text = include_str!("../../../examples/dam_break_2d.toml");
        agrees::<2>(text, 0.3, &[3], [1e-9, 1e-7, 1e-5], 0.0);
    }

    #[test]
    fn the_dam_break_with_the_particles_as_quadrature_points_over_three_ranks_agrees() {
        // the paper's free surface and quadrature: the Poisson rows sum over the particles
        // themselves, so each rank is lent the whole window's particles as ghosts (with the
        // Gauss points two layers of them do)
        let text = include_str!("../../../examples/dam_break_2d.toml").replace(
            "beta = 0.0 ",
            "beta = 0.0\nquadrature = \"particle\"\nfree_surface = \"volume_fraction\"\n",
        );
        agrees::<2>(&text, 0.05, &[3], [1e-9, 1e-7, 1e-5], 0.0);
    }

    #[test]
    fn a_linear_dam_break_with_the_narrowest_window_over_three_ranks_agrees_with_one() {
        // with bubble_cells = 0 the window is the linear stages' reach alone, 4 layers
        // (`slabs::projection_reach`; with a reach of 2 the dam break past its impact, below,
        // was 3e-5 m and 0.1 Pa off at 0.3 s)
        let text = include_str!("../../../examples/dam_break_2d.toml")
            .replace("beta = 0.0 ", "beta = 0.0\nbubble_cells = 0\n");
        agrees::<2>(&text, 0.2, &[3], [1e-9, 1e-7, 1e-5], 0.0);
    }

    #[test]
    fn a_cubic_dam_break_with_a_narrow_window_over_three_ranks_agrees_with_one() {
        // the cubic B-spline reaches two cells from a particle, and with bubble_cells = 0 the
        // window is 8 layers: a particle the density correction moved past its slab's edge
        // must still add to the nodes it reaches (before it went to its new owner, this run
        // was 2e-8 m and 2e-3 Pa off at 0.2 s)
        let text = include_str!("../../../examples/dam_break_2d.toml")
            .replace(
                "shape_function = \"linear\"",
                "shape_function = \"bspline3\"",
            )
            .replace("beta = 0.0 ", "beta = 0.0\nbubble_cells = 0\n");
        agrees::<2>(&text, 0.2, &[3], [1e-9, 1e-7, 1e-5], 0.0);
    }
}
