//! `pmpm plot`: PNG pictures of a run's output directory.
//!
//! * a frame (`frames/particles_NNNNNN.csv`): every particle as a small filled square, twice the
//!   particle's own size (volume^(1/D)) across and clipped to the grid, so that a body of water
//!   looks like a continuum even where the particles have lined up with gaps between the lines;
//!   coloured by pressure, speed or material, with a colour bar (a legend for materials), axes
//!   in metres at equal scale, and the frame's time (from `series.csv`) in the title. A 3D run is
//!   shown as a projection onto a coordinate plane, the particles nearest the viewer on top;
//! * the time series (`series.csv`: kinetic energy, largest speed, pressure iterations, time
//!   step) and, when `probes.csv` has rows, the probes' pressure and speed, as panels of one PNG.
//!
//! The domain drawn is the background grid of `run.toml` (the particles' extent when it cannot be
//! read), so that every frame of a run is drawn at the same place and scale.

use crate::table::Table;
use crate::validation::plot::{self as vplot, colors, Panel, Series};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use pmpm::error::Error;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// What colours the particles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Field {
    /// Pressure (Pa, positive in compression).
    Pressure,
    /// Speed |v| (m/s).
    Speed,
    /// Material index, named from `run.toml`.
    Material,
    /// A velocity component (m/s): 0 for vx, 1 for vy, 2 for vz.
    Velocity(usize),
}

impl Field {
    /// The field of a command-line name (`pressure`, `speed`, `material`).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "pressure" => Some(Field::Pressure),
            "speed" => Some(Field::Speed),
            "material" => Some(Field::Material),
            "vx" => Some(Field::Velocity(0)),
            "vy" => Some(Field::Velocity(1)),
            "vz" => Some(Field::Velocity(2)),
            _ => None,
        }
    }

    /// The name used on the command line and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Field::Pressure => "pressure",
            Field::Speed => "speed",
            Field::Material => "material",
            Field::Velocity(d) => ["vx", "vy", "vz"][d.min(2)],
        }
    }

    fn label(self) -> &'static str {
        match self {
            Field::Pressure => "pressure (Pa)",
            Field::Speed => "speed (m/s)",
            Field::Material => "material",
            Field::Velocity(d) => ["vx (m/s)", "vy (m/s)", "vz (m/s)"][d.min(2)],
        }
    }
}

/// The coordinate plane a 3D run is projected onto (2D runs ignore it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Plane {
    /// x to the right, y up, seen from +z.
    #[default]
    Xy,
    /// x to the right, z up, seen from -y.
    Xz,
    /// y to the right, z up, seen from +x.
    Yz,
}

impl Plane {
    /// The plane of a command-line name (`xy`, `xz`, `yz`).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "xy" => Some(Plane::Xy),
            "xz" => Some(Plane::Xz),
            "yz" => Some(Plane::Yz),
            _ => None,
        }
    }

    /// (horizontal axis, vertical axis, depth axis, depth grows towards the viewer).
    fn axes(self) -> (usize, usize, usize, bool) {
        match self {
            Plane::Xy => (0, 1, 2, true),
            Plane::Xz => (0, 2, 1, false),
            Plane::Yz => (1, 2, 0, true),
        }
    }

    /// Its command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Plane::Xy => "xy",
            Plane::Xz => "xz",
            Plane::Yz => "yz",
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Plane::Xy => {
                "3D run: projection onto the x-y plane, seen from +z (top particles in front)"
            }
            Plane::Xz => {
                "3D run: projection onto the x-z plane, seen from -y (front particles in front)"
            }
            Plane::Yz => {
                "3D run: projection onto the y-z plane, seen from +x (front particles in front)"
            }
        }
    }
}

/// What `pmpm plot` draws.
#[derive(Debug, Clone, Default)]
pub struct PlotOptions {
    /// Frame number (default: the last frame). Ignored with `all` or `series`.
    pub frame: Option<usize>,
    /// Colouring field (default: pressure).
    pub field: Option<Field>,
    /// Output file (a directory with `all`); default: inside the output directory.
    pub out: Option<PathBuf>,
    /// One PNG per frame with a colour range fixed over all frames.
    pub all: bool,
    /// Plot series.csv (and probes.csv) instead of a frame.
    pub series: bool,
    /// Projection plane of a 3D run (default: the vertical plane along x, from gravity in
    /// run.toml).
    pub plane: Option<Plane>,
    /// A 3D run's slab, "AXIS=VALUE": only the particles within `thickness` / 2 of it.
    pub slice: Option<String>,
    /// The slab's thickness (default: one cell).
    pub thickness: Option<f64>,
    /// Every frame into one animated GIF.
    pub movie: bool,
    /// Lower end of the colour range (default: the data's).
    pub min: Option<f64>,
    /// Upper end of the colour range (default: the data's).
    pub max: Option<f64>,
    /// An explicit run's pressure as each particle has it, not smoothed through the grid.
    pub particle_pressure: bool,
    /// A profile of the field along a line, "X0,Y0[,Z0]:X1,Y1[,Z1]" (m).
    pub line: Option<String>,
}

/// Draws what `opts` asks for from the output directory `dir`; returns the PNG files written.
///
/// Errors a user can cause (no such directory, no CSV frames, a frame that does not exist, an
/// unreadable CSV file) are [`Error::Usage`] (exit status 2); a PNG that cannot be written is
/// [`Error::Io`].
pub fn plot(dir: &Path, opts: &PlotOptions) -> Result<Vec<PathBuf>, Error> {
    check_request(dir, opts)?;
    vplot::register();
    if opts.series {
        let out = png_path(opts.out.as_deref(), dir, "plot_series.png")?;
        plot_series(dir, &out)?;
        return Ok(vec![out]);
    }
    let field = opts.field.unwrap_or(Field::Pressure);
    let frames = list_frames(dir)?;
    let info = RunInfo::read(dir);
    let mut view = View::of(opts, &info)?;
    if field == Field::Pressure && info.scheme.as_deref() == Some("explicit") {
        view.smooth = (!opts.particle_pressure).then(|| Hat::of(&info)).flatten();
    }
    let times = read_times(dir);
    let bodies = Bodies::read(dir, &info);
    if opts.all || opts.movie {
        let (range, extent) = range_and_extent_of_all(&frames, &view, field, &info, opts)?;
        let scene = Scene {
            field,
            range,
            info: &info,
            extent,
            view: &view,
            bodies: &bodies,
        };
        if opts.movie {
            return Ok(vec![plot_movie(&scene, &frames, &times, dir, opts)?]);
        }
        return plot_every_frame(&scene, &frames, &times, dir, opts);
    }
    let (n, path) = chosen_frame(dir, &frames, opts.frame)?;
    if let Some(text) = &opts.line {
        let f = Frame::read_all(&path)?;
        let time = times.iter().find(|t| t.0 == n).map(|t| t.1);
        return plot_line(dir, &f, n, time, field, text, &info, opts.out.as_deref());
    }
    let f = Frame::read(&path, &view)?;
    let range = color_range(field, &f.range(field), opts);
    let out = png_path(opts.out.as_deref(), dir, &frame_png_name(field, n))?;
    let extent = picture_extent(
        &info,
        &view,
        f.extent(view.plane, 0.0),
        f.extent(view.plane, 0.5),
    );
    let scene = Scene {
        field,
        range,
        info: &info,
        extent,
        view: &view,
        bodies: &bodies,
    };
    let time = times.iter().find(|t| t.0 == n).map(|t| t.1);
    scene.sketch(&f, n, time).png(&out)?;
    Ok(vec![out])
}

/// Checks the output directory `dir` and the colour range that `opts` gives (usage errors).
fn check_request(dir: &Path, opts: &PlotOptions) -> Result<(), Error> {
    if !dir.exists() {
        return Err(Error::Usage(format!(
            "{}: no such directory",
            dir.display()
        )));
    }
    if !dir.is_dir() {
        return Err(Error::Usage(format!(
            "{}: not a directory (give the output directory of a run)",
            dir.display()
        )));
    }
    for (name, v) in [("--min", opts.min), ("--max", opts.max)] {
        if let Some(v) = v.filter(|v| !v.is_finite()) {
            return Err(Error::Usage(format!(
                "{name}: must be a finite number, got {v}"
            )));
        }
    }
    if let (Some(lo), Some(hi)) = (opts.min, opts.max) {
        if lo >= hi {
            return Err(Error::Usage(format!(
                "--min ({lo}) must be below --max ({hi})"
            )));
        }
    }
    Ok(())
}

/// The file name of frame `n`'s picture of `field`.
fn frame_png_name(field: Field, n: usize) -> String {
    format!("plot_{}_{n:06}.png", field.name())
}

/// The colour range and the drawn rectangle over every frame (`--all`, `--movie`).
fn range_and_extent_of_all(
    frames: &[(usize, PathBuf)],
    view: &View,
    field: Field,
    info: &RunInfo,
    opts: &PlotOptions,
) -> Result<((f64, f64), Extent), Error> {
    let stats = frames
        .par_iter()
        .map(|(_, path)| {
            let f = Frame::read(path, view)?;
            Ok((
                f.range(field),
                f.extent(view.plane, 0.0),
                f.extent(view.plane, 0.5),
            ))
        })
        .collect::<Result<Vec<_>, Error>>()?;
    let mut all = Stats::empty();
    let (mut raw, mut grown) = (Extent::empty(), Extent::empty());
    for (r, e, g) in &stats {
        all = all.union(r);
        raw = raw.union(e);
        grown = grown.union(g);
    }
    let range = color_range(field, &all, opts);
    let extent = picture_extent(info, view, raw, grown);
    Ok((range, extent))
}

/// Every frame into one movie (`--movie`): a GIF, or an MP4 through ffmpeg; returns its path.
fn plot_movie(
    scene: &Scene<'_>,
    frames: &[(usize, PathBuf)],
    times: &[(usize, f64)],
    dir: &Path,
    opts: &PlotOptions,
) -> Result<PathBuf, Error> {
    let time_of = |n: usize| times.iter().find(|t| t.0 == n).map(|t| t.1);
    let out = match &opts.out {
        Some(o) => o.clone(),
        None => dir.join(format!("plot_{}.gif", scene.field.name())),
    };
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_lowercase);
    if !matches!(ext.as_deref(), Some("gif" | "mp4")) {
        return Err(Error::Usage(format!(
            "--out {}: a movie is a .gif file (or .mp4, with ffmpeg on the PATH)",
            out.display()
        )));
    }
    let shot = |(n, path): &(usize, PathBuf)| -> Result<Vec<u8>, Error> {
        let f = Frame::read(path, scene.view)?;
        scene.sketch(&f, *n, time_of(*n)).pixels(&out)
    };
    let three_d = scene.view.three_d(scene.info);
    if ext.as_deref() == Some("mp4") {
        write_mp4(&out, frames, scene.extent, three_d, shot)?;
    } else {
        write_movie(&out, frames, scene.extent, three_d, shot)?;
    }
    Ok(out)
}

/// One PNG per frame (`--all`), into `--out` or the output directory; returns their paths.
fn plot_every_frame(
    scene: &Scene<'_>,
    frames: &[(usize, PathBuf)],
    times: &[(usize, f64)],
    dir: &Path,
    opts: &PlotOptions,
) -> Result<Vec<PathBuf>, Error> {
    let time_of = |n: usize| times.iter().find(|t| t.0 == n).map(|t| t.1);
    let out_dir = opts.out.clone().unwrap_or_else(|| dir.to_path_buf());
    std::fs::create_dir_all(&out_dir).map_err(|e| Error::io(&out_dir, e))?;
    frames
        .par_iter()
        .map(|(n, path)| {
            let f = Frame::read(path, scene.view)?;
            let out = out_dir.join(frame_png_name(scene.field, *n));
            scene.sketch(&f, *n, time_of(*n)).png(&out)?;
            Ok(out)
        })
        .collect()
}

/// The frame `--frame` names (default: the last), as (number, CSV file).
fn chosen_frame(
    dir: &Path,
    frames: &[(usize, PathBuf)],
    frame: Option<usize>,
) -> Result<(usize, PathBuf), Error> {
    Ok(match frame {
        None => frames.last().cloned().expect("list_frames returns frames"),
        Some(n) => match frames.iter().find(|f| f.0 == n) {
            Some(f) => f.clone(),
            None => {
                return Err(Error::Usage(format!(
                    "{}: no frame {n}; the run has frames {} to {}",
                    dir.display(),
                    frames[0].0,
                    frames[frames.len() - 1].0
                )))
            }
        },
    })
}

/// How the frames are seen: the plane a 3D run is projected onto, and the slab of it kept.
#[derive(Debug, Clone)]
struct View {
    plane: Plane,
    /// (axis, lower, upper): only the particles with lower <= x[axis] <= upper.
    slab: Option<(usize, f64, f64)>,
    /// The grid the pressure is smoothed through (an explicit run's pressure pictures).
    smooth: Option<Hat>,
}

impl View {
    /// The view `opts` asks for: --slice's axis is seen along (its plane), else --plane, else
    /// the vertical plane along x that holds gravity (xz with gravity along z, xy along y).
    fn of(opts: &PlotOptions, info: &RunInfo) -> Result<Self, Error> {
        let by_depth = |d: usize| match d {
            0 => Plane::Yz,
            1 => Plane::Xz,
            _ => Plane::Xy,
        };
        if let (Some(2), Some(p)) = (info.dim, opts.plane) {
            return Err(Error::Usage(format!(
                "--plane {}: a 2D run has one plane, x-y",
                p.name()
            )));
        }
        if opts.field == Some(Field::Velocity(2)) && info.dim == Some(2) {
            return Err(Error::Usage(
                "--field vz: a 2D run has no z velocity; its fields are pressure, speed, material, vx and vy"
                    .into(),
            ));
        }
        let Some(text) = &opts.slice else {
            let plane = opts.plane.unwrap_or_else(|| {
                let g = info.gravity.as_deref().unwrap_or(&[]);
                let up = (0..g.len())
                    .max_by(|&a, &b| g[a].abs().total_cmp(&g[b].abs()))
                    .filter(|&d| g[d] != 0.0)
                    .unwrap_or(2);
                if up == 1 {
                    Plane::Xy
                } else {
                    Plane::Xz
                }
            });
            return Ok(Self {
                plane,
                slab: None,
                smooth: None,
            });
        };
        let bad = |why: &str| Error::Usage(format!("--slice {text}: {why}"));
        if info.dim == Some(2) {
            return Err(bad("a 2D run is a slice already"));
        }
        let (axis, value) = text
            .split_once('=')
            .ok_or_else(|| bad("give AXIS=VALUE, for example y=0.15"))?;
        let axis = match axis.trim() {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            other => return Err(bad(&format!("the axis is x, y or z, got \"{other}\""))),
        };
        let value: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| bad("the value is a number (m)"))?;
        if let Some((o, size)) = &info.grid {
            let (lo, hi) = (o[axis], o[axis] + size[axis]);
            let tol = 1e-9 * size[axis];
            if value < lo - tol || value > hi + tol {
                return Err(bad(&format!(
                    "the value lies outside the grid, which spans {} = [{}, {}] m",
                    ["x", "y", "z"][axis],
                    pmpm::limits::short(lo),
                    pmpm::limits::short(hi)
                )));
            }
        }
        let plane = by_depth(axis);
        if let Some(p) = opts.plane.filter(|&p| p != plane) {
            return Err(bad(&format!(
                "a slice across {} is seen in the {} plane, not {}",
                ["x", "y", "z"][axis],
                plane.name(),
                p.name()
            )));
        }
        let thickness = match opts.thickness {
            Some(t) if t.is_finite() && t > 0.0 => t,
            Some(t) => {
                return Err(Error::Usage(format!(
                    "--thickness: must be a positive number (m), got {t}"
                )))
            }
            None => info.cell_size.unwrap_or(0.0),
        };
        Ok(Self {
            plane,
            slab: Some((axis, value - 0.5 * thickness, value + 0.5 * thickness)),
            smooth: None,
        })
    }

    /// Whether the pictures are of a 3D run.
    fn three_d(&self, info: &RunInfo) -> bool {
        info.dim == Some(3)
    }

    /// The line under a 3D picture's title.
    fn describe(&self) -> String {
        match self.slab {
            None => self.plane.describe().to_string(),
            Some((axis, lo, hi)) => format!(
                "3D run: the particles with {} < {} < {} m, seen along {}",
                short(lo),
                ["x", "y", "z"][axis],
                short(hi),
                ["x", "y", "z"][axis]
            ),
        }
    }
}

/// The drawn rectangle: the grid of run.toml and the particles `raw` (should some lie outside
/// it), else the particles' extent grown by half a particle (`grown`).
fn picture_extent(info: &RunInfo, view: &View, raw: Extent, grown: Extent) -> Extent {
    let dim = info.dim.unwrap_or(2);
    let (a, b) = if dim == 2 {
        (0, 1)
    } else {
        let (a, b, _, _) = view.plane.axes();
        (a, b)
    };
    match &info.grid {
        Some((o, s)) if o.len() == dim => Extent {
            x: (o[a], o[a] + s[a]),
            y: (o[b], o[b] + s[b]),
        }
        .union(&raw),
        _ => grown,
    }
    .sane()
}

/// The frames of a movie as an animated GIF at `out`: each drawn by `shot` (a few at once,
/// in order), quantised to 256 colours, a tenth of a second each, looping.
fn write_movie(
    out: &Path,
    frames: &[(usize, PathBuf)],
    extent: Extent,
    three_d: bool,
    shot: impl Fn(&(usize, PathBuf)) -> Result<Vec<u8>, Error> + Sync,
) -> Result<(), Error> {
    let (w, h) = frame_image_size(extent.width(), extent.height(), three_d);
    let (w16, h16) = (
        u16::try_from(w).map_err(|_| Error::Usage("movie too wide".into()))?,
        u16::try_from(h).map_err(|_| Error::Usage("movie too high".into()))?,
    );
    let mut failure = None;
    pmpm::atomic::write_atomic(out, |file| {
        let mut enc = gif::Encoder::new(file, w16, h16, &[]).map_err(std::io::Error::other)?;
        enc.set_repeat(gif::Repeat::Infinite)
            .map_err(std::io::Error::other)?;
        in_order(frames, &shot, |rgb| {
            let mut frame = gif::Frame::from_rgb_speed(w16, h16, &rgb, 10);
            frame.delay = 10;
            enc.write_frame(&frame)
                .map_err(|e| Error::io(out, std::io::Error::other(e)))
        })
        .map_err(|e| {
            failure = Some(e);
            std::io::Error::other("a frame could not be drawn")
        })
    })
    .map_err(|e| failure.take().unwrap_or_else(|| Error::io(out, e)))
}

/// Draws `frames` with `shot`, as many at once as there are workers, and hands each picture
/// to `sink` in the frames' order; stops at the first error.
fn in_order(
    frames: &[(usize, PathBuf)],
    shot: impl Fn(&(usize, PathBuf)) -> Result<Vec<u8>, Error> + Sync,
    mut sink: impl FnMut(Vec<u8>) -> Result<(), Error>,
) -> Result<(), Error> {
    for chunk in frames.chunks(rayon::current_num_threads().max(1)) {
        let shots: Vec<Result<Vec<u8>, Error>> = chunk.par_iter().map(&shot).collect();
        for s in shots {
            sink(s?)?;
        }
    }
    Ok(())
}

/// The frames of a movie as an MP4 (H.264) file at `out`, encoded by ffmpeg from the PATH at
/// 10 frames a second; written to NAME.partial beside `out` and renamed when ffmpeg is done.
/// No ffmpeg is a usage error (exit status 2).
fn write_mp4(
    out: &Path,
    frames: &[(usize, PathBuf)],
    extent: Extent,
    three_d: bool,
    shot: impl Fn(&(usize, PathBuf)) -> Result<Vec<u8>, Error> + Sync,
) -> Result<(), Error> {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let (w, h) = frame_image_size(extent.width(), extent.height(), three_d);
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let part = out.with_file_name(format!("{name}.partial"));
    let mut child = Command::new("ffmpeg")
        .args([
            "-loglevel",
            "error",
            "-y",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
        ])
        .args(["-s", &format!("{w}x{h}"), "-r", "10", "-i", "-"])
        // H.264 in yuv420p wants even sides
        .args([
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-pix_fmt",
            "yuv420p",
            "-f",
            "mp4",
        ])
        .arg(&part)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            Error::Usage(format!(
                "--out {}: an MP4 movie needs ffmpeg on the PATH ({e}); write a .gif instead",
                out.display()
            ))
        })?;
    let mut stdin = child.stdin.take().expect("piped");
    let drawn = in_order(frames, shot, |rgb| {
        stdin.write_all(&rgb).map_err(|e| Error::io(out, e))
    });
    drop(stdin);
    let done = child.wait_with_output().map_err(|e| Error::io(out, e))?;
    let result = drawn.and_then(|()| {
        if done.status.success() {
            std::fs::rename(&part, out).map_err(|e| Error::io(out, e))
        } else {
            Err(Error::io(
                out,
                std::io::Error::other(format!(
                    "ffmpeg failed: {}",
                    String::from_utf8_lossy(&done.stderr).trim()
                )),
            ))
        }
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&part);
    }
    result
}

/// Where one picture goes: `--out` when given (into it, under `name`, when it is a folder),
/// else `name` in the run's directory. A folder that does not exist, or a name that is not a
/// .png, is a usage error (exit status 2) before anything is drawn.
fn png_path(out: Option<&Path>, dir: &Path, name: &str) -> Result<PathBuf, Error> {
    let Some(out) = out else {
        return Ok(dir.join(name));
    };
    if out.is_dir() {
        return Ok(out.join(name));
    }
    if out.as_os_str().to_string_lossy().ends_with('/') {
        return Err(Error::Usage(format!(
            "--out {}: no such folder; create it first",
            out.display()
        )));
    }
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty());
    if let Some(p) = parent.filter(|p| !p.is_dir()) {
        return Err(Error::Usage(format!(
            "--out {}: the folder {} does not exist; create it first",
            out.display(),
            p.display()
        )));
    }
    if !out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        return Err(Error::Usage(format!(
            "--out {}: pmpm plot writes PNG pictures; give a name ending in .png, or a folder",
            out.display()
        )));
    }
    Ok(out.to_path_buf())
}

/// The CSV frames of `dir`, (number, path) in order; a usage error when there are none.
fn list_frames(dir: &Path) -> Result<Vec<(usize, PathBuf)>, Error> {
    let frames_dir = dir.join("frames");
    let mut csv = Vec::new();
    let mut vtu = 0usize;
    if let Ok(entries) = std::fs::read_dir(&frames_dir) {
        for e in entries.flatten() {
            let file = e.file_name();
            let Some(file) = file.to_str() else { continue };
            let Some(rest) = file.strip_prefix("particles_") else {
                continue;
            };
            if let Some(num) = rest.strip_suffix(".csv") {
                if let Ok(n) = num.parse::<usize>() {
                    csv.push((n, e.path()));
                }
            } else if rest.ends_with(".vtu") {
                vtu += 1;
            }
        }
    }
    if csv.is_empty() {
        return Err(Error::Usage(if vtu > 0 {
            format!(
                "{}: the run wrote VTK frames only; add \"csv\" to [output].formats in the deck \
                 and run it again to plot it",
                dir.display()
            )
        } else {
            format!(
                "{}: no frames (frames/particles_NNNNNN.csv); is it the output directory of a run?",
                dir.display()
            )
        }));
    }
    csv.sort();
    Ok(csv)
}

/// What `run.toml` tells about the run (each part optional: the plot works without it).
#[derive(Debug, Default)]
struct RunInfo {
    /// Grid origin and size.
    grid: Option<(Vec<f64>, Vec<f64>)>,
    /// Material names, by index.
    materials: Vec<String>,
    /// 2 or 3.
    dim: Option<usize>,
    /// Gravity (m/s^2).
    gravity: Option<Vec<f64>>,
    /// The grid's cell size (m).
    cell_size: Option<f64>,
    /// The deck's rigid bodies, as run.toml gives them.
    rigid: Vec<toml::Value>,
    /// The scheme ("projection" or "explicit").
    scheme: Option<String>,
    /// Each face's kind ("slip", "no_slip", "open", "outflow", "periodic"), in the order
    /// x_min, x_max, y_min, y_max, z_min, z_max.
    faces: Vec<Option<String>>,
    /// The inflow patches: (face index, lower corner, upper corner).
    inflows: Vec<(usize, Vec<f64>, Vec<f64>)>,
}

impl RunInfo {
    fn read(dir: &Path) -> Self {
        let Ok(text) = std::fs::read_to_string(dir.join("run.toml")) else {
            return Self::default();
        };
        let Ok(t) = text.parse::<toml::Table>() else {
            return Self::default();
        };
        let floats = |v: Option<&toml::Value>| -> Option<Vec<f64>> {
            v?.as_array()?
                .iter()
                .map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64)))
                .collect()
        };
        let grid = t.get("grid").and_then(|g| {
            let size = floats(g.get("size"))?;
            let origin = floats(g.get("origin")).unwrap_or_else(|| vec![0.0; size.len()]);
            (origin.len() == size.len()).then_some((origin, size))
        });
        let materials = t
            .get("materials")
            .and_then(|m| m.as_array())
            .map(|m| {
                m.iter()
                    .enumerate()
                    .map(|(i, m)| {
                        m.get("name")
                            .and_then(|n| n.as_str())
                            .map_or_else(|| format!("material {i}"), str::to_string)
                    })
                    .collect()
            })
            .unwrap_or_default();
        let dim = t
            .get("simulation")
            .and_then(|s| s.get("dimension"))
            .and_then(|d| d.as_integer())
            .map(|d| d as usize)
            .or_else(|| grid.as_ref().map(|g| g.0.len()));
        let number = |v: Option<&toml::Value>| {
            v.and_then(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64)))
        };
        let faces: Vec<Option<String>> = FACES
            .iter()
            .map(|name| {
                let face = t.get("grid")?.get("boundary")?.get(*name)?;
                let kind = face.as_str().or_else(|| face.get("type")?.as_str())?;
                Some(kind.to_string())
            })
            .collect();
        let inflows = t
            .get("inflows")
            .and_then(|i| i.as_array())
            .map(|list| {
                list.iter()
                    .filter_map(|i| {
                        let face = i.get("face")?.as_str()?;
                        let k = FACES.iter().position(|f| *f == face)?;
                        Some((k, floats(i.get("min"))?, floats(i.get("max"))?))
                    })
                    .collect()
            })
            .unwrap_or_default();
        Self {
            scheme: t
                .get("simulation")
                .and_then(|s| s.get("scheme"))
                .and_then(|s| s.as_str())
                .map(str::to_string),
            faces,
            inflows,
            grid,
            materials,
            dim,
            gravity: floats(t.get("simulation").and_then(|s| s.get("gravity"))),
            cell_size: number(t.get("grid").and_then(|g| g.get("cell_size"))),
            rigid: t
                .get("rigid_bodies")
                .and_then(|r| r.as_array())
                .cloned()
                .unwrap_or_default(),
        }
    }
}

/// Points along a profile line.
const LINE_POINTS: usize = 201;

/// `--line`: the field along the segment from A to B in frame `n`, as a PNG and a CSV
/// (`plot_line_<field>_NNNNNN.png` and `.csv`; `--out` names the PNG). At each of 201 points
/// s the value is the particles' mass-weighted mean with the linear hat weights of a cell
/// around s, sum_p N_p(s) m_p q_p / sum_p N_p(s) m_p: the grid's own spreading, at any point.
/// A point with no particle within a cell has no value (left out of the picture, empty in
/// the CSV).
#[allow(clippy::too_many_arguments)]
fn plot_line(
    dir: &Path,
    f: &Frame,
    n: usize,
    time: Option<f64>,
    field: Field,
    text: &str,
    info: &RunInfo,
    out: Option<&Path>,
) -> Result<Vec<PathBuf>, Error> {
    let bad = |why: &str| Error::Usage(format!("--line {text}: {why}"));
    if field == Field::Material {
        return Err(bad("a profile is of pressure, speed, vx, vy or vz"));
    }
    let point = |p: &str| -> Result<[f64; 3], Error> {
        let v: Vec<f64> = p
            .split(',')
            .map(|c| c.trim().parse::<f64>().ok().filter(|c| c.is_finite()))
            .collect::<Option<_>>()
            .ok_or_else(|| bad("give X0,Y0:X1,Y1 (and Z in 3D), numbers in m"))?;
        if v.len() != f.dim {
            return Err(bad(&format!(
                "a point of a {}D run has {} coordinates, got {}",
                f.dim,
                f.dim,
                v.len()
            )));
        }
        Ok(std::array::from_fn(|d| v.get(d).copied().unwrap_or(0.0)))
    };
    let (a, b) = text
        .split_once(':')
        .ok_or_else(|| bad("give two points A:B, as X0,Y0:X1,Y1"))?;
    let (a, b) = (point(a)?, point(b)?);
    if let Some((o, size)) = &info.grid {
        let outside = |p: &[f64; 3]| {
            (0..f.dim.min(o.len())).any(|d| {
                let tol = 1e-9 * size[d];
                p[d] < o[d] - tol || p[d] > o[d] + size[d] + tol
            })
        };
        if let Some((which, _)) = [("A", &a), ("B", &b)].into_iter().find(|(_, p)| outside(p)) {
            let spans: Vec<String> = (0..f.dim.min(o.len()))
                .map(|d| {
                    format!(
                        "{} = [{}, {}]",
                        ["x", "y", "z"][d],
                        pmpm::limits::short(o[d]),
                        pmpm::limits::short(o[d] + size[d])
                    )
                })
                .collect();
            return Err(bad(&format!(
                "the point {which} lies outside the grid, which spans {} m",
                spans.join(", ")
            )));
        }
    }
    let length = (0..3).map(|d| (b[d] - a[d]).powi(2)).sum::<f64>().sqrt();
    if length == 0.0 {
        return Err(bad("the two points are the same"));
    }
    let h = info
        .cell_size
        .ok_or_else(|| bad("run.toml, which gives the cell size, cannot be read"))?;
    let mut rows = Vec::with_capacity(LINE_POINTS);
    for k in 0..LINE_POINTS {
        let t = k as f64 / (LINE_POINTS - 1) as f64;
        let s: [f64; 3] = std::array::from_fn(|d| a[d] + t * (b[d] - a[d]));
        let (mut sum, mut weight) = (0.0, 0.0);
        for p in 0..f.x.len() {
            let w: f64 = (0..f.dim)
                .map(|d| (1.0 - (f.x[p][d] - s[d]).abs() / h).max(0.0))
                .product();
            let q = f.value(field, p);
            if w > 0.0 && q.is_finite() {
                sum += w * f.mass[p] * q;
                weight += w * f.mass[p];
            }
        }
        rows.push((t * length, s, (weight > 0.0).then(|| sum / weight)));
    }
    let name = format!("plot_line_{}_{n:06}", field.name());
    let png = png_path(out, dir, &format!("{name}.png"))?;
    let csv = png.with_extension("csv");
    let axes = &["x", "y", "z"][..f.dim];
    let mut body = format!("distance,{},{}\n", axes.join(","), field.name());
    for (dist, s, v) in &rows {
        let coords: Vec<String> = s[..f.dim].iter().map(|c| format!("{c:.9e}")).collect();
        let value = v.map_or(String::new(), |v| format!("{v:.9e}"));
        body.push_str(&format!("{dist:.9e},{},{value}\n", coords.join(",")));
    }
    pmpm::atomic::write_atomic(&csv, |w| std::io::Write::write_all(w, body.as_bytes()))
        .map_err(|e| Error::io(&csv, e))?;
    let pts: Vec<(f64, f64)> = rows
        .iter()
        .filter_map(|(dist, _, v)| v.map(|v| (*dist, v)))
        .collect();
    let when = time.map_or(String::new(), |t| format!(", t = {}", fmt_time(t)));
    let fmt = |p: &[f64; 3]| {
        let c: Vec<String> = p[..f.dim].iter().map(|c| short(*c)).collect();
        format!("({})", c.join(", "))
    };
    let panel = Panel {
        title: format!(
            "{} from {} to {}, frame {n}{when}",
            field.label(),
            fmt(&a),
            fmt(&b)
        ),
        x_label: "distance along the line (m)".into(),
        y_label: field.label().into(),
        series: vec![line("", pts, colors::PROJ)],
        x_range: Some((0.0, length)),
        ..Default::default()
    };
    vplot::save(&png, &[panel], 1, 800, 500)
        .map_err(|e| Error::io(&png, std::io::Error::other(e)))?;
    Ok(vec![png, csv])
}

/// The faces of the grid, as run.toml names them.
const FACES: [&str; 6] = ["x_min", "x_max", "y_min", "y_max", "z_min", "z_max"];

/// The grid of run.toml with linear hat weights: the explicit scheme's pressure is smoothed
/// through it for display, as the grid frames spread the particles' fields.
#[derive(Debug, Clone)]
struct Hat {
    dim: usize,
    origin: [f64; 3],
    h: f64,
    /// Nodes along each axis (1 past the last axis).
    nodes: [usize; 3],
}

impl Hat {
    fn of(info: &RunInfo) -> Option<Self> {
        let (o, size) = info.grid.as_ref()?;
        let h = info.cell_size.filter(|h| *h > 0.0)?;
        let dim = o.len();
        let mut hat = Self {
            dim,
            origin: [0.0; 3],
            h,
            nodes: [1; 3],
        };
        for d in 0..dim {
            hat.origin[d] = o[d];
            hat.nodes[d] = (size[d] / h).round() as usize + 1;
        }
        Some(hat)
    }

    /// Calls `each(node, weight)` for the nodes of the cell holding `x`, with the linear hat
    /// weights prod_d (1 - |x_d - x_i,d| / h) (a point outside the grid: its nearest cell's).
    fn weights(&self, x: &[f64; 3], mut each: impl FnMut(usize, f64)) {
        let mut base = [0usize; 3];
        let mut frac = [0.0; 3];
        for d in 0..self.dim {
            let c = ((x[d] - self.origin[d]) / self.h).clamp(0.0, (self.nodes[d] - 1) as f64);
            base[d] = (c.floor() as usize).min(self.nodes[d].saturating_sub(2));
            frac[d] = c - base[d] as f64;
        }
        for corner in 0..1usize << self.dim {
            let (mut node, mut stride, mut w) = (0, 1, 1.0);
            for d in 0..self.dim {
                let up = (corner >> d) & 1;
                node += (base[d] + up) * stride;
                stride *= self.nodes[d];
                w *= if up == 1 { frac[d] } else { 1.0 - frac[d] };
            }
            if w > 0.0 {
                each(node, w);
            }
        }
    }
}

/// (frame, time) of each row of series.csv; empty when it cannot be read.
fn read_times(dir: &Path) -> Vec<(usize, f64)> {
    let Ok(t) = read_table(&dir.join("series.csv")) else {
        return Vec::new();
    };
    let (Some(f), Some(time)) = (t.column("frame"), t.column("time")) else {
        return Vec::new();
    };
    f.iter().zip(time).map(|(&f, t)| (f as usize, t)).collect()
}

/// A CSV file of numbers with a header line ([`Table`]), an unreadable file or a bad row as
/// an error naming the file.
fn read_table(path: &Path) -> Result<Table, Error> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    Table::parse(&text).map_err(|e| Error::Usage(format!("{}: {e}", path.display())))
}

/// The particles of one frame.
struct Frame {
    /// 2 or 3.
    dim: usize,
    /// Positions (z = 0 in 2D).
    x: Vec<[f64; 3]>,
    pressure: Vec<f64>,
    speed: Vec<f64>,
    /// Velocity (vz = 0 in 2D).
    v: Vec<[f64; 3]>,
    /// Particle size: volume^(1/D).
    size: Vec<f64>,
    material: Vec<usize>,
    mass: Vec<f64>,
}

impl Frame {
    /// The frame at `path`, only the particles in `view`'s slab.
    fn read(path: &Path, view: &View) -> Result<Self, Error> {
        let mut f = Self::read_all(path)?;
        if let Some(hat) = &view.smooth {
            f.smooth_pressure(hat);
        }
        if let Some((axis, lo, hi)) = view.slab {
            let keep: Vec<bool> = f.x.iter().map(|x| x[axis] >= lo && x[axis] <= hi).collect();
            let mut k = keep.iter();
            f.x.retain(|_| *k.next().unwrap());
            let mut k = keep.iter();
            f.v.retain(|_| *k.next().unwrap());
            for v in [&mut f.pressure, &mut f.speed, &mut f.size] {
                let mut k = keep.iter();
                v.retain(|_| *k.next().unwrap());
            }
            let mut k = keep.iter();
            f.material.retain(|_| *k.next().unwrap());
            let mut k = keep.iter();
            f.mass.retain(|_| *k.next().unwrap());
        }
        Ok(f)
    }

    /// The explicit scheme's pressure p = K (1 - J) alternates from particle to particle (a
    /// checkerboard: J of nearly incompressible water varies at the particles' scale). For
    /// display it is spread to the nodes, sum_p N_ip m_p p_p / sum_p N_ip m_p, and read back
    /// at each particle with the same weights: the field a grid frame holds.
    fn smooth_pressure(&mut self, hat: &Hat) {
        let count: usize = hat.nodes.iter().product();
        let (mut mp, mut m) = (vec![0.0; count], vec![0.0; count]);
        for p in 0..self.x.len() {
            let (mass, pressure) = (self.mass[p], self.pressure[p]);
            if pressure.is_finite() {
                hat.weights(&self.x[p], |i, w| {
                    mp[i] += w * mass * pressure;
                    m[i] += w * mass;
                });
            }
        }
        for p in 0..self.x.len() {
            let (mut sum, mut weight) = (0.0, 0.0);
            hat.weights(&self.x[p], |i, w| {
                if m[i] > 0.0 {
                    sum += w * mp[i] / m[i];
                    weight += w;
                }
            });
            if weight > 0.0 {
                self.pressure[p] = sum / weight;
            }
        }
    }

    fn read_all(path: &Path) -> Result<Self, Error> {
        let t = read_table(path)?;
        let dim = if t.index("z").is_some() { 3 } else { 2 };
        let need = |name: &str| {
            t.index(name).ok_or_else(|| {
                Error::Usage(format!(
                    "{}: no column \"{name}\" in the header (a pmpm frame has \
                     id,x,y,vx,vy,pressure,mass,volume,material)",
                    path.display()
                ))
            })
        };
        let xs = ["x", "y", "z"];
        let vs = ["vx", "vy", "vz"];
        let xi: Vec<usize> = xs[..dim]
            .iter()
            .map(|a| need(a))
            .collect::<Result<_, _>>()?;
        let vi: Vec<usize> = vs[..dim]
            .iter()
            .map(|a| need(a))
            .collect::<Result<_, _>>()?;
        let (pi, voli, mi) = (need("pressure")?, need("volume")?, need("material")?);
        let massi = need("mass")?;
        let n = t.rows.len();
        let mut f = Frame {
            dim,
            x: Vec::with_capacity(n),
            pressure: Vec::with_capacity(n),
            speed: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
            size: Vec::with_capacity(n),
            material: Vec::with_capacity(n),
            mass: Vec::with_capacity(n),
        };
        for r in &t.rows {
            let mut x = [0.0; 3];
            for (d, &i) in xi.iter().enumerate() {
                x[d] = r[i];
            }
            f.x.push(x);
            let mut v = [0.0; 3];
            for (d, &i) in vi.iter().enumerate() {
                v[d] = r[i];
            }
            f.v.push(v);
            f.speed
                .push(vi.iter().map(|&i| r[i] * r[i]).sum::<f64>().sqrt());
            f.pressure.push(r[pi]);
            f.size.push(r[voli].max(0.0).powf(1.0 / dim as f64));
            f.material.push(r[mi].max(0.0) as usize);
            f.mass.push(r[massi]);
        }
        Ok(f)
    }

    fn value(&self, field: Field, p: usize) -> f64 {
        match field {
            Field::Pressure => self.pressure[p],
            Field::Speed => self.speed[p],
            Field::Material => self.material[p] as f64,
            Field::Velocity(d) => self.v[p][d],
        }
    }

    /// The field's finite values: their extremes and the range to colour them over.
    fn range(&self, field: Field) -> Stats {
        let mut v: Vec<f64> = (0..self.x.len())
            .map(|p| self.value(field, p))
            .filter(|v| v.is_finite())
            .collect();
        Stats::of(&mut v)
    }

    /// The particles' extent in the plot's plane, each grown by `grow` times its size.
    fn extent(&self, plane: Plane, grow: f64) -> Extent {
        let (a, b) = self.axes(plane);
        let mut e = Extent::empty();
        for (x, s) in self.x.iter().zip(&self.size) {
            let g = grow * s;
            if x[a].is_finite() && x[b].is_finite() {
                e.x = (e.x.0.min(x[a] - g), e.x.1.max(x[a] + g));
                e.y = (e.y.0.min(x[b] - g), e.y.1.max(x[b] + g));
            }
        }
        e
    }

    fn axes(&self, plane: Plane) -> (usize, usize) {
        if self.dim == 2 {
            (0, 1)
        } else {
            let (a, b, _, _) = plane.axes();
            (a, b)
        }
    }
}

/// The extremes of a field's values, and the range its colours span: the extremes, or where a
/// few values lie far outside the rest (a pressure spike at a wall impact), the 2% and 98%
/// quantiles, so that one particle does not leave the rest in a single colour.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Stats {
    min: f64,
    max: f64,
    lo: f64,
    hi: f64,
}

impl Stats {
    fn empty() -> Self {
        Self {
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }

    fn of(v: &mut [f64]) -> Self {
        if v.is_empty() {
            return Self::empty();
        }
        v.sort_unstable_by(f64::total_cmp);
        let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
        let (min, max) = (v[0], v[v.len() - 1]);
        let (q_lo, q_hi) = (q(0.02), q(0.98));
        let bulk = q_hi - q_lo;
        let lo = if q_lo - min > 0.5 * bulk { q_lo } else { min };
        let hi = if max - q_hi > 0.5 * bulk { q_hi } else { max };
        Self { min, max, lo, hi }
    }

    /// Both ranges over two sets of values (frames of a movie).
    fn union(&self, o: &Stats) -> Stats {
        Stats {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }
}

/// A rectangle in the plot's plane (m).
#[derive(Debug, Clone, Copy)]
struct Extent {
    x: (f64, f64),
    y: (f64, f64),
}

impl Extent {
    fn empty() -> Self {
        Self {
            x: (f64::INFINITY, f64::NEG_INFINITY),
            y: (f64::INFINITY, f64::NEG_INFINITY),
        }
    }

    fn union(&self, o: &Extent) -> Extent {
        Extent {
            x: (self.x.0.min(o.x.0), self.x.1.max(o.x.1)),
            y: (self.y.0.min(o.y.0), self.y.1.max(o.y.1)),
        }
    }

    fn width(&self) -> f64 {
        self.x.1 - self.x.0
    }

    fn height(&self) -> f64 {
        self.y.1 - self.y.0
    }

    /// Non-empty, finite, at least a little wide and high.
    fn sane(self) -> Extent {
        let fix = |(lo, hi): (f64, f64)| {
            if !(lo.is_finite() && hi.is_finite()) {
                (0.0, 1.0)
            } else if hi - lo <= 1e-12 * (1.0 + hi.abs()) {
                (lo - 0.5, hi + 0.5)
            } else {
                (lo, hi)
            }
        };
        let mut e = Extent {
            x: fix(self.x),
            y: fix(self.y),
        };
        // one side never below 1/20 of the other (a line of particles)
        let (w, h) = (e.width(), e.height());
        if h < w / 20.0 {
            let c = 0.5 * (e.y.0 + e.y.1);
            e.y = (c - w / 40.0, c + w / 40.0);
        } else if w < h / 20.0 {
            let c = 0.5 * (e.x.0 + e.x.1);
            e.x = (c - h / 40.0, c + h / 40.0);
        }
        e
    }
}

/// The colour range: the data's (from 0 for speed), overridden by --min / --max.
fn color_range(field: Field, data: &Stats, opts: &PlotOptions) -> (f64, f64) {
    let (mut lo, mut hi) = if data.lo.is_finite() {
        (data.lo, data.hi)
    } else {
        (0.0, 1.0)
    };
    if field == Field::Speed {
        lo = 0.0;
    }
    if field == Field::Material {
        return (lo, hi);
    }
    lo = opts.min.unwrap_or(lo);
    hi = opts.max.unwrap_or(hi);
    if hi - lo <= 1e-12 * (lo.abs() + hi.abs()) || hi <= lo {
        // a constant field (a run at rest): a range around it
        let d = if lo.abs() > 0.0 { 0.1 * lo.abs() } else { 1.0 };
        if opts.min.is_some() {
            hi = lo + d;
        } else if opts.max.is_some() {
            lo = hi - d;
        } else {
            lo -= d;
            hi += d;
            if field == Field::Speed {
                lo = 0.0;
            }
        }
    }
    (lo, hi)
}

/// Viridis (matplotlib), at nine points; `t` in [0, 1].
fn viridis(t: f64) -> RGBColor {
    const C: [(f64, f64, f64); 9] = [
        (68.0, 1.0, 84.0),
        (71.0, 45.0, 123.0),
        (59.0, 82.0, 139.0),
        (44.0, 114.0, 142.0),
        (33.0, 145.0, 140.0),
        (40.0, 174.0, 128.0),
        (94.0, 201.0, 98.0),
        (173.0, 220.0, 48.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let s = t * 8.0;
    let i = (s.floor() as usize).min(7);
    let f = s - i as f64;
    let mix = |a: f64, b: f64| (a + f * (b - a)).round() as u8;
    RGBColor(
        mix(C[i].0, C[i + 1].0),
        mix(C[i].1, C[i + 1].1),
        mix(C[i].2, C[i + 1].2),
    )
}

/// Colours of materials 0, 1, 2, ... (matplotlib's tab10).
const MATERIAL_COLORS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Pixel sizes of the frame picture.
const TITLE_H: u32 = 44;
const TITLE_3D_H: u32 = 24;
const MARGIN: u32 = 14;
const Y_LABELS: u32 = 80;
const X_LABELS: u32 = 56;
const BAR_W: u32 = 126;
const BAR_LABELS: u32 = 76;
/// Particles are drawn this many times their own size: MPM particles line up and leave gaps
/// of up to a particle spacing as the material stretches, which would read as dust.
const SPLAT: f64 = 2.0;

/// Image size (pixels) of a frame picture whose drawn domain is `w` x `h` metres: the plotting
/// area is 1200 pixels wide (at most 800 high, at least 240: the range is widened then, the
/// scale is the same on both axes), plus the title, the axes' labels and the colour bar.
pub fn frame_image_size(w: f64, h: f64, three_d: bool) -> (u32, u32) {
    let (pw, ph) = plot_area_size(w, h);
    (
        Y_LABELS + pw + 2 * MARGIN + BAR_W,
        TITLE_H + if three_d { TITLE_3D_H } else { 0 } + ph + X_LABELS + 2 * MARGIN,
    )
}

fn plot_area_size(w: f64, h: f64) -> (u32, u32) {
    let ar = h / w;
    let mut pw = 1200.0;
    let mut ph = pw * ar;
    if ph > 800.0 {
        ph = 800.0;
        pw = (ph / ar).max(400.0);
    }
    (pw.round() as u32, ph.clamp(240.0, 800.0).round() as u32)
}

/// What every picture of a run shares: the field and its colour range, the drawn rectangle
/// ([`picture_extent`]), the view and the rigid bodies.
struct Scene<'a> {
    field: Field,
    range: (f64, f64),
    info: &'a RunInfo,
    extent: Extent,
    view: &'a View,
    bodies: &'a Bodies,
}

impl<'a> Scene<'a> {
    /// The picture of frame `n` (its particles `f`, at `time`).
    fn sketch(&'a self, f: &'a Frame, n: usize, time: Option<f64>) -> Sketch<'a> {
        Sketch {
            f,
            n,
            time,
            scene: self,
        }
    }
}

/// One frame's picture.
struct Sketch<'a> {
    f: &'a Frame,
    n: usize,
    time: Option<f64>,
    scene: &'a Scene<'a>,
}

impl Sketch<'_> {
    fn size(&self) -> (u32, u32) {
        frame_image_size(
            self.scene.extent.width(),
            self.scene.extent.height(),
            self.scene.view.three_d(self.scene.info) || self.f.dim == 3,
        )
    }

    /// Into the PNG file `out`.
    fn png(&self, out: &Path) -> Result<(), Error> {
        let err = |e: &dyn std::fmt::Display| Error::io(out, std::io::Error::other(e.to_string()));
        let root = BitMapBackend::new(out, self.size()).into_drawing_area();
        self.draw(&root).map_err(|e| err(&*e))?;
        root.present().map_err(|e| err(&e))
    }

    /// As RGB pixels, row by row (`out`: the file they are for, in messages).
    fn pixels(&self, out: &Path) -> Result<Vec<u8>, Error> {
        let err = |e: &dyn std::fmt::Display| Error::io(out, std::io::Error::other(e.to_string()));
        let (w, h) = self.size();
        let mut buf = vec![0u8; 3 * w as usize * h as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            self.draw(&root).map_err(|e| err(&*e))?;
            root.present().map_err(|e| err(&e))?;
        }
        Ok(buf)
    }

    fn draw(&self, root: &Area<'_>) -> DrawResult {
        let f = self.f;
        let (a, b) = f.axes(self.scene.view.plane);
        let extent = self.scene.extent;
        let three_d = f.dim == 3;
        root.fill(&WHITE)?;
        let title_h = TITLE_H + if three_d { TITLE_3D_H } else { 0 };
        let (title, body) = root.split_vertically(title_h);
        let what = match self.scene.field {
            Field::Pressure if self.scene.view.smooth.is_some() => {
                "Pressure (smoothed on the grid)"
            }
            Field::Pressure => "Pressure",
            Field::Speed => "Speed",
            Field::Material => "Material",
            Field::Velocity(0) => "Velocity x",
            Field::Velocity(1) => "Velocity y",
            Field::Velocity(_) => "Velocity z",
        };
        let when = match self.time {
            Some(t) => format!("t = {}", fmt_time(t)),
            None => "time not in series.csv".to_string(),
        };
        let (tw, _) = title.dim_in_pixel();
        title.draw_text(
            &format!("{what}, frame {}, {when}", self.n),
            &("sans-serif", 24)
                .into_text_style(&title)
                .pos(Pos::new(HPos::Center, VPos::Center)),
            (tw as i32 / 2, TITLE_H as i32 / 2 + 4),
        )?;
        if three_d {
            title.draw_text(
                &self.scene.view.describe(),
                &("sans-serif", 16)
                    .into_text_style(&title)
                    .pos(Pos::new(HPos::Center, VPos::Center)),
                (tw as i32 / 2, (TITLE_H + TITLE_3D_H / 2) as i32),
            )?;
        }
        let (bw, _) = body.dim_in_pixel();
        let (plot_area, bar_area) = body.split_horizontally(bw - BAR_W);
        let outlines = self.scene.bodies.outlines(self.time.unwrap_or(0.0), a, b);
        let walls = walls(self.scene.info, a, b);
        draw_particles(
            f,
            self.scene.field,
            self.scene.range,
            extent,
            a,
            b,
            self.scene.view.plane,
            &outlines,
            &walls,
            &plot_area,
        )?;
        match self.scene.field {
            Field::Material => draw_legend(f, self.scene.info, &bar_area)?,
            _ => draw_bar(
                self.scene.field,
                self.scene.range,
                &f.range(self.scene.field),
                &bar_area,
            )?,
        }
        Ok(())
    }
}

/// The rigid bodies of run.toml that a picture can draw (boxes and spheres, 2D or 3D), and
/// their motion from rigid_bodies.csv.
#[derive(Debug, Default)]
struct Bodies {
    list: Vec<Drawn>,
    /// Time, then the columns of rigid_bodies.csv, a row per step.
    table: Vec<Vec<f64>>,
    time: usize,
}

/// A body's shape at t = 0, and its columns' indices in rigid_bodies.csv: the
/// displacement's (u), the reference point's now (x), and in 2D the angle turned.
type Drawn = (BodyShape, Vec<usize>, Vec<usize>, Option<usize>);

/// A drawable shape: a box's corners (min, max) or a sphere's centre and radius.
#[derive(Debug, Clone)]
enum BodyShape {
    Box([f64; 3], [f64; 3]),
    Sphere([f64; 3], f64),
}

impl Bodies {
    /// What run.toml and rigid_bodies.csv in `dir` give (none where either is missing; a
    /// shape with a transform, or of another type, is not drawn).
    fn read(dir: &Path, info: &RunInfo) -> Self {
        let mut out = Bodies::default();
        let Ok(t) = read_table(&dir.join("rigid_bodies.csv")) else {
            return out;
        };
        let Some(time) = t.index("time") else {
            return out;
        };
        let three = |v: Option<&toml::Value>| -> Option<[f64; 3]> {
            let a = v?.as_array()?;
            let mut x = [0.0; 3];
            for (d, e) in a.iter().enumerate().take(3) {
                x[d] = e.as_float().or_else(|| e.as_integer().map(|i| i as f64))?;
            }
            Some(x)
        };
        let axes = ["x", "y", "z"];
        let dim = info.dim.unwrap_or(2);
        for body in &info.rigid {
            let (Some(name), Some(shape)) =
                (body.get("name").and_then(|n| n.as_str()), body.get("shape"))
            else {
                continue;
            };
            if ["scale", "rotate", "translate"]
                .iter()
                .any(|k| shape.get(k).is_some())
            {
                continue;
            }
            let kind = shape.get("type").and_then(|k| k.as_str()).unwrap_or("box");
            let drawn = match kind {
                "box" => match (three(shape.get("min")), three(shape.get("max"))) {
                    (Some(lo), Some(hi)) => BodyShape::Box(lo, hi),
                    _ => continue,
                },
                "sphere" => match (
                    three(shape.get("center")),
                    shape.get("radius").and_then(|r| r.as_float()),
                ) {
                    (Some(c), Some(r)) => BodyShape::Sphere(c, r),
                    _ => continue,
                },
                _ => continue,
            };
            let cols = |prefix: &str| -> Option<Vec<usize>> {
                axes[..dim]
                    .iter()
                    .map(|a| t.index(&format!("{name}_{prefix}{a}")))
                    .collect()
            };
            let (Some(u), Some(x)) = (cols("u"), cols("")) else {
                continue;
            };
            let angle = t.index(&format!("{name}_angle"));
            // a 3D body that turns is not drawn (its rotation is not in the picture's terms)
            if dim == 3 && t.index(&format!("{name}_rx")).is_some() {
                continue;
            }
            out.list.push((drawn, u, x, angle));
        }
        out.table = t.rows;
        out.time = time;
        out
    }

    /// Each body's outline at time `t` in the plane of axes (a, b), as closed polylines:
    /// its row is the last step that ended by `t` (none before the first step: at rest).
    fn outlines(&self, t: f64, a: usize, b: usize) -> Vec<Vec<(f64, f64)>> {
        let row = self
            .table
            .iter()
            .take_while(|r| r[self.time] <= t * (1.0 + 1e-9) + 1e-12)
            .last();
        let mut out = Vec::new();
        for (shape, u, x, angle) in &self.list {
            let at = |cols: &Vec<usize>| -> [f64; 3] {
                let mut v = [0.0; 3];
                if let Some(r) = row {
                    for (d, &i) in cols.iter().enumerate() {
                        v[d] = r[i];
                    }
                }
                v
            };
            let (du, now) = (at(u), at(x));
            let turn = match (angle, row) {
                (Some(i), Some(r)) => r[*i],
                _ => 0.0,
            };
            // a point of the shape at t = 0, moved and turned (about the reference point)
            let moved = |p: [f64; 3]| -> (f64, f64) {
                if row.is_none() {
                    return (p[a], p[b]);
                }
                let r0 = [now[0] - du[0], now[1] - du[1], now[2] - du[2]];
                let (dx, dy) = (p[0] - r0[0], p[1] - r0[1]);
                let (c, s) = (turn.cos(), turn.sin());
                let q = [
                    now[0] + c * dx - s * dy,
                    now[1] + s * dx + c * dy,
                    p[2] + du[2],
                ];
                (q[a], q[b])
            };
            match shape {
                BodyShape::Box(lo, hi) => {
                    let corner = |i: bool, j: bool| {
                        let mut p = *lo;
                        p[a] = if i { hi[a] } else { lo[a] };
                        p[b] = if j { hi[b] } else { lo[b] };
                        // the depth axis at the box's middle
                        for d in 0..3 {
                            if d != a && d != b {
                                p[d] = 0.5 * (lo[d] + hi[d]);
                            }
                        }
                        moved(p)
                    };
                    out.push(vec![
                        corner(false, false),
                        corner(true, false),
                        corner(true, true),
                        corner(false, true),
                        corner(false, false),
                    ]);
                }
                BodyShape::Sphere(c, r) => {
                    let centre = moved(*c);
                    out.push(
                        (0..=64)
                            .map(|k| {
                                let th = k as f64 / 64.0 * std::f64::consts::TAU;
                                (centre.0 + r * th.cos(), centre.1 + r * th.sin())
                            })
                            .collect(),
                    );
                }
            }
        }
        out
    }
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
type DrawResult = Result<(), Box<dyn std::error::Error>>;
/// A frame picture's chart: metres on the plotting area.
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

#[allow(clippy::too_many_arguments)]
fn draw_particles(
    f: &Frame,
    field: Field,
    range: (f64, f64),
    extent: Extent,
    a: usize,
    b: usize,
    plane: Plane,
    outlines: &[Vec<(f64, f64)>],
    walls: &[(Vec<(f64, f64)>, &str)],
    area: &Area<'_>,
) -> DrawResult {
    let (mut chart, ppm) = equal_scale_chart(area, extent)?;
    draw_mesh(&mut chart, a, b)?;
    let order = draw_order(f, plane);
    let span = range.1 - range.0;
    let color = |p: usize| -> RGBColor {
        match field {
            Field::Material => MATERIAL_COLORS[f.material[p] % MATERIAL_COLORS.len()],
            _ => {
                let v = f.value(field, p);
                if v.is_finite() {
                    viridis((v - range.0) / span)
                } else {
                    RGBColor(255, 0, 255)
                }
            }
        }
    };
    // squares in pixels, clipped to the drawn domain: a particle drawn larger than itself at a
    // wall does not spill over the wall (or the axes)
    let (bx, by) = area.get_base_pixel();
    let local = |c: (i32, i32)| (c.0 - bx, c.1 - by);
    let (c0, c1) = (
        local(chart.backend_coord(&(extent.x.0, extent.y.1))),
        local(chart.backend_coord(&(extent.x.1, extent.y.0))),
    );
    for p in order {
        let x = f.x[p];
        if !(x[a].is_finite() && x[b].is_finite()) {
            continue;
        }
        // side in pixels, rounded up so that neighbours touch
        let s = (SPLAT * f.size[p] * ppm).ceil().clamp(2.0, 200.0) as i32;
        let (cx, cy) = local(chart.backend_coord(&(x[a], x[b])));
        let (x0, y0) = ((cx - s / 2).max(c0.0), (cy - s / 2).max(c0.1));
        let (x1, y1) = ((cx - s / 2 + s).min(c1.0), (cy - s / 2 + s).min(c1.1));
        if x0 < x1 && y0 < y1 {
            area.draw(&Rectangle::new([(x0, y0), (x1, y1)], color(p).filled()))?;
        }
    }
    // the drawn domain's border on top of the particles at the walls
    chart.draw_series(std::iter::once(Rectangle::new(
        [(extent.x.0, extent.y.0), (extent.x.1, extent.y.1)],
        RGBColor(90, 90, 90).stroke_width(1),
    )))?;
    draw_walls(&mut chart, walls)?;
    // the rigid bodies' outlines
    chart.draw_series(
        outlines
            .iter()
            .map(|o| PathElement::new(o.clone(), RGBColor(200, 30, 30).stroke_width(2))),
    )?;
    Ok(())
}

/// The chart on `area` holding `extent` at one scale on both axes, and that scale (pixels/m).
fn equal_scale_chart<'a, 'b>(
    area: &'a Area<'b>,
    extent: Extent,
) -> Result<(Chart<'a, 'b>, f64), Box<dyn std::error::Error>> {
    let build = |x: (f64, f64), y: (f64, f64)| {
        ChartBuilder::on(area)
            .margin(MARGIN)
            .x_label_area_size(X_LABELS)
            .y_label_area_size(Y_LABELS)
            .build_cartesian_2d(x.0..x.1, y.0..y.1)
    };
    // equal scale: widen the range on the side with room to spare, at the true pixel size
    let (pw, ph) = build(extent.x, extent.y)?.plotting_area().dim_in_pixel();
    let (pw, ph) = (pw.max(2) as f64 - 1.0, ph.max(2) as f64 - 1.0);
    let ppm = (pw / extent.width()).min(ph / extent.height());
    let grow = |(lo, hi): (f64, f64), pixels: f64| {
        let pad = 0.5 * (pixels / ppm - (hi - lo));
        (lo - pad, hi + pad)
    };
    let xr = grow(extent.x, pw);
    let yr = grow(extent.y, ph);
    Ok((build(xr, yr)?, ppm))
}

/// The chart's axes, labelled by the axes (a, b) of the plane, and its grid lines.
fn draw_mesh(chart: &mut Chart<'_, '_>, a: usize, b: usize) -> DrawResult {
    let axis = ["x (m)", "y (m)", "z (m)"];
    chart
        .configure_mesh()
        .x_desc(axis[a])
        .y_desc(axis[b])
        .x_label_formatter(&vplot::tick)
        .y_label_formatter(&vplot::tick)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .light_line_style(RGBColor(240, 240, 240))
        .bold_line_style(RGBColor(218, 218, 218))
        .draw()?;
    Ok(())
}

/// The order the particles are drawn in: as they come, or in 3D the nearest the viewer last.
fn draw_order(f: &Frame, plane: Plane) -> Vec<usize> {
    let mut order: Vec<usize> = (0..f.x.len()).collect();
    if f.dim == 3 {
        let (_, _, depth, towards) = plane.axes();
        order.sort_by(|&p, &q| {
            let (u, v) = (f.x[p][depth], f.x[q][depth]);
            if towards {
                u.total_cmp(&v)
            } else {
                v.total_cmp(&u)
            }
        });
    }
    order
}

/// Draws the grid's walls seen edge-on, each as its kind looks, and the inflow patches.
fn draw_walls(chart: &mut Chart<'_, '_>, walls: &[(Vec<(f64, f64)>, &str)]) -> DrawResult {
    // the walls by kind: no-slip thick, slip thin, outflow dashed blue, periodic dashed grey,
    // open not drawn; inflow patches green
    for (line, kind) in walls {
        let dark = RGBColor(40, 40, 40);
        match *kind {
            "no_slip" => chart.draw_series([PathElement::new(line.clone(), dark.stroke_width(5))]),
            "slip" => chart.draw_series([PathElement::new(line.clone(), dark.stroke_width(2))]),
            "inflow" => chart.draw_series([PathElement::new(
                line.clone(),
                RGBColor(0, 160, 60).stroke_width(6),
            )]),
            "outflow" => chart.draw_series([DashedPathElement::new(
                line.clone(),
                10,
                6,
                RGBColor(30, 90, 220).stroke_width(3),
            )]),
            "periodic" => chart.draw_series([DashedPathElement::new(
                line.clone(),
                4,
                4,
                RGBColor(120, 120, 120).stroke_width(1),
            )]),
            _ => continue,
        }?;
    }
    Ok(())
}

/// The grid's faces seen edge-on in the plane of axes (a, b), each with its kind, and the
/// inflow patches on them ("inflow"), from run.toml.
fn walls(info: &RunInfo, a: usize, b: usize) -> Vec<(Vec<(f64, f64)>, &str)> {
    let Some((o, s)) = &info.grid else {
        return Vec::new();
    };
    // the edge of face k from `lo` to `hi` along the other axis of the plane
    let edge = |k: usize, lo: &[f64], hi: &[f64]| -> Option<Vec<(f64, f64)>> {
        let (axis, at) = (k / 2, o[k / 2] + if k % 2 == 1 { s[k / 2] } else { 0.0 });
        if axis == a {
            Some(vec![(at, lo[b]), (at, hi[b])])
        } else if axis == b {
            Some(vec![(lo[a], at), (hi[a], at)])
        } else {
            None
        }
    };
    let top: Vec<f64> = o.iter().zip(s).map(|(o, s)| o + s).collect();
    let mut out: Vec<(Vec<(f64, f64)>, &str)> = info
        .faces
        .iter()
        .enumerate()
        .take(o.len() * 2)
        .filter_map(|(k, kind)| Some((edge(k, o, &top)?, kind.as_deref()?)))
        .collect();
    for (k, lo, hi) in &info.inflows {
        if lo.len() == o.len() && hi.len() == o.len() {
            out.extend(edge(*k, lo, hi).map(|line| (line, "inflow")));
        }
    }
    out
}

fn draw_bar(field: Field, range: (f64, f64), data: &Stats, area: &Area<'_>) -> DrawResult {
    let mut chart = ChartBuilder::on(area)
        .margin_top(MARGIN)
        .margin_bottom(MARGIN)
        .margin_left(8)
        .margin_right(MARGIN)
        .x_label_area_size(X_LABELS)
        .right_y_label_area_size(BAR_LABELS)
        .build_cartesian_2d(0.0..1.0, range.0..range.1)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .set_tick_mark_size(LabelAreaPosition::Right, 6)
        .y_desc(field.label())
        .y_label_formatter(&vplot::tick)
        .y_labels(8)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()?;
    let steps = 256;
    let d = (range.1 - range.0) / steps as f64;
    chart.draw_series((0..steps).map(|i| {
        let lo = range.0 + i as f64 * d;
        Rectangle::new(
            [(0.0, lo), (1.0, lo + d * 1.01)],
            viridis((i as f64 + 0.5) / steps as f64).filled(),
        )
    }))?;
    chart.draw_series(std::iter::once(Rectangle::new(
        [(0.0, range.0), (1.0, range.1)],
        BLACK.stroke_width(1),
    )))?;
    // values beyond the range (drawn in the end colours): a triangle at that end of the bar
    let (px, py) = chart.plotting_area().get_pixel_range();
    let (bx, by) = area.get_base_pixel();
    let (x0, x1) = (px.start - bx, px.end - 1 - bx);
    let (top, bottom) = (py.start - by, py.end - 1 - by);
    let xm = (x0 + x1) / 2;
    let tri = (x1 - x0) / 2 + 2;
    if data.max.is_finite() && data.max > range.1 {
        area.draw(&Polygon::new(
            vec![(x0, top - 1), (x1, top - 1), (xm, top - 1 - tri)],
            viridis(1.0).filled(),
        ))?;
    }
    if data.min.is_finite() && data.min < range.0 {
        area.draw(&Polygon::new(
            vec![(x0, bottom + 1), (x1, bottom + 1), (xm, bottom + 1 + tri)],
            viridis(0.0).filled(),
        ))?;
    }
    // the data's extremes under the bar
    if data.min.is_finite() {
        let style = ("sans-serif", 14).into_text_style(area);
        let y = bottom + tri + 8;
        area.draw_text(&format!("min {}", short(data.min)), &style, (x0, y))?;
        area.draw_text(&format!("max {}", short(data.max)), &style, (x0, y + 17))?;
    }
    Ok(())
}

fn draw_legend(f: &Frame, info: &RunInfo, area: &Area<'_>) -> DrawResult {
    let mut present: Vec<usize> = f.material.clone();
    present.sort_unstable();
    present.dedup();
    let style = ("sans-serif", 16).into_text_style(area);
    let x0 = 10;
    let mut y = MARGIN as i32 + 6;
    area.draw_text(
        "material",
        &("sans-serif", 17).into_text_style(area),
        (x0, y),
    )?;
    y += 30;
    for m in present {
        let c = MATERIAL_COLORS[m % MATERIAL_COLORS.len()];
        area.draw(&Rectangle::new([(x0, y), (x0 + 18, y + 18)], c.filled()))?;
        let name = info
            .materials
            .get(m)
            .cloned()
            .unwrap_or_else(|| format!("material {m}"));
        area.draw_text(&name, &style, (x0 + 26, y + 1))?;
        y += 28;
    }
    Ok(())
}

/// A number to about three significant digits.
fn short(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.2e}")
    } else {
        let decimals = (2 - a.log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    }
}

fn fmt_time(t: f64) -> String {
    if t == 0.0 {
        "0 s".into()
    } else if (1e-3..1e4).contains(&t.abs()) {
        format!("{t:.4} s")
    } else {
        format!("{t:.3e} s")
    }
}

/// The series of a run, and its probes when probes.csv has rows, as panels of one PNG.
fn plot_series(dir: &Path, out: &Path) -> Result<(), Error> {
    let path = dir.join("series.csv");
    if !path.is_file() {
        return Err(Error::Usage(format!(
            "{}: no series.csv; is it the output directory of a run?",
            dir.display()
        )));
    }
    let t = read_table(&path)?;
    let col = |name: &str| {
        t.column(name).ok_or_else(|| {
            Error::Usage(format!(
                "{}: no column \"{name}\" in the header",
                path.display()
            ))
        })
    };
    if t.rows.is_empty() {
        return Err(Error::Usage(format!("{}: no rows", path.display())));
    }
    let time = col("time")?;
    // frame 0 comes before any step: no time step, no pressure solve
    let stepped: Vec<bool> = col("step")?.iter().map(|&s| s > 0.0).collect();
    let per_m = if dimension(dir) == Some(2) {
        " per m of thickness"
    } else {
        ""
    };
    let panel = |title: &str, y_label: &str, name: &str, color, scale: f64, all_rows: bool| {
        let pts: Vec<(f64, f64)> = time
            .iter()
            .zip(col(name)?)
            .zip(&stepped)
            .filter(|(_, &s)| all_rows || s)
            .map(|((&t, v), _)| (t, v * scale))
            .collect();
        // y from 0: none of these is negative, and a flat line stays readable
        let hi = pts
            .iter()
            .map(|q| q.1)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        Ok::<_, Error>(Panel {
            title: title.into(),
            x_label: "time (s)".into(),
            y_label: y_label.into(),
            series: vec![line("", pts, color)],
            x_range: Some(time_range(&time)),
            y_range: Some((0.0, if hi > 0.0 { 1.05 * hi } else { 1.0 })),
            ..Default::default()
        })
    };
    let dt_max = col("dt")?.into_iter().fold(0.0, f64::max);
    let (dt_unit, dt_scale) = if dt_max >= 0.1 {
        ("s", 1.0)
    } else if dt_max >= 1e-4 {
        ("ms", 1e3)
    } else {
        ("\u{b5}s", 1e6)
    };
    let mut panels = vec![
        panel(
            "Kinetic energy",
            &format!("kinetic energy (J{per_m})"),
            "kinetic_energy",
            colors::PROJ,
            1.0,
            true,
        )?,
        panel(
            "Largest particle speed",
            "max speed (m/s)",
            "max_speed",
            colors::EXPL,
            1.0,
            true,
        )?,
        panel(
            "Pressure solver iterations (last step before each frame)",
            "iterations",
            "pressure_iterations",
            colors::GREEN,
            1.0,
            false,
        )?,
        panel(
            "Time step (last step before each frame)",
            &format!("dt ({dt_unit})"),
            "dt",
            colors::ORANGE,
            dt_scale,
            false,
        )?,
    ];
    panels.extend(probe_panels(dir)?);
    panels.extend(column_panels(dir, "rigid_bodies.csv", "Rigid bodies")?);
    panels.extend(column_panels(dir, "gauges.csv", "Gauges")?);
    vplot::save(out, &panels, 2, 640, 400).map_err(|e| Error::io(out, std::io::Error::other(e)))
}

/// The time axis: from the first to the last time (a little around a single time).
fn time_range(t: &[f64]) -> (f64, f64) {
    let lo = t.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !(lo.is_finite() && hi.is_finite()) {
        (0.0, 1.0)
    } else if hi - lo <= 1e-12 * (1.0 + hi.abs()) {
        let d = 0.05 * (1.0 + hi.abs());
        (lo - d, hi + d)
    } else {
        (lo, hi)
    }
}

/// The run's dimension: from run.toml, else from the first frame's header.
fn dimension(dir: &Path) -> Option<usize> {
    if let Some(d) = RunInfo::read(dir).dim {
        return Some(d);
    }
    let (_, path) = list_frames(dir).ok()?.into_iter().next()?;
    let text = std::fs::read_to_string(path).ok()?;
    let head = text.lines().next()?;
    Some(if head.split(',').any(|c| c.trim() == "z") {
        3
    } else {
        2
    })
}

/// A line, or markers when there are too few points for a line.
fn line(label: &str, pts: Vec<(f64, f64)>, color: RGBColor) -> Series {
    if pts.len() < 3 {
        Series::markers(label, pts, color)
    } else {
        Series::line(label, pts, color)
    }
}

/// The lines' colours of the series panels, in turn.
const PALETTE: [RGBColor; 7] = [
    colors::PROJ,
    colors::EXPL,
    colors::GREEN,
    colors::ORANGE,
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    colors::REF,
];

/// Pressure and speed of each probe against time; none without probes.csv or rows in it.
fn probe_panels(dir: &Path) -> Result<Vec<Panel>, Error> {
    let path = dir.join("probes.csv");
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let t = read_table(&path)?;
    let Some(ti) = t.index("time") else {
        return Ok(Vec::new());
    };
    if t.rows.is_empty() {
        return Ok(Vec::new());
    }
    let names: Vec<&str> = t
        .header
        .iter()
        .filter_map(|h| h.strip_suffix("_pressure"))
        .collect();
    if names.is_empty() {
        return Ok(Vec::new());
    }
    let palette = PALETTE;
    let mut pressure = Panel {
        title: "Probe pressure".into(),
        x_label: "time (s)".into(),
        y_label: "pressure (Pa)".into(),
        ..Default::default()
    };
    let mut speed = Panel {
        title: "Probe speed".into(),
        x_label: "time (s)".into(),
        y_label: "speed (m/s)".into(),
        ..Default::default()
    };
    for (k, name) in names.iter().enumerate() {
        let c = palette[k % palette.len()];
        let pi = t.index(&format!("{name}_pressure")).expect("found above");
        let vi: Vec<usize> = ["vx", "vy", "vz"]
            .iter()
            .filter_map(|a| t.index(&format!("{name}_{a}")))
            .collect();
        pressure.series.push(thin(
            name,
            t.rows.iter().map(|r| (r[ti], r[pi])).collect(),
            c,
        ));
        speed.series.push(thin(
            name,
            t.rows
                .iter()
                .map(|r| (r[ti], vi.iter().map(|&i| r[i] * r[i]).sum::<f64>().sqrt()))
                .collect(),
            c,
        ));
    }
    let times: Vec<f64> = t.rows.iter().map(|r| r[ti]).collect();
    pressure.x_range = Some(time_range(&times));
    speed.x_range = pressure.x_range;
    Ok(vec![pressure, speed])
}

/// What a column NAME_SUFFIX of rigid_bodies.csv or gauges.csv holds, by its suffix: the
/// quantity it belongs to (its panel), and the panel's title and unit.
fn quantity(suffix: &str) -> Option<(&'static str, &'static str)> {
    Some(match suffix {
        "ux" | "uy" | "uz" => ("displacement", "m"),
        "x" | "y" | "z" => ("position", "m"),
        "vx" | "vy" | "vz" => ("velocity", "m/s"),
        "fx" | "fy" | "fz" => ("force", "N"),
        "angle" | "rx" | "ry" | "rz" => ("angle turned", "rad"),
        "omega" | "wx" | "wy" | "wz" => ("angular velocity", "rad/s"),
        "torque" | "mx" | "my" | "mz" => ("torque", "N m"),
        "height" => ("surface height", "m"),
        "pressure" => ("pressure", "Pa"),
        _ => return None,
    })
}

/// One panel per quantity of `file` (rigid_bodies.csv, gauges.csv), a line per column;
/// none without the file or rows in it.
fn column_panels(dir: &Path, file: &str, what: &str) -> Result<Vec<Panel>, Error> {
    let path = dir.join(file);
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let t = read_table(&path)?;
    let Some(ti) = t.index("time") else {
        return Ok(Vec::new());
    };
    if t.rows.is_empty() {
        return Ok(Vec::new());
    }
    let palette = PALETTE;
    let per_m = dimension(dir) == Some(2);
    let times: Vec<f64> = t.rows.iter().map(|r| r[ti]).collect();
    let mut panels: Vec<(&str, Panel)> = Vec::new();
    for (i, h) in t.header.iter().enumerate() {
        let Some((_, suffix)) = h.rsplit_once('_') else {
            continue;
        };
        let Some((title, unit)) = quantity(suffix) else {
            continue;
        };
        let k = match panels.iter().position(|(q, _)| *q == title) {
            Some(k) => k,
            None => {
                let unit = if per_m && matches!(unit, "N" | "N m") {
                    format!("{unit} per m")
                } else {
                    unit.to_string()
                };
                panels.push((
                    title,
                    Panel {
                        title: format!("{what}: {title}"),
                        x_label: "time (s)".into(),
                        y_label: format!("{title} ({unit})"),
                        x_range: Some(time_range(&times)),
                        ..Default::default()
                    },
                ));
                panels.len() - 1
            }
        };
        let panel = &mut panels[k].1;
        let c = palette[panel.series.len() % palette.len()];
        panel
            .series
            .push(thin(h, t.rows.iter().map(|r| (r[ti], r[i])).collect(), c));
    }
    Ok(panels.into_iter().map(|(_, p)| p).collect())
}

/// A thin line (probes are sampled every step), or markers for very few points.
fn thin(label: &str, pts: Vec<(f64, f64)>, color: RGBColor) -> Series {
    if pts.len() < 3 {
        Series::markers(label, pts, color)
    } else {
        Series::thin(label, pts, color)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_numbers() {
        assert_eq!(short(2799.77), "2800");
        assert_eq!(short(-20.3645), "-20.4");
        assert_eq!(short(0.012345), "0.0123");
        assert_eq!(short(2.2e9), "2.20e9");
    }

    #[test]
    fn smoothing_takes_out_a_checkerboard_and_keeps_a_linear_field() {
        // particles on a lattice of spacing h/2, p = 1000 - 100 y plus a checkerboard of
        // +-50: the nodes' weights see the checkerboard's signs in equal shares, and a linear
        // field is reproduced, so inside the grid the smoothed pressure is the linear part
        let h = 0.1;
        let hat = Hat {
            dim: 2,
            origin: [0.0; 3],
            h,
            nodes: [11, 11, 1],
        };
        let n = 20;
        let mut f = Frame {
            dim: 2,
            x: Vec::new(),
            pressure: Vec::new(),
            speed: Vec::new(),
            v: Vec::new(),
            size: Vec::new(),
            material: Vec::new(),
            mass: Vec::new(),
        };
        for i in 0..n {
            for j in 0..n {
                let (x, y) = ((i as f64 + 0.5) * h / 2.0, (j as f64 + 0.5) * h / 2.0);
                let sign = if (i + j) % 2 == 0 { 1.0 } else { -1.0 };
                f.x.push([x, y, 0.0]);
                f.pressure.push(1000.0 - 100.0 * y + 50.0 * sign);
                f.mass.push(2.5);
            }
        }
        f.smooth_pressure(&hat);
        let mut inside = 0;
        for (x, p) in f.x.iter().zip(&f.pressure) {
            if x[0] > h && x[0] < 0.9 && x[1] > h && x[1] < 0.9 {
                assert!((p - (1000.0 - 100.0 * x[1])).abs() < 1e-9, "{x:?}: {p}");
                inside += 1;
            }
        }
        assert_eq!(inside, 16 * 16);
    }

    #[test]
    fn walls_are_the_faces_seen_edge_on() {
        let info = RunInfo {
            grid: Some((vec![0.0, 0.0], vec![1.0, 0.5])),
            dim: Some(2),
            faces: ["slip", "outflow", "no_slip", "open"]
                .iter()
                .map(|k| Some(k.to_string()))
                .collect(),
            inflows: vec![(0, vec![0.0, 0.0], vec![0.0, 0.2])],
            ..Default::default()
        };
        let w = walls(&info, 0, 1);
        let expected: Vec<(Vec<(f64, f64)>, &str)> = vec![
            (vec![(0.0, 0.0), (0.0, 0.5)], "slip"),
            (vec![(1.0, 0.0), (1.0, 0.5)], "outflow"),
            (vec![(0.0, 0.0), (1.0, 0.0)], "no_slip"),
            (vec![(0.0, 0.5), (1.0, 0.5)], "open"),
            (vec![(0.0, 0.0), (0.0, 0.2)], "inflow"),
        ];
        assert_eq!(w, expected);
        // in 3D the faces across the line of sight are not edges
        let info = RunInfo {
            grid: Some((vec![0.0; 3], vec![1.0, 0.3, 0.5])),
            dim: Some(3),
            faces: vec![Some("no_slip".to_string()); 6],
            ..Default::default()
        };
        assert_eq!(walls(&info, 0, 2).len(), 4);
    }

    #[test]
    fn viridis_ends() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(2.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(f64::NAN), RGBColor(68, 1, 84));
    }

    #[test]
    fn constant_fields_get_a_range() {
        let o = PlotOptions::default();
        assert_eq!(
            color_range(Field::Speed, &Stats::of(&mut [0.0]), &o),
            (0.0, 1.0)
        );
        let (lo, hi) = color_range(Field::Pressure, &Stats::of(&mut [100.0, 100.0]), &o);
        assert!(lo < 100.0 && hi > 100.0);
        let s = Stats::of(&mut [0.2, 1.5]);
        assert_eq!(color_range(Field::Speed, &s, &o), (0.0, 1.5));
    }

    #[test]
    fn a_spike_does_not_set_the_range() {
        // a column at rest: the range is the data's
        let mut v: Vec<f64> = (0..1000).map(|i| i as f64).collect();
        let s = Stats::of(&mut v);
        assert_eq!((s.lo, s.hi), (0.0, 999.0));
        // one particle at 100 times the rest: the range stops at the 98% quantile
        v[3] = 1e5;
        let s = Stats::of(&mut v);
        assert_eq!((s.min, s.max), (0.0, 1e5));
        assert!(s.hi < 1000.0);
    }

    #[test]
    fn image_keeps_the_aspect() {
        // a wide tank: the plotting area is 1200 x 480
        assert_eq!(plot_area_size(0.4, 0.16), (1200, 480));
        // a tall one: at most 800 high, narrower
        assert_eq!(plot_area_size(0.2, 0.4), (400, 800));
    }
}
