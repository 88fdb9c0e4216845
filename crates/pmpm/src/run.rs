//! The run driver: time-step control, frames and probes, and what happens when a run fails.

use crate::checkpoint::{self, DriverState};
use crate::deck::Deck;
use crate::driver::{next_after, Clock, Driver};
use crate::error::Error;
use crate::output::OutputWriter;
use crate::scheme::Simulation;
use crate::timing::Phase;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// How a run is asked for.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Write into a directory that holds an earlier run.
    pub force: bool,
    /// Stop after this many steps (benchmarks), as if the end time were reached.
    pub max_steps: Option<u64>,
    /// Go on from this checkpoint instead of starting from the deck's initial state.
    pub resume: Option<std::path::PathBuf>,
    /// Set from outside (a signal handler) to stop the run at the end of its current step,
    /// with a frame and a checkpoint written; the run then returns [`Error::Interrupted`].
    pub interrupt: Option<Arc<AtomicBool>>,
    /// The MPI ranks the run is spread over (`mpirun`, the `mpi` feature); one process where
    /// `None` ([`crate::distributed`]).
    pub ranks: Option<crate::comm::Ranks>,
}

/// Where a run is, as its [`Observer`] is told.
#[derive(Debug, Clone, Copy)]
pub struct Status {
    /// Dimension of the run.
    pub dimension: usize,
    /// Simulated time reached (s).
    pub time: f64,
    /// The deck's end time (s).
    pub end_time: f64,
    /// Steps taken, counting those before a resume.
    pub steps: u64,
    /// Steps taken before this run started (a resumed run).
    pub start_steps: u64,
    /// The last step's size (s); 0 before the first step.
    pub dt: f64,
    /// Particles.
    pub particles: usize,
    /// Grid nodes.
    pub nodes: usize,
    /// Frames written so far.
    pub frames: usize,
    /// The largest particle speed (m/s); only filled in for [`Observer::frame_written`].
    pub max_speed: f64,
    /// Pressure iterations of the last step (projection).
    pub pressure_iterations: usize,
    /// Wall-clock seconds since the run started.
    pub wall_seconds: f64,
}

/// What a run tells as it goes: the application draws a progress bar or prints a line per
/// frame; the library itself prints nothing.
pub trait Observer {
    /// Once, before the first step.
    fn started(&mut self, _status: &Status) {}
    /// Once, after [`Observer::started`], for a run over MPI ranks: how it is spread over
    /// them, in words.
    fn spread(&mut self, _how: &str) {}
    /// After every step.
    fn stepped(&mut self, _status: &Status) {}
    /// After every frame written after a step.
    fn frame_written(&mut self, _status: &Status) {}
    /// When the run stops, for whatever reason, before it returns.
    fn stopped(&mut self) {}
}

/// An observer that does nothing.
#[derive(Debug, Default, Clone, Copy)]
pub struct Silent;

impl Observer for Silent {}

/// What a finished run reports.
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// Steps taken.
    pub steps: u64,
    /// Frames written.
    pub frames: usize,
    /// Particles.
    pub particles: usize,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Simulated time reached.
    pub time: f64,
    /// Wall-clock seconds per phase of the step.
    pub timers: crate::timing::PhaseTimers,
    /// Pressure iterations summed over the steps, and the most in one step.
    pub pressure_iterations: (u64, usize),
    /// Peak resident memory of the process (bytes), where the system tells it.
    pub peak_memory: Option<u64>,
    /// The last step's size (s).
    pub last_dt: f64,
}

/// Runs a validated deck into `dir`, generic over the dimension; `file` names the deck in
/// messages and in the resume command.
pub fn run(
    deck: &Deck,
    file: &str,
    dir: &Path,
    opts: &RunOptions,
    observer: &mut dyn Observer,
) -> Result<RunSummary, Error> {
    let result = match deck.simulation.dimension {
        2 => run_dim::<2>(deck, file, dir, opts, observer),
        3 => run_dim::<3>(deck, file, dir, opts, observer),
        d => unreachable!("validated: dimension is 2 or 3, got {d}"),
    };
    observer.stopped();
    result
}

/// The observer's view of `sim`.
fn status<const D: usize>(
    sim: &Simulation<D>,
    end_time: f64,
    start_steps: u64,
    dt: f64,
    frames: usize,
    wall_seconds: f64,
) -> Status {
    Status {
        dimension: D,
        time: sim.time,
        end_time,
        steps: sim.steps,
        start_steps,
        dt,
        particles: sim.particles.len(),
        nodes: sim.grid.geo.node_count(),
        frames,
        max_speed: 0.0,
        pressure_iterations: sim.pressure_iterations(),
        wall_seconds,
    }
}

/// Runs the deck in `D` dimensions: sets up the simulation and its output (or resumes them
/// from a checkpoint), then steps to the end, writing frames, rows and checkpoints as they
/// fall due.
fn run_dim<const D: usize>(
    deck: &Deck,
    file: &str,
    dir: &Path,
    opts: &RunOptions,
    observer: &mut dyn Observer,
) -> Result<RunSummary, Error> {
    let start = Instant::now();
    let comm = opts
        .ranks
        .as_ref()
        .map_or_else(crate::comm::serial, |r| r.0.clone());
    let (mut sim, _lock, mut w, mut driver, mut generation, mut gauges) =
        begin::<D>(deck, file, dir, opts, observer, &comm, start)?;
    let launch = launcher(&*comm);
    let mut last_dt = 0.0;
    sim.timers.lap(Phase::Other);
    let result = loop {
        if driver.finished(&sim) || opts.max_steps.is_some_and(|n| sim.steps >= n) {
            break Ok(());
        }
        let t0 = sim.time;
        let stepped = driver.step(&mut sim);
        let interrupted = comm.any(
            opts.interrupt
                .as_ref()
                .is_some_and(|f| f.load(Ordering::SeqCst)),
        );
        let last = opts.max_steps.is_some_and(|n| sim.steps >= n);
        let end = stepped.as_ref().ok().map(|step| StepEnd {
            scheduled: step.frame,
            last,
            interrupted,
        });
        sim.timers.lap(Phase::Other);
        // what the step brings to write: the ranks' parts of a frame first, then the rest on
        // rank 0, with every rank's particles there where it reads them all
        let due = Due::agreed(&*comm, w.as_ref().map(|w| w.due(t0, &sim, end)));
        let parts = write_parts(deck, dir, &mut sim, (&mut w, &mut gauges), due);
        let written = parts.and_then(|_| {
            crate::distributed::gathered(&mut sim, due.whole, |sim| match &mut w {
                Some(w) => {
                    w.driver.next_frame = driver.next_frame;
                    w.count_iterations(sim);
                    w.step_rows(t0, sim, end.is_some())?;
                    match (end, &stepped) {
                        (Some(end), Ok(step)) => w.after_step(deck, sim, step.dt, end, observer),
                        _ => Ok(()),
                    }
                }
                None => Ok(()),
            })
        });
        // the checkpoint rank 0 found due, written by every rank (its own piece)
        let written = match written {
            Ok(()) if due.checkpoint => {
                write_checkpoint(deck, &mut sim, &mut w, dir, &mut generation)
            }
            written => written,
        };
        if let Err(e) = written {
            break Err(e);
        }
        let step = match stepped {
            Ok(step) => step,
            Err(e) => {
                let resume = resume_command(file, &checkpoint_path(dir), dir, deck, &launch);
                let last = w.as_ref().and_then(|w| w.last_checkpoint);
                break Err(blow_up_hint(e.with_file(file), last, &resume, file));
            }
        };
        last_dt = step.dt;
        sim.timers.lap(Phase::Output);
        if let Some(w) = &w {
            let wall = start.elapsed().as_secs_f64();
            observer.stepped(&w.status(&sim, step.dt, wall));
        }
        if interrupted {
            let resume = resume_command(file, &checkpoint_path(dir), dir, deck, &launch);
            break Err(interrupted_error(&sim, &resume));
        }
    };
    let summary = summary(&sim, &w, start, last_dt);
    let finished = match &mut w {
        Some(w) => w.finish(result, file, dir, deck),
        None => result,
    };
    // rank 0's last flush decides for every rank (their step errors were rank 0's already)
    crate::distributed::agree_on_root(&*comm, finished)?;
    Ok(summary)
}

/// What a step brings to write that reads the particles, as rank 0 finds it
/// ([`Writing::due`]) and every rank learns it ([`Due::agreed`]).
#[derive(Debug, Clone, Copy, Default)]
struct Due {
    /// The frame to write, by its number.
    frame: Option<usize>,
    /// The final state's probe row (a sum of the particles onto the grid first).
    final_probe: bool,
    /// A gauges' row.
    gauges: bool,
    /// A checkpoint (written after the rest).
    checkpoint: bool,
    /// Whether rank 0 reads every particle of a run over ranks: a frame of the grid's nodes.
    whole: bool,
}

impl Due {
    /// Rank 0's `found` on every rank of `comm`.
    fn agreed(comm: &dyn crate::comm::Comm, found: Option<Due>) -> Due {
        if !comm.is_distributed() {
            return found.unwrap_or_default();
        }
        let flag = |b: bool| f64::from(u8::from(b));
        let mut v = found.map_or([0.0; 5], |d| {
            [
                d.frame.map_or(0.0, |n| n as f64 + 1.0),
                flag(d.final_probe),
                flag(d.gauges),
                flag(d.checkpoint),
                flag(d.whole),
            ]
        });
        comm.max(&mut v);
        Due {
            frame: (v[0] > 0.0).then(|| v[0] as usize - 1),
            final_probe: v[1] > 0.0,
            gauges: v[2] > 0.0,
            checkpoint: v[3] > 0.0,
            whole: v[4] > 0.0,
        }
    }
}

/// The gauges, on the ranks that do not write (they read them with rank 0), and a row of
/// their readings.
type Gauges = (Vec<crate::gauges::Gauge>, Vec<f64>);

/// In a run over ranks, what every rank writes of what is `due` before rank 0 writes the
/// rest (every rank calls it; on one process it does nothing): the gauges' readings, the sum
/// onto the grid that the final probe row reads, and each rank's part of the frame's
/// particle files and figures ([`crate::output::write_parts`]), handed to rank 0's output.
fn write_parts<const D: usize>(
    deck: &Deck,
    dir: &Path,
    sim: &mut Simulation<D>,
    (w, gauges): (&mut Option<Writing>, &mut Gauges),
    due: Due,
) -> Result<(), Error> {
    if !sim.comm.0.is_distributed() {
        return Ok(());
    }
    if due.gauges {
        match w {
            Some(w) => w.out.read_gauges(sim),
            None => crate::output::read_gauges(&gauges.0, sim, &mut gauges.1),
        }
    }
    // the final state's probe values, kept for rank 0's row after the step's (the step's
    // values are put back: its row is written first)
    let final_probes = due.final_probe.then(|| {
        let step = sim.probes.values.clone();
        sim.particles_to_grid();
        std::mem::replace(&mut sim.probes.values, step)
    });
    let parts = match due.frame {
        Some(n) => Some(crate::output::write_parts(dir, deck, n, sim)?),
        None => None,
    };
    if let Some(w) = w {
        w.out.parts = parts;
        w.final_probes = final_probes;
    }
    Ok(())
}

/// Writes the checkpoint every rank of the run of `sim` has found due: on one process, the
/// one file; over ranks, each rank but rank 0 its piece first, then (where all of them are
/// written) rank 0 its file, which names them and makes them the checkpoint. `generation`
/// counts the checkpoints written over ranks (their pieces' names alternate with it).
fn write_checkpoint<const D: usize>(
    deck: &Deck,
    sim: &mut Simulation<D>,
    w: &mut Option<Writing>,
    dir: &Path,
    generation: &mut u64,
) -> Result<(), Error> {
    let comm = sim.comm.0.clone();
    if !comm.is_distributed() {
        return w.as_mut().map_or(Ok(()), |w| w.checkpoint(deck, sim, None));
    }
    *generation += 1;
    let rank = comm.rank();
    let failed = (!comm.is_root())
        .then(|| {
            let piece = checkpoint::piece_path(&checkpoint_path(dir), *generation, rank);
            checkpoint::write(&piece, deck, sim, &DriverState::none(), None).err()
        })
        .flatten()
        .map(|e| format!("rank {rank}: {e}"));
    if let Some(message) = comm.agree(failed) {
        return Err(Error::Io {
            path: "a rank's piece of the checkpoint".into(),
            source: std::io::Error::other(message),
        });
    }
    let mut counts = vec![0.0; comm.size()];
    counts[rank] = sim.particles.len() as f64;
    comm.sum(&mut counts);
    let pieces = checkpoint::Pieces {
        generation: *generation,
        counts: counts.iter().map(|&n| n as u64).collect(),
    };
    let written = w
        .as_mut()
        .map_or(Ok(()), |w| w.checkpoint(deck, sim, Some(&pieces)));
    crate::distributed::agree_on_root(&*comm, written)
}

/// The run set up on this rank: its simulation (its own particles; a resumed run's from the
/// checkpoint), and on rank 0 the directory's lock and the output, a fresh run's frame of
/// t = 0 written; the driver's clock set to the next frame; the checkpoints' generation
/// ([`checkpoint::Pieces`]); the gauges the other ranks read with rank 0.
type Begun<const D: usize> = (
    Simulation<D>,
    Option<crate::output::DirectoryLock>,
    Option<Writing>,
    Driver,
    u64,
    Gauges,
);

/// Sets the run up on every rank of `comm` ([`Begun`]); the run began at `start`.
fn begin<const D: usize>(
    deck: &Deck,
    file: &str,
    dir: &Path,
    opts: &RunOptions,
    observer: &mut dyn Observer,
    comm: &Arc<dyn crate::comm::Comm>,
    start: Instant,
) -> Result<Begun<D>, Error> {
    let comm = comm.clone();
    // each rank builds its own particles (on one process, every particle)
    let (mut sim, plan) =
        crate::distributed::build::<D>(deck, &*comm).map_err(|e| e.with_file(file))?;
    if comm.is_distributed() {
        // refused on every rank alike, before rank 0 takes the directory
        crate::distributed::check(&sim, comm.size()).map_err(|e| e.with_file(file))?;
        if opts.resume.is_none() {
            crate::distributed::check_plan(&sim, &plan, comm.size())
                .map_err(|e| e.with_file(file))?;
        }
    }
    let clock = crate::build::clock(deck);
    // rank 0 writes; the directory's lock is held to the run's end, after the output is
    // closed: a second run on it is refused
    let (lock, mut w) = open_on_root(&*comm, || {
        Writing::open(deck, &mut sim, file, dir, opts, &clock, start)
    })?;
    let (driver, resumed) = match &opts.resume {
        Some(path) => {
            // the other ranks read it too (on several machines, from a shared file system),
            // each its own piece where it has one: where one cannot, every rank stops with
            // its message
            let (rank, ranks) = (comm.rank(), comm.size());
            let read = match &w {
                Some(w) => Ok(w.resumed),
                None => checkpoint::read(path, deck, &mut sim, rank, ranks).map(|(_, r)| r),
            };
            let failed = read.as_ref().err().map(|e| e.to_string());
            if let Some(message) = comm.agree(failed) {
                return Err(Error::Usage(message));
            }
            let next = w.as_ref().map_or(0.0, |w| w.driver.next_frame);
            let resumed = read.expect("agreed: every rank read the checkpoint");
            (Driver::resume(clock, comm.max_scalar(next)), resumed)
        }
        None => (Driver::new(clock), checkpoint::Resumed::default()),
    };
    let held = match (&opts.resume, resumed.own) {
        (None, _) => crate::distributed::Held::Fresh(plan),
        (Some(_), true) => crate::distributed::Held::Own(sim.decomposition.clone()),
        (Some(_), false) => crate::distributed::Held::Every,
    };
    crate::distributed::distribute(&mut sim, comm.clone(), held).map_err(|e| e.with_file(file))?;
    // (rank 0's are its output's)
    let mut gauges: Gauges = match &w {
        None if comm.is_distributed() => (deck.gauges(), Vec::new()),
        _ => Default::default(),
    };
    if opts.resume.is_none() {
        let due = Due::agreed(&*comm, w.as_ref().map(|w| w.first_due()));
        write_parts(deck, dir, &mut sim, (&mut w, &mut gauges), due)?;
        crate::distributed::gathered(&mut sim, due.whole, |sim| match &mut w {
            Some(w) => w
                .out
                .first_frame(sim)
                .map_err(|e| write_failure_hint(e, None, "")),
            None => Ok(()),
        })?;
    }
    let particles = comm.sum_scalar(sim.particles.len() as f64) as usize;
    if let Some(w) = &mut w {
        let mut status = w.status(&sim, 0.0, 0.0);
        status.particles = particles;
        observer.started(&status);
        if let Some(how) = crate::distributed::describe(&sim) {
            observer.spread(&how);
        }
        w.driver.next_frame = driver.next_frame;
    }
    Ok((sim, lock, w, driver, resumed.generation, gauges))
}

/// The run's output, opened on rank 0 by `open` ([`Writing::open`]; a resumed run reads its
/// checkpoint there); every rank learns whether it opened, and stops with rank 0's error
/// where it did not.
fn open_on_root(
    comm: &dyn crate::comm::Comm,
    open: impl FnOnce() -> Result<(crate::output::DirectoryLock, Writing), Error>,
) -> Result<(Option<crate::output::DirectoryLock>, Option<Writing>), Error> {
    let opened = if comm.is_root() {
        open()
    } else {
        Err(Error::Usage(String::new()))
    };
    if !comm.is_distributed() {
        let (lock, w) = opened?;
        return Ok((Some(lock), Some(w)));
    }
    let mut message = match &opened {
        Err(e) if comm.is_root() => crate::distributed::error_bytes(e),
        _ => Vec::new(),
    };
    comm.broadcast(&mut message);
    match opened {
        Ok((lock, w)) => Ok((Some(lock), Some(w))),
        Err(e) if comm.is_root() => Err(e),
        Err(_) if message.is_empty() => Ok((None, None)),
        Err(_) => Err(crate::distributed::error_from_bytes(&message)),
    }
}

/// What starts a run over `comm`'s ranks again, for the messages that say how to resume it.
fn launcher(comm: &dyn crate::comm::Comm) -> String {
    if comm.is_distributed() {
        format!("mpirun -n {} ", comm.size())
    } else {
        String::new()
    }
}

/// Where the run's checkpoint is written.
fn checkpoint_path(dir: &Path) -> std::path::PathBuf {
    dir.join("checkpoint.bin")
}

/// What the finished run reports; its particles counted over every rank.
fn summary<const D: usize>(
    sim: &Simulation<D>,
    w: &Option<Writing>,
    start: Instant,
    last_dt: f64,
) -> RunSummary {
    let particles = sim.comm.sum_scalar(sim.particles.len() as f64) as usize;
    RunSummary {
        steps: sim.steps,
        frames: w.as_ref().map_or(0, |w| w.out.frames),
        particles,
        wall_seconds: start.elapsed().as_secs_f64(),
        time: sim.time,
        timers: sim.timers.clone(),
        pressure_iterations: w.as_ref().map_or((0, 0), |w| w.driver.iterations),
        peak_memory: peak_memory(),
        last_dt,
    }
}

/// How a step ended, for what is written after it ([`Writing::after_step`]).
#[derive(Debug, Clone, Copy)]
struct StepEnd {
    /// A frame is due by the schedule.
    scheduled: bool,
    /// The last step asked for (`max_steps`).
    last: bool,
    /// The run was interrupted (Ctrl-C, a signal).
    interrupted: bool,
}

/// The error that stops a run interrupted after the step that brought `sim` where it is,
/// with the command (`resume`) that goes on from its checkpoint.
fn interrupted_error<const D: usize>(sim: &Simulation<D>, resume: &str) -> Error {
    Error::Interrupted(format!(
        "interrupted at step {}, t = {:.6} s; the frame and a checkpoint are written. \
         To go on: {}",
        sim.steps, sim.time, resume
    ))
}

/// What the driver's loop writes and when: the output, the clocks of frames and checkpoints,
/// and the last checkpoint written.
struct Writing {
    out: OutputWriter,
    driver: DriverState,
    checkpoint_path: std::path::PathBuf,
    checkpoint_interval: f64,
    /// Tolerance of the time comparisons (far below any step).
    eps: f64,
    end: f64,
    start: Instant,
    /// Wall-clock seconds the run took before this process (a resumed run's).
    wall_before: f64,
    /// Steps taken before this run started (a resumed run).
    start_steps: u64,
    /// The time of the last checkpoint written (a resumed run: the one it started from).
    last_checkpoint: Option<f64>,
    /// The guard against inflows that fill a closed grid.
    room: Option<RoomGuard>,
    /// What starts the run (`mpirun -n N ` over N ranks), for the resume command.
    launch: String,
    /// What a resumed run's rank 0 read from its checkpoint.
    resumed: checkpoint::Resumed,
    /// The final probe row's values, where every rank has summed the particles onto the
    /// grid for it ([`write_parts`]).
    final_probes: Option<Vec<f64>>,
}

/// Stops a run whose inflows have filled a closed grid ([`crate::deck::room`]): the
/// particles' lattice volume (what the run started with, and what entered since, from the
/// ledger) against the room the rigid bodies leave in the grid.
struct RoomGuard {
    /// The room (m^3; m^2 in 2D).
    room: f64,
    /// The particles' lattice volume when the run started, less the ledger's volume in then.
    base: f64,
}

impl RoomGuard {
    /// The guard of a run starting from `sim` (None when material can leave or none enters).
    fn of<const D: usize>(deck: &Deck, sim: &Simulation<D>) -> Option<Self> {
        let room = crate::deck::room::run_room(deck)?;
        let held: f64 = sim.particles.volume0.iter().sum();
        Some(Self {
            room,
            base: held - sim.ledger.volume_in,
        })
    }

    /// An error once the material `sim` holds is more than the room, by 1 % (the room is
    /// measured on a lattice).
    fn check<const D: usize>(&self, deck: &Deck, sim: &Simulation<D>) -> Result<(), Error> {
        let held = self.base + sim.ledger.volume_in;
        if held <= 1.01 * self.room {
            return Ok(());
        }
        let names: Vec<String> = (0..deck.inflows.len())
            .map(|i| format!("inflows[{i}]"))
            .collect();
        let unit = if D == 3 { "m3" } else { "m2" };
        Err(Error::BlowUp(format!(
            "run stopped at t = {:.6} s: the inflow ({}) has filled the domain: the material \
             holds {:.3e} {unit} (its particles' volume as placed), more than the {:.3e} {unit} the \
             grid leaves beside its rigid bodies, and no face is open or an outflow for it to \
             leave by; make a face \"outflow\", slow the inflow or shorten the run",
            sim.time,
            names.join(", "),
            held,
            self.room
        )))
    }
}

impl Writing {
    /// Opens the run's output (a resumed run reads its checkpoint into `sim`) and sets the
    /// clocks of frames and checkpoints from the deck's `clock`; the run began at `start`. A
    /// fresh run's frame of t = 0 is written after ([`OutputWriter::first_frame`]), once the
    /// particles are shared out.
    /// Returns the directory's lock first: bound in that order, the output is closed before
    /// the lock is released.
    fn open<const D: usize>(
        deck: &Deck,
        sim: &mut Simulation<D>,
        file: &str,
        dir: &Path,
        opts: &RunOptions,
        clock: &Clock,
        start: Instant,
    ) -> Result<(crate::output::DirectoryLock, Self), Error> {
        let (end, interval, eps) = (clock.end, clock.interval, clock.eps());
        // checkpoints at every frame unless the deck says otherwise: one file, overwritten, and
        // small next to the frames
        let checkpoint_interval = deck.output.checkpoint_interval.unwrap_or(interval);
        let checkpoint_path = checkpoint_path(dir);
        let (out, driver, lock, resumed) =
            open_output(deck, sim, file, dir, opts, checkpoint_interval, eps)?;
        let wall_before = driver.wall_seconds;
        let w = Writing {
            out,
            driver,
            checkpoint_path,
            checkpoint_interval,
            eps,
            end,
            start,
            wall_before,
            start_steps: sim.steps,
            // a resumed run's last good state is the checkpoint it started from
            last_checkpoint: opts.resume.as_ref().map(|_| sim.time),
            room: RoomGuard::of(deck, sim),
            launch: opts
                .ranks
                .as_ref()
                .map_or_else(String::new, |r| launcher(&**r)),
            resumed,
            final_probes: None,
        };
        Ok((lock, w))
    }

    /// The observer's view of `sim` after a step of `dt`, `wall` seconds into the run.
    fn status<const D: usize>(&self, sim: &Simulation<D>, dt: f64, wall: f64) -> Status {
        status(sim, self.end, self.start_steps, dt, self.out.frames, wall)
    }

    /// What a step from `t0` to `sim.time` brings to write that reads the particles (`end`:
    /// how the step ended, `None` where it failed, and only the probes' row is written): a
    /// frame, the final probe row, a gauges' row.
    fn due<const D: usize>(&self, t0: f64, sim: &Simulation<D>, end: Option<StepEnd>) -> Due {
        let Some(end) = end else {
            return Due::default();
        };
        let frame = end.scheduled || end.last || end.interrupted;
        let at_end = sim.time >= self.end - self.eps;
        let checkpoint = sim.time >= self.driver.next_checkpoint - self.eps;
        Due {
            frame: frame.then_some(self.out.frames),
            final_probe: at_end || end.last,
            gauges: self.out.gauge_due(t0, sim.time),
            checkpoint: checkpoint || at_end || end.interrupted,
            whole: frame && self.out.grid_frames(),
        }
    }

    /// What a fresh run's frame of t = 0 reads ([`Writing::due`]).
    fn first_due(&self) -> Due {
        Due {
            frame: Some(self.out.frames),
            final_probe: false,
            gauges: self.out.has_gauges(),
            checkpoint: false,
            whole: self.out.grid_frames(),
        }
    }

    /// Adds the last step's pressure iterations to the run's totals.
    fn count_iterations<const D: usize>(&mut self, sim: &Simulation<D>) {
        let (iters, max_iters) = &mut self.driver.iterations;
        *iters += sim.pressure_iterations() as u64;
        *max_iters = (*max_iters).max(sim.pressure_iterations());
    }

    /// The time series' rows of a step from `t0`: the probes' always, the rigid bodies' and
    /// the gauges' only when the step was taken (`stepped`).
    fn step_rows<const D: usize>(
        &mut self,
        t0: f64,
        sim: &Simulation<D>,
        stepped: bool,
    ) -> Result<(), Error> {
        self.out.probe_row(t0, sim)?;
        if stepped {
            self.out
                .rigid_row(sim)
                .and_then(|_| self.out.gauge_row(t0, sim))?;
        }
        Ok(())
    }

    /// After a step of `dt`: the frame the driver found due (`end.scheduled`) and the final
    /// probe row, where they are due (the checkpoint that is due follows, written by every
    /// rank: [`Writing::due`], [`write_checkpoint`]). At the end there are all three; at the
    /// `last` step asked for (a benchmark), a frame and the probe row; when `interrupted`, a
    /// frame and a checkpoint. A frame written only because the run was interrupted is not
    /// counted: the resumed run writes the next frame of the schedule under its number, so
    /// that its frames are those of the run never stopped.
    fn after_step<const D: usize>(
        &mut self,
        deck: &Deck,
        sim: &mut Simulation<D>,
        dt: f64,
        end: StepEnd,
        observer: &mut dyn Observer,
    ) -> Result<(), Error> {
        let StepEnd {
            scheduled,
            last,
            interrupted,
        } = end;
        if let Some(guard) = &self.room {
            guard.check(deck, sim)?;
        }
        let eps = self.eps;
        let at_end = sim.time >= self.end - eps;
        if scheduled || last || interrupted {
            let stats = self.out.frame(
                sim,
                dt,
                self.wall_before + self.start.elapsed().as_secs_f64(),
            )?;
            let wall = self.start.elapsed().as_secs_f64();
            let mut s = status(sim, self.end, self.start_steps, dt, self.out.frames, wall);
            s.max_speed = stats.max_speed;
            s.particles = stats.count;
            observer.frame_written(&s);
            if !(scheduled || last || at_end) {
                self.out.uncount_frame();
            }
        }
        if at_end || last {
            // the final state's probe row, before the last checkpoint: a run killed after
            // that checkpoint is complete (over ranks, every rank summed onto the grid)
            match self.final_probes.take() {
                Some(values) => sim.probes.values = values,
                None => sim.particles_to_grid(),
            }
            self.out.probe_row(sim.time, sim)?;
        }
        // (the checkpoint that is due is written after, by every rank: [`write_checkpoint`])
        Ok(())
    }

    /// Writes the checkpoint of `sim` (rank 0's file of a run over ranks, which names the
    /// other ranks' `pieces`).
    fn checkpoint<const D: usize>(
        &mut self,
        deck: &Deck,
        sim: &Simulation<D>,
        pieces: Option<&checkpoint::Pieces>,
    ) -> Result<(), Error> {
        let eps = self.eps;
        self.driver.next_checkpoint = next_after(
            self.driver.next_checkpoint,
            sim.time + eps,
            self.checkpoint_interval,
        );
        self.driver.frames = self.out.frames;
        self.driver.pvd.clone_from(&self.out.pvd);
        self.driver.wall_seconds = self.wall_before + self.start.elapsed().as_secs_f64();
        // the time series reach the disk before the checkpoint that a resume cuts them
        // back to: a crash after it loses no row
        self.out.sync()?;
        checkpoint::write(&self.checkpoint_path, deck, sim, &self.driver, pieces)?;
        self.last_checkpoint = Some(sim.time);
        Ok(())
    }

    /// Flushes the output at the run's end, and returns the run's error (`result`), or else
    /// the flush's, with where the last good state is and how to go on from it.
    fn finish(
        &mut self,
        result: Result<(), Error>,
        file: &str,
        dir: &Path,
        deck: &Deck,
    ) -> Result<(), Error> {
        let flushed = self.out.finish();
        let resume = resume_command(file, &self.checkpoint_path, dir, deck, &self.launch);
        result.map_err(|e| write_failure_hint(e, self.last_checkpoint, &resume))?;
        flushed.map_err(|e| write_failure_hint(e, self.last_checkpoint, &resume))
    }
}

/// The output directory and the driver's clocks: a new run claims the directory (only once
/// the run can start: a deck that cannot build its simulation, or a bad checkpoint, leaves an
/// earlier run as it was); a resumed one reads its checkpoint into `sim` and cuts the
/// directory's files back to it.
fn open_output<const D: usize>(
    deck: &Deck,
    sim: &mut Simulation<D>,
    file: &str,
    dir: &Path,
    opts: &RunOptions,
    checkpoint_interval: f64,
    eps: f64,
) -> Result<Opened, Error> {
    let end = deck.simulation.end_time;
    Ok(match &opts.resume {
        None => {
            // the directory is taken only once the run can start: a deck that cannot build
            // its simulation, or a bad checkpoint, leaves an earlier run as it was
            let lock = crate::output::claim_directory(dir, opts.force, None)?;
            let out = OutputWriter::new(dir, deck)?;
            let driver = DriverState {
                next_frame: 0.0,
                next_checkpoint: checkpoint_interval,
                frames: 0,
                pvd: Vec::new(),
                iterations: (0, 0),
                wall_seconds: 0.0,
            };
            (out, driver, lock, checkpoint::Resumed::default())
        }
        Some(path) => {
            // (rank 0 of a run over ranks)
            let ranks = opts.ranks.as_ref().map_or(1, |r| r.0.size());
            let (driver, resumed) = checkpoint::read(path, deck, sim, 0, ranks)?;
            if sim.time >= end - eps {
                return Err(Error::Usage(format!(
                    "{}: the checkpoint is at t = {} s, at or past simulation.end_time = {end} s \
                     in {file}: raise end_time to go on",
                    path.display(),
                    sim.time
                )));
            }
            let lock = crate::output::claim_directory(dir, opts.force, Some(path))?;
            crate::output::remove_frames_from(dir, driver.frames)?;
            let out = OutputWriter::resume(dir, deck, sim, &driver)?;
            (out, driver, lock, resumed)
        }
    })
}

/// What [`open_output`] opens: the output, the driver's clocks, the directory's lock and
/// what a resumed run read from its checkpoint.
type Opened = (
    OutputWriter,
    DriverState,
    crate::output::DirectoryLock,
    checkpoint::Resumed,
);

/// The command that resumes this run from its checkpoint.
/// `launch`: what starts it (`mpirun -n N ` for a run over N ranks, else nothing).
fn resume_command(file: &str, checkpoint: &Path, dir: &Path, deck: &Deck, launch: &str) -> String {
    let output = if dir != Path::new(&deck.output.directory) {
        format!(" --output {}", dir.display())
    } else {
        String::new()
    };
    format!(
        "{launch}pmpm run {file} --resume {}{output}",
        checkpoint.display()
    )
}

/// Adds to a failed write (a full disk, a file-size limit) where the last good state is and
/// how to go on from it once there is room.
fn write_failure_hint(e: Error, checkpoint: Option<f64>, resume: &str) -> Error {
    if !matches!(e, Error::Io { .. }) {
        return e;
    }
    let hint = match checkpoint {
        Some(t) => format!(
            "; the run stopped there; its files up to the last checkpoint, at t = {t:.6} s, are \
             whole. Make room (or raise the file-size limit) and go on: {resume}"
        ),
        None => "; the run stopped there, before its first checkpoint; make room (or raise the \
                 file-size limit) and run it again"
            .to_string(),
    };
    e.with_note(&hint)
}

/// Adds to a blow-up message where the last good state is and how to go on from it.
fn blow_up_hint(e: Error, checkpoint: Option<f64>, resume: &str, file: &str) -> Error {
    match (e, checkpoint) {
        (Error::BlowUp(m), Some(t)) => Error::BlowUp(format!(
            "{m}. Every frame is kept, and the last checkpoint, at t = {t:.6} s: to go on from \
             it with a smaller step, lower simulation.cfl (or dt) in {file} and run {resume}"
        )),
        (Error::BlowUp(m), None) => Error::BlowUp(format!(
            "{m}. Every frame is kept; no checkpoint was written yet (the first is at the first \
             frame or output.checkpoint_interval)"
        )),
        (e, _) => e,
    }
}

/// Peak resident set size of this process (VmHWM of /proc/self/status, Linux), in bytes.
pub fn peak_memory() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Loads a deck file, with defaults filled in.
pub fn load(path: &Path) -> Result<Deck, Error> {
    Ok(Deck::load(path)?)
}
