//! A run spread over ranks (MPI processes): the particles shared out, and gathered again on
//! rank 0 for what the run writes (docs/distributed.md).
//!
//! This first stage keeps the whole grid on every rank. Each rank holds an equal contiguous
//! share of the particles in cell order (a row-major space-filling curve, weighted by
//! particles) and moves only those; every sum of particles onto the grid is added up over the
//! ranks ([`crate::comm::Comm::sum`]) before it is read, and every rank then does the grid's
//! work on its own copy, with the same bits. The particles' transfers, the constitutive update
//! and the moves, the bulk of the explicit scheme's step, are divided among the ranks; the grid
//! and its memory are not yet (a decomposition of the grid by blocks is the next stage), nor
//! is the projection's pressure solve (its stages read the particles in ways this stage does
//! not yet add up over ranks, and are refused: [`unsupported`]).
//!
//! For the output, rank 0 gathers every rank's particles, in rank order, and for that moment
//! is the run on one process ([`gathered`]): frames, series rows, gauges and checkpoints are
//! those of one process, written by one writer, atomically. A checkpoint is one file, so a run
//! resumes on any number of ranks.

use crate::comm::{self, Comm};
use crate::error::Error;
use crate::particles::{FlatParticles, Particles};
use crate::scheme::Simulation;
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
                "{value} not supported yet in a run over {} MPI ranks (this stage runs the \
                 explicit scheme without outflow faces, inflows, body-force fields, implicit \
                 viscosity or the particles' packing; docs/distributed.md). Run it on one process (without mpirun), or change the key",
                size
            ),
        });
    }
    Ok(())
}

/// Shares the particles of `sim` out among `comm`'s ranks and makes `sim` a rank of a
/// distributed run ([`check`] first). A `fresh` run's particles are put in cell order first,
/// so that each rank's share is a compact piece of the material; a resumed run's are shared
/// in the order its checkpoint holds them (rank 0's, then rank 1's, ...), so that on the
/// same number of ranks each rank takes back the particles it had, in their order, and the
/// run goes on bit for bit.
pub fn distribute<const D: usize>(
    sim: &mut Simulation<D>,
    comm: Arc<dyn Comm>,
    fresh: bool,
) -> Result<(), Error> {
    if !comm.is_distributed() {
        sim.set_comm(comm);
        return Ok(());
    }
    check(sim, comm.size())?;
    if fresh {
        sim.sort_particles();
    }
    let range = comm::share(sim.particles.len(), comm.rank(), comm.size());
    let kept: Vec<u32> = (range.start as u32..range.end as u32).collect();
    sim.particles.keep(&kept);
    sim.particles.shrink_to_fit();
    sim.fit_particle_arrays();
    sim.set_comm(comm);
    Ok(())
}

/// Runs `write` on rank 0, and where it reads the particles (`due`) with every rank's
/// particles in `sim` (in rank order) and the run on one process ([`comm::Serial`]), then
/// gives rank 0 its own particles and the ranks back; on the other ranks `write` is not run.
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
    let mine = postcard::to_stdvec(&sim.particles.flatten())
        .expect("the particles' flat form serialises: plain numbers and vectors");
    // one gather moves at most 2 GiB (MPI's counts are 32-bit): refused on every rank alike
    let total = comm.sum_scalar(mine.len() as f64);
    if total > i32::MAX as f64 {
        return Err(Error::Usage(format!(
            "the particles are {:.1} GB in all, more than rank 0 can gather in one piece (2 GiB) \
             to write a frame or a checkpoint in this stage of the distributed run \
             (docs/distributed.md): run fewer particles over ranks, or on one process",
            total / 1e9
        )));
    }
    let pieces = comm.gather(&mine);
    if comm.is_root() {
        let mut all = Particles::<D> {
            stored: sim.particles.stored,
            ..Particles::default()
        };
        for piece in &pieces {
            let flat: FlatParticles<D> = postcard::from_bytes(piece)
                .expect("the bytes of a rank's particles, as that rank wrote them");
            let mut piece = Particles::unflatten(&flat);
            piece.stored = all.stored;
            all.append(&mut piece);
        }
        let own = std::mem::replace(&mut sim.particles, all);
        sim.set_comm(comm::serial());
        let result = write(sim);
        sim.set_comm(comm.clone());
        sim.particles = own;
        return agree_on_root(&*comm, result);
    }
    agree_on_root(&*comm, Ok(()))
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
