//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A fresh, empty scratch directory under the target directory.
pub fn scratch_dir(name: &str) -> PathBuf {
    static N: AtomicUsize = AtomicUsize::new(0);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!(
        "{name}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs the pmpm binary with arguments.
pub fn pmpm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pmpm"))
        .args(args)
        .output()
        .expect("the pmpm binary runs")
}

/// A small valid 2D deck (explicit scheme) that runs in well under a second.
pub const SMALL_2D: &str = r#"
[simulation]
dimension = 2
scheme = "explicit"
end_time = 0.05
cfl = 0.4
gravity = [0.0, -9.81]
transfer = "apic"

[grid]
origin = [0.0, 0.0]
size = [0.4, 0.2]
cell_size = 0.02

[grid.boundary]
x_min = "slip"
x_max = "slip"
y_min = "no_slip"
y_max = "open"

[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3
bulk_modulus = 4.0e4

[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [0.1, 0.1] }
particles_per_cell = 2

[output]
interval = 0.01
formats = ["vtk", "csv"]

[[output.probes]]
name = "base"
position = [0.01, 0.01]
"#;

/// Runs `f` on a worker of a pool of `threads` threads: a step's short parallel loops then start
/// without waking threads from outside the pool (as `pmpm run` does).
pub fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
        .install(f)
}

/// A deck parsed and validated from text.
pub fn deck(text: &str) -> pmpm::Deck {
    let mut d = pmpm::Deck::parse(text, "test.toml").expect("test deck parses");
    d.validate("test.toml").expect("test deck is valid");
    d
}

/// Steps `sim` to the end time of its deck `d` through the driver `pmpm run` uses: the deck's
/// fixed `dt` or its adaptive step at its `cfl`, landing on frame times as the deck says.
/// `each` sees the state and the step after every step and returns `false` to stop early.
pub fn drive<const D: usize>(
    d: &pmpm::Deck,
    sim: &mut pmpm::scheme::Simulation<D>,
    each: impl FnMut(&pmpm::scheme::Simulation<D>, &pmpm::driver::Step) -> bool,
) {
    pmpm::driver::Driver::new(pmpm::build::clock(d))
        .run(sim, each)
        .expect("the run reaches its end time");
}
