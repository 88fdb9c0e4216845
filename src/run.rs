//! The run driver: time-step control, frames and probes, and what happens when a run fails.

use crate::checkpoint::{self, DriverState};
use crate::deck::{Deck, Scheme};
use crate::error::Error;
use crate::output::OutputWriter;
use crate::scheme::Simulation;
use crate::timing::Phase;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// How a run is asked for from the command line.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// No progress bar or lines.
    pub quiet: bool,
    /// Write into a directory that holds an earlier run.
    pub force: bool,
    /// Stop after this many steps (benchmarks), as if the end time were reached.
    pub max_steps: Option<u64>,
    /// Go on from this checkpoint instead of starting from the deck's initial state.
    pub resume: Option<std::path::PathBuf>,
}

/// Set by SIGINT / SIGTERM: the run finishes its step, writes a frame and a checkpoint, and
/// stops.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Seconds after the first interrupt within which a second one is ignored.
const FORCE_AFTER_SECONDS: f64 = 2.0;

/// Makes SIGINT (Ctrl-C) and SIGTERM stop a run cleanly at the end of its current step instead
/// of killing it: the run writes a frame and a checkpoint and exits with status 130. A second
/// signal within [`FORCE_AFTER_SECONDS`] is ignored (coreutils `timeout` and a shell's job
/// control may send two at once; dying at the second used to leave a frame without its series
/// row); one after that stops the run at once, as SIGKILL would, which every file it writes
/// survives.
///
/// SIGXFSZ (a file-size limit, `ulimit -f`) is ignored too, so that a write past the limit
/// fails with an error pmpm reports, naming the last good checkpoint, instead of killing it.
pub fn catch_interrupts() {
    let first = std::sync::Mutex::new(None::<Instant>);
    let _ = ctrlc::set_handler(move || {
        let mut first = first.lock().unwrap_or_else(|e| e.into_inner());
        match *first {
            None => {
                *first = Some(Instant::now());
                INTERRUPTED.store(true, Ordering::SeqCst);
                eprintln!(
                    "\npmpm: interrupted: finishing this step, then writing a frame and a \
                     checkpoint (interrupt again after {FORCE_AFTER_SECONDS} s to stop at once)"
                );
            }
            // the second of a pair sent at once: ignored
            Some(t) if t.elapsed().as_secs_f64() < FORCE_AFTER_SECONDS => {}
            Some(_) => {
                // a step that does not end (a long solve): every file is whole at any
                // instant, so stopping here loses only the work since the last checkpoint
                eprintln!(
                    "pmpm: interrupted again: stopping now; the run goes on from its last \
                     checkpoint"
                );
                std::process::exit(130);
            }
        }
    });
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to SIG_IGN installs no handler code and is
    // async-signal-safe; it is done once, before any file is written.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

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
}

/// Runs a validated deck into `dir`, generic over the dimension.
pub fn run(deck: &Deck, file: &str, dir: &Path, opts: &RunOptions) -> Result<RunSummary, Error> {
    match deck.simulation.dimension {
        2 => run_dim::<2>(deck, file, dir, opts),
        3 => run_dim::<3>(deck, file, dir, opts),
        d => unreachable!("validated: dimension is 2 or 3, got {d}"),
    }
}

fn run_dim<const D: usize>(
    deck: &Deck,
    file: &str,
    dir: &Path,
    opts: &RunOptions,
) -> Result<RunSummary, Error> {
    let start = Instant::now();
    let mut sim = Simulation::<D>::new(deck).map_err(|e| e.with_file(file))?;
    let end = deck.simulation.end_time;
    let interval = deck.output.interval.expect("validated: interval filled in");
    // checkpoints at every frame unless the deck says otherwise: one file, overwritten, and
    // small next to the frames
    let checkpoint_interval = deck.output.checkpoint_interval.unwrap_or(interval);
    // times are compared with a tolerance far below any step, so that frame k lands at k interval
    let eps = 1e-9 * interval.min(end);
    let checkpoint_path = dir.join("checkpoint.bin");
    let (mut out, mut driver) = match &opts.resume {
        None => {
            // the directory is taken only once the run can start: a deck that cannot build
            // its simulation, or a bad checkpoint, leaves an earlier run as it was
            crate::output::claim_directory(dir, opts.force, None)?;
            let out = OutputWriter::new(dir, &sim)?;
            let driver = DriverState {
                next_frame: 0.0,
                next_checkpoint: checkpoint_interval,
                frames: 0,
                pvd: Vec::new(),
                iterations: (0, 0),
            };
            (out, driver)
        }
        Some(path) => {
            let driver = checkpoint::read(path, &mut sim)?;
            if sim.time >= end - eps {
                return Err(Error::Usage(format!(
                    "{}: the checkpoint is at t = {} s, at or past simulation.end_time = {end} s \
                     in {file}: raise end_time to go on",
                    path.display(),
                    sim.time
                )));
            }
            crate::output::claim_directory(dir, opts.force, Some(path))?;
            crate::output::remove_frames_from(dir, driver.frames)?;
            let out = OutputWriter::resume(dir, &sim, &driver)?;
            (out, driver)
        }
    };
    if !opts.quiet {
        let from = match &opts.resume {
            Some(p) => format!(" from {} (t = {} s)", p.display(), sim.time),
            None => String::new(),
        };
        eprintln!(
            "pmpm: {}D {:?} run of {}{from}: {} particles, {} grid nodes, to t = {end} s",
            D,
            deck.simulation.scheme,
            file,
            sim.particles.len(),
            sim.grid.geo.node_count()
        );
    }
    for w in warnings(deck) {
        eprintln!("warning: {file}: {}", crate::limits::shorten_numbers(&w));
    }
    if opts.resume.is_none() {
        out.frame(&sim, 0.0, 0.0)
            .map_err(|e| write_failure_hint(e, None, ""))?;
        driver.next_frame = interval;
    }
    let progress = Progress::new(opts.quiet, sim.time, sim.steps, end);
    let mut last_dt = 0.0;
    // a resumed run's last good state is the checkpoint it started from
    let mut last_checkpoint: Option<f64> = opts.resume.as_ref().map(|_| sim.time);
    sim.timers.lap(Phase::Other);
    let result = loop {
        if sim.time >= end - eps || opts.max_steps.is_some_and(|n| sim.steps >= n) {
            break Ok(());
        }
        let next_frame = driver.next_frame;
        let mut dt = match (deck.simulation.dt, deck.simulation.cfl) {
            (Some(dt), _) => dt,
            (None, Some(cfl)) => {
                // adaptive steps land exactly on frame times, without a sliver of a step
                // before each frame: the remaining time is split into equal steps (with the
                // projection a tiny step turns the leftover divergence into a pressure spike).
                // Without landing, the stable step is taken as is (up to one frame interval)
                // and frames are written at the first step end at or past their time.
                let dt = sim.stable_dt(cfl);
                let left = next_frame.min(end) - sim.time;
                if deck.simulation.land_on_frames == Some(false) {
                    // at most one frame interval, so that no frame is skipped
                    dt.min(interval)
                } else if dt.is_finite() && dt > 0.0 && left > 0.0 {
                    left / (left / dt).ceil()
                } else {
                    dt
                }
            }
            (None, None) => unreachable!("validated: dt or cfl"),
        };
        dt = dt.min(end - sim.time);
        if !(dt > 0.0 && dt.is_finite()) {
            // at rest with nothing to bound the step: step to the next frame
            dt = (next_frame.min(end) - sim.time).max(eps);
        }
        let t0 = sim.time;
        let stepped = sim.step(dt);
        let (iters, max_iters) = &mut driver.iterations;
        *iters += sim.pressure_iterations as u64;
        *max_iters = (*max_iters).max(sim.pressure_iterations);
        sim.timers.lap(Phase::Other);
        if let Err(e) = out.probe_row(t0, &sim) {
            break Err(e);
        }
        if stepped.is_ok() {
            if let Err(e) = out.rigid_row(&sim) {
                break Err(e);
            }
        }
        if let Err(e) = stepped {
            progress.clear();
            let resume = resume_command(file, &checkpoint_path, dir, deck);
            break Err(blow_up_hint(
                e.with_file(file),
                last_checkpoint,
                &resume,
                file,
            ));
        }
        last_dt = dt;
        let interrupted = INTERRUPTED.load(Ordering::SeqCst);
        let last = opts.max_steps.is_some_and(|n| sim.steps >= n);
        let at_end = sim.time >= end - eps;
        if sim.time >= next_frame - eps || at_end || last || interrupted {
            if let Err(e) = out.frame(&sim, dt, start.elapsed().as_secs_f64()) {
                break Err(e);
            }
            driver.next_frame = next_after(driver.next_frame, sim.time + eps, interval);
            if !opts.quiet && !progress.is_bar() {
                eprintln!(
                    "frame {:>5}  t = {:.5} s  step {:>8}  dt = {:.3e} s  max |v| = {:.4} m/s  wall {:.1} s",
                    out.frames - 1,
                    sim.time,
                    sim.steps,
                    dt,
                    sim.max_speed(),
                    start.elapsed().as_secs_f64()
                );
            }
        }
        if at_end || last {
            // the final state's probe row, before the last checkpoint: a run killed after
            // that checkpoint is complete
            sim.particles_to_grid();
            if let Err(e) = out.probe_row(sim.time, &sim) {
                break Err(e);
            }
        }
        let checkpoint_due = sim.time >= driver.next_checkpoint - eps;
        if checkpoint_due || at_end || interrupted {
            driver.next_checkpoint =
                next_after(driver.next_checkpoint, sim.time + eps, checkpoint_interval);
            driver.frames = out.frames;
            driver.pvd.clone_from(&out.pvd);
            // the time series reach the disk before the checkpoint that a resume cuts them
            // back to: a crash after it loses no row
            if let Err(e) = out.sync() {
                break Err(e);
            }
            if let Err(e) = checkpoint::write(&checkpoint_path, &sim, &driver) {
                break Err(e);
            }
            last_checkpoint = Some(sim.time);
        }
        sim.timers.lap(Phase::Output);
        progress.update(&sim, start.elapsed().as_secs_f64());
        if interrupted {
            progress.clear();
            break Err(Error::Interrupted(format!(
                "interrupted at step {}, t = {:.6} s; the frame and a checkpoint are written. \
                 To go on: {}",
                sim.steps,
                sim.time,
                resume_command(file, &checkpoint_path, dir, deck)
            )));
        }
    };
    progress.clear();
    let flushed = out.finish();
    let resume = resume_command(file, &checkpoint_path, dir, deck);
    result.map_err(|e| write_failure_hint(e, last_checkpoint, &resume))?;
    flushed.map_err(|e| write_failure_hint(e, last_checkpoint, &resume))?;
    let summary = RunSummary {
        steps: sim.steps,
        frames: out.frames,
        particles: sim.particles.len(),
        wall_seconds: start.elapsed().as_secs_f64(),
        time: sim.time,
        timers: sim.timers.clone(),
        pressure_iterations: driver.iterations,
        peak_memory: peak_memory(),
    };
    if !opts.quiet {
        eprintln!(
            "pmpm: done: {} steps, {} frames, {:.2} s wall, last dt = {last_dt:.3e} s, output in {}",
            summary.steps,
            summary.frames,
            summary.wall_seconds,
            dir.display()
        );
    }
    Ok(summary)
}

/// The command that resumes this run from its checkpoint.
fn resume_command(file: &str, checkpoint: &Path, dir: &Path, deck: &Deck) -> String {
    let output = if dir != Path::new(&deck.output.directory) {
        format!(" --output {}", dir.display())
    } else {
        String::new()
    };
    format!("pmpm run {file} --resume {}{output}", checkpoint.display())
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

/// The progress display: an indicatif bar on a terminal (simulated time of end time, steps per
/// second, the last step's pressure iterations, time left), nothing otherwise (the driver
/// prints one line per frame instead).
struct Progress {
    bar: Option<indicatif::ProgressBar>,
    /// Steps taken before this process started (a resumed run), for the step rate.
    start_steps: u64,
    end: f64,
}

/// Bar resolution: the bar's length in ticks.
const TICKS: u64 = 10_000;

impl Progress {
    fn new(quiet: bool, time: f64, start_steps: u64, end: f64) -> Self {
        use std::io::IsTerminal;
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let bar = indicatif::ProgressBar::new(TICKS);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{bar:30} {percent:>3}%  {msg}  [{elapsed_precise} elapsed, {eta} left]",
                )
                .expect("a valid template"),
            );
            bar.set_position((TICKS as f64 * time / end) as u64);
            bar.reset_eta();
            bar
        });
        Self {
            bar,
            start_steps,
            end,
        }
    }

    fn is_bar(&self) -> bool {
        self.bar.is_some()
    }

    fn update<const D: usize>(&self, sim: &Simulation<D>, wall: f64) {
        let Some(bar) = &self.bar else { return };
        bar.set_position((TICKS as f64 * sim.time / self.end).min(TICKS as f64) as u64);
        let rate = (sim.steps - self.start_steps) as f64 / wall.max(1e-9);
        let iters = if sim.scheme == Scheme::Projection {
            format!(", {} pressure iterations", sim.pressure_iterations)
        } else {
            String::new()
        };
        bar.set_message(format!(
            "t = {:.4} / {} s, step {}, {rate:.1} steps/s{iters}",
            sim.time, self.end, sim.steps
        ));
    }

    fn clear(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// The table `pmpm bench` prints: per phase seconds, ms per step and share of the wall time;
/// particle updates per second; pressure iterations; peak memory per particle. The last line,
/// `BENCH key=value ...`, is for scripts.
pub fn bench_report(deck: &Deck, file: &str, r: &RunSummary, threads: usize) -> String {
    use std::fmt::Write;
    let steps = r.steps.max(1) as f64;
    let total = r.timers.total();
    let mut t = String::new();
    let _ = writeln!(
        t,
        "pmpm bench {file}: {}D {:?}, {} particles, {} steps to t = {:.6} s, {threads} thread(s)\n",
        deck.simulation.dimension, deck.simulation.scheme, r.particles, r.steps, r.time
    );
    let _ = writeln!(t, "| phase | seconds | ms/step | share |");
    let _ = writeln!(t, "|---|---:|---:|---:|");
    for p in Phase::ALL {
        let sec = r.timers.seconds(p);
        if sec == 0.0 {
            continue;
        }
        let _ = writeln!(
            t,
            "| {} | {:.3} | {:.3} | {:.1}% |",
            p.name(),
            sec,
            1e3 * sec / steps,
            100.0 * sec / total.max(1e-300)
        );
    }
    let _ = writeln!(
        t,
        "| **step loop** | **{total:.3}** | **{:.3}** | 100% |\n",
        1e3 * total / steps
    );
    let updates = r.particles as f64 * r.steps as f64 / total.max(1e-300);
    let _ = writeln!(t, "particle updates per second: {updates:.3e}");
    let (iters, max_iters) = r.pressure_iterations;
    if deck.simulation.scheme == Scheme::Projection {
        let _ = writeln!(
            t,
            "pressure iterations: {:.1} per step, at most {max_iters}",
            iters as f64 / steps
        );
    }
    let mem = r
        .peak_memory
        .map(|b| (b, b as f64 / r.particles.max(1) as f64));
    match mem {
        Some((b, per)) => {
            let _ = writeln!(
                t,
                "peak memory: {:.1} MB, {per:.0} bytes per particle (whole process: grid, solver and buffers included)",
                b as f64 / 1e6
            );
        }
        None => {
            let _ = writeln!(t, "peak memory: not available on this system");
        }
    }
    let _ = write!(
        t,
        "BENCH dim={} scheme={:?} particles={} steps={} sim_time={:.6} threads={threads} wall_s={total:.4} ms_per_step={:.4} updates_per_s={updates:.4e} pressure_iterations={iters} max_iterations={max_iters} peak_bytes={} bytes_per_particle={}",
        deck.simulation.dimension,
        deck.simulation.scheme,
        r.particles,
        r.steps,
        r.time,
        1e3 * total / steps,
        mem.map_or(0, |m| m.0),
        mem.map_or(0.0, |m| m.1).round()
    );
    for p in Phase::ALL {
        let _ = write!(t, " {}={:.4}", p.key(), r.timers.seconds(p));
    }
    t.push('\n');
    t
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

/// Warnings about a valid deck that is likely to go wrong.
pub fn warnings(deck: &Deck) -> Vec<String> {
    use crate::deck::{ShapeFunction, Transfer};
    let s = &deck.simulation;
    let mut w = Vec::new();
    if s.transfer == Some(Transfer::Apic)
        && s.scheme == crate::deck::Scheme::Explicit
        && matches!(
            s.shape_function,
            ShapeFunction::Linear | ShapeFunction::Gimp
        )
    {
        w.push(format!(
            "simulation.transfer: \"apic\" with shape_function = \"{}\" grows an unstable mode at free surfaces with the explicit scheme (seen in the dam break); use \"bspline2\" or transfer = \"flip\"",
            format!("{:?}", s.shape_function).to_lowercase()
        ));
    }
    // FLIP under the projection for a fluid: its particle noise goes into the particles'
    // volumes (a closed tank's splash and the two-fluid column stopped on a particle's volume
    // with FLIP where APIC ran)
    if s.transfer == Some(Transfer::Flip)
        && s.scheme == crate::deck::Scheme::Projection
        && !deck
            .materials
            .iter()
            .any(crate::deck::MaterialDeck::is_solid)
    {
        w.push(
            "simulation.transfer: \"flip\" with the projection scheme: FLIP's particle noise enters the particles' volumes, and after splashes single particles can be crushed or blown up until the run stops; the projection's default for fluids, \"apic\", keeps them (docs/deck.md)".to_string(),
        );
    }
    // an elastic solid with APIC under MUSL and linear or GIMP shapes: the remap takes the last
    // step's affine matrix (`transfer::grid_to_particles`), the strain rate lags a step, and
    // the solid's waves grow (a von Mises block on a floor blew up in 390 explicit steps)
    if s.transfer == Some(Transfer::Apic)
        && s.stress_update == crate::deck::StressUpdate::Musl
        && matches!(
            s.shape_function,
            ShapeFunction::Linear | ShapeFunction::Gimp
        )
    {
        if let Some(m) = deck.materials.iter().find(|m| m.shear_modulus.is_some()) {
            w.push(format!(
                "simulation.stress_update: \"musl\" with transfer = \"apic\" can let the elastic waves of \"{}\" ({}) grow: the remap takes the last step's affine matrix (a von Mises block at cfl 0.5 blew up within 400 steps); use shape_function = \"bspline2\", transfer = \"flip\", or a step well below the wave limit",
                m.name,
                m.model.name()
            ));
        }
    }
    // a nearly incompressible solid under the explicit scheme without the nodal averaging:
    // one volume constraint per particle locks the grid (the strip footing's load 38% high at
    // K = 100 G, and a thin layer on a no-slip floor held still)
    if s.scheme == crate::deck::Scheme::Explicit
        && s.volumetric_averaging == crate::deck::VolumetricAveraging::None
    {
        let stiff = deck
            .materials
            .iter()
            .find_map(|m| match (m.shear_modulus, m.bulk_modulus) {
                (Some(g), Some(k)) if g > 0.0 && k >= 10.0 * g => Some((m, k / g)),
                _ => None,
            });
        if let Some((m, ratio)) = stiff {
            w.push(format!(
                "materials \"{}\": bulk_modulus / shear_modulus = {:.0} with the explicit scheme: such a nearly incompressible solid can lock (respond too stiffly); set simulation.volumetric_averaging = \"nodal\" (docs/materials.md), or use the projection scheme",
                m.name, ratio
            ));
        }
    }
    // solids only, under the projection with the nodal pressure: its stabilisation residual
    // lets a loaded solid creep (the elastic column 75% past its settlement and sinking)
    if s.scheme == crate::deck::Scheme::Projection
        && deck.pressure.unknowns == crate::deck::PressureUnknowns::Nodes
        && deck
            .materials
            .iter()
            .all(crate::material::MaterialParams::is_solid)
    {
        w.push("every material is a solid and the projection's pressure sits on the nodes: a solid under a steady load creeps with it (docs/method.md, \"One pressure per cell\"); set pressure.unknowns = \"cells\" with simulation.stress_update = \"usl\"".into());
    }
    // material that starts inside a rigid body: the body's nodes take its velocity, and the
    // particles inside are squeezed out (or held) in the first steps
    for (b, body) in deck.bodies.iter().enumerate() {
        for (r, rigid) in deck.rigid_bodies.iter().enumerate() {
            if let Some(x) = overlap_point(&body.shape, &rigid.shape) {
                let at: Vec<String> = x.iter().map(|c| format!("{c}")).collect();
                w.push(format!(
                    "bodies[{b}] starts inside rigid_bodies[{r}] (for example at ({})): its material there will be pushed out of the body in the first steps; cut the body around the rigid one",
                    at.join(", ")
                ));
            }
        }
    }
    w
}

/// A point inside both a body's shape and a rigid body's box, if the two overlap (tested on a
/// lattice of 9^D points over the boxes' common part).
fn overlap_point(
    body: &crate::deck::ShapeDeck,
    rigid: &crate::deck::ShapeDeck,
) -> Option<Vec<f64>> {
    let (blo, bhi) = body.bounds();
    let (rlo, rhi) = rigid.bounds();
    let dim = blo.len();
    let lo: Vec<f64> = (0..dim).map(|d| blo[d].max(rlo[d])).collect();
    let hi: Vec<f64> = (0..dim).map(|d| bhi[d].min(rhi[d])).collect();
    if (0..dim).any(|d| hi[d] <= lo[d]) {
        return None;
    }
    let n = 9usize;
    (0..n.pow(dim as u32)).find_map(|k| {
        let x: Vec<f64> = (0..dim)
            .map(|d| {
                let i = (k / n.pow(d as u32)) % n;
                lo[d] + (hi[d] - lo[d]) * (i as f64 + 0.5) / n as f64
            })
            .collect();
        (body.contains(&x) && rigid.contains(&x)).then_some(x)
    })
}

/// The summary `pmpm check` prints: what the deck sets up and what a run will cost.
pub fn check_summary(deck: &Deck, file: &str) -> Result<String, Error> {
    match deck.simulation.dimension {
        2 => summary_dim::<2>(deck, file),
        3 => summary_dim::<3>(deck, file),
        d => unreachable!("validated: dimension is 2 or 3, got {d}"),
    }
}

fn summary_dim<const D: usize>(deck: &Deck, file: &str) -> Result<String, Error> {
    let sim = Simulation::<D>::new(deck).map_err(|e| e.with_file(file))?;
    let s = &deck.simulation;
    let geo = &sim.grid.geo;
    let mut out = format!("{file}: deck is valid\n");
    for w in warnings(deck) {
        out += &format!("warning: {w}\n");
    }
    out += &format!(
        "  dimension        {D}\n  scheme           {:?}\n",
        s.scheme
    );
    out += &format!(
        "  grid             {} cells of h = {} m, {} nodes (with ghosts)\n",
        geo.cells
            .iter()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(" x "),
        geo.h,
        geo.node_count()
    );
    // particles per body (the bodies are filled in deck order, so body b's particles are a
    // range of ids), and those of a later body that lie inside an earlier one
    let per_body: Vec<usize> = (0..deck.bodies.len())
        .map(|b| {
            let mut one = deck.clone();
            one.bodies = vec![deck.bodies[b].clone()];
            crate::particles::Particles::<D>::from_deck(&one, geo).len()
        })
        .collect();
    let mut overlaps: Vec<(usize, usize, usize)> = Vec::new();
    let mut first = 0;
    for (b, &n) in per_body.iter().enumerate() {
        let xs = &sim.particles.x[first..first + n];
        for a in 0..b {
            let inside = xs
                .iter()
                .filter(|x| deck.bodies[a].shape.contains(x.as_slice()))
                .count();
            if inside > 0 {
                overlaps.push((a, b, inside));
            }
        }
        first += n;
    }
    let mut warn = Vec::new();
    for (b, body) in deck.bodies.iter().enumerate() {
        out += &format!(
            "  bodies[{b}]        {} particles of \"{}\" ({} per cell per direction)\n",
            per_body[b], body.material, body.particles_per_cell
        );
        if body.particles_per_cell < 2 {
            warn.push(format!(
                "bodies[{b}].particles_per_cell = {}: fewer than 2 particles per cell per \
                 direction leave cells empty as the material deforms (the pressure then \
                 checkerboards and the free surface is found inside the water); use 2 or more",
                body.particles_per_cell
            ));
        }
    }
    for (a, b, n) in overlaps {
        warn.push(format!(
            "bodies[{a}] and bodies[{b}] overlap: {n} particles of bodies[{b}] lie inside \
             bodies[{a}], which has its own there (more mass than the material's density)"
        ));
    }
    for m in &deck.materials {
        out += &format!("  material         {}\n", m.describe());
    }
    for r in &deck.rigid_bodies {
        let (lo, hi) = r.shape.bounds();
        let v = r.velocity.clone().unwrap_or_else(|| vec![0.0; D]);
        let sides = match r.sides {
            crate::deck::RigidSides::Rough => "rough",
            crate::deck::RigidSides::Smooth => "smooth sides",
        };
        // how the faces act: where they lie (cut cells), or at the nodes inside
        let faces = if deck.simulation.scheme == crate::deck::Scheme::Projection
            && deck.pressure.cuts_cells(s.shape_function)
        {
            "faces cut the cells where they lie"
        } else {
            "faces act at node resolution (put them midway between node rows)"
        };
        out += &format!(
            "  rigid body       \"{}\": box {lo:?} to {hi:?} m, velocity {v:?} m/s, {sides}, {faces}; its force in rigid_bodies.csv every step\n",
            r.name
        );
    }
    out += &format!("  particles        {}\n", sim.particles.len());
    out += &format!(
        "  transfer         {:?}, shape functions {:?}\n",
        s.transfer.unwrap_or_default(),
        s.shape_function
    );
    let dt = match (s.dt, s.cfl) {
        (Some(dt), _) => format!("fixed dt = {dt:e} s"),
        (None, Some(cfl)) => {
            let dt0 = sim.stable_dt(cfl);
            if dt0.is_finite() {
                format!("adaptive, cfl = {cfl}; at t = 0 dt = {dt0:.3e} s")
            } else {
                format!("adaptive, cfl = {cfl}; at rest at t = 0 (set by the flow)")
            }
        }
        (None, None) => unreachable!("validated: dt or cfl"),
    };
    out += &format!("  time step        {dt}\n");
    let g = sim.settings.gravity;
    let gnorm = g.norm();
    let estimate = crate::limits::estimate(deck);
    let flow = estimate.flow_steps;
    let steps = (estimate.steps > 0.0 && estimate.steps.is_finite()).then_some(estimate.steps);
    if let Some(n) = steps {
        out += &format!(
            "  steps            about {} to t = {} s{}\n",
            crate::limits::short(n.ceil()),
            s.end_time,
            if s.dt.is_none() {
                " (at most: with cfl the step follows the flow)"
            } else {
                ""
            }
        );
    }
    if let (Some(dt), Scheme::Projection) = (s.dt, s.scheme) {
        if gnorm > 0.0 && dt > (geo.h / gnorm).sqrt() {
            warn.push(format!(
                "simulation.dt = {dt} s is above sqrt(h / |g|) = {:.3e} s: a particle falling \
                 from rest crosses more than a cell in a step; lower dt or use cfl",
                (geo.h / gnorm).sqrt()
            ));
        }
    }
    // gravity pulling the material out of the grid through an open face
    let faces = deck.grid.boundary.faces();
    for d in 0..D {
        if g[d] == 0.0 {
            continue;
        }
        let face = 2 * d + usize::from(g[d] > 0.0);
        let open = faces[face]
            .as_ref()
            .is_none_or(|f| f.kind() == crate::deck::BoundaryKind::Open);
        if open {
            warn.push(format!(
                "grid.boundary.{} is open and gravity pulls the material towards it: particles \
                 that fall out of the grid stop the run (exit status 3); make it a wall \
                 (\"slip\" or \"no_slip\") unless the bodies rest on something",
                crate::deck::FACE_NAMES[face]
            ));
        }
    }

    let (wave, viscous) = deck.dt_limits();
    if wave.is_finite() {
        out += &format!(
            "  wave limit       h / c = {wave:.3e} s ({}): about {:.0} steps or more to t = {}\n",
            if s.scheme == Scheme::Explicit {
                "c the sound speed"
            } else {
                "c the shear wave speed"
            },
            s.end_time / (wave * s.cfl.unwrap_or(1.0)),
            s.end_time
        );
    }
    // the viscous limit, where it binds: below the wave limit and asking for more steps than
    // the flow does (a yield-stress fluid's regularisation sets it; plain water never does)
    if viscous.0 < wave && s.end_time / viscous.0 > flow {
        out += &format!(
            "  viscous limit    h^2 rho / (2 D mu) = {:.3e} s (material \"{}\"): about {:.0} steps or more to t = {}\n",
            viscous.0,
            deck.materials[viscous.1].name,
            (s.end_time / viscous.0).ceil(),
            s.end_time
        );
    }
    if s.scheme == Scheme::Projection {
        let p = &deck.pressure;
        let lower = |x: String| x.to_lowercase();
        if p.unknowns == crate::deck::PressureUnknowns::Cells {
            out += &format!(
                "  pressure         one per cell (unknowns = \"cells\"): {} ({}), tolerance {:e}, at most {} iterations; each cell's weak divergence held at zero, no free-surface detection\n",
                lower(format!("{:?}", p.solver)),
                lower(format!("{:?}", p.preconditioner)),
                p.tolerance,
                p.max_iterations,
            );
        } else {
            let surface = match p.free_surface.unwrap_or_default() {
                crate::deck::FreeSurface::LevelSet => {
                    "free surface from the level set (ghost fluid)".to_string()
                }
                crate::deck::FreeSurface::VolumeFraction => format!(
                    "free surface (the paper's rule) where a cell is below {} full",
                    p.volume_fraction_tolerance
                ),
                crate::deck::FreeSurface::None => "no free surface".to_string(),
            };
            let density = match p.density_correction.unwrap_or_default() {
                crate::deck::DensityCorrection::Positions => {
                    "particle volumes restored by a position correction"
                }
                crate::deck::DensityCorrection::None => "no density correction",
            };
            out += &format!(
                "  pressure         {} ({}), tolerance {:e}, at most {} iterations; rhs {}, beta = {}; {surface}; {density}\n",
                lower(format!("{:?}", p.solver)),
                lower(format!("{:?}", p.preconditioner)),
                p.tolerance,
                p.max_iterations,
                lower(format!("{:?}", p.rhs)),
                p.beta,
            );
        }
    }
    let frames = (s.end_time / deck.output.interval.unwrap_or(s.end_time)).round() as usize + 1;
    let n = sim.particles.len() as f64;
    // bytes per particle: a CSV row (about 17 characters per number), the .vtu's raw arrays,
    // the checkpoint's particle state
    let csv = 17.0 * (2 * D + 5) as f64;
    let vtu = 8.0 * 3.0 * 2.0 + 8.0 * 4.0 + 4.0 + 17.0;
    let checkpoint = 8.0 * (2 * D + 5 + 4 * D * D) as f64 + 6.0;
    let formats = &deck.output.formats;
    let has = |f: crate::deck::Format| formats.contains(&f);
    let per_frame = n
        * (if has(crate::deck::Format::Csv) {
            csv
        } else {
            0.0
        } + if has(crate::deck::Format::Vtk) {
            vtu
        } else {
            0.0
        });
    out += &format!(
        "  output           {} every {} s into {}: {frames} frames of about {}, {} in all, \
         and a checkpoint of {}\n",
        formats
            .iter()
            .map(|f| format!("{f:?}").to_lowercase())
            .collect::<Vec<_>>()
            .join(", "),
        deck.output.interval.unwrap_or(0.0),
        deck.output.directory,
        bytes(per_frame),
        bytes(per_frame * frames as f64),
        bytes(n * checkpoint + 8.0 * geo.node_count() as f64)
    );
    let k = usize::from(D == 3);
    out += &format!(
        "  memory           about {} ({} MB, {} B per particle and {} B per grid node, from \
         the benchmarks)\n",
        bytes(crate::limits::memory(D, n, geo.node_count() as f64)),
        crate::limits::BYTES_BASE / 1e6,
        crate::limits::BYTES_PER_PARTICLE[k],
        crate::limits::BYTES_PER_NODE[k],
    );
    for w in warn {
        out += &format!("warning: {w}\n");
    }
    Ok(out)
}

use crate::limits::bytes;

/// The first of `next`, `next + interval`, `next + 2 interval`, ... past `t`, found without a
/// loop: an interval below the spacing of floating-point numbers near `t` would never get
/// there by adding.
fn next_after(next: f64, t: f64, interval: f64) -> f64 {
    if next > t {
        return next;
    }
    let k = ((t - next) / interval).floor() + 1.0;
    let mut n = next + k * interval;
    if n <= t {
        // (t - next) / interval rounded down across a whole number
        n += interval;
    }
    if n > t {
        n
    } else {
        // interval below the floating-point spacing at t: the next number above t
        f64::from_bits(t.to_bits() + 1).max(n)
    }
}

#[cfg(test)]
mod tests {
    use super::next_after;

    #[test]
    fn the_next_output_time_is_found_without_a_loop() {
        assert_eq!(next_after(0.5, 0.2, 0.1), 0.5);
        let n = next_after(0.1, 0.35, 0.1);
        assert!((n - 0.4).abs() < 1e-15, "{n}");
        // an interval far below the spacing of numbers near t: the next number above t, at once
        let n = next_after(1e-300, 0.01, 1e-300);
        assert!(n > 0.01 && n - 0.01 < 1e-17, "{n}");
    }
}
