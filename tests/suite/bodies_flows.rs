//! Rigid bodies, inflows, materials and runs that used to pass `check` and then go wrong
//! (issue 52): a prescribed body too fast for the step limit, a rigid body's velocity that
//! depends on position or is not a number within the run, free bodies that start inside
//! another, an inflow into a full box or under a solid, a material parameter the run cannot
//! take, two runs on one directory, and plots of what is not there.

use crate::common;

use common::{pmpm, scratch_dir, SMALL_2D};

/// Runs `args` and returns (exit status, stderr, stdout).
fn run(args: &[&str]) -> (i32, String, String) {
    let o = pmpm(args);
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
    )
}

/// The small deck with `extra` appended, written to a scratch folder: its path.
fn deck_with(name: &str, extra: &str) -> (std::path::PathBuf, String) {
    let dir = scratch_dir(name);
    let path = dir.join("deck.toml");
    std::fs::write(&path, format!("{SMALL_2D}\n{extra}")).unwrap();
    (dir, path.to_str().unwrap().to_string())
}

/// `check` and `run` refuse the small deck with `extra` appended: exit 2, the message holds
/// every one of `want`, and nothing is written.
fn refused(name: &str, extra: &str, want: &[&str]) {
    let (dir, d) = deck_with(name, extra);
    let out = dir.join("out");
    for cmd in ["check", "run"] {
        let mut args = vec![cmd, d.as_str()];
        if cmd == "run" {
            args.extend(["-o", out.to_str().unwrap()]);
        }
        let (status, err, _) = run(&args);
        assert_eq!(status, 2, "{name} ({cmd}): {err}");
        for w in want {
            assert!(err.contains(w), "{name} ({cmd}): wanted {w:?} in: {err}");
        }
    }
    assert!(!out.exists(), "{name}: nothing may be written");
}

/// `check` accepts the small deck with `extra` appended.
fn accepted(name: &str, extra: &str) {
    let (_dir, d) = deck_with(name, extra);
    let (status, err, _) = run(&["check", &d]);
    assert_eq!(status, 0, "{name}: {err}");
}

const PADDLE: &str = "[[rigid_bodies]]\nname = \"paddle\"\nshape = { type = \"box\", min = [0.2, 0.12], max = [0.26, 0.16] }\n";

/// A prescribed body whose speed over the run asks for more than 1e9 steps is refused naming
/// its key (1e12 rad/s and exp(1000 t) m/s used to pass with "about 13 steps").
#[test]
fn a_prescribed_body_too_fast_for_the_step_limit_is_refused() {
    refused(
        "fast-spin",
        &format!("{PADDLE}angular_velocity = 1e12\n"),
        &[
            "rigid_bodies[0].angular_velocity: the body's fastest point moves at",
            "more than 1e9",
            "--allow-large",
        ],
    );
    refused(
        "fast-exp",
        &format!("{PADDLE}velocity = [\"exp(1000*t)\", \"0\"]\n"),
        &[
            "rigid_bodies[0].velocity: the body's fastest point moves at 5.185e21 m/s at t = 0.05 s",
        ],
    );
    // a body at a walking pace is well within the limit
    accepted("slow-spin", &format!("{PADDLE}angular_velocity = 2.0\n"));
}

/// A rigid body's velocity that names x, y or z is refused even where sampling would not show
/// it (sin(pi y) is 0 at y = 0 and 1), and so is one that is not a finite number within the
/// run; one that is NaN only after end_time is not looked at there.
#[test]
fn a_rigid_velocity_of_position_or_not_a_number_within_the_run_is_refused() {
    for (name, v) in [
        ("pos-y", "[\"sin(pi*y)\", \"0\"]"),
        ("pos-x0", "[\"t + 0*x\", \"0\"]"),
    ] {
        refused(
            name,
            &format!("{PADDLE}velocity = {v}\n"),
            &["rigid_bodies[0].velocity: may depend on t only"],
        );
    }
    refused(
        "nan-within",
        &format!("{PADDLE}velocity = [\"sqrt(0.02 - t)\", \"0\"]\n"),
        &[
            "rigid_bodies[0].velocity: is not a finite number at t = 0.02",
            "simulation.end_time = 0.05 s",
        ],
    );
    refused(
        "nan-spin-within",
        &format!("{PADDLE}angular_velocity = \"sqrt(0.01 - t)\"\n"),
        &["rigid_bodies[0].angular_velocity: is not a finite number at t = 0.01"],
    );
    // NaN from t = 0.5 s on, after end_time = 0.05 s (it used to be refused as depending on x)
    accepted(
        "nan-after",
        &format!("{PADDLE}velocity = [\"sqrt(0.5 - t)\", \"0\"]\n"),
    );
}

/// A free body that starts inside another rigid body is a deck error naming both (it was a
/// warning).
#[test]
fn a_free_body_overlapping_another_at_the_start_is_refused() {
    let extra = "[[rigid_bodies]]\nname = \"quay\"\nshape = { type = \"box\", min = [0.3, 0.0], max = [0.4, 0.14] }\n\n\
                 [[rigid_bodies]]\nname = \"boat\"\nshape = { type = \"box\", min = [0.26, 0.12], max = [0.34, 0.18] }\nmotion = \"free\"\ndensity = 500.0\n";
    refused(
        "free-overlap",
        extra,
        &["rigid_bodies[1].shape: the free body \"boat\" overlaps rigid_bodies[0] (\"quay\") at t = 0"],
    );
    accepted(
        "free-apart",
        &extra.replace(
            "min = [0.26, 0.12], max = [0.34, 0.18]",
            "min = [0.2, 0.15], max = [0.28, 0.19]",
        ),
    );
}

/// An inflow patch under a rigid body is refused naming both (water used to enter through
/// the solid).
#[test]
fn an_inflow_under_a_rigid_body_is_refused() {
    let inflow = "[[inflows]]\nmaterial = \"water\"\nface = \"x_min\"\nmin = [0.0, 0.12]\nmax = [0.0, 0.16]\nvelocity = [0.1, 0.0]\n";
    refused(
        "inflow-covered",
        &format!("{inflow}\n[[rigid_bodies]]\nname = \"plug\"\nshape = {{ type = \"box\", min = [0.0, 0.1], max = [0.06, 0.18] }}\n"),
        &["inflows[0].min: the patch on the face x_min is covered by rigid_bodies[0] (\"plug\") at t = 0"],
    );
    accepted("inflow-free", &format!("{inflow}\n{PADDLE}"));
}

/// A closed 0.2 x 0.1 m box holding a little water, with an inflow of 1 m/s through 4 cm of
/// its left wall: full after about 0.46 s.
const CLOSED_BOX: &str = r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.2
cfl = 0.5
gravity = [0.0, -9.81]

[grid]
origin = [0.0, 0.0]
size = [0.2, 0.1]
cell_size = 0.02

[grid.boundary]
x_min = "slip"
x_max = "slip"
y_min = "slip"
y_max = "slip"

[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3

[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [0.04, 0.04] }

[[inflows]]
material = "water"
face = "x_min"
min = [0.0, 0.0]
max = [0.0, 0.04]
velocity = [1.0, 0.0]

[output]
interval = 0.1
formats = ["csv"]
"#;

/// An inflow into a closed box that brings in more than the box holds is refused by check
/// (it used to run to exit 0 holding 1.7 times the water the box can hold); one that fits
/// passes.
#[test]
fn an_inflow_that_would_fill_a_closed_box_is_refused() {
    let dir = scratch_dir("inflow-fill");
    let path = dir.join("deck.toml");
    std::fs::write(
        &path,
        CLOSED_BOX.replace("end_time = 0.2", "end_time = 1.0"),
    )
    .unwrap();
    let (status, err, _) = run(&["check", path.to_str().unwrap()]);
    assert_eq!(status, 2, "{err}");
    assert!(
        err.contains("inflows[0].velocity: the inflows bring in about 4.000e-2 m2 of material by simulation.end_time = 1 s, and the grid has room for about 1.841e-2 m2"),
        "{err}"
    );
    std::fs::write(&path, CLOSED_BOX).unwrap();
    let (status, err, _) = run(&["check", path.to_str().unwrap()]);
    assert_eq!(status, 0, "{err}");
}

/// A run whose inflow fills its closed box stops with exit status 3 and says so (here the end
/// time is raised past the check's, as a deck the check cannot judge would run on).
#[test]
fn a_run_stops_once_its_inflow_has_filled_a_closed_box() {
    let mut deck = common::deck(CLOSED_BOX);
    deck.simulation.end_time = 1.0;
    let dir = scratch_dir("inflow-filled");
    let out = dir.join("out");
    let result = common::in_pool(2, || {
        pmpm::run::run(
            &deck,
            "deck.toml",
            &out,
            &pmpm::run::RunOptions::default(),
            &mut pmpm::run::Silent,
        )
    });
    let err = result.expect_err("the run must stop");
    assert_eq!(err.exit_code(), 3, "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("the inflow (inflows[0]) has filled the domain"),
        "{msg}"
    );
    // full at 0.46 s, stopped within a few steps of it
    let t: f64 = msg["run stopped at t = ".len()..]
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((0.44..0.52).contains(&t), "{msg}");
}

/// A viscosity past what the run can compute with is refused naming the key: 1e300 by the
/// bound on every material parameter, 1e20 Pa s by the implicit solve's round-off (it used
/// to be accepted and then blamed on a blow-up).
#[test]
fn a_viscosity_the_run_cannot_take_is_refused() {
    let projection = SMALL_2D.replace("scheme = \"explicit\"", "scheme = \"projection\"");
    for (name, mu, want) in [
        ("visc-1e300", "1.0e300", "materials[0].viscosity: 1.000e300 is beyond what a run can compute with: at most 1e100"),
        ("visc-1e20", "1.0e20", "materials[0].viscosity: \"water\" is too viscous for the implicit viscous solve"),
    ] {
        let dir = scratch_dir(name);
        let path = dir.join("deck.toml");
        std::fs::write(&path, projection.replace("viscosity = 1.0e-3", &format!("viscosity = {mu}"))).unwrap();
        let (status, err, _) = run(&["check", path.to_str().unwrap()]);
        assert_eq!(status, 2, "{name}: {err}");
        assert!(err.contains(want), "{name}: {err}");
    }
    // honey, and a stiff paste, pass
    for mu in ["10.0", "1.0e6"] {
        let dir = scratch_dir("visc-ok");
        let path = dir.join("deck.toml");
        std::fs::write(
            &path,
            projection.replace("viscosity = 1.0e-3", &format!("viscosity = {mu}")),
        )
        .unwrap();
        let (status, err, _) = run(&["check", path.to_str().unwrap()]);
        assert_eq!(status, 0, "{mu}: {err}");
    }
}

/// A run takes an exclusive lock on its output directory: while another process holds it, a
/// second `run --force` or a resume is refused at once (exit 2, naming the holder's pid) and
/// the run there is left as it was; the lock file survives --force (two runs on one directory
/// used to race: one died with a wrong message, one left a series.csv of its header only).
#[test]
fn a_second_run_on_a_locked_directory_is_refused() {
    let (dir, d) = deck_with("lock", "");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let (status, err, _) = run(&["run", &d, "-o", o, "--quiet"]);
    assert_eq!(status, 0, "{err}");
    let lock_path = out.join(".pmpm-lock");
    assert!(lock_path.exists());
    let series = std::fs::read(out.join("series.csv")).unwrap();
    // another run's hold on the directory: this process's
    let lock = pmpm::output::lock_directory(&out).unwrap();
    let holder = format!(
        "another pmpm is running in this output directory (pid {})",
        std::process::id()
    );
    let checkpoint = out.join("checkpoint.bin");
    let longer = dir.join("longer.toml");
    std::fs::write(
        &longer,
        SMALL_2D.replace("end_time = 0.05", "end_time = 0.1"),
    )
    .unwrap();
    let longer = longer.to_str().unwrap();
    for args in [
        vec!["run", &d, "-o", o, "--force"],
        vec![
            "run",
            longer,
            "-o",
            o,
            "--resume",
            checkpoint.to_str().unwrap(),
        ],
    ] {
        let (status, err, _) = run(&args);
        assert_eq!(status, 2, "{args:?}: {err}");
        assert!(err.contains(&holder), "{args:?}: {err}");
        assert_eq!(std::fs::read(out.join("series.csv")).unwrap(), series);
    }
    drop(lock);
    let (status, err, _) = run(&["run", &d, "-o", o, "--force", "--quiet"]);
    assert_eq!(status, 0, "{err}");
    assert!(lock_path.exists(), "--force keeps the lock file");
}

/// `pmpm plot` refuses what would draw a blank picture (it used to exit 0): a `--line` with a
/// point outside the grid, `--field vz` of a 2D run, a `--slice` outside a 3D run's grid; the
/// message names the option and what is valid.
#[test]
fn plots_of_what_is_not_there_are_refused() {
    let (dir, d) = deck_with("plot-blank-2d", "");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let (status, err, _) = run(&["run", &d, "-o", o, "--quiet"]);
    assert_eq!(status, 0, "{err}");
    for (args, want) in [
        (
            vec!["plot", o, "--field", "vz"],
            "--field vz: a 2D run has no z velocity; its fields are pressure, speed, material, vx and vy",
        ),
        (
            vec!["plot", o, "--line", "0.5,0.05:0.9,0.05"],
            "--line 0.5,0.05:0.9,0.05: the point A lies outside the grid, which spans x = [0, 0.4], y = [0, 0.2] m",
        ),
        (
            vec!["plot", o, "--line", "0.1,0.05:0.1,-0.3"],
            "--line 0.1,0.05:0.1,-0.3: the point B lies outside the grid, which spans x = [0, 0.4], y = [0, 0.2] m",
        ),
    ] {
        let (status, err, stdout) = run(&args);
        assert_eq!(status, 2, "{args:?}: {err}");
        assert_eq!(err, format!("error: {want}\n"), "{args:?}");
        assert!(stdout.is_empty(), "{args:?}: {stdout}");
    }
    let deck3 = r#"
[simulation]
dimension = 3
scheme = "explicit"
end_time = 0.01
cfl = 0.4
gravity = [0.0, 0.0, -9.81]

[grid]
size = [0.2, 0.1, 0.1]
cell_size = 0.025

[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3
bulk_modulus = 4.0e4

[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0, 0.0], max = [0.05, 0.1, 0.05] }

[output]
interval = 0.01
formats = ["csv"]
"#;
    let dir = scratch_dir("plot-blank-3d");
    let path = dir.join("deck.toml");
    std::fs::write(&path, deck3).unwrap();
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let (status, err, _) = run(&["run", path.to_str().unwrap(), "-o", o, "--quiet"]);
    assert_eq!(status, 0, "{err}");
    let (status, err, _) = run(&["plot", o, "--slice", "y=0.5"]);
    assert_eq!(status, 2, "{err}");
    assert_eq!(
        err,
        "error: --slice y=0.5: the value lies outside the grid, which spans y = [0, 0.1] m\n"
    );
    let (status, err, _) = run(&["plot", o, "--slice", "y=0.05"]);
    assert_eq!(status, 0, "{err}");
}
