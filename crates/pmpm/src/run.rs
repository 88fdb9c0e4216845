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
    let mut sim = Simulation::<D>::new(deck).map_err(|e| e.with_file(file))?;
    if comm.is_distributed() {
        // refused on every rank alike, before rank 0 takes the directory
        crate::distributed::check(&sim, comm.size()).map_err(|e| e.with_file(file))?;
    }
    let clock = crate::build::clock(deck);
    let launch = launcher(&*comm);
    // rank 0 writes, and a fresh run's frame of t = 0 now, while it still holds every particle
    // (they are shared out after); the directory's lock is held to the run's end, after the
    // output is closed: a second run on it is refused
    let (_lock, mut w) = open_on_root(&*comm, || {
        Writing::open(deck, &mut sim, file, dir, opts, &clock, start)
    })?;
    let mut driver = match &opts.resume {
        Some(path) => {
            // the other ranks read it too (on several machines, from a shared file system):
            // where one cannot, every rank stops with its message
            let failed = (!comm.is_root())
                .then(|| checkpoint::read(path, deck, &mut sim).err())
                .flatten()
                .map(|e| e.to_string());
            if let Some(message) = comm.agree(failed) {
                return Err(Error::Usage(message));
            }
            let next = w.as_ref().map_or(0.0, |w| w.driver.next_frame);
            Driver::resume(clock, comm.max_scalar(next))
        }
        None => Driver::new(clock),
    };
    // (before the particles are shared out: the count is the run's)
    let started = w.as_ref().map(|w| w.status(&sim, 0.0, 0.0));
    crate::distributed::distribute(&mut sim, comm.clone(), opts.resume.is_none())?;
    if let (Some(w), Some(status)) = (&mut w, started) {
        observer.started(&status);
        if let Some(how) = crate::distributed::describe(&sim) {
            observer.spread(&how);
        }
        w.driver.next_frame = driver.next_frame;
    }
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
        // what the step brings to write, with every rank's particles on rank 0 where it reads
        // them
        let due = w.as_ref().is_some_and(|w| w.reads_particles(t0, &sim, end));
        let due = comm.any(due);
        let written = crate::distributed::gathered(&mut sim, due, |sim| match &mut w {
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
        });
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
    /// Opens the run's output (a resumed run reads its checkpoint into `sim`; a fresh run's
    /// frame of t = 0 is written) and sets the clocks of frames and checkpoints from the
    /// deck's `clock`; the run began at `start`.
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
        let (out, driver, lock) =
            open_output(deck, sim, file, dir, opts, checkpoint_interval, eps)?;
        let wall_before = driver.wall_seconds;
        let mut w = Writing {
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
        };
        if opts.resume.is_none() {
            w.out
                .first_frame(sim)
                .map_err(|e| write_failure_hint(e, None, ""))?;
        }
        Ok((lock, w))
    }

    /// The observer's view of `sim` after a step of `dt`, `wall` seconds into the run.
    fn status<const D: usize>(&self, sim: &Simulation<D>, dt: f64, wall: f64) -> Status {
        status(sim, self.end, self.start_steps, dt, self.out.frames, wall)
    }

    /// Whether what a step from `t0` to `sim.time` brings to write reads the particles: a
    /// frame, a gauges' row, the final probe row or a checkpoint (`end`: how the step ended,
    /// `None` where it failed, and only the probes' row is written).
    fn reads_particles<const D: usize>(
        &self,
        t0: f64,
        sim: &Simulation<D>,
        end: Option<StepEnd>,
    ) -> bool {
        let Some(end) = end else { return false };
        let at_end = sim.time >= self.end - self.eps;
        let checkpoint = sim.time >= self.driver.next_checkpoint - self.eps;
        end.scheduled
            || end.last
            || end.interrupted
            || at_end
            || checkpoint
            || self.out.gauge_due(t0, sim.time)
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

    /// After a step of `dt`: the frame the driver found due (`end.scheduled`), the final
    /// probe row and the checkpoint that are due. At the end there are all three; at the
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
            self.out.frame(
                sim,
                dt,
                self.wall_before + self.start.elapsed().as_secs_f64(),
            )?;
            let wall = self.start.elapsed().as_secs_f64();
            let mut s = status(sim, self.end, self.start_steps, dt, self.out.frames, wall);
            s.max_speed = sim.max_speed();
            observer.frame_written(&s);
            if !(scheduled || last || at_end) {
                self.out.uncount_frame();
            }
        }
        if at_end || last {
            // the final state's probe row, before the last checkpoint: a run killed after
            // that checkpoint is complete
            sim.particles_to_grid();
            self.out.probe_row(sim.time, sim)?;
        }
        let checkpoint_due = sim.time >= self.driver.next_checkpoint - eps;
        if checkpoint_due || at_end || interrupted {
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
            checkpoint::write(&self.checkpoint_path, deck, sim, &self.driver)?;
            self.last_checkpoint = Some(sim.time);
        }
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
) -> Result<(OutputWriter, DriverState, crate::output::DirectoryLock), Error> {
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
            (out, driver, lock)
        }
        Some(path) => {
            let driver = checkpoint::read(path, deck, sim)?;
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
            (out, driver, lock)
        }
    })
}

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
