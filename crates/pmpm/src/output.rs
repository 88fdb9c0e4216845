//! Output files of docs/deck.md: particle frames (CSV, VTK .vtu + .pvd), grid frames (VTK .vti
//! + grid.pvd), series.csv, probes.csv and run.toml.
//!
//! The .vtu files are written by hand with raw appended binary data: the smallest and fastest
//! form for ParaView to read, and a few dozen lines (vtkio writes inline base64 only).

use crate::deck::{Deck, Format};
use crate::error::Error;
use crate::grid_fields::{
    particle_shear_rate, particle_strain_rate, particle_stress, particle_yielded, NodeFields,
};
use crate::scheme::Simulation;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes every output file of a run into one directory.
pub struct OutputWriter {
    dir: PathBuf,
    csv: bool,
    vtk: bool,
    /// Whether frames of the grid's nodes are written (.vti, grid.pvd).
    grid: bool,
    /// (time, file name) of each .vtu frame, for particles.pvd (kept for the grid's frames
    /// too, which are numbered alike, when only they are written).
    pub pvd: Vec<(f64, String)>,
    series: BufWriter<File>,
    probes: Option<BufWriter<File>>,
    /// rigid_bodies.csv, when the deck has rigid bodies.
    rigid: Option<BufWriter<File>>,
    /// gauges.csv and the gauges, when the deck has gauges; the rows' interval (None: every
    /// step), and a buffer for a row.
    gauges: Option<BufWriter<File>>,
    gauge_list: Vec<crate::gauges::Gauge>,
    gauge_interval: Option<f64>,
    gauge_row: Vec<f64>,
    /// Whether `gauge_row` holds the readings of the next row ([`OutputWriter::read_gauges`]).
    gauges_read: bool,
    /// Whether series.csv has the open boundaries' columns.
    flow: bool,
    /// Node spacing c of the interior fill series.csv reports ([`crate::fill`]).
    fill_spacing: f64,
    /// Frames written so far.
    pub frames: usize,
    /// The next frame's figures and particle files, where every rank of a run over ranks has
    /// written its part of them ([`write_parts`]); `None` on one process.
    pub parts: Option<Parts>,
}

/// What the ranks of a run over ranks have written of a frame before rank 0 writes the rest
/// ([`write_parts`]).
#[derive(Debug, Clone, Copy)]
pub struct Parts {
    /// The frame's figures, over every rank.
    pub stats: FrameStats,
    /// The ranks, each with its piece of the .vtu frame.
    pub ranks: usize,
}

/// What series.csv reports of a frame's particles, over every rank.
#[derive(Debug, Clone, Copy)]
pub struct FrameStats {
    /// Kinetic energy (J; J/m in 2D).
    pub kinetic: f64,
    /// Largest particle speed.
    pub max_speed: f64,
    /// Particles.
    pub count: usize,
    /// Their mass.
    pub mass: f64,
    /// Interior fill ([`crate::fill`]; read on rank 0).
    pub fill: crate::fill::FillFigures,
}

impl FrameStats {
    /// The figures of `sim`'s particles, over its ranks (every rank calls it), the fill
    /// measured on a lattice of `fill_spacing`.
    pub fn of<const D: usize>(sim: &Simulation<D>, fill_spacing: f64) -> Self {
        let comm = &*sim.comm.0;
        let lattice = crate::fill::FillLattice {
            origin: sim.grid.geo.origin,
            spacing: fill_spacing,
        };
        let ps = &sim.particles;
        Self {
            kinetic: sim.kinetic_energy(),
            max_speed: sim.max_speed(),
            count: comm.sum_scalar(ps.len() as f64) as usize,
            mass: comm.sum_scalar(ps.mass.iter().sum()),
            fill: lattice.measure_over(comm, &ps.x, &ps.volume0),
        }
    }
}

/// Writes frame `n`'s particle files for a run over ranks, every rank its own particles
/// (every rank calls it): the CSV file one rank after the other (`write_in_turn`), each
/// rank's rows in id order, and each rank's piece of the .vtu frame, which rank 0's .pvtu
/// names ([`OutputWriter::frame`]). Then the figures of the frame, for rank 0 to write.
/// Every rank's result is the same: a write that failed on one rank fails on all.
pub fn write_parts<const D: usize>(
    dir: &Path,
    deck: &Deck,
    n: usize,
    sim: &Simulation<D>,
) -> Result<Parts, Error> {
    let comm = &*sim.comm.0;
    let formats = &deck.output.formats;
    if formats.contains(&Format::Csv) {
        let path = dir.join(format!("frames/particles_{n:06}.csv"));
        let written = write_in_turn(comm, &path, |w| {
            if comm.is_root() {
                csv_header::<D>(w)?;
            }
            csv_rows(w, sim)
        });
        let failed = comm.agree(written.err().map(|e| e.to_string()));
        if let Some(e) = failed {
            return Err(Error::io(&path, std::io::Error::other(e)));
        }
    }
    if formats.contains(&Format::Vtk) {
        let path = dir.join(piece_name(n, comm.rank()));
        let written = write_vtu(&path, sim).map_err(|e| format!("{}: {e}", path.display()));
        if let Some(e) = comm.agree(written.err()) {
            return Err(Error::Io {
                path: "a piece of a frame".into(),
                source: std::io::Error::other(e),
            });
        }
    }
    Ok(Parts {
        stats: FrameStats::of(sim, crate::fill::spacing(deck)),
        ranks: comm.size(),
    })
}

/// The readings of `gauges` now, in `row` (cleared first), over every rank of `sim`'s run
/// (every rank calls it at once).
pub fn read_gauges<const D: usize>(
    gauges: &[crate::gauges::Gauge],
    sim: &Simulation<D>,
    row: &mut Vec<f64>,
) {
    row.clear();
    for g in gauges {
        g.read(sim, row);
    }
}

/// Frame `n`'s piece of rank `rank` (under the run directory).
fn piece_name(n: usize, rank: usize) -> String {
    format!("frames/particles_{n:06}_{rank:04}.vtu")
}

/// Writes `path` whole or not at all ([`write_atomic`]), each rank of `comm` writing its part
/// with `write` in turn, rank 0's first: rank 0 creates `<name>.partial`, each rank appends
/// its part, syncs it to the disk and hands the turn on to the next, and rank 0 renames the
/// file once the last rank has written (on several machines, the file system is shared).
/// A rank whose part fails hands its error on in place of the turn: rank 0 then removes the
/// file and returns the error. Every rank calls it.
fn write_in_turn(
    comm: &dyn crate::comm::Comm,
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let (rank, size) = (comm.rank(), comm.size());
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let tmp = path.with_file_name(name);
    // the turn: empty, or the first error
    let mut turn = if rank == 0 {
        Vec::new()
    } else {
        comm.receive_bytes(rank - 1)
    };
    if turn.is_empty() || turn == [0] {
        let opened = if rank == 0 {
            File::create(&tmp)
        } else {
            std::fs::OpenOptions::new().append(true).open(&tmp)
        };
        let written = opened.and_then(|f| {
            let mut w = BufWriter::new(f);
            write(&mut w)?;
            w.flush()?;
            w.get_ref().sync_all()
        });
        turn = match written {
            Ok(()) => vec![0],
            Err(e) => [&[1u8][..], format!("rank {rank}: {e}").as_bytes()].concat(),
        };
    }
    if size > 1 {
        comm.send_bytes((rank + 1) % size, &turn);
    }
    if rank != 0 {
        return Ok(());
    }
    let last = if size > 1 {
        comm.receive_bytes(size - 1)
    } else {
        turn
    };
    if last != [0] {
        let _ = std::fs::remove_file(&tmp);
        return Err(std::io::Error::other(
            String::from_utf8_lossy(&last[1..]).into_owned(),
        ));
    }
    std::fs::rename(&tmp, path)
}

/// The file that marks a directory as a pmpm run's, written when a run starts in it: pmpm writes
/// only into an empty directory or one holding this file, and `--force` removes only the files
/// pmpm writes.
pub const MARKER: &str = ".pmpm-run";

/// The file a run holds an exclusive lock on (flock) while it writes into its directory, with
/// its process id in it: a second run on the directory is refused while the first holds it.
/// It is never removed (removing a locked file would let a third run lock a new one beside
/// it), and is not part of a run's files: a directory holding only it is empty.
pub const LOCK: &str = ".pmpm-lock";

/// A run's hold on its output directory ([`LOCK`]), released when dropped (or when the
/// process ends, however it ends).
#[derive(Debug)]
pub struct DirectoryLock {
    _file: File,
}

/// Takes the lock of `dir` (creating the directory), or refuses at once (exit status 2) when
/// another process holds it; a run takes it through [`claim_directory`].
pub fn lock_directory(dir: &Path) -> Result<DirectoryLock, Error> {
    use std::io::{Read, Seek};
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let path = dir.join(LOCK);
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| Error::io(&path, e))?;
    match try_lock(&file) {
        Ok(true) => {}
        Ok(false) => {
            let mut text = String::new();
            let _ = file.read_to_string(&mut text);
            let pid = match text.trim().parse::<u32>() {
                Ok(pid) => format!(" (pid {pid})"),
                Err(_) => String::new(),
            };
            return Err(Error::Usage(format!(
                "{}: another pmpm is running in this output directory{pid}; wait for it to \
                 end or stop it, or write elsewhere with --output",
                dir.display()
            )));
        }
        Err(e) => return Err(Error::io(&path, e)),
    }
    let io = |e| Error::io(&path, e);
    file.set_len(0).map_err(io)?;
    file.rewind().map_err(io)?;
    writeln!(file, "{}", std::process::id()).map_err(io)?;
    Ok(DirectoryLock { _file: file })
}

/// Tries an exclusive lock (flock) on `file` without waiting: true when taken, false when
/// another open file holds it. (std's File::try_lock needs Rust 1.89, past the MSRV.)
#[cfg(unix)]
fn try_lock(file: &File) -> std::io::Result<bool> {
    use std::os::unix::io::AsRawFd;
    // SAFETY: flock on the descriptor `file` owns, open for the whole call.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
        Ok(false)
    } else {
        Err(e)
    }
}

/// Elsewhere no lock is taken.
#[cfg(not(unix))]
fn try_lock(_: &File) -> std::io::Result<bool> {
    Ok(true)
}

/// Whether `name`, a file directly in a run directory, is one pmpm writes.
fn run_file(name: &str) -> bool {
    let name = name.strip_suffix(".partial").unwrap_or(name);
    matches!(
        name,
        MARKER
            | "run.toml"
            | "series.csv"
            | "probes.csv"
            | "rigid_bodies.csv"
            | "gauges.csv"
            | "particles.pvd"
            | "grid.pvd"
            | "checkpoint.bin"
    ) || crate::checkpoint::is_piece(name)
}

/// Whether `name`, a file in a run's `frames/`, is a frame pmpm writes; its number if so.
fn frame_number(name: &str) -> Option<usize> {
    let name = name.strip_suffix(".partial").unwrap_or(name);
    let num = match name.strip_prefix("particles_") {
        Some(rest) => match rest.strip_suffix(".vtu") {
            // a rank's piece of a frame of a run over ranks: NNNNNN_RRRR.vtu
            Some(piece) => match piece.split_once('_') {
                Some((num, rank))
                    if rank.len() >= 4 && rank.bytes().all(|b| b.is_ascii_digit()) =>
                {
                    num
                }
                Some(_) => return None,
                None => piece,
            },
            None => rest
                .strip_suffix(".csv")
                .or_else(|| rest.strip_suffix(".pvtu"))?,
        },
        None => name.strip_prefix("grid_")?.strip_suffix(".vti")?,
    };
    (num.len() == 6 && num.bytes().all(|b| b.is_ascii_digit()))
        .then(|| num.parse().ok())
        .flatten()
}

/// The names in `dir` (empty when it does not exist).
fn entries(dir: &Path) -> Result<Vec<String>, Error> {
    match std::fs::read_dir(dir) {
        Ok(rd) => Ok(rd
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(Error::io(dir, e)),
    }
}

/// What `dir` holds, for a run about to write into it.
enum Holds {
    /// Nothing (or it does not exist).
    Nothing,
    /// A run pmpm wrote (its marker, or, from before the marker, only files pmpm writes).
    Run,
    /// Files pmpm did not write: the first of them.
    Other(String),
}

fn holds(dir: &Path) -> Result<Holds, Error> {
    let mut names = entries(dir)?;
    names.retain(|n| n != LOCK);
    if names.is_empty() {
        return Ok(Holds::Nothing);
    }
    // the marker, or the part of it a run killed while writing it left
    if names
        .iter()
        .any(|n| n.strip_suffix(".partial").unwrap_or(n) == MARKER)
    {
        return Ok(Holds::Run);
    }
    let frames_ok = entries(&dir.join("frames"))?
        .iter()
        .all(|n| frame_number(n).is_some());
    match names
        .iter()
        .find(|n| !(run_file(n) || (*n == "frames" && frames_ok)))
    {
        Some(other) => Ok(Holds::Other(other.clone())),
        None if names.iter().any(|n| n == "series.csv") => Ok(Holds::Run),
        None => Ok(Holds::Other(names[0].clone())),
    }
}

/// Removes the files pmpm writes from a run directory, and nothing else.
fn remove_run_files(dir: &Path) -> Result<(), Error> {
    remove_frames_from(dir, 0)?;
    for name in entries(dir)? {
        if run_file(&name) && name != MARKER {
            let p = dir.join(&name);
            std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
        }
    }
    Ok(())
}

/// Takes `dir` for a run: a new run writes into a new or empty directory, or with `force` into
/// one holding an earlier run, whose files it removes first; a resumed run (`resume`, its
/// checkpoint) writes into the checkpoint's own directory, or into a new or empty one that first
/// receives a copy of the checkpoint's run. A directory holding files pmpm did not write is
/// refused (exit status 2), `force` or not, and so is one another run holds ([`LOCK`]), before
/// anything in it is removed or written. Leaves the marker in `dir`, and returns the lock,
/// which the run holds to its end.
pub fn claim_directory(
    dir: &Path,
    force: bool,
    resume: Option<&Path>,
) -> Result<DirectoryLock, Error> {
    let own = resume.and_then(|ck| {
        let ck_dir = ck.parent().filter(|p| !p.as_os_str().is_empty())?;
        let a = std::fs::canonicalize(ck_dir).ok()?;
        let b = std::fs::canonicalize(dir).ok()?;
        Some(a == b)
    });
    if dir.exists() && !dir.is_dir() {
        return Err(Error::Usage(format!(
            "{}: the output directory is a file; name a new or empty directory (--output or \
             output.directory)",
            dir.display()
        )));
    }
    // what is refused is refused before the lock file is put in the directory, and again
    // under the lock (another run may have written into it meanwhile)
    let refused = |held: &Holds| match held {
        Holds::Other(name) => Some(other_files(dir, name)),
        Holds::Run if resume.is_none() && !force => Some(Error::Usage(format!(
            "{}: the output directory holds an earlier run; pass --force to replace it or \
             --output to write elsewhere",
            dir.display()
        ))),
        Holds::Run if resume.is_some() && own != Some(true) => Some(Error::Usage(format!(
            "{}: the output directory holds another run; resume into the checkpoint's own \
             directory or into a new or empty one",
            dir.display()
        ))),
        _ => None,
    };
    if let Some(e) = refused(&holds(dir)?) {
        return Err(e);
    }
    let lock = lock_directory(dir)?;
    let held = holds(dir)?;
    if let Some(e) = refused(&held) {
        return Err(e);
    }
    match held {
        Holds::Other(_) => {}
        Holds::Run if resume.is_none() => remove_run_files(dir)?,
        Holds::Run => {}
        Holds::Nothing => {
            if let Some(ck) = resume {
                let from = ck.parent().unwrap_or(Path::new("."));
                copy_run(from, dir)?;
            }
        }
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let marker = dir.join(MARKER);
    write_atomic(&marker, |w| {
        w.write_all(b"This directory holds a pmpm run; pmpm run --force replaces it.\n")
    })
    .map_err(|e| Error::io(&marker, e))?;
    Ok(lock)
}

/// The refusal of a directory that holds `name`, a file pmpm did not write.
fn other_files(dir: &Path, name: &str) -> Error {
    Error::Usage(format!(
        "{}: the output directory holds {name:?}, which pmpm did not write; run into a new or \
         empty directory (--output), or into an earlier pmpm run's",
        dir.display()
    ))
}

/// Copies the files pmpm writes from the run directory `from` into the new directory `to`.
fn copy_run(from: &Path, to: &Path) -> Result<(), Error> {
    let frames_to = to.join("frames");
    std::fs::create_dir_all(&frames_to).map_err(|e| Error::io(&frames_to, e))?;
    for name in entries(from)? {
        if run_file(&name) && !name.ends_with(".partial") {
            let p = from.join(&name);
            std::fs::copy(&p, to.join(&name)).map_err(|e| Error::io(&p, e))?;
        }
    }
    for name in entries(&from.join("frames"))? {
        if frame_number(&name).is_some() && !name.ends_with(".partial") {
            let p = from.join("frames").join(&name);
            std::fs::copy(&p, frames_to.join(&name)).map_err(|e| Error::io(&p, e))?;
        }
    }
    Ok(())
}

/// Removes the frames numbered `from` and above: a resumed run writes them again, and those of
/// the run after its checkpoint must not stand beside them.
pub fn remove_frames_from(dir: &Path, from: usize) -> Result<(), Error> {
    let frames = dir.join("frames");
    for name in entries(&frames)? {
        if frame_number(&name).is_some_and(|k| k >= from) {
            let p = frames.join(&name);
            std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
        }
    }
    Ok(())
}

pub use crate::atomic::write_atomic;

fn create(path: &Path) -> Result<BufWriter<File>, Error> {
    File::create(path)
        .map(BufWriter::new)
        .map_err(|e| Error::io(path, e))
}

/// The header of series.csv.
const SERIES_HEADER: &str =
    "frame,time,step,dt,kinetic_energy,max_speed,pressure_iterations,wall_seconds";

/// The columns series.csv gains when the deck has open boundaries (an outflow face or an
/// inflow): the particles and their mass now, what entered and left, and the mass balance
/// (m(0) + m_in - m_out - m(t)) / (m(0) + m_in).
const FLOW_COLUMNS: &str = ",particles,mass,mass_in,mass_out,volume_in,volume_out,mass_balance";

/// The columns that close every row of series.csv: the interior fill of the particles'
/// rest volumes ([`crate::fill`]), its 1st and 99th percentiles, the share of interior nodes
/// within 5 % of 1 and their count.
const FILL_COLUMNS: &str = ",fill_p1,fill_p99,fill_within_5pct,fill_nodes";

/// The header of series.csv for `deck`.
fn series_header(deck: &Deck) -> String {
    let mut head = SERIES_HEADER.to_string();
    if deck.has_open_flow() {
        head += FLOW_COLUMNS;
    }
    head + FILL_COLUMNS
}

/// The header of probes.csv: time, then per probe its pressure and velocity components.
fn probes_header(deck: &Deck, dim: usize) -> String {
    let mut head = String::from("time");
    let axes = ["vx", "vy", "vz"];
    for p in &deck.output.probes {
        head += &format!(",{}_pressure", p.name);
        for a in &axes[..dim] {
            head += &format!(",{}_{a}", p.name);
        }
    }
    head
}

/// The frames directory and run.toml (the deck as run).
fn prepare(dir: &Path, deck: &Deck) -> Result<(), Error> {
    let frames_dir = dir.join("frames");
    std::fs::create_dir_all(&frames_dir).map_err(|e| Error::io(&frames_dir, e))?;
    let run_toml = dir.join("run.toml");
    let text = deck.to_run_toml();
    write_atomic(&run_toml, |w| w.write_all(text.as_bytes())).map_err(|e| Error::io(&run_toml, e))
}

/// The header of rigid_bodies.csv: time, then per body its displacement, its centre, its
/// velocity and the force the material exerts on it.
fn rigid_header(deck: &Deck, dim: usize) -> String {
    let mut head = String::from("time");
    let axes = ["x", "y", "z"];
    for b in &deck.rigid_bodies {
        for what in ["u", "", "v", "f"] {
            for a in &axes[..dim] {
                head += &format!(",{}_{what}{a}", b.name);
            }
        }
        // a turning body's angle (its rotation vector in 3D), angular velocity and torque
        if b.turns() {
            if dim == 2 {
                head += &format!(",{0}_angle,{0}_omega,{0}_torque", b.name);
            } else {
                for what in ["r", "w", "m"] {
                    for a in &axes {
                        head += &format!(",{}_{what}{a}", b.name);
                    }
                }
            }
        }
    }
    head
}

/// The header of gauges.csv: time, then per gauge its columns ([`crate::gauges::Gauge::columns`]).
fn gauges_header(deck: &Deck, gauges: &[crate::gauges::Gauge]) -> String {
    let mut head = String::from("time");
    for (q, g) in deck.output.gauges.iter().zip(gauges) {
        for c in g.columns(deck.simulation.dimension) {
            head += &format!(",{}_{c}", q.name);
        }
    }
    head
}

/// A new CSV file at `path` holding only `header`.
fn fresh(path: &Path, header: &str) -> Result<BufWriter<File>, Error> {
    let mut w = create(path)?;
    writeln!(w, "{header}").map_err(|e| Error::io(path, e))?;
    Ok(w)
}

/// Rewrites the CSV file at `path` with its header and the rows `keep` accepts (by their first
/// field), and opens it for appending; a missing file is created with `header`.
fn reopen(
    path: &Path,
    header: &str,
    keep: impl Fn(&str) -> bool,
) -> Result<BufWriter<File>, Error> {
    let old = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
        Err(e) => return Err(Error::io(path, e)),
    };
    let mut w = create(path)?;
    let columns = header.split(',').count();
    let r = (|| {
        writeln!(w, "{header}")?;
        for line in old.lines().skip(1) {
            if keep(line.split(',').next().unwrap_or("")) {
                // a row an earlier build wrote without the later columns (at the end) gets
                // NaN in them, so that every row has the header's columns
                let missing = columns.saturating_sub(line.split(',').count());
                writeln!(w, "{line}{}", ",NaN".repeat(missing))?;
            }
        }
        w.flush()
    })();
    r.map_err(|e| Error::io(path, e))?;
    Ok(w)
}

impl OutputWriter {
    /// Creates the directory and the files that grow during the run (series.csv, probes.csv),
    /// and writes run.toml.
    pub fn new(dir: &Path, deck: &Deck) -> Result<Self, Error> {
        prepare(dir, deck)?;
        let dim = deck.simulation.dimension;
        let series = fresh(&dir.join("series.csv"), &series_header(deck))?;
        let probes = if deck.output.probes.is_empty() {
            None
        } else {
            Some(fresh(&dir.join("probes.csv"), &probes_header(deck, dim))?)
        };
        let rigid = if deck.rigid_bodies.is_empty() {
            None
        } else {
            Some(fresh(
                &dir.join("rigid_bodies.csv"),
                &rigid_header(deck, dim),
            )?)
        };
        let gauge_list = deck.gauges();
        let gauges = if gauge_list.is_empty() {
            None
        } else {
            Some(fresh(
                &dir.join("gauges.csv"),
                &gauges_header(deck, &gauge_list),
            )?)
        };
        Ok(Self::with(
            dir,
            deck,
            [Some(series), probes, rigid, gauges],
            gauge_list,
            Vec::new(),
            0,
        ))
    }

    /// The writer over files already opened.
    /// `files`: series.csv, probes.csv, rigid_bodies.csv and gauges.csv; `gauge_list`: the
    /// deck's gauges.
    fn with(
        dir: &Path,
        deck: &Deck,
        files: [Option<BufWriter<File>>; 4],
        gauge_list: Vec<crate::gauges::Gauge>,
        pvd: Vec<(f64, String)>,
        frames: usize,
    ) -> Self {
        let formats = &deck.output.formats;
        let [series, probes, rigid, gauges] = files;
        Self {
            series: series.expect("series.csv is always written"),
            gauges,
            gauge_list,
            gauge_interval: deck.output.gauge_interval,
            gauge_row: Vec::new(),
            gauges_read: false,
            dir: dir.to_path_buf(),
            csv: formats.contains(&Format::Csv),
            flow: deck.has_open_flow(),
            fill_spacing: crate::fill::spacing(deck),
            vtk: formats.contains(&Format::Vtk),
            grid: formats.contains(&Format::Grid),
            pvd,
            probes,
            rigid,
            frames,
            parts: None,
        }
    }

    /// Reopens the output of a run resumed from a checkpoint: series.csv keeps the rows of the
    /// frames written before the checkpoint, probes.csv the rows before its time (later rows,
    /// from the stretch of the run after the checkpoint, are dropped: the resumed run writes them
    /// again), and frames go on from the checkpoint's frame count.
    pub fn resume<const D: usize>(
        dir: &Path,
        deck: &Deck,
        sim: &Simulation<D>,
        driver: &crate::checkpoint::DriverState,
    ) -> Result<Self, Error> {
        prepare(dir, deck)?;
        let frames = driver.frames;
        let series = reopen(&dir.join("series.csv"), &series_header(deck), |f| {
            f.parse::<usize>().is_ok_and(|k| k < frames)
        })?;
        // rows are stamped with the time at the start of their step, printed as {:.9e}
        let t: f64 = format!("{:.9e}", sim.time).parse().expect("a number");
        let probes = if deck.output.probes.is_empty() {
            None
        } else {
            Some(reopen(
                &dir.join("probes.csv"),
                &probes_header(deck, D),
                |f| f.parse::<f64>().is_ok_and(|s| s < t),
            )?)
        };
        // rigid-body rows are stamped with the time at the end of their step
        let rigid = if deck.rigid_bodies.is_empty() {
            None
        } else {
            Some(reopen(
                &dir.join("rigid_bodies.csv"),
                &rigid_header(deck, D),
                |f| f.parse::<f64>().is_ok_and(|s| s <= t),
            )?)
        };
        let gauge_list = deck.gauges();
        let gauges = if gauge_list.is_empty() {
            None
        } else {
            Some(reopen(
                &dir.join("gauges.csv"),
                &gauges_header(deck, &gauge_list),
                |f| f.parse::<f64>().is_ok_and(|s| s <= t),
            )?)
        };
        Ok(Self::with(
            dir,
            deck,
            [Some(series), probes, rigid, gauges],
            gauge_list,
            driver.pvd.clone(),
            frames,
        ))
    }

    /// Appends one row of rigid-body displacements and forces (the last step's, stamped with
    /// its end time).
    pub fn rigid_row<const D: usize>(&mut self, sim: &Simulation<D>) -> Result<(), Error> {
        if let Some(w) = &mut self.rigid {
            let r = &sim.boundary.rigid;
            let res = (|| {
                write!(w, "{:.9e}", sim.time)?;
                for b in 0..r.len() {
                    let (u, c, v) = (
                        r.displacement(b, sim.time),
                        r.centre(b, sim.time),
                        r.velocity(b),
                    );
                    for x in u
                        .iter()
                        .chain(c.iter())
                        .chain(v.iter())
                        .chain(r.force(b).iter())
                    {
                        write!(w, ",{x:.9e}")?;
                    }
                    if r.turns(b) {
                        let pose = r.pose_now(b, sim.time);
                        // in 2D the angle turned, unwrapped; in 3D the rotation vector
                        let angle = if D == 2 {
                            nalgebra::Vector3::new(0.0, 0.0, pose.turned)
                        } else {
                            pose.rotation_vector()
                        };
                        let (omega, torque) = (pose.omega, r.torque(b));
                        let from = if D == 2 { 2 } else { 0 };
                        for v in [angle, omega, torque] {
                            for x in &v.as_slice()[from..] {
                                write!(w, ",{x:.9e}")?;
                            }
                        }
                    }
                }
                writeln!(w)
            })();
            res.map_err(|e| Error::io(self.dir.join("rigid_bodies.csv"), e))?;
        }
        Ok(())
    }

    /// Forgets the last frame written (an interrupted run's, off the schedule): the next frame
    /// takes its number and its files, and the checkpoint's list of frames leaves it out.
    pub fn uncount_frame(&mut self) {
        self.frames -= 1;
        if self.vtk || self.grid {
            self.pvd.pop();
        }
    }

    /// Appends one row of gauge readings after a step from `before` to `sim.time` (stamped
    /// with its end time): every step, or with `output.gauge_interval` the steps that reach
    /// or pass a multiple of it.
    pub fn gauge_row<const D: usize>(
        &mut self,
        before: f64,
        sim: &Simulation<D>,
    ) -> Result<(), Error> {
        if !self.gauge_due(before, sim.time) {
            return Ok(());
        }
        self.gauge_row_now(sim)
    }

    /// Whether the run has gauges (gauges.csv).
    pub fn has_gauges(&self) -> bool {
        self.gauges.is_some()
    }

    /// Whether frames of the grid's nodes are written.
    pub fn grid_frames(&self) -> bool {
        self.grid
    }

    /// Whether a step from `before` to `time` brings a row of gauge readings.
    pub fn gauge_due(&self, before: f64, time: f64) -> bool {
        if self.gauges.is_none() {
            return false;
        }
        self.gauge_interval.is_none_or(|every| {
            let eps = 1e-9 * every;
            ((time + eps) / every).floor() > ((before + eps) / every).floor()
        })
    }

    /// Frame 0 and the gauges' row of the state at t = 0, before the first step (the probes'
    /// first row, sampled at the first step's start, is stamped t = 0 too).
    pub fn first_frame<const D: usize>(&mut self, sim: &Simulation<D>) -> Result<(), Error> {
        self.frame(sim, 0.0, 0.0)?;
        self.gauge_row_now(sim)
    }

    /// Reads the gauges now, over every rank of a run over ranks (every rank calls
    /// [`read_gauges`] at once, and rank 0 this), for the next gauges' row.
    pub fn read_gauges<const D: usize>(&mut self, sim: &Simulation<D>) {
        read_gauges(&self.gauge_list, sim, &mut self.gauge_row);
        self.gauges_read = true;
    }

    /// Appends one row of gauge readings of the state now, due or not.
    fn gauge_row_now<const D: usize>(&mut self, sim: &Simulation<D>) -> Result<(), Error> {
        let Some(w) = &mut self.gauges else {
            return Ok(());
        };
        if !std::mem::take(&mut self.gauges_read) {
            read_gauges(&self.gauge_list, sim, &mut self.gauge_row);
        }
        let r = (|| {
            write!(w, "{:.9e}", sim.time)?;
            for v in &self.gauge_row {
                write!(w, ",{v:.9e}")?;
            }
            writeln!(w)
        })();
        r.map_err(|e| Error::io(self.dir.join("gauges.csv"), e))
    }

    /// Appends one row of probe samples (taken at time `time`).
    pub fn probe_row<const D: usize>(
        &mut self,
        time: f64,
        sim: &Simulation<D>,
    ) -> Result<(), Error> {
        if let Some(w) = &mut self.probes {
            let r = (|| {
                write!(w, "{time:.9e}")?;
                for v in &sim.probes.values {
                    write!(w, ",{v:.9e}")?;
                }
                writeln!(w)
            })();
            r.map_err(|e| Error::io(self.dir.join("probes.csv"), e))?;
        }
        Ok(())
    }

    /// Writes frame `self.frames` of the particles and its series.csv row, and returns the
    /// frame's figures. Where the ranks of a run over ranks have written their parts of it
    /// ([`OutputWriter::parts`]), rank 0 writes the .pvtu that names the .vtu pieces, not the
    /// particle files.
    pub fn frame<const D: usize>(
        &mut self,
        sim: &Simulation<D>,
        dt: f64,
        wall_seconds: f64,
    ) -> Result<FrameStats, Error> {
        let n = self.frames;
        let parts = self.parts.take();
        if self.csv && parts.is_none() {
            let path = self.dir.join(format!("frames/particles_{n:06}.csv"));
            write_csv(&path, sim).map_err(|e| Error::io(&path, e))?;
        }
        let particles = match parts {
            Some(_) => format!("frames/particles_{n:06}.pvtu"),
            None => format!("frames/particles_{n:06}.vtu"),
        };
        if self.vtk || self.grid {
            self.pvd.push((sim.time, particles.clone()));
        }
        if self.vtk {
            let path = self.dir.join(&particles);
            match parts {
                Some(p) => write_pvtu(&path, sim, n, p.ranks),
                None => write_vtu(&path, sim),
            }
            .map_err(|e| Error::io(&path, e))?;
            let pvd = self.dir.join("particles.pvd");
            write_pvd(&pvd, &self.pvd).map_err(|e| Error::io(&pvd, e))?;
        }
        if self.grid {
            let path = self.dir.join(format!("frames/grid_{n:06}.vti"));
            write_vti(&path, sim).map_err(|e| Error::io(&path, e))?;
            let grid: Vec<(f64, String)> = self
                .pvd
                .iter()
                .map(|(t, f)| {
                    let f = f.replace("particles_", "grid_");
                    (*t, f.replace(".pvtu", ".vti").replace(".vtu", ".vti"))
                })
                .collect();
            let pvd = self.dir.join("grid.pvd");
            write_pvd(&pvd, &grid).map_err(|e| Error::io(&pvd, e))?;
        }
        let stats = match parts {
            Some(p) => p.stats,
            None => FrameStats::of(sim, self.fill_spacing),
        };
        let series_path = self.dir.join("series.csv");
        write!(
            self.series,
            "{n},{:.9e},{},{dt:.6e},{:.9e},{:.9e},{},{wall_seconds:.3}",
            sim.time,
            sim.steps,
            stats.kinetic,
            stats.max_speed,
            sim.pressure_iterations(),
        )
        .and_then(|_| {
            if !self.flow {
                return Ok(());
            }
            // (open boundaries run on one process: the ledger reads its particles)
            let l = &sim.ledger;
            write!(
                self.series,
                ",{},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.3e}",
                stats.count,
                stats.mass,
                l.mass_in,
                l.mass_out,
                l.volume_in,
                l.volume_out,
                l.balance(&sim.particles)
            )
        })
        .and_then(|_| {
            let f = stats.fill;
            writeln!(
                self.series,
                ",{:.6},{:.6},{:.6},{}",
                f.p1, f.p99, f.within, f.nodes
            )
        })
        .and_then(|_| self.series.flush())
        .map_err(|e| Error::io(&series_path, e))?;
        if let Some(w) = &mut self.probes {
            w.flush()
                .map_err(|e| Error::io(self.dir.join("probes.csv"), e))?;
        }
        if let Some(w) = &mut self.rigid {
            w.flush()
                .map_err(|e| Error::io(self.dir.join("rigid_bodies.csv"), e))?;
        }
        if let Some(w) = &mut self.gauges {
            w.flush()
                .map_err(|e| Error::io(self.dir.join("gauges.csv"), e))?;
        }
        self.frames += 1;
        Ok(stats)
    }

    /// Flushes the time series (series.csv, probes.csv, rigid_bodies.csv) and has the system
    /// put them on the disk: called before each checkpoint, so that the rows a resume keeps
    /// are all there after a crash.
    pub fn sync(&mut self) -> Result<(), Error> {
        let dir = &self.dir;
        let sync = |w: &mut BufWriter<File>, name: &str| {
            w.flush()
                .and_then(|_| w.get_ref().sync_data())
                .map_err(|e| Error::io(dir.join(name), e))
        };
        sync(&mut self.series, "series.csv")?;
        if let Some(w) = &mut self.probes {
            sync(w, "probes.csv")?;
        }
        if let Some(w) = &mut self.rigid {
            sync(w, "rigid_bodies.csv")?;
        }
        if let Some(w) = &mut self.gauges {
            sync(w, "gauges.csv")?;
        }
        Ok(())
    }

    /// Flushes what is buffered (also on a blow-up, so nothing written is lost).
    pub fn finish(&mut self) -> Result<(), Error> {
        self.series
            .flush()
            .map_err(|e| Error::io(self.dir.join("series.csv"), e))?;
        if let Some(w) = &mut self.probes {
            w.flush()
                .map_err(|e| Error::io(self.dir.join("probes.csv"), e))?;
        }
        if let Some(w) = &mut self.rigid {
            w.flush()
                .map_err(|e| Error::io(self.dir.join("rigid_bodies.csv"), e))?;
        }
        if let Some(w) = &mut self.gauges {
            w.flush()
                .map_err(|e| Error::io(self.dir.join("gauges.csv"), e))?;
        }
        Ok(())
    }
}

fn write_csv<const D: usize>(path: &Path, sim: &Simulation<D>) -> std::io::Result<()> {
    write_atomic(path, |w| write_csv_to(w, sim))
}

fn write_csv_to<const D: usize>(
    w: &mut BufWriter<File>,
    sim: &Simulation<D>,
) -> std::io::Result<()> {
    csv_header::<D>(w)?;
    csv_rows(w, sim)?;
    w.flush()
}

/// The particle CSV file's header line.
fn csv_header<const D: usize>(w: &mut BufWriter<File>) -> std::io::Result<()> {
    if D == 2 {
        writeln!(w, "id,x,y,vx,vy,pressure,mass,volume,material")
    } else {
        writeln!(w, "id,x,y,z,vx,vy,vz,pressure,mass,volume,material")
    }
}

/// The particle CSV file's rows of `sim`'s particles, in id order.
fn csv_rows<const D: usize>(w: &mut BufWriter<File>, sim: &Simulation<D>) -> std::io::Result<()> {
    let ps = &sim.particles;
    // rows in id order, wherever the last sort put each particle
    for &p in &ps.places() {
        write!(w, "{}", ps.id[p])?;
        for c in ps.x[p].iter().chain(ps.v[p].iter()) {
            write!(w, ",{c:.9e}")?;
        }
        writeln!(
            w,
            ",{:.9e},{:.9e},{:.9e},{}",
            ps.pressure[p],
            ps.mass[p],
            ps.volume(p),
            ps.material[p]
        )?;
    }
    Ok(())
}

/// One appended data array: its XML description and its bytes.
struct Array {
    name: &'static str,
    vtk_type: &'static str,
    components: usize,
    bytes: Vec<u8>,
}

fn f64s(v: impl Iterator<Item = f64>) -> Vec<u8> {
    v.flat_map(f64::to_le_bytes).collect()
}

/// The particles as a VTK UnstructuredGrid (.vtu) of one vertex each, in id order, with raw
/// appended binary data.
fn write_vtu<const D: usize>(path: &Path, sim: &Simulation<D>) -> std::io::Result<()> {
    let ps = &sim.particles;
    let n = ps.len();
    // points in id order, wherever the last sort put each particle
    let at = ps.places();
    let points = Array {
        name: "Points",
        vtk_type: "Float64",
        components: 3,
        bytes: f64s(at.iter().flat_map(|&p| pad3(&ps.x[p]))),
    };
    let point_data = vtu_point_data(sim, &at);
    let cells = vtu_cells(n);
    let xml = vtu_header(sim.time, n, &point_data, &points, &cells);
    write_atomic(path, |w| {
        w.write_all(xml.as_bytes())?;
        for a in point_data
            .iter()
            .chain(std::iter::once(&points))
            .chain(&cells)
        {
            w.write_all(&(a.bytes.len() as u64).to_le_bytes())?;
            w.write_all(&a.bytes)?;
        }
        w.write_all(b"\n  </AppendedData>\n</VTKFile>\n")
    })
}

/// The .pvtu of frame `n` of a run over `ranks` ranks: the arrays of the .vtu frame, and the
/// pieces ([`piece_name`]) that hold them, each rank's particles (`sim` gives the arrays'
/// names and types).
fn write_pvtu<const D: usize>(
    path: &Path,
    sim: &Simulation<D>,
    n: usize,
    ranks: usize,
) -> std::io::Result<()> {
    let arrays = |list: &[Array]| {
        list.iter()
            .map(|a| {
                format!(
                    "      <PDataArray type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\"/>\n",
                    a.vtk_type, a.name, a.components
                )
            })
            .collect::<String>()
    };
    let mut xml = String::new();
    xml += "<?xml version=\"1.0\"?>\n";
    xml += "<VTKFile type=\"PUnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
    xml += "  <PUnstructuredGrid GhostLevel=\"0\">\n";
    xml += "    <PPointData Scalars=\"pressure\" Vectors=\"velocity\">\n";
    xml += &arrays(&vtu_point_data(sim, &[]));
    xml += "    </PPointData>\n    <PPoints>\n";
    xml += "      <PDataArray type=\"Float64\" NumberOfComponents=\"3\"/>\n";
    xml += "    </PPoints>\n";
    for rank in 0..ranks {
        let piece = piece_name(n, rank);
        let file = piece.strip_prefix("frames/").unwrap_or(&piece);
        xml += &format!("    <Piece Source=\"{file}\"/>\n");
    }
    xml += "  </PUnstructuredGrid>\n</VTKFile>\n";
    write_atomic(path, |w| w.write_all(xml.as_bytes()))
}

/// A vector with 3 components, as ParaView wants points and vectors: 2D padded with z = 0.
fn pad3<const D: usize>(v: &crate::grid::Vector<D>) -> [f64; 3] {
    std::array::from_fn(|d| if d < D { v[d] } else { 0.0 })
}

/// The .vtu's point data: the particle fields, at the particles `at` (in id order), and
/// whether each has yielded where a material has a yield stress.
fn vtu_point_data<const D: usize>(sim: &Simulation<D>, at: &[usize]) -> Vec<Array> {
    let ps = &sim.particles;
    let mut point_data = vec![
        Array {
            name: "id",
            vtk_type: "Int64",
            components: 1,
            bytes: at
                .iter()
                .flat_map(|&p| (ps.id[p] as i64).to_le_bytes())
                .collect(),
        },
        Array {
            name: "velocity",
            vtk_type: "Float64",
            components: 3,
            bytes: f64s(at.iter().flat_map(|&p| pad3(&ps.v[p]))),
        },
        Array {
            name: "pressure",
            vtk_type: "Float64",
            components: 1,
            bytes: f64s(at.iter().map(|&p| ps.pressure[p])),
        },
        Array {
            name: "mass",
            vtk_type: "Float64",
            components: 1,
            bytes: f64s(at.iter().map(|&p| ps.mass[p])),
        },
        Array {
            name: "volume",
            vtk_type: "Float64",
            components: 1,
            bytes: f64s(at.iter().map(|&p| ps.volume(p))),
        },
        Array {
            name: "J",
            vtk_type: "Float64",
            components: 1,
            bytes: f64s(at.iter().map(|&p| ps.jacobian[p])),
        },
        Array {
            name: "stress",
            vtk_type: "Float64",
            components: 9,
            bytes: f64s(at.iter().flat_map(|&p| particle_stress(sim, p))),
        },
        Array {
            name: "strain_rate",
            vtk_type: "Float64",
            components: 9,
            bytes: f64s(at.iter().flat_map(|&p| particle_strain_rate(ps, p))),
        },
        Array {
            name: "shear_rate",
            vtk_type: "Float64",
            components: 1,
            bytes: f64s(at.iter().map(|&p| particle_shear_rate(ps, p))),
        },
        Array {
            name: "material",
            vtk_type: "Int32",
            components: 1,
            bytes: at
                .iter()
                .flat_map(|&p| (ps.material[p] as i32).to_le_bytes())
                .collect(),
        },
    ];
    if sim.materials.iter().any(|m| m.law.has_yield()) {
        point_data.push(Array {
            name: "yielded",
            vtk_type: "Float64",
            components: 1,
            bytes: f64s(at.iter().map(|&p| particle_yielded(sim, p))),
        });
    }
    point_data
}

/// The .vtu's cells: one vertex per point, `n` of them.
fn vtu_cells(n: usize) -> [Array; 3] {
    [
        Array {
            name: "connectivity",
            vtk_type: "Int64",
            components: 1,
            // each vertex's point, by its place in the file (not the particle's id: ids have
            // gaps where particles left, and a rank's piece holds some of them)
            bytes: (0..n as i64).flat_map(i64::to_le_bytes).collect(),
        },
        Array {
            name: "offsets",
            vtk_type: "Int64",
            components: 1,
            bytes: (1..=n as i64).flat_map(i64::to_le_bytes).collect(),
        },
        Array {
            name: "types",
            vtk_type: "UInt8",
            components: 1,
            bytes: vec![1u8; n], // VTK_VERTEX
        },
    ]
}

/// The .vtu's XML up to its appended data: the time, the point and cell counts (`n`), and
/// each array's description, with its offset in the appended data that follows.
fn vtu_header(
    time: f64,
    n: usize,
    point_data: &[Array],
    points: &Array,
    cells: &[Array],
) -> String {
    let mut offset = 0usize;
    let mut describe = |a: &Array| {
        let s = format!(
            "        <DataArray type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"appended\" offset=\"{offset}\"/>\n",
            a.vtk_type, a.name, a.components
        );
        offset += 8 + a.bytes.len();
        s
    };
    let mut xml = String::new();
    xml += "<?xml version=\"1.0\"?>\n";
    xml += "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
    xml += &format!(
        "  <UnstructuredGrid>\n    <FieldData>\n      <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">{:e}</DataArray>\n    </FieldData>\n",
        time
    );
    xml += &format!("    <Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{n}\">\n");
    xml += "      <PointData Scalars=\"pressure\" Vectors=\"velocity\">\n";
    for a in point_data {
        xml += &describe(a);
    }
    xml += "      </PointData>\n      <Points>\n";
    xml += &describe(points);
    xml += "      </Points>\n      <Cells>\n";
    for a in cells {
        xml += &describe(a);
    }
    xml +=
        "      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n  <AppendedData encoding=\"raw\">\n_";
    xml
}

/// The grid's nodes as VTK ImageData (.vti) with the fields of [`NodeFields`], raw appended
/// binary like the .vtu.
fn write_vti<const D: usize>(path: &Path, sim: &Simulation<D>) -> std::io::Result<()> {
    let f = NodeFields::of(sim);
    let scalar = |name: &'static str, v: &[f64]| Array {
        name,
        vtk_type: "Float64",
        components: 1,
        bytes: f64s(v.iter().copied()),
    };
    let mut arrays = vec![
        scalar("mass", &f.mass),
        Array {
            name: "velocity",
            vtk_type: "Float64",
            components: 3,
            bytes: f64s(f.velocity.iter().flatten().copied()),
        },
        scalar("pressure", &f.pressure),
        scalar("volume_fraction", &f.volume_fraction),
        scalar("density", &f.density),
        Array {
            name: "strain_rate",
            vtk_type: "Float64",
            components: 9,
            bytes: f64s(f.strain_rate.iter().flatten().copied()),
        },
        scalar("shear_rate", &f.shear_rate),
        Array {
            name: "stress",
            vtk_type: "Float64",
            components: 9,
            bytes: f64s(f.stress.iter().flatten().copied()),
        },
    ];
    if let Some(y) = &f.yielded {
        arrays.push(scalar("yielded", y));
    }
    let extent = format!(
        "0 {} 0 {} 0 {}",
        f.nodes[0] - 1,
        f.nodes[1] - 1,
        f.nodes[2] - 1
    );
    let mut xml = String::new();
    xml += "<?xml version=\"1.0\"?>\n";
    xml += "<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
    xml += &format!(
        "  <ImageData WholeExtent=\"{extent}\" Origin=\"{:e} {:e} {:e}\" Spacing=\"{:e} {:e} {:e}\">\n",
        f.origin[0], f.origin[1], f.origin[2], f.h, f.h, f.h
    );
    xml += &format!(
        "    <FieldData>\n      <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">{:e}</DataArray>\n    </FieldData>\n",
        sim.time
    );
    xml += &format!("    <Piece Extent=\"{extent}\">\n");
    xml += "      <PointData Scalars=\"pressure\" Vectors=\"velocity\" Tensors=\"stress\">\n";
    let mut offset = 0usize;
    for a in &arrays {
        xml += &format!(
            "        <DataArray type=\"{}\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"appended\" offset=\"{offset}\"/>\n",
            a.vtk_type, a.name, a.components
        );
        offset += 8 + a.bytes.len();
    }
    xml += "      </PointData>\n      <CellData>\n      </CellData>\n    </Piece>\n  </ImageData>\n  <AppendedData encoding=\"raw\">\n_";
    write_atomic(path, |w| {
        w.write_all(xml.as_bytes())?;
        for a in &arrays {
            w.write_all(&(a.bytes.len() as u64).to_le_bytes())?;
            w.write_all(&a.bytes)?;
        }
        w.write_all(b"\n  </AppendedData>\n</VTKFile>\n")
    })
}

fn write_pvd(path: &Path, frames: &[(f64, String)]) -> std::io::Result<()> {
    write_atomic(path, |w| write_pvd_to(w, frames))
}

fn write_pvd_to(w: &mut BufWriter<File>, frames: &[(f64, String)]) -> std::io::Result<()> {
    writeln!(w, "<?xml version=\"1.0\"?>")?;
    writeln!(
        w,
        "<VTKFile type=\"Collection\" version=\"1.0\" byte_order=\"LittleEndian\">\n  <Collection>"
    )?;
    for (t, f) in frames {
        writeln!(
            w,
            "    <DataSet timestep=\"{t:.9e}\" part=\"0\" file=\"{f}\"/>"
        )?;
    }
    writeln!(w, "  </Collection>\n</VTKFile>")?;
    w.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The frames a run writes, over ranks too, are known by their number (a resume removes
    /// those from its checkpoint's on; `--force` removes them all), and nothing else is.
    #[test]
    fn frames_and_their_pieces_are_known_by_number() {
        for (name, n) in [
            ("particles_000012.csv", 12),
            ("particles_000012.vtu", 12),
            ("particles_000012.pvtu", 12),
            ("particles_000012_0003.vtu", 12),
            ("particles_000012_12345.vtu", 12),
            ("particles_000012.csv.partial", 12),
            ("grid_000007.vti", 7),
        ] {
            assert_eq!(frame_number(name), Some(n), "{name}");
        }
        for name in [
            "particles_000012_03.vtu",
            "particles_000012_0003.csv",
            "particles_12.vtu",
            "particles_+00012.vtu",
            "notes.txt",
        ] {
            assert_eq!(frame_number(name), None, "{name}");
        }
    }

    /// A write that fails half-way leaves the old file as it was and no `.partial` beside it;
    /// one that succeeds replaces it whole.
    #[test]
    fn a_file_is_replaced_whole_or_not_at_all() {
        let dir = std::env::temp_dir().join(format!("pmpm-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("particles.pvd");
        std::fs::write(&path, "old frames\n").unwrap();
        let failed = write_atomic(&path, |w| {
            w.write_all(b"new fr")?;
            Err(std::io::Error::other("disk full"))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old frames\n");
        assert!(!dir.join("particles.pvd.partial").exists());
        write_atomic(&path, |w| w.write_all(b"new frames\n")).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "new frames\n");
        assert!(!dir.join("particles.pvd.partial").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
