//! `pmpm plot`: PNG pictures of a tiny run's frames and series, and the errors a user can cause
//! (exit status 2, one message, no panic).

use crate::common;
use common::{pmpm, scratch_dir, SMALL_2D};
use std::path::{Path, PathBuf};
use std::process::Output;

/// Runs `deck` (text) into `name`/out and returns that directory.
fn run_deck(name: &str, deck: &str) -> PathBuf {
    let dir = scratch_dir(name);
    let file = dir.join("deck.toml");
    std::fs::write(&file, deck).unwrap();
    let out = dir.join("out");
    let o = pmpm(&[
        "run",
        file.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(
        o.status.success(),
        "run failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

fn plot(args: &[&str]) -> Output {
    let mut all = vec!["plot"];
    all.extend_from_slice(args);
    pmpm(&all)
}

fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "plot failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Width and height from a PNG's header, after checking the signature and the IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(bytes.len() > 33, "{} is too short", path.display());
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG signature");
    assert_eq!(&bytes[12..16], b"IHDR", "first chunk is not IHDR");
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    assert_eq!(bytes[24], 8, "bit depth");
    assert!(bytes.ends_with(&[0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82]));
    (w, h)
}

/// Exit status 2, exactly `message` (after "error: ") on stderr, nothing on stdout.
fn fails_with(o: &Output, message: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "stderr: {err}");
    assert_eq!(err, format!("error: {message}\n"));
    assert!(o.stdout.is_empty());
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

// SMALL_2D: a 0.4 x 0.2 m grid, frames 0 to 5. The plotting area is 1200 x 600 pixels (equal
// scale), plus 80 + 2 x 14 + 126 pixels across for the y labels, margins and colour bar, and
// 44 + 56 + 2 x 14 down for the title, x labels and margins.
const FRAME_2D: (u32, u32) = (1434, 728);

#[test]
fn frame_pictures_of_a_small_run() {
    let out = run_deck("plot-2d", SMALL_2D);
    assert_eq!(pmpm_cli::plot::frame_image_size(0.4, 0.2, false), FRAME_2D);

    // default: pressure, last frame, into the output directory
    let o = plot(&[s(&out)]);
    ok(&o);
    let png = out.join("plot_pressure_000005.png");
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        format!("wrote {}\n", png.display())
    );
    assert_eq!(png_size(&png), FRAME_2D);

    // another field and frame, to a file of our choice
    let file = out.join("speed2.png");
    ok(&plot(&[
        s(&out),
        "--field",
        "speed",
        "--frame",
        "2",
        "--out",
        s(&file),
    ]));
    assert_eq!(png_size(&file), FRAME_2D);

    ok(&plot(&[s(&out), "--field", "material", "--frame", "0"]));
    assert_eq!(png_size(&out.join("plot_material_000000.png")), FRAME_2D);

    // a fixed colour range
    ok(&plot(&[s(&out), "--min", "-10", "--max", "2000"]));
    assert_eq!(png_size(&png), FRAME_2D);
}

#[test]
fn every_frame_for_a_movie() {
    let out = run_deck("plot-all", SMALL_2D);
    let movie = out.join("movie");
    let o = plot(&[s(&out), "--all", "--field", "speed", "--out", s(&movie)]);
    ok(&o);
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 6);
    for n in 0..=5 {
        let png = movie.join(format!("plot_speed_{n:06}.png"));
        assert_eq!(png_size(&png), FRAME_2D, "{}", png.display());
    }
}

#[test]
fn series_and_probes() {
    let out = run_deck("plot-series", SMALL_2D);
    ok(&plot(&[s(&out), "--series"]));
    // six panels of 640 x 400, two across: the series and the probe's pressure and speed
    assert_eq!(png_size(&out.join("plot_series.png")), (1280, 1200));

    // without probes: the four series panels
    let deck = SMALL_2D.replace(
        "[[output.probes]]\nname = \"base\"\nposition = [0.01, 0.01]\n",
        "",
    );
    assert_ne!(deck, SMALL_2D);
    let out = run_deck("plot-series-noprobe", &deck);
    let file = out.join("series.png");
    ok(&plot(&[s(&out), "--series", "--out", s(&file)]));
    assert_eq!(png_size(&file), (1280, 800));
}

#[test]
fn a_3d_run_is_projected() {
    let deck = r#"
[simulation]
dimension = 3
scheme = "explicit"
end_time = 0.02
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
particles_per_cell = 2

[output]
interval = 0.01
formats = ["csv"]
"#;
    let out = run_deck("plot-3d", deck);
    // x-y: a 0.2 x 0.1 m plane; the title has a second line saying which projection
    let (w, h) = pmpm_cli::plot::frame_image_size(0.2, 0.1, true);
    assert_eq!((w, h), (1434, 752));
    ok(&plot(&[s(&out)]));
    assert_eq!(png_size(&out.join("plot_pressure_000002.png")), (w, h));
    // x-z: 0.2 x 0.1 m too
    let file = out.join("side.png");
    ok(&plot(&[s(&out), "--plane", "xz", "--out", s(&file)]));
    assert_eq!(png_size(&file), (w, h));
}

#[test]
fn errors_name_the_problem() {
    let dir = scratch_dir("plot-errors");

    let missing = dir.join("nowhere");
    fails_with(
        &plot(&[s(&missing)]),
        &format!("{}: no such directory", missing.display()),
    );

    let file = dir.join("deck.toml");
    std::fs::write(&file, SMALL_2D).unwrap();
    fails_with(
        &plot(&[s(&file)]),
        &format!(
            "{}: not a directory (give the output directory of a run)",
            file.display()
        ),
    );

    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    fails_with(
        &plot(&[s(&empty)]),
        &format!(
            "{}: no frames (frames/particles_NNNNNN.csv); is it the output directory of a run?",
            empty.display()
        ),
    );
    fails_with(
        &plot(&[s(&empty), "--series"]),
        &format!(
            "{}: no series.csv; is it the output directory of a run?",
            empty.display()
        ),
    );

    // a run that wrote VTK frames only
    let vtk = run_deck(
        "plot-vtk",
        &SMALL_2D.replace("formats = [\"vtk\", \"csv\"]", "formats = [\"vtk\"]"),
    );
    fails_with(
        &plot(&[s(&vtk)]),
        &format!(
            "{}: the run wrote VTK frames only; add \"csv\" to [output].formats in the deck \
             and run it again to plot it",
            vtk.display()
        ),
    );

    // a frame that does not exist
    let out = run_deck("plot-bad-frame", SMALL_2D);
    fails_with(
        &plot(&[s(&out), "--frame", "99"]),
        &format!("{}: no frame 99; the run has frames 0 to 5", out.display()),
    );
    fails_with(
        &plot(&[s(&out), "--min", "5", "--max", "1"]),
        "--min (5) must be below --max (1)",
    );
    // a frame file cut short
    let frame = out.join("frames/particles_000003.csv");
    let text = std::fs::read_to_string(&frame).unwrap();
    let second = text.lines().nth(1).unwrap();
    let cut = &second[..second.len() / 2];
    std::fs::write(&frame, format!("{}\n{cut}\n", text.lines().next().unwrap())).unwrap();
    fails_with(
        &plot(&[s(&out), "--frame", "3"]),
        &format!(
            "{}: line 2: expected 9 numbers (id,x,y,vx,vy,pressure,mass,volume,material)",
            frame.display()
        ),
    );
    // nothing was written for any of these
    assert!(!out.join("plot_pressure_000003.png").exists());
    assert!(!out.join("plot_pressure_000099.png").exists());

    // bad arguments are clap's (exit status 2)
    let o = plot(&[s(&out), "--field", "colour"]);
    assert_eq!(o.status.code(), Some(2));
    let o = plot(&[s(&out), "--series", "--frame", "1"]);
    assert_eq!(o.status.code(), Some(2));
}

/// A 3D run is seen from the side by default (the plane that holds gravity, here x-z), with
/// its rigid body drawn; `--slice` keeps a slab of it; `--movie` writes an animated GIF of
/// every frame; a slice across an axis the plane does not look along is refused.
#[test]
fn a_3d_run_from_the_side_in_slices_and_a_movie() {
    let deck = r#"
[simulation]
dimension = 3
scheme = "explicit"
end_time = 0.02
cfl = 0.4
gravity = [0.0, 0.0, -9.81]

[grid]
size = [0.2, 0.1, 0.3]
cell_size = 0.025

[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3
bulk_modulus = 4.0e4

[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0, 0.0], max = [0.05, 0.1, 0.05] }
particles_per_cell = 2

[[rigid_bodies]]
name = "block"
shape = { type = "box", min = [0.1375, 0.0, 0.0], max = [0.1625, 0.1, 0.05] }

[output]
interval = 0.01
formats = ["csv"]
"#;
    let out = run_deck("plot-3d-side", deck);
    // x-z: 0.2 x 0.3 m (x-y would be 0.2 x 0.1)
    let side = pmpm_cli::plot::frame_image_size(0.2, 0.3, true);
    ok(&plot(&[s(&out)]));
    assert_eq!(png_size(&out.join("plot_pressure_000002.png")), side);
    let file = out.join("slice.png");
    ok(&plot(&[s(&out), "--slice", "y=0.05", "--out", s(&file)]));
    assert_eq!(png_size(&file), side);
    let top = out.join("top.png");
    ok(&plot(&[
        s(&out),
        "--slice",
        "z=0.01",
        "--thickness",
        "0.02",
        "--out",
        s(&top),
    ]));
    assert_eq!(
        png_size(&top),
        pmpm_cli::plot::frame_image_size(0.2, 0.1, true)
    );
    fails_with(
        &plot(&[s(&out), "--slice", "y=0.05", "--plane", "xy"]),
        "--slice y=0.05: a slice across y is seen in the xz plane, not xy",
    );
    fails_with(
        &plot(&[s(&out), "--slice", "w=1"]),
        "--slice w=1: the axis is x, y or z, got \"w\"",
    );
    let o = plot(&[s(&out), "--movie", "--field", "speed"]);
    ok(&o);
    // and a 2D run has one plane
    let flat = run_deck("plot-2d-plane", SMALL_2D);
    fails_with(
        &plot(&[s(&flat), "--plane", "xz"]),
        "--plane xz: a 2D run has one plane, x-y",
    );
    ok(&o);
    let gif = std::fs::read(out.join("plot_speed.gif")).unwrap();
    assert_eq!(&gif[..6], b"GIF89a");
    let (w, h) = (
        u16::from_le_bytes([gif[6], gif[7]]) as u32,
        u16::from_le_bytes([gif[8], gif[9]]) as u32,
    );
    assert_eq!((w, h), side);
    // three frames: three image descriptors (0x2C after a graphic control extension)
    let frames = gif.windows(2).filter(|w| w == &[0x00, 0x2C]).count();
    assert!(frames >= 3, "{frames} frames");
    assert_eq!(gif.last(), Some(&0x3B));
}

#[test]
fn a_line_profile_reads_the_hydrostatic_pressure() {
    // A column at rest under the projection: p = rho g (H - y) at the particles, to
    // round-off. Linear hat weights over a lattice of spacing h/2 reproduce a linear field,
    // so the profile up the middle reads it exactly where the weights see a whole cell of
    // water on each side (y from 2h to H - 2h).
    let deck = r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.02
dt = 0.005
gravity = [0.0, -9.81]

[grid]
size = [0.4, 0.3]
cell_size = 0.02

[grid.boundary]
x_min = "slip"
x_max = "slip"
y_min = "slip"
y_max = "open"

[[materials]]
name = "water"
density = 1000.0
viscosity = 1.0e-3

[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [0.4, 0.2] }
particles_per_cell = 2

[output]
interval = 0.02
formats = ["csv"]
"#;
    let out = run_deck("plot-line", deck);
    let o = plot(&[s(&out), "--line", "0.2,0:0.2,0.3"]);
    ok(&o);
    let (png, csv) = (
        out.join("plot_line_pressure_000001.png"),
        out.join("plot_line_pressure_000001.csv"),
    );
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        format!("wrote {}\nwrote {}\n", png.display(), csv.display())
    );
    assert_eq!(png_size(&png), (800, 500));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("distance,x,y,pressure"));
    let (rho_g, top, h) = (1000.0 * 9.81, 0.2, 0.02);
    let (mut inside, mut above) = (0, 0);
    for line in lines {
        let v: Vec<&str> = line.split(',').collect();
        let y: f64 = v[2].parse().unwrap();
        if y > top + h {
            assert_eq!(v[3], "", "no water within a cell of y = {y}");
            above += 1;
        } else if (2.0 * h..=top - 2.0 * h).contains(&y) {
            let p: f64 = v[3].parse().unwrap();
            assert!(
                (p - rho_g * (top - y)).abs() < 1e-9 * rho_g * top,
                "y = {y}: {p} against {}",
                rho_g * (top - y)
            );
            inside += 1;
        }
    }
    assert_eq!(text.lines().count(), 202);
    assert!(
        inside >= 80 && above > 50,
        "{inside} points inside, {above} above"
    );

    fails_with(
        &plot(&[s(&out), "--line", "0.2,0"]),
        "--line 0.2,0: give two points A:B, as X0,Y0:X1,Y1",
    );
    fails_with(
        &plot(&[s(&out), "--line", "0.2,0,0:0.2,0.3,0"]),
        "--line 0.2,0,0:0.2,0.3,0: a point of a 2D run has 2 coordinates, got 3",
    );
    fails_with(
        &plot(&[s(&out), "--line", "0.2,0:0.2,0.3", "--field", "material"]),
        "--line 0.2,0:0.2,0.3: a profile is of pressure, speed, vx, vy or vz",
    );
    // a velocity component colours a frame too
    ok(&plot(&[s(&out), "--field", "vy"]));
    assert!(out.join("plot_vy_000001.png").is_file());
}

#[test]
fn an_mp4_needs_ffmpeg() {
    let out = run_deck("plot-mp4", SMALL_2D);
    let movie = out.join("movie.mp4");
    // no ffmpeg where PATH points: a usage error, and no file
    let empty = scratch_dir("plot-no-path");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pmpm"))
        .args(["plot", s(&out), "--movie", "--out", s(&movie)])
        .env("PATH", &empty)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.starts_with(&format!(
            "error: --out {}: an MP4 movie needs ffmpeg on the PATH (",
            movie.display()
        )),
        "{err}"
    );
    assert!(!movie.exists());
    assert!(!out.join("movie.mp4.partial").exists());
    // with ffmpeg, where this machine has it: an MP4 file
    let has_ffmpeg = std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    if has_ffmpeg {
        ok(&plot(&[s(&out), "--movie", "--out", s(&movie)]));
        let bytes = std::fs::read(&movie).unwrap();
        assert_eq!(&bytes[4..8], b"ftyp", "an MP4 starts with its ftyp box");
    }
}
