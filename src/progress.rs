//! What the user sees while a run goes: a progress bar on a terminal, a line per frame
//! elsewhere, and Ctrl-C that stops a run cleanly.

use pmpm::run::{Observer, Status};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

/// Set by SIGINT / SIGTERM: the run finishes its step, writes a frame and a checkpoint, and
/// stops.
static INTERRUPTED: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// The flag a run reads (`RunOptions::interrupt`), shared with the handler.
pub fn interrupt_flag() -> Arc<AtomicBool> {
    INTERRUPTED
        .get_or_init(|| Arc::new(AtomicBool::new(false)))
        .clone()
}

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
///
/// `speak`: whether this process says so (over MPI ranks, rank 0 alone: mpirun hands the
/// signal to every rank).
pub fn catch_interrupts(speak: bool) {
    let flag = interrupt_flag();
    let first = std::sync::Mutex::new(None::<Instant>);
    let _ = ctrlc::set_handler(move || {
        let mut first = first.lock().unwrap_or_else(|e| e.into_inner());
        match *first {
            None => {
                *first = Some(Instant::now());
                flag.store(true, Ordering::SeqCst);
                if !speak {
                    return;
                }
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
                if speak {
                    eprintln!(
                        "pmpm: interrupted again: stopping now; the run goes on from its last \
                         checkpoint"
                    );
                }
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

/// The progress display: an indicatif bar on a terminal (simulated time of end time, steps per
/// second, the last step's pressure iterations, time left), one line per frame elsewhere (a
/// log file, CI), nothing when quiet.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    quiet: bool,
    /// Whether the run is a projection run (the bar shows pressure iterations).
    projection: bool,
    /// The opening line: what is run, from where.
    title: String,
    /// Warnings about the deck, printed once the simulation is built (a deck error comes first).
    warnings: Vec<String>,
}

/// Bar resolution: the bar's length in ticks.
const TICKS: u64 = 10_000;

impl Progress {
    /// A display for a run of `title` (the scheme and the deck's name, from where) that prints
    /// `warnings` (whole lines) when the run starts, even when quiet.
    pub fn new(quiet: bool, projection: bool, title: String, warnings: Vec<String>) -> Self {
        Self {
            bar: None,
            quiet,
            projection,
            title,
            warnings,
        }
    }
}

impl Observer for Progress {
    fn spread(&mut self, how: &str) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(bar) => bar.println(format!("pmpm: {how}")),
            None => eprintln!("pmpm: {how}"),
        }
    }

    fn started(&mut self, s: &Status) {
        use std::io::IsTerminal;
        if !self.quiet {
            let at = if s.start_steps > 0 {
                format!(" (t = {} s)", s.time)
            } else {
                String::new()
            };
            eprintln!(
                "pmpm: {}D {}{at}: {} particles, {} grid nodes, to t = {} s",
                s.dimension, self.title, s.particles, s.nodes, s.end_time
            );
        }
        for w in &self.warnings {
            eprintln!("{w}");
        }
        if !self.quiet && std::io::stderr().is_terminal() {
            let bar = indicatif::ProgressBar::new(TICKS);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{bar:30} {percent:>3}%  {msg}  [{elapsed_precise} elapsed, {eta} left]",
                )
                .expect("a valid template"),
            );
            bar.set_position((TICKS as f64 * s.time / s.end_time) as u64);
            bar.reset_eta();
            self.bar = Some(bar);
        }
    }

    fn stepped(&mut self, s: &Status) {
        let Some(bar) = &self.bar else { return };
        bar.set_position((TICKS as f64 * s.time / s.end_time).min(TICKS as f64) as u64);
        let rate = (s.steps - s.start_steps) as f64 / s.wall_seconds.max(1e-9);
        let iters = if self.projection {
            format!(", {} pressure iterations", s.pressure_iterations)
        } else {
            String::new()
        };
        bar.set_message(format!(
            "t = {:.4} / {} s, step {}, {rate:.1} steps/s{iters}",
            s.time, s.end_time, s.steps
        ));
    }

    fn frame_written(&mut self, s: &Status) {
        if self.quiet || self.bar.is_some() {
            return;
        }
        eprintln!(
            "frame {:>5}  t = {:.5} s  step {:>8}  dt = {:.3e} s  max |v| = {:.4} m/s  wall {:.1} s",
            s.frames - 1,
            s.time,
            s.steps,
            s.dt,
            s.max_speed,
            s.wall_seconds
        );
    }

    fn stopped(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}
