//! The `pmpm` command line.

use clap::{Parser, Subcommand};
use pmpm::run::{self, RunOptions};
use pmpm::Error;
use std::path::PathBuf;
use std::process::ExitCode;

/// pmpm: material point method for incompressible materials (water, mud, clay, rubber).
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Worker threads (default: all cores). Results are bitwise repeatable for a given count.
    #[arg(long, global = true)]
    threads: Option<usize>,
}

#[derive(Subcommand)]
enum Command {
    /// Run a deck: writes frames, series.csv, probes.csv and run.toml into the output directory.
    Run {
        /// The deck (TOML).
        deck: PathBuf,
        /// Output directory (overrides [output].directory).
        #[arg(long, short)]
        output: Option<PathBuf>,
        /// No progress lines.
        #[arg(long, short)]
        quiet: bool,
        /// Overwrite an output directory that holds an earlier run.
        #[arg(long)]
        force: bool,
    },
    /// Parse and validate a deck, and print a summary; runs nothing.
    Check {
        /// The deck (TOML).
        deck: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if n == 0 {
            eprintln!("error: --threads must be at least 1");
            return ExitCode::from(2);
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
        {
            eprintln!("error: cannot start {n} threads: {e}");
            return ExitCode::from(2);
        }
    }
    match execute(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

fn execute(cmd: Command) -> Result<(), Error> {
    match cmd {
        Command::Run {
            deck,
            output,
            quiet,
            force,
        } => {
            let d = run::load(&deck)?;
            let dir = output.unwrap_or_else(|| PathBuf::from(&d.output.directory));
            run::run(
                &d,
                &deck.display().to_string(),
                &dir,
                &RunOptions { quiet, force },
            )?;
            Ok(())
        }
        Command::Check { deck } => {
            let d = run::load(&deck)?;
            print!("{}", run::check_summary(&d, &deck.display().to_string())?);
            Ok(())
        }
    }
}
