//! Limits up front: decks that cannot run on this machine (memory, steps, threads) or cannot
//! start (an initial field that is not a number) are refused by `check` and `run` with exit
//! status 2 and a message, before anything is allocated or written; numbers in messages are
//! short (issue: never lose or mix a user's results, items 8, 10, 11 and 13).

use crate::common;

use common::{pmpm, scratch_dir, SMALL_2D};
use std::time::{Duration, Instant};

/// Runs `args` and returns (exit status, stderr, stdout).
fn run(args: &[&str]) -> (i32, String, String) {
    let o = pmpm(args);
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
    )
}

/// The small deck with `from` replaced by `to`, written to a scratch folder.
fn deck(name: &str, from: &str, to: &str) -> (std::path::PathBuf, String) {
    assert_eq!(SMALL_2D.matches(from).count(), 1, "{from}");
    let dir = scratch_dir(name);
    let path = dir.join("deck.toml");
    std::fs::write(&path, SMALL_2D.replace(from, to)).unwrap();
    (dir, path.to_str().unwrap().to_string())
}

/// A deck needing hundreds of GB is refused at once (it used to allocate for seconds and
/// abort with SIGABRT), by check and by run, and the output directory is not created.
#[test]
fn a_deck_larger_than_the_machine_is_refused_before_allocating() {
    let (dir, d) = deck("limits-memory", "cell_size = 0.02", "cell_size = 0.00001");
    let out = dir.join("out");
    for cmd in ["check", "run"] {
        let t = Instant::now();
        let mut args = vec![cmd, d.as_str()];
        if cmd == "run" {
            args.extend(["-o", out.to_str().unwrap()]);
        }
        let (status, err, _) = run(&args);
        assert_eq!(status, 2, "{cmd}: {err}");
        assert!(
            err.contains("the run needs about 95.8 GB of memory") && err.contains("--allow-large"),
            "{cmd}: {err}"
        );
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "{cmd} took {:?}",
            t.elapsed()
        );
    }
    assert!(!out.exists());
}

/// A deck needing 1e298 steps (dt = 1e-300, or a bulk modulus of 1e100) is refused, with the
/// count in short form; --allow-large lets check describe it, the step count in short form
/// too (it used to print 300 digits).
#[test]
fn a_runaway_step_count_is_refused_and_printed_short() {
    let (_dir, d) = deck("limits-steps", "cfl = 0.4", "dt = 1e-300");
    let (status, err, _) = run(&["check", &d]);
    assert_eq!(status, 2, "{err}");
    assert!(
        err.contains("the run needs about 5.000e298 steps to simulation.end_time = 0.05 s"),
        "{err}"
    );
    let (status, err, out) = run(&["check", &d, "--allow-large"]);
    assert_eq!(status, 0, "{err}");
    assert!(
        out.contains("steps            about 5.000e298 to t = 0.05 s"),
        "{out}"
    );
    // (1e100 is the largest modulus a deck may give)
    let (dir, k) = deck("limits-k", "bulk_modulus = 4.0e4", "bulk_modulus = 1e100");
    let out = dir.join("out");
    let (status, err, _) = run(&["run", &k, "-q", "-o", out.to_str().unwrap()]);
    assert_eq!(status, 2, "{err}");
    assert!(err.contains("e49 steps"), "{err}");
    assert!(err.lines().all(|l| l.len() < 400), "{err}");
    assert!(!out.exists());
}

/// --threads beyond what the machine can use is refused at once (it used to spend minutes
/// starting 100,000 threads).
#[test]
fn too_many_threads_are_refused() {
    let (_dir, d) = deck("limits-threads", "end_time = 0.05", "end_time = 0.05");
    let t = Instant::now();
    let (status, err, _) = run(&["--threads", "100000", "check", &d]);
    assert_eq!(status, 2, "{err}");
    assert!(err.contains("--threads 100000: at most"), "{err}");
    assert!(t.elapsed() < Duration::from_secs(5));
}

/// `pmpm check` on the small deck with `from` replaced by `to`: asserts exit 2 and returns
/// the message.
fn refused_by_check(name: &str, from: &str, to: &str) -> String {
    let (_dir, d) = deck(name, from, to);
    let (status, err, _) = run(&["check", &d]);
    assert_eq!(status, 2, "{err}");
    err
}

/// An initial velocity or a body force that is not a number where the run reads it is a deck
/// error from check (it used to pass check and stop the run after frame 0).
#[test]
fn an_expression_that_is_not_a_number_at_the_start_is_refused() {
    let err = refused_by_check(
        "limits-nan-v",
        "particles_per_cell = 2",
        "particles_per_cell = 2\nvelocity = [\"log(x - 0.05)\", \"0\"]",
    );
    assert!(
        err.contains("bodies[0].velocity: is not a finite number at (0.005000, 0.005000)"),
        "{err}"
    );
    let err = refused_by_check(
        "limits-nan-g",
        "gravity = [0.0, -9.81]",
        "gravity = [\"0\", \"-9.81 / x\"]",
    );
    assert!(
        err.contains("simulation.gravity: is not a finite number at (0.000000, 0.000000)"),
        "{err}"
    );
}

/// A long number in a message is printed short: a probe at x = 1e300.
#[test]
fn numbers_in_messages_are_short() {
    let err = refused_by_check(
        "limits-short",
        "position = [0.01, 0.01]",
        "position = [1e300, 0.01]",
    );
    assert!(
        err.ends_with("lies outside the grid along x: x = 1e300, the grid spans [0, 0.4]\n"),
        "{err}"
    );
}

/// `plot --out` into a folder that does not exist is a usage error with a sentence, not a
/// debug dump of the image library's error.
#[test]
fn plot_into_a_missing_folder_says_so() {
    let (dir, d) = deck("limits-plot", "end_time = 0.05", "end_time = 0.02");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    assert_eq!(run(&["run", &d, "-o", o, "-q"]).0, 0);
    let missing = dir.join("nowhere/picture.png");
    let (status, err, _) = run(&["plot", o, "--out", missing.to_str().unwrap()]);
    assert_eq!(status, 2, "{err}");
    assert!(err.contains("does not exist; create it first"), "{err}");
    assert!(!err.contains("Error("), "{err}");
}
