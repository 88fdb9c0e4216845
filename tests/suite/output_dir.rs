//! The output directory is pmpm's own: a run writes only into a new or empty directory or into
//! an earlier pmpm run's (with --force), never over a user's files, and leaves no frame of an
//! earlier run behind (issue: never lose or mix a user's results).

use crate::common;

use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::Path;

fn write_deck(dir: &Path, name: &str, text: &str) -> String {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn run(args: &[&str]) -> (i32, String) {
    let o = pmpm(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    (o.status.code().unwrap_or(-1), err)
}

/// The frame files in `dir/frames`, sorted.
fn frames(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// A directory holding a user's file (here the deck itself, as with `--output .` in the deck's
/// folder) is refused with exit status 2, with --force too, and the file is left as it was.
#[test]
fn a_directory_with_the_users_files_is_refused() {
    let dir = scratch_dir("outdir-user");
    let deck = write_deck(&dir, "run.toml", SMALL_2D);
    let d = dir.to_str().unwrap();
    for force in [false, true] {
        let mut args = vec!["run", deck.as_str(), "-o", d, "-q"];
        if force {
            args.push("--force");
        }
        let (status, err) = run(&args);
        assert_eq!(status, 2, "{err}");
        assert!(err.contains("which pmpm did not write"), "{err}");
        assert_eq!(std::fs::read_to_string(&deck).unwrap(), SMALL_2D);
        assert!(!dir.join("series.csv").exists());
    }
}

/// --force replaces an earlier run whole: a shorter run leaves none of the earlier run's later
/// frames behind (`plot` would draw the old last frame), and a file the user put in the
/// directory stays.
#[test]
fn force_removes_the_earlier_runs_frames_and_nothing_else() {
    let dir = scratch_dir("outdir-force");
    let deck = write_deck(&dir, "deck.toml", SMALL_2D);
    let short = write_deck(
        &dir,
        "short.toml",
        &SMALL_2D.replace("end_time = 0.05", "end_time = 0.02"),
    );
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    assert_eq!(run(&["run", &deck, "-o", o, "-q"]).0, 0);
    assert_eq!(frames(&out).len(), 12, "{:?}", frames(&out));
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let (status, err) = run(&["run", &short, "-o", o, "-q"]);
    assert_eq!(
        status, 2,
        "an earlier run is not replaced without --force: {err}"
    );
    assert_eq!(frames(&out).len(), 12);
    assert_eq!(run(&["run", &short, "-o", o, "-q", "--force"]).0, 0);
    let f = frames(&out);
    assert_eq!(
        f.len(),
        6,
        "frames 0 to 2 in two formats, none older: {f:?}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    let series = std::fs::read_to_string(out.join("series.csv")).unwrap();
    assert_eq!(series.lines().count(), 4, "{series}");
}

/// A resume writes into the checkpoint's own directory; into a directory holding another run it
/// is refused and that run is left as it was; into a new directory it first copies the
/// checkpoint's run, so the new directory holds the whole run.
#[test]
fn a_resume_writes_only_into_its_own_run_or_a_new_directory() {
    let dir = scratch_dir("outdir-resume");
    let first = write_deck(
        &dir,
        "first.toml",
        &SMALL_2D.replace("end_time = 0.05", "end_time = 0.03"),
    );
    let deck = write_deck(&dir, "deck.toml", SMALL_2D);
    let (a, b, c) = (dir.join("a"), dir.join("b"), dir.join("c"));
    let (sa, sb, sc) = (
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        c.to_str().unwrap(),
    );
    assert_eq!(run(&["run", &first, "-o", sa, "-q"]).0, 0);
    assert_eq!(run(&["run", &deck, "-o", sb, "-q"]).0, 0);
    let other = std::fs::read_to_string(b.join("series.csv")).unwrap();
    let ck = a.join("checkpoint.bin");
    let ck = ck.to_str().unwrap();
    // into another run: refused, that run untouched
    let (status, err) = run(&["run", &deck, "-o", sb, "-q", "--resume", ck]);
    assert_eq!(status, 2, "{err}");
    assert!(err.contains("holds another run"), "{err}");
    assert_eq!(
        std::fs::read_to_string(b.join("series.csv")).unwrap(),
        other
    );
    // into a new directory: the whole run there, the checkpoint's directory untouched
    let before = std::fs::read_to_string(a.join("series.csv")).unwrap();
    assert_eq!(run(&["run", &deck, "-o", sc, "-q", "--resume", ck]).0, 0);
    assert_eq!(
        std::fs::read_to_string(a.join("series.csv")).unwrap(),
        before
    );
    assert_eq!(
        frames(&c),
        frames(&b),
        "the copied and resumed run has every frame"
    );
    let series = std::fs::read_to_string(c.join("series.csv")).unwrap();
    assert_eq!(series.lines().count(), 7, "{series}");
    // into its own directory
    assert_eq!(run(&["run", &deck, "-o", sa, "-q", "--resume", ck]).0, 0);
    assert_eq!(frames(&a), frames(&b));
}

/// series.csv closes every row with the particles' interior fill: 1 to round-off for the
/// block as seeded (frame 0), with every interior node within 5 %; a row an earlier build wrote
/// without those columns gets NaN in them when the run is resumed, so every row keeps the
/// header's columns.
#[test]
fn series_reports_the_interior_fill_and_a_resume_pads_older_rows() {
    let dir = scratch_dir("outdir-fill");
    // the block off the walls, so that its edge nodes' fill is far from 1/2
    let text = SMALL_2D.replace(
        "min = [0.0, 0.0], max = [0.1, 0.1]",
        "min = [0.03, 0.03], max = [0.23, 0.15]",
    );
    let first = write_deck(
        &dir,
        "first.toml",
        &text.replace("end_time = 0.05", "end_time = 0.03"),
    );
    let deck = write_deck(&dir, "deck.toml", &text);
    let out = dir.join("out");
    let so = out.to_str().unwrap();
    assert_eq!(run(&["run", &first, "-o", so, "-q"]).0, 0);
    let t = pmpm_cli::table::Table::read(&out.join("series.csv")).unwrap();
    let col = |name: &str| t.column(name).unwrap_or_else(|| panic!("no column {name}"));
    let (p1, p99, within, nodes) = (
        col("fill_p1"),
        col("fill_p99"),
        col("fill_within_5pct"),
        col("fill_nodes"),
    );
    // 20 x 12 particles of spacing h / 2: fill nodes of c = h, 8 x 4 interior ones (the
    // second row in from each edge has fill 7/8, the first 1/8)
    assert_eq!(nodes[0], 32.0);
    assert!((p1[0] - 1.0).abs() < 1e-12 && (p99[0] - 1.0).abs() < 1e-12);
    assert_eq!(within[0], 1.0);
    assert!(p99.iter().all(|v| v.is_finite()), "{p99:?}");
    // an earlier build's rows: the fill columns cut off every row; the resume pads them
    let ck = out.join("checkpoint.bin");
    let series = std::fs::read_to_string(out.join("series.csv")).unwrap();
    let cut: Vec<String> = series
        .lines()
        .map(|l| l.split(',').take(8).collect::<Vec<_>>().join(","))
        .collect();
    std::fs::write(out.join("series.csv"), cut.join("\n") + "\n").unwrap();
    let ck = ck.to_str().unwrap();
    assert_eq!(run(&["run", &deck, "-o", so, "-q", "--resume", ck]).0, 0);
    let t = pmpm_cli::table::Table::read(&out.join("series.csv")).unwrap();
    let p99 = t.column("fill_p99").unwrap();
    assert!(p99[0].is_nan() && p99[3].is_nan(), "{p99:?}");
    assert!(p99[4..].iter().all(|v| v.is_finite()), "{p99:?}");
}
