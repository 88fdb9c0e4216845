//! Fault injection: a run killed at any instant (SIGKILL, or the two SIGTERMs `timeout` sends)
//! leaves a directory that reads and resumes to the bits of the run that was never stopped,
//! time series included; a file-size limit stops a run with pmpm's own message (issue: never
//! lose or mix a user's results).

use crate::common;

use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A closed tank under the projection with a fixed step, a probe and a rigid body: a frame every
/// 25 steps and a checkpoint every 10, so that most instants fall between a checkpoint and the
/// next frame (where the time series' rows are at stake). About half a second on 2 threads.
fn deck(dir: &Path) -> String {
    let text = SMALL_2D
        .replace("\"explicit\"", "\"projection\"")
        .replace("transfer = \"apic\"", "transfer = \"flip\"")
        .replace("y_max = \"open\"", "y_max = \"slip\"")
        .replace("cfl = 0.4", "dt = 1.0e-3")
        .replace("end_time = 0.05", "end_time = 0.3")
        .replace(
            "interval = 0.01",
            "interval = 0.025\ncheckpoint_interval = 0.01",
        )
        .replace("cell_size = 0.02", "cell_size = 0.01")
        + r#"
[[rigid_bodies]]
name = "block"
shape = { type = "box", min = [0.25, 0.0], max = [0.3, 0.05] }
"#;
    let path = dir.join("deck.toml");
    std::fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_pmpm"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn run_to_end(args: &[&str]) {
    let o = pmpm(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The tests here time their signals against a run's length: one at a time, so that another
/// test's load does not change the length in between.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// A small deterministic generator for the kill instants (the test must repeat).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The frame files particles.pvd lists; each must exist.
fn pvd_frames(dir: &Path) -> Vec<String> {
    let Ok(text) = std::fs::read_to_string(dir.join("particles.pvd")) else {
        return Vec::new();
    };
    assert!(
        text.trim_end().ends_with("</VTKFile>"),
        "particles.pvd is cut short: {text}"
    );
    text.split("file=\"")
        .skip(1)
        .map(|s| s.split('"').next().unwrap().to_string())
        .collect()
}

/// series.csv without its wall-clock column (`wall_seconds`), which no two runs share.
fn series(dir: &Path) -> String {
    let text = std::fs::read_to_string(dir.join("series.csv")).unwrap();
    let wall = text
        .lines()
        .next()
        .and_then(|h| h.split(',').position(|c| c == "wall_seconds"))
        .expect("series.csv has a wall_seconds column");
    text.lines()
        .map(|l| {
            let kept: Vec<&str> = l
                .split(',')
                .enumerate()
                .filter(|(k, _)| *k != wall)
                .map(|(_, v)| v)
                .collect();
            kept.join(",") + "\n"
        })
        .collect()
}

fn read(dir: &Path, name: &str) -> Vec<u8> {
    std::fs::read(dir.join(name)).unwrap_or_else(|e| panic!("{}: {e}", dir.join(name).display()))
}

/// Resumes `dir` from its checkpoint to the end, or runs it again where it was killed before
/// its first checkpoint.
fn finish(deck: &str, dir: &Path) {
    let d = dir.to_str().unwrap();
    let ck = dir.join("checkpoint.bin");
    let ck = ck.to_str().unwrap();
    if Path::new(ck).exists() {
        let o = pmpm(&["--threads", "2", "run", deck, "-o", d, "-q", "--resume", ck]);
        let err = String::from_utf8_lossy(&o.stderr);
        // killed after its last checkpoint, at the end time: the run is complete
        let complete = o.status.code() == Some(2) && err.contains("raise end_time to go on");
        assert!(o.status.success() || complete, "resume {d}: {err}");
    } else {
        run_to_end(&["--threads", "2", "run", deck, "-o", d, "-q", "--force"]);
    }
}

/// The finished run in `b` is the reference run `a`, bit for bit: every frame, series.csv (less
/// the wall clock), probes.csv and rigid_bodies.csv.
fn assert_same_run(a: &Path, b: &Path, what: &str) {
    assert_eq!(
        frame_files(a),
        frame_files(b),
        "{what}: the frame files differ"
    );
    for f in frame_files(a) {
        assert!(
            read(a, &format!("frames/{f}")) == read(b, &format!("frames/{f}")),
            "{what}: frame {f} differs"
        );
    }
    assert_eq!(series(a), series(b), "{what}: series.csv differs");
    for name in ["probes.csv", "rigid_bodies.csv", "particles.pvd"] {
        assert!(read(a, name) == read(b, name), "{what}: {name} differs");
    }
}

/// A scratch folder with the deck, and the reference run never stopped in its `reference`
/// folder: (folder, deck, reference, seconds the run took).
fn reference_run(name: &str) -> (std::path::PathBuf, String, std::path::PathBuf, f64) {
    let dir = scratch_dir(name);
    let deck = deck(&dir);
    let reference = dir.join("reference");
    let t0 = Instant::now();
    run_to_end(&[
        "--threads",
        "2",
        "run",
        &deck,
        "-o",
        reference.to_str().unwrap(),
        "-q",
    ]);
    (dir, deck, reference, t0.elapsed().as_secs_f64())
}

/// The frame files of a run (`.partial` ones left by a kill aside), sorted.
fn frame_files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !n.ends_with(".partial"))
        .collect();
    v.sort();
    v
}

/// SIGKILL at 50 instants spread over the run: after each, particles.pvd is whole and lists
/// only frames that exist, and the run, resumed from what the kill left, ends equal to the run
/// that was never stopped.
#[test]
fn a_run_killed_at_any_instant_resumes_to_the_same_bits() {
    let _serial = serial();
    let (dir, deck, reference, length) = reference_run("faults-kill");
    let mut rng = Lcg(20261126);
    let mut killed_mid_run = 0;
    for k in 0..50 {
        let out = dir.join(format!("k{k}"));
        let o = out.to_str().unwrap();
        let mut child = spawn(&["--threads", "2", "run", &deck, "-o", o, "-q"]);
        std::thread::sleep(Duration::from_secs_f64(rng.next() * length * 1.1));
        let _ = child.kill();
        let status = child.wait().unwrap();
        for f in pvd_frames(&out) {
            assert!(
                out.join(&f).exists(),
                "kill {k}: particles.pvd lists {f}, not there"
            );
        }
        if !status.success() {
            killed_mid_run += 1;
            finish(&deck, &out);
        }
        assert_same_run(&reference, &out, &format!("kill {k}"));
        let _ = std::fs::remove_dir_all(&out);
    }
    assert!(
        killed_mid_run >= 25,
        "only {killed_mid_run} of 50 kills fell inside the run"
    );
}

/// Two SIGTERMs at once (as `timeout` sends them), 20 times: each run stops at a step with exit
/// status 130, its last frame has its series row and the checkpoint is at that frame, and the
/// run goes on from there to the reference run's last state.
#[test]
fn a_double_signal_stops_cleanly_and_the_run_goes_on() {
    let _serial = serial();
    let (dir, deck, reference, length) = reference_run("faults-term");
    let last = "frames/particles_000012.csv";
    let mut rng = Lcg(7);
    let mut stopped = 0;
    for k in 0..20 {
        let out = dir.join(format!("t{k}"));
        let o = out.to_str().unwrap();
        let child = spawn(&["--threads", "2", "run", &deck, "-o", o, "-q"]);
        // once frame 0 is written the handler is installed
        let start = Instant::now();
        while !out.join("frames/particles_000000.csv").exists()
            && start.elapsed() < Duration::from_secs(20)
        {
            std::thread::sleep(Duration::from_millis(2));
        }
        std::thread::sleep(Duration::from_secs_f64(rng.next() * length * 0.8));
        for _ in 0..2 {
            let _ = Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status();
        }
        let o_ = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o_.stderr);
        if o_.status.success() {
            // the run ended before the signals came
            assert!(out.join(last).exists());
            continue;
        }
        stopped += 1;
        assert_eq!(o_.status.code(), Some(130), "signal pair {k}: {err}");
        assert!(err.contains("To go on: pmpm run"), "{err}");
        let frames = frame_files(&out)
            .iter()
            .filter(|n| n.ends_with(".csv"))
            .count();
        let rows = series(&out).lines().count() - 1;
        assert_eq!(
            rows, frames,
            "signal pair {k}: a frame without its series row"
        );
        finish(&deck, &out);
        // the stopped run wrote one frame more, at the time it stopped, unless that was a
        // frame's time
        let csv: Vec<String> = frame_files(&out)
            .into_iter()
            .filter(|n| n.ends_with(".csv"))
            .collect();
        let end = format!("frames/{}", csv.last().unwrap());
        assert!(
            read(&reference, last) == read(&out, &end),
            "signal pair {k}: the last states differ"
        );
        assert!(
            read(&reference, "probes.csv") == read(&out, "probes.csv"),
            "signal pair {k}: probes.csv differs"
        );
        let _ = std::fs::remove_dir_all(&out);
    }
    assert!(
        stopped >= 10,
        "only {stopped} of 20 signal pairs fell inside the run"
    );
}

/// A file-size limit (`ulimit -f`) stops the run with exit status 1 and a message that names
/// the file, not with SIGXFSZ (status 153 and no word), and leaves no part-written file.
#[test]
fn a_file_size_limit_is_reported() {
    let _serial = serial();
    let dir = scratch_dir("faults-fsize");
    let deck = dir.join("deck.toml");
    std::fs::write(&deck, SMALL_2D).unwrap();
    let out = dir.join("out");
    let o = under_ulimit("-f 10", "", &deck, &out, "");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("particles_000000.csv") && err.contains("before its first checkpoint"),
        "{err}"
    );
    let partial = std::fs::read_dir(out.join("frames"))
        .unwrap()
        .flatten()
        .any(|e| e.file_name().to_string_lossy().ends_with(".partial"));
    assert!(!partial, "a part-written frame was left behind");
}

/// `pmpm [global] run DECK -o OUT -q [extra]` in a shell under `ulimit LIMIT`.
fn under_ulimit(limit: &str, global: &str, deck: &Path, out: &Path, extra: &str) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit {limit} && exec {} {global} run {} -o {} -q {extra}",
            env!("CARGO_BIN_EXE_pmpm"),
            deck.display(),
            out.display()
        ))
        .output()
        .unwrap()
}

/// Under an address-space limit (`ulimit -v`) a deck that needs more is refused before it
/// allocates (exit 2), and one let through with --allow-large that runs out of memory stops
/// with exit 1 and pmpm's message, not an abort (134).
#[test]
fn an_address_space_limit_is_reported() {
    let _serial = serial();
    let dir = scratch_dir("faults-vlimit");
    let deck = dir.join("deck.toml");
    // 640,000 particles: about 0.8 GB, well past the limit, and one step
    let text = SMALL_2D
        .replace("cell_size = 0.02", "cell_size = 0.00025")
        .replace("cfl = 0.4", "dt = 1.0e-6")
        .replace("end_time = 0.05", "end_time = 1.0e-6");
    std::fs::write(&deck, text).unwrap();
    for (extra, status, message) in [
        ("", 2, "(ulimit -v): raise the limit"),
        ("--allow-large", 1, "error: out of memory"),
    ] {
        let out = dir.join(format!("out{status}"));
        let o = under_ulimit("-v 300000", "--threads 2", &deck, &out, extra);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(status), "{extra}: {err}");
        assert!(err.contains(message), "{extra}: {err}");
    }
}

/// SIGTERM stops `pmpm bench` at a step (exit 130), and the scratch folder it ran in is removed
/// (bench used to ignore the signal and leave the folder).
#[test]
fn bench_stops_on_sigterm_and_removes_its_scratch_folder() {
    let _serial = serial();
    let dir = scratch_dir("faults-bench");
    let deck = deck(&dir);
    let text = std::fs::read_to_string(&deck)
        .unwrap()
        .replace("end_time = 0.3", "end_time = 100.0")
        .replace("interval = 0.025", "interval = 1.0");
    std::fs::write(&deck, text).unwrap();
    let mut child = spawn(&["--threads", "2", "bench", &deck]);
    let scratch = std::env::temp_dir().join(format!("pmpm-bench-{}", child.id()));
    let start = Instant::now();
    while !scratch.join("frames/particles_000000.csv").exists()
        && start.elapsed() < Duration::from_secs(20)
    {
        std::thread::sleep(Duration::from_millis(5));
    }
    if !scratch.exists() {
        let _ = child.kill();
        panic!("bench does not run in {}", scratch.display());
    }
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(
        err.contains("bench interrupted; the bench ran in a scratch folder, now removed"),
        "{err}"
    );
    assert!(!scratch.exists(), "{} is left", scratch.display());
}

/// Unmounts the test's small file system when the test ends, passed or not.
struct Mounted(std::path::PathBuf);
impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A full disk stops the run with exit status 1 and a message that names the file and the
/// command that goes on; once there is room, the run goes on from its last checkpoint to the
/// bits of a run that never ran out (frames, series.csv less the wall clock, probes.csv). It
/// needs a small tmpfs, which only root may mount: elsewhere it says that it did not run.
#[test]
fn a_full_disk_stops_the_run_and_it_goes_on_once_there_is_room() {
    let _serial = serial();
    let dir = scratch_dir("faults-full");
    let deck = dir.join("deck.toml");
    std::fs::write(&deck, SMALL_2D.replace("end_time = 0.05", "end_time = 0.2")).unwrap();
    let deck = deck.to_str().unwrap();
    let disk = dir.join("disk");
    std::fs::create_dir_all(&disk).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=200k", "tmpfs"])
        .arg(&disk)
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !mounted {
        eprintln!("not run: this machine does not let the test mount a small tmpfs");
        return;
    }
    let _unmount = Mounted(disk.clone());
    let reference = dir.join("reference");
    run_to_end(&[
        "--threads",
        "2",
        "run",
        deck,
        "-o",
        reference.to_str().unwrap(),
        "-q",
    ]);
    let out = disk.join("run");
    let o = out.to_str().unwrap();
    let r = pmpm(&["--threads", "2", "run", deck, "-o", o, "-q"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(
        err.contains("No space left on device") && err.contains("and go on: pmpm run"),
        "{err}"
    );
    let grown = Command::new("mount")
        .args(["-o", "remount,size=8m", "tmpfs"])
        .arg(&disk)
        .status()
        .unwrap();
    assert!(grown.success());
    finish(deck, &out);
    for f in frame_files(&reference) {
        let name = format!("frames/{f}");
        assert!(read(&reference, &name) == read(&out, &name), "{f} differs");
    }
    assert_eq!(series(&reference), series(&out));
    assert!(read(&reference, "probes.csv") == read(&out, "probes.csv"));
}
