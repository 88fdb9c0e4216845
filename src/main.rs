//! The `pmpm` command line.

use clap::{Parser, Subcommand};
use pmpm::deck::Scheme;
use pmpm::run::{self, RunOptions};
use pmpm::Error;
use pmpm_cli::check;
use pmpm_cli::progress::{self, Progress};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// pmpm: material point method for incompressible materials (water, mud, clay, rubber).
#[derive(Parser)]
#[command(
    version,
    about,
    long_about = None,
    after_help = "Examples:\n  pmpm check examples/dam_break_2d.toml\n  pmpm run examples/dam_break_2d.toml\n  pmpm plot out/dam_break_2d --field speed\n  pmpm run examples/dam_break_2d.toml --resume out/dam_break_2d/checkpoint.bin\n\nExit status: 0 done, 1 a file could not be written, 2 a bad deck, argument or checkpoint,\n3 the run blew up, 4 validate --strict with a missed bound, 130 interrupted (Ctrl-C).\nThe deck keys: docs/deck.md."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Worker threads (default: all cores). Results are bitwise repeatable for a given count.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Run (or check) a deck that needs more memory than this machine has or more than 1e9
    /// steps, which are otherwise refused before anything is allocated.
    #[arg(long, global = true)]
    allow_large: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Run a deck: frames, series.csv, probes.csv, run.toml and checkpoints in the output directory.
    ///
    /// On a terminal a progress bar shows the simulated time, steps per second, the last step's
    /// pressure iterations and the time left; elsewhere (a log file, CI) one line per frame.
    /// Ctrl-C (or SIGTERM) finishes the current step, writes the frame and a checkpoint, and
    /// stops with exit status 130; `--resume OUTDIR/checkpoint.bin` goes on from there.
    Run {
        /// The deck (TOML).
        deck: PathBuf,
        /// Output directory (overrides [output].directory).
        #[arg(long, short)]
        output: Option<PathBuf>,
        /// No progress bar or lines.
        #[arg(long, short)]
        quiet: bool,
        /// Replace an earlier pmpm run in the output directory (only the files pmpm wrote are
        /// removed; a directory with other files is refused).
        #[arg(long)]
        force: bool,
        /// Go on from a checkpoint (OUTDIR/checkpoint.bin) written by a run of the same deck;
        /// simulation.end_time, the time step (dt, cfl, max_dt) and [output] may have changed.
        /// The frames, series.csv and probes.csv go on in the output directory.
        #[arg(long, value_name = "CHECKPOINT")]
        resume: Option<PathBuf>,
    },
    /// Time a deck, phase by phase.
    ///
    /// Runs it (to its end time, or --steps steps) and prints, per phase of the step, seconds and milliseconds per step, then particle updates per second, pressure
    /// iterations and peak memory per particle. Frames go to a scratch directory that is
    /// removed afterwards, unless --output is given.
    Bench {
        /// The deck (TOML).
        deck: PathBuf,
        /// Stop after this many steps.
        #[arg(long)]
        steps: Option<u64>,
        /// Keep the frames in this directory (overwritten).
        #[arg(long, short)]
        output: Option<PathBuf>,
    },
    /// Write a commented starter deck (a dam break) to begin a case from.
    ///
    /// Every key it sets has a comment; docs/deck.md has them all. The file is not replaced
    /// unless --force is given.
    Init {
        /// Where to write it.
        #[arg(default_value = "deck.toml")]
        deck: PathBuf,
        /// 2 or 3.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(2..=3))]
        dimension: u8,
        /// Replace the file if it exists.
        #[arg(long)]
        force: bool,
    },
    /// Validate a deck and print what it sets up, what it will cost, and warnings.
    ///
    /// Runs nothing: prints the grid, particles per body, materials, time step and estimated
    /// steps, output and checkpoint sizes and memory, and warns of common mistakes.
    Check {
        /// The deck (TOML).
        deck: PathBuf,
    },
    /// Run the validation suite and write REPORT.md with plots.
    ///
    /// The cases are in validation/decks. Exit status
    /// 0 once the report is written, failed cases included (they are in the report); 4 with
    /// --strict when a case does not meet its bound.
    Validate {
        /// Coarse versions of the same cases (a few minutes; CI).
        #[arg(long)]
        quick: bool,
        /// Exit with status 4 when a row does not meet its bound.
        #[arg(long)]
        strict: bool,
        /// Directory with the reference series that are not in the repository (lobovsky2014/).
        #[arg(long, default_value = "../shared/reference-data")]
        reference: PathBuf,
        /// Output directory [default: validation/report, or target/validation-quick with --quick].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Only these cases (hydrostatic, martin_moyce, conservation, lobovsky, cavity,
        /// poiseuille, couette, taylor_green, bingham_poiseuille, strip_footing, elastic).
        #[arg(long = "case", num_args = 1..)]
        case: Vec<String>,
    },
    /// Draw a run's output as PNG pictures.
    ///
    /// A frame's particles coloured by a field
    /// (default: the last frame, into OUTDIR/plot_<field>_NNNNNN.png), every frame (--all), or
    /// the time series and probes (--series, into OUTDIR/plot_series.png). Needs the CSV frames
    /// ("csv" in [output].formats).
    Plot {
        /// The output directory of a run.
        outdir: PathBuf,
        /// Frame number [default: the last frame].
        #[arg(long, conflicts_with_all = ["all", "series"])]
        frame: Option<usize>,
        /// Colour the particles by this field.
        #[arg(long, default_value = "pressure", value_parser = ["pressure", "speed", "material", "vx", "vy", "vz"])]
        field: String,
        /// Output PNG file (with --all: a directory) [default: in OUTDIR].
        #[arg(long)]
        out: Option<PathBuf>,
        /// One PNG per frame (for a movie), with one colour range over all frames.
        #[arg(long, conflicts_with = "series")]
        all: bool,
        /// Plot series.csv (kinetic energy, max speed, pressure iterations, dt) and the probes.
        #[arg(long)]
        series: bool,
        /// 3D runs: the plane the particles are projected onto [default: the vertical plane
        /// along x that holds gravity: xz with gravity along z].
        #[arg(long, value_parser = ["xy", "xz", "yz"])]
        plane: Option<String>,
        /// 3D runs: only the particles in a slab across an axis, AXIS=VALUE (m), seen along
        /// that axis (y=0.15: the slab about y = 0.15 m, in the xz plane).
        #[arg(long, value_name = "AXIS=VALUE", conflicts_with = "series")]
        slice: Option<String>,
        /// The slice's thickness (m) [default: one grid cell].
        #[arg(long, requires = "slice")]
        thickness: Option<f64>,
        /// Every frame into one animated GIF (OUTDIR/plot_<field>.gif, or --out), with one
        /// colour range over all frames; `--out NAME.mp4` writes an MP4 with ffmpeg from the
        /// PATH.
        #[arg(long, conflicts_with_all = ["series", "all", "frame"])]
        movie: bool,
        /// Lower end of the colour range [default: the data's].
        #[arg(long, allow_negative_numbers = true)]
        min: Option<f64>,
        /// Upper end of the colour range [default: the data's].
        #[arg(long, allow_negative_numbers = true)]
        max: Option<f64>,
        /// An explicit run's pressure as each particle has it; by default it is smoothed
        /// through the grid (the particles' own values form a checkerboard).
        #[arg(long)]
        particle_pressure: bool,
        /// A profile of --field along the segment from A to B, "X0,Y0:X1,Y1" (with Z in 3D,
        /// in m), as a PNG and a CSV (plot_line_<field>_NNNNNN.png and .csv).
        #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["series", "all", "movie"])]
        line: Option<String>,
    },
}

/// The system allocator, except that running out of memory (the machine's, or `ulimit -v`)
/// ends pmpm with exit status 1 and its own message instead of an abort (status 134): every
/// file a run writes is whole at any instant, so the run goes on from its last checkpoint.
struct Allocator;

/// Writes the out-of-memory message and exits, allocating nothing (the allocator is what
/// failed): `write` and `_exit` are async-signal-safe system calls.
#[cold]
fn out_of_memory() -> ! {
    const MESSAGE: &[u8] = b"error: out of memory (an allocation was refused: the address-space \
limit of ulimit -v, or the machine's memory): pmpm stopped; a run's files up to its last checkpoint are whole. Free memory, raise \
the limit, or use fewer --threads or a coarser grid, then go on with --resume \
OUTDIR/checkpoint.bin (or run again where there is no checkpoint yet)\n";
    #[cfg(unix)]
    // SAFETY: write(2) reads MESSAGE, a static; _exit ends the process without running
    // anything that could allocate.
    unsafe {
        libc::write(2, MESSAGE.as_ptr().cast(), MESSAGE.len());
        libc::_exit(1)
    }
    #[cfg(not(unix))]
    std::process::abort()
}

// SAFETY: every call goes to the system allocator with the same arguments; a null result
// (out of memory) never returns.
unsafe impl std::alloc::GlobalAlloc for Allocator {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        let p = std::alloc::System.alloc(layout);
        if p.is_null() {
            out_of_memory()
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        let p = std::alloc::System.alloc_zeroed(layout);
        if p.is_null() {
            out_of_memory()
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        std::alloc::System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, size: usize) -> *mut u8 {
        let p = std::alloc::System.realloc(ptr, layout, size);
        if p.is_null() {
            out_of_memory()
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Allocator = Allocator;

fn main() -> ExitCode {
    let cli = Cli::parse();
    // under mpirun (the `mpi` feature), one process of several: MPI is started here, before
    // the worker threads, and finalised as `ranks` goes out of scope at the end of main
    let ranks = match mpi_ranks() {
        Ok(ranks) => ranks,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let root = ranks.as_ref().is_none_or(|r| r.0.is_root());
    if ranks.as_ref().is_some_and(|r| r.0.is_distributed())
        && !matches!(cli.command, Command::Run { .. })
    {
        if root {
            eprintln!(
                "error: only `pmpm run` runs over MPI ranks; run the other commands without mpirun"
            );
        }
        return ExitCode::from(2);
    }
    if cli.threads == Some(0) {
        eprintln!("error: --threads must be at least 1");
        return ExitCode::from(2);
    }
    let most = max_threads();
    if let Some(n) = cli.threads.filter(|&n| n > most) {
        eprintln!(
            "error: --threads {n}: at most {most} on this machine ({} cores; up to 8 threads a \
             core, at least 64, so that a run made elsewhere with more threads can be repeated \
             bit for bit)",
            cores()
        );
        return ExitCode::from(2);
    }
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = cli.threads {
        builder = builder.num_threads(n);
    }
    let pool = match builder.build() {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: cannot start the worker threads: {e}");
            return ExitCode::from(2);
        }
    };
    // The whole run executes on a worker of the pool: the many short parallel loops of a step
    // then start without waking a sleeping thread from outside the pool each time.
    let allow_large = cli.allow_large;
    match pool.install(|| execute(cli.command, allow_large, ranks.clone())) {
        Ok(0) => ExitCode::SUCCESS,
        Ok(failed) => {
            eprintln!("validate: {failed} row(s) did not meet their bound");
            ExitCode::from(4)
        }
        Err(e) => {
            // every rank stops with the same error: rank 0 says it
            if root {
                eprintln!("error: {}", pmpm::limits::shorten_numbers(&e.to_string()));
            }
            ExitCode::from(e.exit_code())
        }
    }
}

/// The MPI ranks of a run started under `mpirun` (None on one process, or without the `mpi`
/// feature).
#[cfg(feature = "mpi")]
fn mpi_ranks() -> Result<Option<pmpm::comm::Ranks>, String> {
    let Some(mpi) = pmpm::comm::Mpi::init() else {
        return Ok(None);
    };
    Ok(Some(pmpm::comm::Ranks(std::sync::Arc::new(mpi?))))
}

/// The MPI ranks of a run started under `mpirun` (None on one process, or without the `mpi`
/// feature).
#[cfg(not(feature = "mpi"))]
fn mpi_ranks() -> Result<Option<pmpm::comm::Ranks>, String> {
    Ok(None)
}

/// The cores this process may use.
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The most worker threads `--threads` accepts: starting tens of thousands of threads takes
/// minutes and memory for nothing.
fn max_threads() -> usize {
    (8 * cores()).max(64)
}

/// The deck's warnings, a line each, as `run` and `bench` print them when the run starts.
fn warning_lines(d: &pmpm::Deck, file: &str) -> Vec<String> {
    check::warnings(d)
        .iter()
        .map(|w| format!("warning: {file}: {}", pmpm::limits::shorten_numbers(w)))
        .collect()
}

/// Runs a command; Ok(number of failed validation rows).
fn execute(
    cmd: Command,
    allow_large: bool,
    ranks: Option<pmpm::comm::Ranks>,
) -> Result<usize, Error> {
    match cmd {
        Command::Run {
            deck,
            output,
            quiet,
            force,
            resume,
        } => run_command(&deck, output, quiet, force, resume, allow_large, ranks),
        Command::Bench {
            deck,
            steps,
            output,
        } => bench_command(&deck, steps, output, allow_large),
        Command::Init {
            deck,
            dimension,
            force,
        } => {
            let text = if dimension == 2 {
                include_str!("init/starter_2d.toml")
            } else {
                include_str!("init/starter_3d.toml")
            };
            if deck.exists() && !force {
                return Err(Error::Usage(format!(
                    "{}: exists; give another path, or --force to replace it",
                    deck.display()
                )));
            }
            pmpm::atomic::write_atomic(&deck, |w| std::io::Write::write_all(w, text.as_bytes()))
                .map_err(|e| Error::io(&deck, e))?;
            println!(
                "wrote {}: a {dimension}D dam break to start from; next: pmpm check {0}",
                deck.display()
            );
            Ok(0)
        }
        Command::Check { deck } => {
            let d = run::load(&deck)?;
            pmpm::limits::refuse_beyond_limits(&d, &deck.display().to_string(), allow_large)?;
            let summary = check::check_summary(&d, &deck.display().to_string())?;
            print!("{}", pmpm::limits::shorten_numbers(&summary));
            Ok(0)
        }
        Command::Validate {
            quick,
            strict,
            reference,
            out,
            case,
        } => {
            let out = out.unwrap_or_else(|| {
                PathBuf::from(if quick {
                    "target/validation-quick"
                } else {
                    "validation/report"
                })
            });
            let failed = pmpm_cli::validation::validate(pmpm_cli::validation::Options {
                quick,
                reference,
                out,
                cases: case,
            })?;
            Ok(if strict { failed } else { 0 })
        }
        Command::Plot {
            outdir,
            frame,
            field,
            out,
            all,
            series,
            plane,
            slice,
            thickness,
            movie,
            min,
            max,
            particle_pressure,
            line,
        } => {
            let opts = pmpm_cli::plot::PlotOptions {
                frame,
                field: pmpm_cli::plot::Field::from_name(&field),
                out,
                all,
                series,
                plane: plane.as_deref().and_then(pmpm_cli::plot::Plane::from_name),
                slice,
                thickness,
                movie,
                min,
                max,
                particle_pressure,
                line,
            };
            for png in pmpm_cli::plot::plot(&outdir, &opts)? {
                println!("wrote {}", png.display());
            }
            Ok(0)
        }
    }
}

/// `pmpm run`: the deck run to its end, with a progress bar unless `quiet`.
fn run_command(
    deck: &Path,
    output: Option<PathBuf>,
    quiet: bool,
    force: bool,
    resume: Option<PathBuf>,
    allow_large: bool,
    ranks: Option<pmpm::comm::Ranks>,
) -> Result<usize, Error> {
    // rank 0 speaks for a run over several ranks
    let root = ranks.as_ref().is_none_or(|r| r.0.is_root());
    progress::catch_interrupts(root);
    let quiet = quiet || !root;
    let d = run::load(deck)?;
    let file = deck.display().to_string();
    pmpm::limits::refuse_beyond_limits(&d, &file, allow_large)?;
    let dir = output.unwrap_or_else(|| PathBuf::from(&d.output.directory));
    let from = match &resume {
        Some(p) => format!(" from {}", p.display()),
        None => String::new(),
    };
    let mut progress = Progress::new(
        quiet,
        d.simulation.scheme == Scheme::Projection,
        format!("{:?} run of {file}{from}", d.simulation.scheme),
        warning_lines(&d, &file),
    );
    let summary = run::run(
        &d,
        &file,
        &dir,
        &RunOptions {
            force,
            max_steps: None,
            resume,
            interrupt: Some(progress::interrupt_flag()),
            ranks,
        },
        &mut progress,
    )?;
    if !quiet {
        eprintln!(
            "pmpm: done: {} steps, {} frames, {:.2} s wall, last dt = {:.3e} s, output in {}",
            summary.steps,
            summary.frames,
            summary.wall_seconds,
            summary.last_dt,
            dir.display()
        );
    }
    Ok(0)
}

/// `pmpm bench`: the deck timed phase by phase, in a scratch folder unless `output` is given.
fn bench_command(
    deck: &Path,
    steps: Option<u64>,
    output: Option<PathBuf>,
    allow_large: bool,
) -> Result<usize, Error> {
    // Ctrl-C or SIGTERM ends the timed run at a step and removes the scratch folder
    progress::catch_interrupts(true);
    let d = run::load(deck)?;
    pmpm::limits::refuse_beyond_limits(&d, &deck.display().to_string(), allow_large)?;
    let scratch = output.is_none();
    let dir = output
        .unwrap_or_else(|| std::env::temp_dir().join(format!("pmpm-bench-{}", std::process::id())));
    let file = deck.display().to_string();
    let summary = run::run(
        &d,
        &file,
        &dir,
        &RunOptions {
            force: true,
            max_steps: steps,
            resume: None,
            interrupt: Some(progress::interrupt_flag()),
            ranks: None,
        },
        // the deck's warnings only, as the run starts
        &mut Progress::new(true, false, String::new(), warning_lines(&d, &file)),
    );
    let removed = scratch.then(|| std::fs::remove_dir_all(&dir));
    // a message that points to a checkpoint or a file in the scratch folder says that
    // the folder is gone (or that it could not be removed)
    let scratch_note = match &removed {
        Some(Ok(())) => "; the bench ran in a scratch folder, now removed: pmpm bench \
                         --output DIR keeps its files"
            .to_string(),
        Some(Err(e)) => format!(
            "; the bench's scratch folder {} could not be removed ({e})",
            dir.display()
        ),
        None => String::new(),
    };
    let summary = summary.map_err(|e| match e {
        // its resume command points into the removed folder
        Error::Interrupted(_) if scratch => {
            Error::Interrupted(format!("bench interrupted{scratch_note}"))
        }
        e => e.with_note(&scratch_note),
    })?;
    if let Some(Err(e)) = removed {
        eprintln!(
            "warning: the bench's scratch folder {} could not be removed: {e}",
            dir.display()
        );
    }
    print!(
        "{}",
        check::bench_report(&d, &file, &summary, rayon::current_num_threads())
    );
    Ok(0)
}
