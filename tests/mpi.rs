//! Runs spread over MPI ranks (`mpirun -n N pmpm run DECK`), against the same deck on one
//! process. Built only with the `mpi` feature (`cargo test --release --features mpi --test
//! mpi`, after scripts/install-mpi.sh), and run by `.ci/run` where MPICH can be installed.
//!
//! The ranks add up the particles' sums in another order than one process does, so a run
//! over ranks agrees with one process to round-off, not to the bit: within 1e-9 of each
//! field's largest value below (the CSV files print 10 digits; measured: 5e-10 at most, on 3
//! ranks).
//! A given rank count repeats bit for bit, and so does a run resumed on the ranks that wrote
//! its checkpoint.
#![cfg(feature = "mpi")]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh scratch directory under the target directory.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("mpi-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `pmpm --threads 1 ARGS` on `ranks` MPI ranks (0: one process, without mpirun).
fn run_on(ranks: usize, args: &[&str]) -> Output {
    let pmpm = env!("CARGO_BIN_EXE_pmpm");
    let mut cmd = if ranks == 0 {
        Command::new(pmpm)
    } else {
        let mut c = Command::new("mpirun");
        c.args(["-n", &ranks.to_string(), pmpm]);
        c
    };
    cmd.args(["--threads", "1"])
        .args(args)
        .current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("examples"))
        .output()
        .expect("mpirun is on the PATH (scripts/install-mpi.sh)")
}

/// Runs `deck` into `dir/NAME-N` on `ranks` ranks and returns that directory; the run must
/// succeed.
fn run(ranks: usize, deck: &Path, dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(format!("{name}-{ranks}"));
    let o = run_on(
        ranks,
        &[
            &["run", deck.to_str().unwrap(), "-q", "--force", "-o"],
            &[out.to_str().unwrap()][..],
        ]
        .concat(),
    );
    assert!(
        o.status.success(),
        "{ranks} ranks: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// An example deck with `end_time` and its output interval replaced, written into `dir`.
fn deck(example: &str, end_time: f64, interval: f64, dir: &Path) -> PathBuf {
    deck_named(example, end_time, interval, dir, "")
}

/// [`deck`], its file name ending in `tag`.
fn deck_named(example: &str, end_time: f64, interval: f64, dir: &Path, tag: &str) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("examples/{example}.toml")),
    )
    .unwrap();
    let text: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with("end_time") {
                format!("end_time = {end_time}")
            } else if l.starts_with("interval") {
                format!("interval = {interval}")
            } else {
                l.to_string()
            }
        })
        .collect();
    let path = dir.join(format!("{example}-{end_time}{tag}.toml"));
    std::fs::write(&path, text.join("\n")).unwrap();
    path
}

/// A CSV file's header and rows of numbers.
fn table(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

/// The largest difference in each column of two tables of the same shape, over its scale
/// (the largest magnitude in the column, at least `floor`).
fn relative_differences(a: &Path, b: &Path, floor: f64) -> Vec<(String, f64)> {
    let ((header, mut ra), (_, mut rb)) = (table(a), table(b));
    // a frame's rows by id (over ranks, each rank's rows in id order, rank after rank)
    if let Some(id) = header.iter().position(|h| h == "id") {
        for rows in [&mut ra, &mut rb] {
            rows.sort_by(|x, y| x[id].total_cmp(&y[id]));
        }
    }
    assert_eq!(ra.len(), rb.len(), "{a:?} and {b:?}: row counts");
    (0..header.len())
        .map(|k| {
            let scale = ra.iter().map(|r| r[k].abs()).fold(floor, f64::max);
            let diff = ra
                .iter()
                .zip(&rb)
                .map(|(x, y)| (x[k] - y[k]).abs())
                .fold(0.0, f64::max);
            (header[k].clone(), diff / scale)
        })
        .collect()
}

/// Asserts that every column of `file` in `a` and `b` agrees within `bound` of its scale,
/// the columns named in `skip` aside.
fn agree(a: &Path, b: &Path, file: &str, bound: f64, skip: &[&str]) {
    agree_above(a, b, file, bound, skip, 1e-12);
}

/// [`agree`], a column's scale at least `floor` (a component that is round-off about 0).
fn agree_above(a: &Path, b: &Path, file: &str, bound: f64, skip: &[&str], floor: f64) {
    for (name, d) in relative_differences(&a.join(file), &b.join(file), floor) {
        if !skip.contains(&name.as_str()) {
            assert!(
                d <= bound,
                "{file}, {name}: differs by {d:.2e} of its scale (bound {bound:.0e})"
            );
        }
    }
}

/// The last frame's CSV file name.
fn last_frame(out: &Path) -> String {
    let mut frames: Vec<String> = std::fs::read_dir(out.join("frames"))
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".csv"))
        .collect();
    frames.sort();
    format!("frames/{}", frames.last().unwrap())
}

#[test]
fn the_explicit_dam_break_on_two_and_three_ranks_agrees_with_one_process() {
    let dir = scratch("dam-break");
    let deck = deck("dam_break_2d_explicit", 0.02, 0.01, &dir);
    let one = run(0, &deck, &dir, "out");
    for ranks in [2, 3] {
        let many = run(ranks, &deck, &dir, "out");
        let frame = last_frame(&one);
        assert_eq!(frame, last_frame(&many));
        // positions, velocities and pressures of every particle (by id)
        agree(&one, &many, &frame, 1e-9, &[]);
        agree(&one, &many, "probes.csv", 1e-9, &[]);
        agree(&one, &many, "series.csv", 1e-9, &["wall_seconds"]);
    }
}

#[test]
fn a_rank_count_repeats_bit_for_bit_and_resumes_bit_for_bit() {
    let dir = scratch("repeat");
    let short = deck("dam_break_2d_explicit", 0.01, 0.005, &dir);
    let long = deck("dam_break_2d_explicit", 0.02, 0.005, &dir);
    let a2 = run(2, &long, &dir, "first");
    let b = run(2, &long, &dir, "second");
    let frame = last_frame(&b);
    for file in [frame.as_str(), "probes.csv"] {
        assert_eq!(
            std::fs::read(a2.join(file)).unwrap(),
            std::fs::read(b.join(file)).unwrap(),
            "{file}: two runs on 2 ranks differ"
        );
    }
    // to 0.01 s, then resumed to 0.02 s: on the same ranks bit for bit, on 3 to round-off
    let cut = run(2, &short, &dir, "cut");
    let checkpoint = cut.join("checkpoint.bin");
    let copy = dir.join("cut-copy");
    std::fs::create_dir_all(&copy).unwrap();
    for ranks in [2, 3] {
        let _ = std::fs::remove_dir_all(&copy);
        copy_dir(&cut, &copy);
        resume(ranks, &long, &copy);
        if ranks == 2 {
            assert_eq!(
                std::fs::read(copy.join(&frame)).unwrap(),
                std::fs::read(b.join(&frame)).unwrap(),
                "resumed on 2 ranks: the last frame differs from the run never stopped"
            );
        } else {
            agree(&b, &copy, &frame, 1e-9, &[]);
        }
    }
    assert!(checkpoint.exists());
}

#[test]
fn particles_that_cross_into_another_slab_and_new_cuts_keep_the_agreement() {
    // to 0.1 s the column falls and the front moves 0.1 m: particles cross the first cut and
    // the ranks cut again (at steps 510, 750, 950 and 1,140 of 1,393, as measured)
    let dir = scratch("slabs");
    let deck = deck("dam_break_2d_explicit", 0.1, 0.02, &dir);
    let one = run(0, &deck, &dir, "out");
    let two = run(2, &deck, &dir, "out");
    let frame = last_frame(&one);
    agree(&one, &two, &frame, 1e-9, &[]);
    agree(&one, &two, "probes.csv", 1e-9, &[]);
    // stopped at 0.06 s, after the new cuts, and resumed on 2 ranks: bit for bit
    let short = deck_named("dam_break_2d_explicit", 0.06, 0.02, &dir, "short");
    let cut = run(2, &short, &dir, "cut");
    resume(2, &deck, &cut);
    assert!(
        std::fs::read(cut.join(&frame)).unwrap() == std::fs::read(two.join(&frame)).unwrap(),
        "resumed on 2 ranks after new cuts: the last frame differs from the run never stopped"
    );
}

#[test]
fn frames_and_checkpoints_are_a_file_a_rank_and_a_lost_piece_is_named() {
    let dir = scratch("pieces");
    let short = deck("dam_break_2d_explicit", 0.01, 0.005, &dir);
    let long = deck("dam_break_2d_explicit", 0.02, 0.005, &dir);
    let two = run(2, &long, &dir, "whole");
    // the last frame: a .pvtu naming each rank's .vtu piece, which hold every particle of
    // the CSV frame; particles.pvd names the .pvtu
    let pvtu = std::fs::read_to_string(two.join("frames/particles_000004.pvtu")).unwrap();
    let mut points = 0;
    for rank in 0..2 {
        let piece = format!("particles_000004_{rank:04}.vtu");
        assert!(
            pvtu.contains(&format!("<Piece Source=\"{piece}\"/>")),
            "{pvtu}"
        );
        let bytes = std::fs::read(two.join("frames").join(&piece)).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        let at = text.find("NumberOfPoints=\"").unwrap() + 16;
        let digits: String = text[at..]
            .chars()
            .take_while(char::is_ascii_digit)
            .collect();
        points += digits.parse::<usize>().unwrap();
    }
    let (_, rows) = table(&two.join("frames/particles_000004.csv"));
    assert_eq!(points, rows.len());
    let pvd = std::fs::read_to_string(two.join("particles.pvd")).unwrap();
    assert!(pvd.contains("frames/particles_000004.pvtu"), "{pvd}");
    let cut = run(2, &short, &dir, "cut");
    // checkpoints at 0.005 s and 0.01 s: the second one's piece of rank 1 is in the set 0
    // (the first one's, in the set 1, is left until the next one is whole)
    let piece = cut.join("checkpoint.bin.0.rank0001");
    assert!(piece.exists() && cut.join("checkpoint.bin.1.rank0001").exists());
    // resumed on one process from a checkpoint of two ranks: every piece read
    let copy = dir.join("one");
    copy_dir(&cut, &copy);
    resume(0, &long, &copy);
    let frame = last_frame(&two);
    agree(&two, &copy, &frame, 1e-9, &[]);
    // without the piece of rank 1 the resume stops before it touches the directory (here
    // its frames after the checkpoint's, from the longer run), and names the file
    let copy = dir.join("lost");
    copy_dir(&two, &copy);
    for name in [
        "checkpoint.bin",
        "checkpoint.bin.1.rank0001",
        "checkpoint.bin.0.rank0001",
    ] {
        std::fs::copy(cut.join(name), copy.join(name)).unwrap();
    }
    std::fs::remove_file(copy.join("checkpoint.bin.0.rank0001")).unwrap();
    let before = std::fs::read(copy.join("series.csv")).unwrap();
    let frames = std::fs::read_dir(copy.join("frames")).unwrap().count();
    let o = resumed(2, &long, &copy);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("checkpoint.bin.0.rank0001"), "{err}");
    assert_eq!(std::fs::read(copy.join("series.csv")).unwrap(), before);
    assert_eq!(
        std::fs::read_dir(copy.join("frames")).unwrap().count(),
        frames
    );
}

/// Resumes the run in `out` from its checkpoint with `deck` on `ranks` ranks; it must succeed.
fn resume(ranks: usize, deck: &Path, out: &Path) {
    let o = resumed(ranks, deck, out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// What resuming the run in `out` from its checkpoint with `deck` on `ranks` ranks gives.
fn resumed(ranks: usize, deck: &Path, out: &Path) -> Output {
    run_on(
        ranks,
        &[
            "run",
            deck.to_str().unwrap(),
            "-q",
            "-o",
            out.to_str().unwrap(),
            "--resume",
            out.join("checkpoint.bin").to_str().unwrap(),
        ],
    )
}

/// Copies a run's directory (files and the frames folder).
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to.join("frames")).unwrap();
    for sub in ["", "frames"] {
        for e in std::fs::read_dir(from.join(sub)).unwrap() {
            let e = e.unwrap();
            if e.file_type().unwrap().is_file() {
                std::fs::copy(e.path(), to.join(sub).join(e.file_name())).unwrap();
            }
        }
    }
}

#[test]
fn a_bingham_slump_with_nodal_averaging_agrees_on_two_ranks() {
    let dir = scratch("bingham");
    let deck = deck("bingham_slump_2d_explicit", 0.05, 0.025, &dir);
    let one = run(0, &deck, &dir, "out");
    let two = run(2, &deck, &dir, "out");
    agree(&one, &two, &last_frame(&one), 1e-9, &[]);
}

#[test]
fn a_deck_this_stage_cannot_spread_is_refused_with_its_key() {
    let dir = scratch("refused");
    let base = deck("dam_break_2d", 0.01, 0.01, &dir);
    // the incomplete Cholesky preconditioner is not spread
    let text = std::fs::read_to_string(&base)
        .unwrap()
        .replace("preconditioner = \"jacobi\"", "preconditioner = \"ic0\"");
    let deck = dir.join("ic0.toml");
    std::fs::write(&deck, text).unwrap();
    let out = dir.join("out");
    let o = run_on(
        2,
        &[
            "run",
            deck.to_str().unwrap(),
            "-q",
            "-o",
            out.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("pressure.preconditioner") && err.contains("not supported yet"),
        "{err}"
    );
    // said once (by rank 0), and nothing written
    assert_eq!(err.matches("error:").count(), 1, "{err}");
    assert!(!out.exists());
    // a grid too short for two slabs as wide as the projection's window (8 layers): 10 x 4
    // cells, 15 x 9 nodes with the padding
    let text = std::fs::read_to_string(&base)
        .unwrap()
        .replace("cell_size = 0.0028575", "cell_size = 0.05");
    let deck = dir.join("coarse.toml");
    std::fs::write(&deck, text).unwrap();
    let args = [
        "run",
        deck.to_str().unwrap(),
        "-q",
        "-o",
        out.to_str().unwrap(),
    ];
    let o = run_on(2, &args);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("simulation.scheme") && err.contains("run it on at most 1 ranks"),
        "{err}"
    );
    assert!(!out.exists());
}

// The projection's solves stop at a relative residual of 1e-8 and their dot products round
// otherwise over ranks: its runs agree with one process to 1e-7 of each column's scale (they
// agree to the CSV's digits, 1e-10, as measured).

#[test]
fn the_projection_dam_break_on_two_ranks_agrees_repeats_and_resumes() {
    let dir = scratch("projection");
    // to 0.1 s (62 steps): the column falls and the surge starts along the floor; the steps
    // land on the frames, so that the run stopped at 0.05 s ends where the full one passes
    let landing = |path: PathBuf| {
        let text = std::fs::read_to_string(&path).unwrap();
        let text = text.replace("[simulation]", "[simulation]\nland_on_frames = true");
        std::fs::write(&path, text).unwrap();
        path
    };
    let deck_file = landing(deck("dam_break_2d", 0.1, 0.05, &dir));
    let one = run(0, &deck_file, &dir, "out");
    let two = run(2, &deck_file, &dir, "out");
    let frame = last_frame(&one);
    assert_eq!(frame, last_frame(&two));
    agree(&one, &two, &frame, 1e-7, &[]);
    agree(&one, &two, "probes.csv", 1e-7, &[]);
    agree(&one, &two, "series.csv", 1e-7, &["wall_seconds"]);
    // the same rank count, bit for bit; stopped at 0.05 s and resumed, bit for bit
    let again = run(2, &deck_file, &dir, "again");
    let short = landing(deck_named("dam_break_2d", 0.05, 0.05, &dir, "short"));
    let cut = run(2, &short, &dir, "cut");
    resume(2, &deck_file, &cut);
    for other in [&again, &cut] {
        for file in [frame.as_str(), "probes.csv"] {
            assert!(
                std::fs::read(two.join(file)).unwrap() == std::fs::read(other.join(file)).unwrap(),
                "{file}: a second run on 2 ranks, or one resumed, differs"
            );
        }
    }
    // resumed on one process (every piece read, each rank's node pressure on its own slab):
    // to round-off
    let cut = run(2, &short, &dir, "cut-again");
    resume(0, &deck_file, &cut);
    agree(&two, &cut, &frame, 1e-7, &[]);
}

#[test]
fn the_projection_bingham_slump_cut_along_x_agrees_on_two_ranks() {
    let dir = scratch("bingham-projection");
    // a layer 12 cells deep: the slabs are cut along x
    let deck = deck("bingham_slump_2d", 0.05, 0.025, &dir);
    let one = run(0, &deck, &dir, "out");
    let two = run(2, &deck, &dir, "out");
    agree(&one, &two, &last_frame(&one), 1e-7, &[]);
}

#[test]
fn the_projection_3d_column_and_its_rigid_body_agree_on_two_ranks() {
    let dir = scratch("column-3d-projection");
    // past t = 0.15 s, when the surge reaches the column
    let deck = deck("dam_break_column_3d", 0.2, 0.1, &dir);
    let one = run(0, &deck, &dir, "out");
    let two = run(2, &deck, &dir, "out");
    agree(&one, &two, &last_frame(&one), 1e-7, &[]);
    // the force on the column (N; its spanwise part is round-off about 0 on both)
    agree_above(&one, &two, "rigid_bodies.csv", 1e-7, &[], 1.0);
    let (header, rows) = table(&two.join("rigid_bodies.csv"));
    let fx = header.iter().position(|h| h == "column_fx").unwrap();
    assert!(
        rows.iter().any(|r| r[fx] > 1.0),
        "the surge reached the column"
    );
}

#[test]
fn the_3d_column_and_its_rigid_body_agree_on_two_ranks() {
    let dir = scratch("column-3d");
    // past t = 0.15 s, when the surge reaches the column
    let deck = deck("dam_break_column_3d_explicit", 0.2, 0.1, &dir);
    let one = run(0, &deck, &dir, "out");
    let two = run(2, &deck, &dir, "out");
    agree(&one, &two, &last_frame(&one), 1e-9, &[]);
    // the force on the column (N; its spanwise part is round-off about 0 on both)
    agree_above(&one, &two, "rigid_bodies.csv", 1e-9, &[], 1.0);
    let (header, rows) = table(&two.join("rigid_bodies.csv"));
    let fx = header.iter().position(|h| h == "column_fx").unwrap();
    assert!(
        rows.iter().any(|r| r[fx] > 1.0),
        "the surge reached the column"
    );
}

#[test]
fn gauges_and_particle_probes_read_every_ranks_particles() {
    let dir = scratch("gauges");
    let base = deck("dam_break_2d_explicit", 0.02, 0.01, &dir);
    let text = std::fs::read_to_string(&base)
        .unwrap()
        .replace("[output]", "[output]\ngauge_interval = 0.002");
    let extra = r#"
[[output.probes]]
name = "foot"
position = [0.01, 0.01]
sample = "particles"
radius = 0.01

[[output.gauges]]
name = "level"
type = "surface"
position = [0.03]

[[output.gauges]]
name = "p"
type = "pressure"
position = [0.02, 0.02]

[[output.gauges]]
name = "wall"
type = "wall_force"
face = "x_min"
"#;
    let deck = dir.join("gauged.toml");
    std::fs::write(&deck, text + extra).unwrap();
    let one = run(0, &deck, &dir, "out");
    let two = run(2, &deck, &dir, "out");
    // the particles' means (a probe over a radius, gauges) over all ranks' particles: a rank's
    // own would read about half the water
    agree(&one, &two, "probes.csv", 1e-9, &[]);
    agree(&one, &two, "gauges.csv", 1e-9, &[]);
    let (header, rows) = table(&two.join("gauges.csv"));
    let level = header.iter().position(|h| h == "level_height").unwrap();
    assert!(
        rows.iter().all(|r| r[level] > 0.05),
        "the column stands above 0.05 m at x = 0.03 m"
    );
}
