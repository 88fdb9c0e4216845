//! Checkpoint and restart: a run stopped half-way and resumed writes the same frames, bit for
//! bit, as the run that never stopped; Ctrl-C stops cleanly with a checkpoint; a checkpoint
//! from another deck or a damaged file is refused with a clear message.

use crate::common;

use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::Path;
use std::process::Command;

fn write_deck(dir: &Path, name: &str, text: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn run_ok(args: &[&str]) {
    let o = pmpm(args);
    assert!(
        o.status.success(),
        "pmpm {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The first line of stderr, with the `error: ` prefix, and the exit status.
fn failure(args: &[&str]) -> (i32, String) {
    let o = pmpm(args);
    let err = String::from_utf8_lossy(&o.stderr);
    let line = err
        .lines()
        .find(|l| l.starts_with("error: "))
        .unwrap_or("")
        .to_string();
    (o.status.code().unwrap_or(-1), line)
}

/// Every file of `a/frames` is in `b/frames` with the same bytes.
fn same_frames(a: &Path, b: &Path) -> usize {
    let mut n = 0;
    for e in std::fs::read_dir(a.join("frames")).unwrap() {
        let p = e.unwrap().path();
        let other = b.join("frames").join(p.file_name().unwrap());
        assert!(
            std::fs::read(&p).unwrap() == std::fs::read(&other).unwrap(),
            "{} differs",
            p.display()
        );
        n += 1;
    }
    n
}

/// Stopped at t = 0.02 s (a frame time, with a checkpoint at the end) and resumed to 0.05 s
/// with end_time raised, as a user would, the run writes every frame (CSV and VTU) and every
/// probe row exactly as the run straight to 0.05 s, for both schemes and for the projection
/// with one pressure per cell (an elastic block), on 2 threads.
#[test]
fn a_resumed_run_writes_the_frames_of_the_uninterrupted_run() {
    let cells = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace(
            "density = 1000.0\nviscosity = 1.0e-3\nbulk_modulus = 4.0e4",
            "model = \"neo_hookean_incompressible\"\ndensity = 1000.0\nshear_modulus = 1.0e5",
        )
        // the solid's shear wave sets a step that does not divide 0.02 s: the steps land on
        // the frame times, so that the stopped run ends where the full one writes its frame
        .replace(
            "transfer = \"apic\"",
            "transfer = \"apic\"\nstress_update = \"usl\"\nland_on_frames = true",
        )
        + "\n[pressure]\nunknowns = \"cells\"\n";
    assert!(cells.contains("neo_hookean"), "the edit found its lines");
    let open = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace("gravity = [0.0, -9.81]", "gravity = [5.0, -9.81]")
        .replace("x_max = \"slip\"", "x_max = \"outflow\"")
        .replace("min = [0.0, 0.0], max = [0.1, 0.1]", "min = [0.3, 0.0], max = [0.4, 0.1]")
        + "\n[[inflows]]\nmaterial = \"water\"\nface = \"x_min\"\nmin = [0.0, 0.0]\nmax = [0.0, 0.06]\nvelocity = [0.5, 0.0]\n";
    assert!(
        open.contains("outflow") && open.contains("[0.3, 0.0]") && open.contains("[5.0"),
        "the edit found its lines"
    );
    // a free box (no turning) afloat and a free disc that turns, dropped on the water: their
    // pose, velocity and the velocity of the step before carry over
    // (the disc's speed sets the step, which does not divide 0.02 s: the steps land on frames)
    let free = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace("transfer = \"apic\"", "transfer = \"apic\"\nland_on_frames = true")
        + "\n[[rigid_bodies]]\nname = \"boat\"\nshape = { type = \"box\", min = [0.02, 0.08], max = [0.08, 0.12] }\nmotion = \"free\"\ndensity = 500.0\nfixed = [\"rotation\"]\n\n[[rigid_bodies]]\nname = \"log\"\nshape = { type = \"sphere\", center = [0.2, 0.1], radius = 0.03 }\nmotion = \"free\"\ndensity = 800.0\nvelocity = [-1.0, 0.0]\nangular_velocity = 2.0\n";
    for (scheme, full) in [
        ("explicit", SMALL_2D.to_string()),
        ("free", free),
        (
            "projection",
            SMALL_2D.replace("\"explicit\"", "\"projection\""),
        ),
        ("cells", cells),
        // material enters through an inflow and leaves through an outflow face: the
        // particle count changes, and the ledger and the next particle id carry over
        ("open", open),
    ] {
        let dir = scratch_dir(&format!("resume-{scheme}"));
        let half = full.replace("end_time = 0.05", "end_time = 0.02");
        let full_deck = write_deck(&dir, "full.toml", &full);
        let half_deck = write_deck(&dir, "half.toml", &half);
        let (a, b) = (dir.join("a"), dir.join("b"));
        let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());
        run_ok(&["--threads", "2", "run", &full_deck, "-o", a, "-q"]);
        run_ok(&["--threads", "2", "run", &half_deck, "-o", b, "-q"]);
        let checkpoint = format!("{b}/checkpoint.bin");
        run_ok(&[
            "--threads",
            "2",
            "run",
            &full_deck,
            "-o",
            b,
            "-q",
            "--resume",
            &checkpoint,
        ]);
        let n = same_frames(Path::new(a), Path::new(b));
        assert_eq!(n, 12, "{scheme}: 6 frames in CSV and VTU");
        let rigid = Path::new(a).join("rigid_bodies.csv").exists();
        assert_eq!(rigid, scheme == "free", "{scheme}: rigid_bodies.csv");
        let files: &[&str] = if rigid {
            &["probes.csv", "particles.pvd", "rigid_bodies.csv"]
        } else {
            &["probes.csv", "particles.pvd"]
        };
        for file in files {
            assert_eq!(
                std::fs::read_to_string(Path::new(a).join(file)).unwrap(),
                std::fs::read_to_string(Path::new(b).join(file)).unwrap(),
                "{scheme}: {file}"
            );
        }
        // series.csv: the same rows but for the wall-clock column (the 8th)
        let rows = |d: &str| -> Vec<String> {
            std::fs::read_to_string(Path::new(d).join("series.csv"))
                .unwrap()
                .lines()
                .map(|l| {
                    let mut f: Vec<&str> = l.split(',').collect();
                    f.remove(7);
                    f.join(",")
                })
                .collect()
        };
        assert_eq!(rows(a), rows(b), "{scheme}: series.csv");
    }
}

/// A checkpoint is refused, with exit status 2 and a message that says why, when the deck
/// differs in a key that matters, when the file is damaged or cut short, when it is not a
/// checkpoint, and when the run it holds is already at the deck's end time.
#[test]
fn bad_checkpoints_are_refused_with_a_reason() {
    let dir = scratch_dir("resume-refused");
    let deck = write_deck(&dir, "deck.toml", SMALL_2D);
    let half = write_deck(
        &dir,
        "half.toml",
        &SMALL_2D.replace("end_time = 0.05", "end_time = 0.02"),
    );
    let other = write_deck(
        &dir,
        "other.toml",
        &SMALL_2D.replace("density = 1000.0", "density = 1020.0"),
    );
    let out = dir.join("out");
    let out = out.to_str().unwrap();
    run_ok(&["run", &half, "-o", out, "-q"]);
    let good = format!("{out}/checkpoint.bin");
    let bytes = std::fs::read(&good).unwrap();
    let damaged = dir.join("damaged.bin");
    let mut d = bytes.clone();
    d[bytes.len() / 2] ^= 1;
    std::fs::write(&damaged, &d).unwrap();
    let cut = dir.join("cut.bin");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let (damaged, cut) = (damaged.to_str().unwrap(), cut.to_str().unwrap());
    let cases = [
        (
            other.as_str(),
            good.as_str(),
            format!(
                "error: {good}: cannot resume from this file: it was written with a different \
                 deck: materials[0].density was 1000.0, the deck has 1020.0 (only \
                 simulation.end_time, simulation.dt, simulation.cfl, simulation.max_dt, \
                 output.directory, output.interval, output.formats, output.checkpoint_interval \
                 may change on resume)"
            ),
        ),
        (
            deck.as_str(),
            damaged,
            format!(
                "error: {damaged}: cannot resume from this file: it is damaged (checksum mismatch)"
            ),
        ),
        (
            deck.as_str(),
            cut,
            format!(
                "error: {cut}: cannot resume from this file: it is truncated or damaged ({} bytes \
                 of state, {} expected)",
                bytes.len() - 124,
                bytes.len() - 24
            ),
        ),
        (
            deck.as_str(),
            deck.as_str(),
            format!("error: {deck}: cannot resume from this file: it is not a pmpm checkpoint"),
        ),
        (
            half.as_str(),
            good.as_str(),
            format!(
                "error: {good}: the checkpoint is at t = 0.02 s, at or past simulation.end_time \
                 = 0.02 s in {half}: raise end_time to go on"
            ),
        ),
    ];
    let missing = dir.join("missing.bin");
    let missing = missing.to_str().unwrap();
    let cases = cases.into_iter().chain([
        (
            deck.as_str(),
            missing,
            format!("error: {missing}: cannot resume from this file: there is no such file"),
        ),
        (
            deck.as_str(),
            out,
            format!(
                "error: {out}: cannot resume from this file: it is a directory; give the \
                 checkpoint.bin inside it"
            ),
        ),
    ]);
    for (deck, file, message) in cases {
        let (status, line) = failure(&["run", deck, "-o", out, "-q", "--resume", file]);
        assert_eq!(status, 2, "{line}");
        assert_eq!(line, message);
    }
}

/// SIGINT (Ctrl-C) stops the run at the end of a step with exit status 130, a frame and a
/// checkpoint, and a message with the command that goes on; going on writes the frames of
/// the run that was never stopped, the same files under the same numbers (the frame written
/// at the interruption is off the schedule and the resumed run writes over it), and the
/// wall time in series.csv goes on from where it stopped.
#[test]
fn ctrl_c_stops_cleanly_and_the_run_goes_on_from_there() {
    let dir = scratch_dir("interrupt");
    // a closed tank, fixed small step: long enough (about 15,000 steps) to be interrupted
    let text = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace("transfer = \"apic\"", "transfer = \"flip\"")
        .replace("y_max = \"open\"", "y_max = \"slip\"")
        .replace("cfl = 0.4", "dt = 2.0e-4")
        .replace("end_time = 0.05", "end_time = 1.0")
        .replace("interval = 0.01", "interval = 0.1")
        .replace("cell_size = 0.02", "cell_size = 0.01");
    let deck = write_deck(&dir, "deck.toml", &text);
    let (a, b) = (dir.join("a"), dir.join("b"));
    let (a_s, b_s) = (a.to_str().unwrap(), b.to_str().unwrap());
    run_ok(&["--threads", "2", "run", &deck, "-o", a_s, "-q"]);
    let child = Command::new(env!("CARGO_BIN_EXE_pmpm"))
        .args(["--threads", "2", "run", &deck, "-o", b_s, "-q"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // once frame 1 is written the handler is installed and the run is under way
    while !b.join("frames/particles_000001.csv").exists() {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    let checkpoint = format!("{b_s}/checkpoint.bin");
    assert!(
        err.contains(&format!(
            "the frame and a checkpoint are written. To go on: pmpm run {deck} --resume \
             {checkpoint} --output {b_s}"
        )),
        "{err}"
    );
    run_ok(&[
        "--threads",
        "2",
        "run",
        &deck,
        "-o",
        b_s,
        "-q",
        "--resume",
        &checkpoint,
    ]);
    for n in 0..=10 {
        let name = format!("frames/particles_{n:06}.csv");
        let (fa, fb) = (
            std::fs::read(a.join(&name)).unwrap(),
            std::fs::read(b.join(&name)).unwrap(),
        );
        assert!(fa == fb, "frame {n} differs");
    }
    assert!(!b.join("frames/particles_000011.csv").exists());
    // series.csv: frames 0 to 10 once each, the wall time never going back
    let series = std::fs::read_to_string(b.join("series.csv")).unwrap();
    let rows: Vec<Vec<&str>> = series
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    let frames: Vec<&str> = rows.iter().map(|r| r[0]).collect();
    let want: Vec<String> = (0..=10).map(|n| n.to_string()).collect();
    assert_eq!(frames, want);
    let wall: Vec<f64> = rows.iter().map(|r| r[7].parse().unwrap()).collect();
    assert!(wall.windows(2).all(|w| w[1] >= w[0]), "{wall:?}");
}

/// A checkpoint that an earlier build wrote (`tests/fixtures/checkpoint_format1`: format 1,
/// pmpm 0.1.0, a projection dam break stopped at t = 0.02 s) still resumes, and the run goes
/// on from the state it holds: the frame at t = 0.03 s lists the same particles as a run from
/// the start with this build, each within a tenth of a cell of its place there and with its
/// volume within 1 %. Physics changes move them far less than that in 0.01 s; a field read
/// into the wrong place (positions, velocities, volumes, the ids' order) moves them far more.
#[test]
fn a_checkpoint_written_by_an_earlier_build_still_resumes() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/checkpoint_format1");
    let text = std::fs::read_to_string(fixture.join("deck.toml")).unwrap();
    assert!(
        text.contains("end_time = 0.02\n"),
        "the edit finds its line"
    );
    // the fixture's build held its walls both ways, where they now let the water go by
    // default: the deck says so, as the refusal of a deck without it asks
    let text = text.replace(
        "[grid.boundary]\n",
        "[grid.boundary]\ncontact = \"bonded\"\n",
    );
    // and it corrected the particles' volumes from J, where a free surface with linear
    // shapes now packs them by default
    let text = text.replace(
        "\n[[materials]]",
        "\n[pressure]\ndensity_correction = \"positions\"\n\n[[materials]]",
    );
    let dir = scratch_dir("resume-fixture");
    // the fixture's build solved viscosity explicitly, and the projection's default is now
    // implicit: the deck as it stands is refused by that key, and resumes once it says so
    let refused = write_deck(
        &dir,
        "refused.toml",
        &text.replace("end_time = 0.02\n", "end_time = 0.03\n"),
    );
    let out = pmpm(&[
        "run",
        &refused,
        "-o",
        dir.join("refused").to_str().unwrap(),
        "-q",
        "--resume",
        fixture.join("checkpoint.bin").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("simulation.viscosity was \"explicit\", the deck has \"implicit\""),
        "{err}"
    );
    let deck = write_deck(
        &dir,
        "deck.toml",
        &text.replace(
            "end_time = 0.02\n",
            "end_time = 0.03\nviscosity = \"explicit\"\n",
        ),
    );
    let (resumed, fresh) = (dir.join("resumed"), dir.join("fresh"));
    let checkpoint = fixture.join("checkpoint.bin");
    run_ok(&[
        "--threads",
        "1",
        "run",
        &deck,
        "-o",
        resumed.to_str().unwrap(),
        "-q",
        "--resume",
        checkpoint.to_str().unwrap(),
    ]);
    run_ok(&[
        "--threads",
        "1",
        "run",
        &deck,
        "-o",
        fresh.to_str().unwrap(),
        "-q",
    ]);
    let frame = |d: &Path| -> Vec<Vec<f64>> {
        std::fs::read_to_string(d.join("frames/particles_000003.csv"))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#') && !l.starts_with("id"))
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect()
    };
    let (a, b) = (frame(&resumed), frame(&fresh));
    assert_eq!(a.len(), 100, "the fixture's particles");
    assert_eq!(a.len(), b.len());
    // columns: id, x, y, vx, vy, pressure, mass, volume, material
    let h = 0.02;
    for (p, q) in a.iter().zip(&b) {
        assert_eq!(p[0], q[0], "ids in the same order");
        let moved = ((p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        assert!(
            moved < 0.1 * h,
            "particle {}: {moved} m from the fresh run's",
            p[0]
        );
        assert!(
            (p[7] / q[7] - 1.0).abs() < 0.01,
            "particle {}: volume",
            p[0]
        );
        assert_eq!(p[6], q[6], "particle {}: mass", p[0]);
    }
}

/// A resume after a mesh file the deck reads changed on disk is refused naming the file: the
/// run records each mesh file's length and CRC-32 with its deck. It used to resume with the
/// changed file (a body moved 6 cm between the checkpoint and the next step).
#[test]
fn a_resume_after_a_mesh_file_changed_is_refused() {
    let dir = scratch_dir("resume-mesh");
    let stl = dir.join("part.stl");
    let write = |lo: f32| {
        crate::geometry::write_binary_stl(
            &stl,
            "part",
            &crate::geometry::box_triangles([lo, lo, 0.0], [lo + 0.06, lo + 0.06, 0.06]),
        )
    };
    write(0.02);
    let text = r#"
[simulation]
dimension = 3
end_time = 0.004
cfl = 0.5
gravity = [0.0, 0.0, -9.81]

[grid]
size = [0.1, 0.1, 0.1]
cell_size = 0.02

[[materials]]
name = "water"
density = 1000.0

[[bodies]]
material = "water"
shape = { type = "mesh", file = "part.stl" }

[output]
interval = 0.002
formats = ["csv"]
"#;
    let half = write_deck(&dir, "half.toml", text);
    let full = write_deck(&dir, "full.toml", &text.replace("0.004", "0.008"));
    let out = dir.join("out");
    let out = out.to_str().unwrap();
    run_ok(&["run", &half, "-o", out, "-q"]);
    let checkpoint = format!("{out}/checkpoint.bin");
    // the same bytes: the resume goes on
    let again = dir.join("again");
    let again = again.to_str().unwrap();
    run_ok(&["run", &half, "-o", again, "-q"]);
    run_ok(&[
        "run",
        &full,
        "-o",
        again,
        "-q",
        "--resume",
        &format!("{again}/checkpoint.bin"),
    ]);
    // the part moved by a cell: refused
    write(0.04);
    let (status, line) = failure(&["run", &full, "-o", out, "-q", "--resume", &checkpoint]);
    assert_eq!(status, 2, "{line}");
    let file = std::fs::canonicalize(&stl).unwrap();
    assert!(
        line.contains(&format!(
            "the mesh file {} changed since the run began",
            file.display()
        )),
        "{line}"
    );
}
