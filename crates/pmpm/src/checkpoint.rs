//! Checkpoints: the full state of a run in one file, from which `pmpm run DECK --resume FILE`
//! goes on as if it had never stopped (the same frames, bit for bit, on the same thread count).
//!
//! The file is `PMPMCKPT`, a format version (u32), the CRC-32 of the payload (u32), the payload's
//! length (u64), then the payload: the state, serialised with postcard. It is written to a
//! temporary name and renamed, so a run killed while writing leaves the previous checkpoint
//! whole. A resumed run must use the same deck, except for the keys a user may change on resume
//! ([`RESUMABLE_KEYS`]); anything else is refused with the first key that differs.
//!
//! A run over MPI ranks writes one such file a rank, each with the rank's own particles
//! ([`Pieces`]): the other ranks' pieces first, beside the checkpoint, then rank 0's file,
//! which names them and is the one a resume is given. The pieces alternate between two sets
//! of names, so that a run killed while writing them leaves the checkpoint before whole.

use crate::deck::Deck;
use crate::error::Error;
use crate::flow::Ledger;
use crate::grid::Vector;
use crate::particles::{FieldValue, FlatParticles, FlatSlice, Particles, Stored};
use crate::scheme::Simulation;
use serde::{Deserialize, Serialize};
use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

const MAGIC: &[u8; 8] = b"PMPMCKPT";
/// What stands before the [`Pieces`] in rank 0's file of a run over ranks.
const PIECES_TAG: &[u8; 6] = b"PIECES";
const FORMAT: u32 = 1;

/// Deck keys that may differ between the run that wrote a checkpoint and the run that resumes
/// from it: when to stop, the time step (to go on with a smaller one after a blow-up), and where
/// and how often to write.
pub const RESUMABLE_KEYS: [&str; 8] = [
    "simulation.end_time",
    "simulation.dt",
    "simulation.cfl",
    "simulation.max_dt",
    "output.directory",
    "output.interval",
    "output.formats",
    "output.checkpoint_interval",
];

/// What the run driver keeps between steps besides the simulation: frame and checkpoint clocks,
/// the .pvd list and the pressure-iteration totals.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DriverState {
    /// Time of the next frame.
    pub next_frame: f64,
    /// Time of the next checkpoint.
    pub next_checkpoint: f64,
    /// Frames written.
    pub frames: usize,
    /// (time, file) of the .vtu frames written, for particles.pvd.
    pub pvd: Vec<(f64, String)>,
    /// Pressure iterations summed over the steps, and the most in one step.
    pub iterations: (u64, usize),
    /// Wall-clock seconds the run has taken so far, over all its resumes (stored after the
    /// other sections, so that a checkpoint without it still reads: 0 then).
    #[serde(skip)]
    pub wall_seconds: f64,
}

impl DriverState {
    /// The state of a driver that has written nothing (in the pieces of the ranks that do
    /// not write: a resume reads rank 0's).
    pub fn none() -> Self {
        Self {
            next_frame: 0.0,
            next_checkpoint: 0.0,
            frames: 0,
            pvd: Vec::new(),
            iterations: (0, 0),
            wall_seconds: 0.0,
        }
    }
}

/// The pieces of a checkpoint of a run over ranks, named in rank 0's file (after the cut of
/// the grid): each rank's particles in a file of its own ([`piece_path`]).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Pieces {
    /// The checkpoints the run has written over ranks, this one counted: its pieces' names
    /// alternate with it.
    pub generation: u64,
    /// The particles each rank holds (rank 0's in its own file).
    pub counts: Vec<u64>,
}

/// The file of rank `rank`'s piece (rank 1 and above) of the checkpoint at `path` of
/// generation `generation`.
pub fn piece_path(path: &Path, generation: u64, rank: usize) -> std::path::PathBuf {
    let name = path.file_name().map_or_else(
        || "checkpoint.bin".into(),
        |n| n.to_string_lossy().into_owned(),
    );
    path.with_file_name(piece_name(&name, generation, rank))
}

/// [`piece_path`]'s file name, beside a checkpoint named `name`.
fn piece_name(name: &str, generation: u64, rank: usize) -> String {
    format!("{name}.{}.rank{rank:04}", generation % 2)
}

/// Whether `name` is a piece of a checkpoint named `checkpoint.bin` ([`piece_path`]).
pub fn is_piece(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("checkpoint.bin.") else {
        return false;
    };
    let Some((set, rank)) = rest.split_once(".rank") else {
        return false;
    };
    matches!(set, "0" | "1") && rank.len() >= 4 && rank.bytes().all(|b| b.is_ascii_digit())
}

/// The payload.
#[derive(Serialize, Deserialize)]
struct State<const D: usize> {
    version: String,
    dimension: usize,
    /// The deck, as TOML, with the resumable keys removed.
    deck: String,
    time: f64,
    steps: u64,
    pressure_iterations: usize,
    driver: DriverState,
    /// The particle arrays, field by field in their declaration order.
    particles: FlatParticles<D>,
    /// The body force at the particles (empty when it is constant).
    body_force: Vec<f64>,
    /// The projection's node pressure p^n and per-particle V / rho (empty for the explicit
    /// scheme).
    node_pressure: Vec<f64>,
    volume_over_density: Vec<f64>,
}

/// The key of the fingerprint that holds the mesh files' digests (not a deck key).
const MESH_FILES: &str = "mesh_files";

/// The deck as a TOML tree without the keys a resume may change, and with the digests of the
/// mesh files it read under [`MESH_FILES`].
fn fingerprint(deck: &Deck) -> toml::Table {
    let mut d = deck.clone();
    d.pmpm = None;
    let mut t = toml::Table::try_from(&d).expect("a deck serialises to TOML");
    for key in RESUMABLE_KEYS {
        let (section, name) = key.split_once('.').expect("section.key");
        if let Some(toml::Value::Table(s)) = t.get_mut(section) {
            s.remove(name);
        }
    }
    // earlier builds filled in "positions" under the explicit scheme, which never read it:
    // under it the key counts only where it packs
    if deck.simulation.scheme == crate::scheme::Scheme::Explicit
        && deck.pressure.density_correction != Some(crate::pressure::DensityCorrection::Particles)
    {
        if let Some(toml::Value::Table(p)) = t.get_mut("pressure") {
            p.remove("density_correction");
        }
    }
    if !deck.mesh_files.is_empty() {
        let files: toml::Table = deck
            .mesh_files
            .iter()
            .map(|(path, digest)| (path.clone(), digest.as_str().into()))
            .collect();
        t.insert(MESH_FILES.into(), files.into());
    }
    t
}

/// Refuses a resume whose deck differs from the checkpoint's fingerprint `theirs` (`ours`,
/// the deck's) in a mesh file's bytes or in a key that a resume may not change.
fn same_deck(path: &Path, mut theirs: toml::Table, mut ours: toml::Table) -> Result<(), Error> {
    if let Some((file, was, now)) = changed_mesh_file(&mut theirs, &mut ours) {
        return Err(refuse(
            path,
            format!(
                "the mesh file {file} changed since the run began (it was {was}, it is {now}): \
                 the bodies it shapes would not be the ones the run moved; put the file back, \
                 or start a new run"
            ),
        ));
    }
    theirs.remove(MESH_FILES);
    ours.remove(MESH_FILES);
    if let Some((key, was, now)) =
        first_difference("", &toml::Value::Table(theirs), &toml::Value::Table(ours))
    {
        return Err(refuse(
            path,
            format!(
                "it was written with a different deck: {key} was {was}, the deck has {now} \
                 (only {} may change on resume)",
                RESUMABLE_KEYS.join(", ")
            ),
        ));
    }
    Ok(())
}

/// The first mesh file whose digest differs between the checkpoint's fingerprint and the
/// deck's, as (path, then, now), the digests taken out of both. A checkpoint written before
/// the digests were recorded has none, and is taken as it is.
fn changed_mesh_file(
    theirs: &mut toml::Table,
    ours: &mut toml::Table,
) -> Option<(String, String, String)> {
    let then = theirs.remove(MESH_FILES)?;
    let now = ours.remove(MESH_FILES)?;
    let (toml::Value::Table(then), toml::Value::Table(now)) = (then, now) else {
        return None;
    };
    now.iter().find_map(|(path, digest)| {
        let was = then.get(path)?;
        (was != digest).then(|| (path.clone(), was.to_string(), digest.to_string()))
    })
}

/// Fills in the keys a checkpoint's deck lacks because the build that wrote it had no such
/// key, with the values that build ran with: a resume then goes on as the run began, and a
/// deck whose new defaults differ from them is refused by name (for example
/// `simulation.viscosity was "explicit", the deck has "implicit"`: add the key to the deck).
fn as_run_then(deck: &mut toml::Table) {
    // before `sample` (pmpm 0.1 up to 2026-12-02) every probe read the grid's nodes
    if let Some(toml::Value::Array(probes)) = deck
        .get_mut("output")
        .and_then(|o| o.as_table_mut())
        .and_then(|o| o.get_mut("probes"))
    {
        for p in probes.iter_mut().filter_map(|p| p.as_table_mut()) {
            p.entry("sample").or_insert_with(|| "nodes".into());
        }
    }
    // before separating walls (pmpm 0.1 up to 2026-12-03) every wall held v . n both ways
    if let Some(toml::Value::Table(b)) = deck
        .get_mut("grid")
        .and_then(|g| g.as_table_mut())
        .and_then(|g| g.get_mut("boundary"))
    {
        b.entry("contact").or_insert_with(|| "bonded".into());
        // before wall friction (pmpm 0.1 up to 2026-12-03) the slip walls slid freely
        b.entry("friction").or_insert_with(|| "none".into());
    }
    let Some(toml::Value::Table(s)) = deck.get_mut("simulation") else {
        return;
    };
    // before implicit viscosity (pmpm 0.1 up to 2026-11-28) every viscous stress was explicit
    if !s.contains_key("viscosity") {
        s.insert("viscosity".into(), "explicit".into());
        s.insert("viscosity_tolerance".into(), 1e-8.into());
        s.insert("viscosity_max_iterations".into(), 2000.into());
    }
}

/// The first key (dotted path) whose value differs between two TOML trees, with both values.
fn first_difference(
    path: &str,
    a: &toml::Value,
    b: &toml::Value,
) -> Option<(String, String, String)> {
    use toml::Value;
    let join = |k: &str| {
        if path.is_empty() {
            k.to_string()
        } else {
            format!("{path}.{k}")
        }
    };
    match (a, b) {
        (Value::Table(x), Value::Table(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| match (x.get(k), y.get(k)) {
                (Some(u), Some(v)) => first_difference(&join(k), u, v),
                (u, v) => Some((
                    join(k),
                    u.map_or("(absent)".into(), |u| u.to_string()),
                    v.map_or("(absent)".into(), |v| v.to_string()),
                )),
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (u, v))| first_difference(&format!("{path}[{i}]"), u, v)),
        _ if a == b => None,
        _ => Some((path.to_string(), a.to_string(), b.to_string())),
    }
}

/// [`State`] as it is written: the same fields in the same order, serialised to the same
/// bytes, but borrowing the particle arrays and node fields instead of copying them.
#[derive(Serialize)]
struct StateView<'a, const D: usize> {
    version: &'a str,
    dimension: usize,
    deck: String,
    time: f64,
    steps: u64,
    pressure_iterations: usize,
    driver: &'a DriverState,
    particles: crate::particles::FlatView<'a, D>,
    body_force: FlatSlice<'a, Vector<D>>,
    node_pressure: &'a [f64],
    volume_over_density: &'a [f64],
}

/// Passes bytes on to `inner` while counting them and taking their CRC-32. The serialiser
/// reports a failed write as its own error; the write's error (a full disk) is kept here to
/// be reported instead.
struct Checksummed<W> {
    inner: W,
    hasher: crc32fast::Hasher,
    len: u64,
    failed: Option<std::io::Error>,
}

impl<W: Write> Write for Checksummed<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf).inspect_err(|e| {
            self.failed = Some(std::io::Error::new(e.kind(), e.to_string()));
        })?;
        self.hasher.update(&buf[..n]);
        self.len += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Writes the state of `sim`, built from `deck`, and of the driver to `path` (through a
/// temporary file).
///
/// The payload is streamed to the file from the simulation's own arrays, and the header's
/// checksum and length are filled in after it: a checkpoint costs no copy of the state in
/// memory (a copy would double the peak memory of a large run).
/// `pieces`: where rank 0 of a run over ranks writes its file, the other ranks' pieces (they
/// write theirs with `None`).
pub fn write<const D: usize>(
    path: &Path,
    deck: &Deck,
    sim: &Simulation<D>,
    driver: &DriverState,
    pieces: Option<&Pieces>,
) -> Result<(), Error> {
    let projection = sim.stepper.projection();
    let state = StateView {
        version: env!("CARGO_PKG_VERSION"),
        dimension: D,
        deck: fingerprint(deck).to_string(),
        time: sim.time,
        steps: sim.steps,
        pressure_iterations: sim.pressure_iterations(),
        driver,
        particles: sim.particles.flat_view(),
        body_force: FlatSlice(sim.body_force_values().unwrap_or(&[])),
        node_pressure: projection.map_or(&[], |p| &p.previous[..]),
        volume_over_density: projection.map_or(&[], |p| p.volume_over_density()),
    };
    crate::atomic::write_atomic(path, |w| {
        w.write_all(MAGIC)?;
        w.write_all(&FORMAT.to_le_bytes())?;
        w.write_all(&[0; 12])?; // checksum and length, filled in below
        let mut payload = Checksummed {
            inner: &mut *w,
            hasher: crc32fast::Hasher::new(),
            len: 0,
            failed: None,
        };
        // the open boundaries' ledger follows the format's fields when the deck has them: a
        // checkpoint without them is the same bytes as before they existed
        let flow = deck.has_open_flow().then_some(sim.ledger);
        // and then the free rigid bodies' state, where the deck has any
        let free = deck
            .has_free_bodies()
            .then(|| sim.boundary.rigid.free_states(sim.time));
        let mut encoded = postcard::to_io(&state, &mut payload).map(|_| ());
        if let (Ok(()), Some(f)) = (&encoded, &flow) {
            encoded = postcard::to_io(f, &mut payload).map(|_| ());
        }
        if let (Ok(()), Some(f)) = (&encoded, &free) {
            encoded = postcard::to_io(f, &mut payload).map(|_| ());
        }
        // and last the run's wall time so far
        if encoded.is_ok() {
            encoded = postcard::to_io(&driver.wall_seconds, &mut payload).map(|_| ());
        }
        // and after it, for a run over ranks with the grid in slabs, where it is cut
        if let (Ok(()), Some(d)) = (&encoded, &sim.decomposition) {
            encoded = postcard::to_io(d, &mut payload).map(|_| ());
        }
        // and after that, in rank 0's file of a run over ranks, the other ranks' pieces
        // (behind a tag: a cut's first byte is its axis, 0 to 2)
        if let (Ok(()), Some(p)) = (&encoded, pieces) {
            encoded = payload
                .write_all(PIECES_TAG)
                .map_err(|_| postcard::Error::SerializeBufferFull)
                .and_then(|_| postcard::to_io(p, &mut payload).map(|_| ()));
        }
        if let Err(e) = encoded {
            return Err(payload.failed.take().unwrap_or_else(|| {
                std::io::Error::other(format!("cannot encode the checkpoint: {e}"))
            }));
        }
        let (crc, len) = (payload.hasher.finalize(), payload.len);
        w.seek(SeekFrom::Start(12))?;
        w.write_all(&crc.to_le_bytes())?;
        w.write_all(&len.to_le_bytes())?;
        w.seek(SeekFrom::End(0)).map(|_| ())
    })
    .map_err(|e| Error::io(path, e))
}

/// The state in a checkpoint file's bytes and the bytes after it (the open boundaries' and the
/// free rigid bodies' state, where the deck has them), or why it cannot be had.
fn decode<const D: usize>(bytes: &[u8]) -> Result<(State<D>, &[u8]), String> {
    if bytes.len() < 24 || &bytes[..8] != MAGIC {
        return Err("it is not a pmpm checkpoint".into());
    }
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let format = word(8);
    if format != FORMAT {
        return Err(format!(
            "it has format {format}, this pmpm reads format {FORMAT}"
        ));
    }
    let crc = word(12);
    let len = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes"));
    let payload = &bytes[24..];
    if payload.len() as u64 != len {
        return Err(format!(
            "it is truncated or damaged ({} bytes of state, {len} expected)",
            payload.len()
        ));
    }
    if crc32fast::hash(payload) != crc {
        return Err("it is damaged (checksum mismatch)".into());
    }
    let cannot = |e: postcard::Error| format!("it cannot be decoded ({e})");
    let (state, rest) = postcard::take_from_bytes(payload).map_err(cannot)?;
    Ok((state, rest))
}

/// Why a checkpoint file cannot be used, as the user should read it.
fn refuse(path: &Path, why: impl std::fmt::Display) -> Error {
    Error::Usage(format!(
        "{}: cannot resume from this file: {why}",
        path.display()
    ))
}

/// Reads a checkpoint into `sim` (set up from the same deck) for rank `rank` of `ranks`, and
/// returns the driver's state and whether `sim` now holds the rank's own particles. A file
/// that is not a checkpoint, is damaged, or was written by another deck, another dimension
/// or another particle count is refused with a message that says which.
///
/// A checkpoint of a run over as many ranks gives each rank its own piece, in its order (so
/// that the run goes on bit for bit); one of another number of ranks gives each rank its share
/// of every rank's particles, cut anew, read a piece at a time; one process takes every
/// particle, rank 0's first.
pub fn read<const D: usize>(
    path: &Path,
    deck: &Deck,
    sim: &mut Simulation<D>,
    rank: usize,
    ranks: usize,
) -> Result<(DriverState, Resumed), Error> {
    let bytes = read_bytes(path)?;
    let (s, rest) = decode::<D>(&bytes).map_err(|why| refuse(path, why))?;
    let Trailer {
        flow,
        free,
        wall_seconds,
        decomposition,
        pieces,
    } = trailer(path, deck, rest)?;
    check_free_bodies(path, sim, free.as_deref())?;
    check_deck(path, deck, &s)?;
    let open = deck.has_open_flow();
    let flow = check_open_flow(path, open, flow)?;
    if let Some(p) = &pieces {
        let total: u64 = p.counts.iter().sum();
        if !open && total != sim.seeded as u64 {
            return Err(refuse(
                path,
                format!(
                    "its pieces hold {total} particles, the deck makes {}",
                    sim.seeded
                ),
            ));
        }
        if rank == 0 {
            // rank 0 reads first, alone, before the directory is cut back to the checkpoint:
            // every piece is there, whole and of this checkpoint, or nothing is touched
            for r in 1..p.counts.len() {
                read_piece(path, p, r, &s)?;
            }
        }
    }
    let (s, own, expected, decomposition) = match &pieces {
        None => (s, false, None, decomposition),
        Some(p) if p.counts.len() == ranks => {
            let n = Some(p.counts[rank] as usize);
            (own_piece(path, p, s, rank)?, true, n, decomposition)
        }
        Some(p) if ranks > 1 => {
            let geo = &sim.grid.geo;
            let s = whole_pressure(path, p, s, geo, decomposition.as_ref())?;
            let (s, cut) =
                share_of_pieces(path, p, s, geo, (rank, ranks, (sim.window(), sim.reach())))?;
            let n = Some(s.particles.id.len());
            (s, true, n, cut)
        }
        Some(p) => {
            let s = whole_pressure(path, p, s, &sim.grid.geo, decomposition.as_ref())?;
            (every_piece(path, p, s)?, false, None, decomposition)
        }
    };
    check_particles(path, open, sim, &s, flow.as_ref(), expected)?;
    let driver = restore(sim, s, flow, free);
    sim.decomposition = decomposition;
    let resumed = Resumed {
        own,
        generation: pieces.map_or(0, |p| p.generation),
    };
    Ok((
        DriverState {
            wall_seconds,
            ..driver
        },
        resumed,
    ))
}

/// What a rank resumed from ([`read`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Resumed {
    /// Whether the rank holds its own particles, not every particle, and the simulation's
    /// decomposition is their cut (a checkpoint of a run over ranks, resumed over ranks).
    pub own: bool,
    /// The checkpoint's generation ([`Pieces::generation`]; 0 for one of one process).
    pub generation: u64,
}

/// Rank `rank`'s piece of the checkpoint at `path` whose rank 0 holds `first` and names the
/// `pieces`: `first` itself on rank 0.
fn own_piece<const D: usize>(
    path: &Path,
    pieces: &Pieces,
    first: State<D>,
    rank: usize,
) -> Result<State<D>, Error> {
    if rank == 0 {
        return Ok(first);
    }
    let mut piece = read_piece(path, pieces, rank, &first)?;
    piece.driver = first.driver;
    Ok(piece)
}

/// `first`, rank 0's state of a checkpoint of the projection over ranks cut as `cut`, with the
/// node pressure of every piece on its own node layers, where the rank that wrote it found the
/// free surface (each rank's is exact only on its slab and the window around it); as it is
/// without a cut or the projection's state.
fn whole_pressure<const D: usize>(
    path: &Path,
    pieces: &Pieces,
    mut first: State<D>,
    geo: &crate::grid::GridGeometry<D>,
    cut: Option<&crate::slabs::Decomposition>,
) -> Result<State<D>, Error> {
    let Some(d) = cut.filter(|_| !first.node_pressure.is_empty()) else {
        return Ok(first);
    };
    for r in 1..pieces.counts.len().min(d.ranks()) {
        let piece = read_piece(path, pieces, r, &first)?;
        for l in d.cuts[r]..d.cuts[r + 1] {
            for i in geo.layer_nodes(d.axis, l) {
                first.node_pressure[i] = piece.node_pressure[i];
            }
        }
    }
    Ok(first)
}

/// The projection's V_p / rho_p = V_p^0 V_p^0 / m_p of `s`'s particles (what a run keeps of
/// them from the start), where `s` holds the projection's state.
fn volume_over_density<const D: usize>(s: &mut State<D>) {
    if s.node_pressure.is_empty() && s.volume_over_density.is_empty() {
        return;
    }
    let (v0, m) = (&s.particles.volume0, &s.particles.mass);
    s.volume_over_density = v0.iter().zip(m).map(|(v, m)| v * v / m).collect();
}

/// Every rank's particles of the checkpoint at `path` whose rank 0 holds `first` and names
/// the `pieces`, in rank order, with `first`'s state.
fn every_piece<const D: usize>(
    path: &Path,
    pieces: &Pieces,
    first: State<D>,
) -> Result<State<D>, Error> {
    let mut all = Particles::unflatten(&first.particles);
    for rank in 1..pieces.counts.len() {
        let piece = read_piece(path, pieces, rank, &first)?;
        let mut more = Particles::unflatten(&piece.particles);
        more.stored = all.stored;
        all.append(&mut more);
    }
    let mut s = State {
        particles: all.flatten(),
        ..first
    };
    volume_over_density(&mut s);
    Ok(s)
}

/// Rank `rank`'s share of every rank's particles of the checkpoint at `path` (written by
/// another number of ranks) whose rank 0 holds `first` and names the `pieces`, with `first`'s
/// state, and the cut of `geo` over `ranks` that shares them. The pieces are read one at a
/// time, twice: once to count the particles per cell layer, from which the cut is planned as
/// a fresh run's is ([`Decomposition::plan`]), once to keep the rank's own (those in its slab,
/// or without slabs an equal share in rank order). No rank holds more than its share and one
/// piece, where taking every particle first held the whole run on every rank; the particles
/// and their order are those of that way.
///
/// [`Decomposition::plan`]: crate::slabs::Decomposition::plan
fn share_of_pieces<const D: usize>(
    path: &Path,
    pieces: &Pieces,
    first: State<D>,
    geo: &crate::grid::GridGeometry<D>,
    (rank, ranks, sight): (usize, usize, (usize, usize)),
) -> Result<(State<D>, Option<crate::slabs::Decomposition>), Error> {
    let each = |r: usize, f: &mut dyn FnMut(&FlatParticles<D>)| -> Result<(), Error> {
        if r == 0 {
            f(&first.particles);
        } else {
            f(&read_piece(path, pieces, r, &first)?.particles);
        }
        Ok(())
    };
    // (the positions alone, as the flat piece holds them)
    let mut counts = crate::slabs::Counts::default();
    counts.reset(geo);
    for r in 0..pieces.counts.len() {
        each(r, &mut |flat| {
            for x in flat.x.chunks_exact(D) {
                counts.add(geo, &Vector::<D>::from_column_slice(x));
            }
        })?;
    }
    let plan = crate::slabs::Decomposition::plan(geo, &counts, ranks, sight);
    let total: u64 = pieces.counts.iter().sum();
    let share = crate::comm::share(total as usize, rank, ranks);
    let mut mine = Particles::<D>::default();
    let (mut at, mut keep) = (0, Vec::new());
    for r in 0..pieces.counts.len() {
        each(r, &mut |flat| {
            let ps = Particles::unflatten(flat);
            keep.clear();
            keep.extend((0..ps.len()).filter_map(|p| {
                let own = match &plan {
                    Some(d) => d.owner_of(geo, &ps.x[p]) == rank,
                    None => share.contains(&(at + p)),
                };
                own.then_some(p as u32)
            }));
            at += ps.len();
            let mut kept = ps.pick(&keep);
            kept.stored = mine.stored;
            mine.append(&mut kept);
        })?;
    }
    let particles = mine.flatten();
    let mut s = State { particles, ..first };
    volume_over_density(&mut s);
    Ok((s, plan))
}

/// The piece of rank `rank` of the checkpoint at `path` (whose rank 0 holds `first`),
/// checked against it: the same run, step and dimension, the particles rank 0 counted, and
/// none of the state a run over ranks does not keep (the projection's, a body force field's).
fn read_piece<const D: usize>(
    path: &Path,
    pieces: &Pieces,
    rank: usize,
    first: &State<D>,
) -> Result<State<D>, Error> {
    let at = piece_path(path, pieces.generation, rank);
    let bytes = read_bytes(&at)?;
    let (piece, _) = decode::<D>(&bytes).map_err(|why| {
        refuse(
            path,
            format!("its piece of rank {rank}, {}: {why}", at.display()),
        )
    })?;
    let fits = piece.dimension == D
        && piece.deck == first.deck
        && piece.time.to_bits() == first.time.to_bits()
        && piece.steps == first.steps
        && piece.particles.id.len() as u64 == pieces.counts[rank]
        && piece.body_force.is_empty()
        // the projection's state: each rank's node pressure, and its particles' V / rho
        && piece.node_pressure.len() == first.node_pressure.len()
        && (piece.volume_over_density.len() == piece.particles.id.len()
            || first.node_pressure.is_empty() && piece.volume_over_density.is_empty());
    if !fits {
        return Err(refuse(
            path,
            format!(
                "its piece of rank {rank}, {}, is of another checkpoint (it is at step {}, \
                 the checkpoint at {}; it holds {} particles, the checkpoint counts {})",
                at.display(),
                piece.steps,
                first.steps,
                piece.particles.id.len(),
                pieces.counts[rank]
            ),
        ));
    }
    Ok(piece)
}

/// The bytes of the checkpoint file at `path`; a directory or a missing file is refused.
fn read_bytes(path: &Path) -> Result<Vec<u8>, Error> {
    if path.is_dir() {
        return Err(refuse(
            path,
            "it is a directory; give the checkpoint.bin inside it",
        ));
    }
    std::fs::read(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => refuse(path, "there is no such file"),
        _ => Error::io(path, e),
    })
}

/// The sections of a checkpoint after its state, each present only where the run that wrote
/// it had it.
struct Trailer {
    /// The open boundaries' ledger.
    flow: Option<Ledger>,
    /// The free rigid bodies' state.
    free: Option<Vec<crate::rigid::FreeState>>,
    /// The run's wall time so far (0 in a checkpoint without it).
    wall_seconds: f64,
    /// Where a run over ranks cut the grid into slabs.
    decomposition: Option<crate::slabs::Decomposition>,
    /// The other ranks' pieces, in rank 0's file of a run over ranks.
    pieces: Option<Pieces>,
}

/// Decodes the bytes after the state (`rest`): the ledger and the free bodies' state where
/// `deck` has them, then the wall time; anything left over, or a wall time that is not a
/// time, is refused.
fn trailer(path: &Path, deck: &Deck, rest: &[u8]) -> Result<Trailer, Error> {
    let cannot = |e: postcard::Error| refuse(path, format!("it cannot be decoded ({e})"));
    let (flow, rest) = if deck.has_open_flow() && !rest.is_empty() {
        let (f, rest) = postcard::take_from_bytes::<Ledger>(rest).map_err(cannot)?;
        (Some(f), rest)
    } else {
        (None, rest)
    };
    let (free, rest) = if deck.has_free_bodies() && !rest.is_empty() {
        let (f, rest) =
            postcard::take_from_bytes::<Vec<crate::rigid::FreeState>>(rest).map_err(cannot)?;
        (Some(f), rest)
    } else {
        (None, rest)
    };
    // the wall time so far, in the checkpoints that hold it
    let (wall_seconds, rest) = if rest.is_empty() {
        (0.0, rest)
    } else {
        postcard::take_from_bytes::<f64>(rest).map_err(cannot)?
    };
    let (decomposition, rest) = if rest.is_empty() || rest.starts_with(PIECES_TAG) {
        (None, rest)
    } else {
        let (d, rest) = postcard::take_from_bytes(rest).map_err(cannot)?;
        (Some(d), rest)
    };
    let (pieces, rest) = match rest.strip_prefix(PIECES_TAG) {
        Some(rest) => {
            let (p, rest) = postcard::take_from_bytes::<Pieces>(rest).map_err(cannot)?;
            (Some(p), rest)
        }
        None => (None, rest),
    };
    if !(rest.is_empty() && wall_seconds.is_finite() && wall_seconds >= 0.0) {
        return Err(refuse(
            path,
            "it holds state of open boundaries or free rigid bodies the deck has none for, or is \
             damaged after its sections (it may come from a newer pmpm)",
        ));
    }
    Ok(Trailer {
        flow,
        free,
        wall_seconds,
        decomposition,
        pieces,
    })
}

/// Refuses a checkpoint whose free rigid bodies' state is missing, damaged or not for the
/// free bodies of `sim`.
fn check_free_bodies<const D: usize>(
    path: &Path,
    sim: &Simulation<D>,
    free: Option<&[crate::rigid::FreeState]>,
) -> Result<(), Error> {
    let wanted = (0..sim.boundary.rigid.len())
        .filter(|&b| sim.boundary.rigid.is_free(b))
        .count();
    match free {
        None if wanted > 0 => Err(refuse(
            path,
            "it holds no state of the free rigid bodies the deck has",
        )),
        Some(f)
            if f.len() != wanted
                || f.iter().any(|s| {
                    // the velocities of the step before are NaN before the first step
                    s.centre
                        .iter()
                        .chain(&s.rotation)
                        .chain(&s.velocity)
                        .chain(&s.omega)
                        .chain([&s.turned])
                        .any(|x| !x.is_finite())
                        || s.last_velocity.iter().chain(&s.last_omega).any(|x| x.is_infinite())
                }) =>
        {
            Err(refuse(
                path,
                format!(
                    "its state of the free rigid bodies is damaged or not this deck's ({} bodies, the deck has {wanted})",
                    f.len()
                ),
            ))
        }
        _ => Ok(()),
    }
}

/// Refuses a state written for another dimension or by another deck than `deck`.
fn check_deck<const D: usize>(path: &Path, deck: &Deck, s: &State<D>) -> Result<(), Error> {
    if s.dimension != D {
        return Err(refuse(
            path,
            format!("it holds a {}D run, the deck is {D}D", s.dimension),
        ));
    }
    let mut theirs: toml::Table = s
        .deck
        .parse()
        .map_err(|e| refuse(path, format!("its deck cannot be read ({e})")))?;
    as_run_then(&mut theirs);
    same_deck(path, theirs, fingerprint(deck))
}

/// The open boundaries' ledger, which a checkpoint holds exactly when the deck has open
/// boundaries (`open`); refuses one that lacks it or holds it for no open boundary.
fn check_open_flow(path: &Path, open: bool, flow: Option<Ledger>) -> Result<Option<Ledger>, Error> {
    match (open, flow) {
        (true, Some(f)) => Ok(Some(f)),
        (true, _) => Err(refuse(
            path,
            "it holds no state of the open boundaries (inflows, outflow faces) the deck has",
        )),
        (false, Some(_)) => Err(refuse(
            path,
            "it holds open boundaries' state the deck has none for",
        )),
        (false, None) => Ok(None),
    }
}

/// Refuses a state whose particle count, ledger of the open boundaries (`flow`, where the
/// deck has them: `open`) or fields do not fit `sim` ([`consistent`]).
fn check_particles<const D: usize>(
    path: &Path,
    open: bool,
    sim: &Simulation<D>,
    s: &State<D>,
    flow: Option<&Ledger>,
    piece: Option<usize>,
) -> Result<(), Error> {
    // with open boundaries the count changes as material enters and leaves; a rank's piece
    // holds what rank 0 counted for it
    let n = match piece {
        _ if open => s.particles.id.len(),
        Some(n) => n,
        None => sim.seeded,
    };
    if let Some(l) = flow {
        let finite = [l.mass0, l.mass_in, l.mass_out, l.volume_in, l.volume_out]
            .iter()
            .all(|x| x.is_finite() && *x >= 0.0);
        if !finite || (l.next_id as usize) < n {
            return Err(refuse(path, "its ledger of the open boundaries is damaged"));
        }
    }
    // (a piece's ids are some of the run's)
    let id_limit = flow.map_or(piece.map_or(n, |_| sim.seeded), |f| f.next_id as usize);
    if s.particles.id.len() != n {
        return Err(refuse(
            path,
            format!(
                "it holds {} particles, the deck makes {n}",
                s.particles.id.len()
            ),
        ));
    }
    let node_pressure_len = sim.stepper.projection().map(|_| sim.grid.geo.node_count());
    let variable_body_force = sim.body_force_values().is_some();
    consistent::<D>(
        s,
        n,
        id_limit,
        (sim.materials.len(), sim.particles.stored),
        &sim.grid.geo,
        node_pressure_len,
        variable_body_force,
    )
    .map_err(|why| refuse(path, why))
}

/// Moves a checked state, with its ledger and free bodies' state, into `sim`, and returns
/// the driver's state it holds.
fn restore<const D: usize>(
    sim: &mut Simulation<D>,
    s: State<D>,
    flow: Option<Ledger>,
    free: Option<Vec<crate::rigid::FreeState>>,
) -> DriverState {
    let stored = sim.particles.stored;
    sim.particles = Particles::unflatten(&s.particles);
    // a checkpoint of a build that stored every field resumes in one that stores fewer
    sim.particles.set_stored(stored);
    sim.time = s.time;
    sim.steps = s.steps;
    if let Some(f) = sim.body_force_values_mut() {
        *f = <Vector<D> as FieldValue>::unflatten(&s.body_force);
    }
    if let Some(p) = sim.stepper.projection_mut() {
        p.last.stats.iterations = s.pressure_iterations;
        p.previous = s.node_pressure;
        p.restore_volume_over_density(s.volume_over_density);
    }
    if let Some(ledger) = flow {
        sim.ledger = ledger;
    }
    if let Some(f) = free {
        sim.boundary.rigid.set_free_states(&f);
    }
    sim.fit_particle_arrays();
    s.driver
}

/// Checks a decoded state field by field before any of it is used or any output is touched:
/// a checksum guards against damage, not against a file written by a faulty or hostile tool,
/// and a material index, id or position out of range would otherwise stop the run with a
/// panic after series.csv was already cut back. Returns what is wrong, for the message.
fn consistent<const D: usize>(
    s: &State<D>,
    n: usize,
    id_limit: usize,
    materials: (usize, Stored),
    geo: &crate::grid::GridGeometry<D>,
    node_pressure_len: Option<usize>,
    variable_body_force: bool,
) -> Result<(), String> {
    consistent_driver(s)?;
    consistent_particles(s, n, id_limit, materials, geo)?;
    if variable_body_force && s.body_force.len() != n * D {
        return Err("it holds no body force values".into());
    }
    if node_pressure_len.is_some() && s.volume_over_density.len() != n {
        return Err("it holds no projection state".into());
    }
    if let Some(len) = node_pressure_len {
        // empty before the first step has sized it
        if !s.node_pressure.is_empty() && s.node_pressure.len() != len {
            return Err(format!(
                "its node pressure holds {} values, the grid has {len} nodes",
                s.node_pressure.len()
            ));
        }
    }
    Ok(())
}

/// The time and the driver's clocks and frame list of a decoded state ([`consistent`]).
fn consistent_driver<const D: usize>(s: &State<D>) -> Result<(), String> {
    if !(s.time.is_finite() && s.time >= 0.0) {
        return Err(format!("its time is {}", s.time));
    }
    let d = &s.driver;
    if !(d.next_frame.is_finite() && d.next_checkpoint.is_finite()) {
        return Err("its next frame or checkpoint time is not a number".into());
    }
    if d.pvd.len() > d.frames || d.frames as f64 > crate::deck::MAX_OUTPUTS + 1.0 {
        return Err(format!(
            "its frame count ({}) and frame list ({}) disagree",
            d.frames,
            d.pvd.len()
        ));
    }
    // the frame list goes into particles.pvd as it is (.pvtu: a frame of a run over ranks)
    if let Some((_, name)) = d.pvd.iter().find(|(t, name)| {
        !t.is_finite()
            || !name
                .strip_prefix("frames/particles_")
                .and_then(|r| r.strip_suffix(".vtu").or_else(|| r.strip_suffix(".pvtu")))
                .is_some_and(|k| k.len() == 6 && k.bytes().all(|c| c.is_ascii_digit()))
    }) {
        return Err(format!("its frame list names {name:?}"));
    }
    Ok(())
}

/// The particle fields of a decoded state: their lengths, ids, material indices, finite and
/// positive values, and positions inside the grid ([`consistent`]), for a run of `materials`
/// materials that stores the optional fields `stored`.
fn consistent_particles<const D: usize>(
    s: &State<D>,
    n: usize,
    id_limit: usize,
    (materials, stored): (usize, Stored),
    geo: &crate::grid::GridGeometry<D>,
) -> Result<(), String> {
    let ps = &s.particles;
    let lengths = ps.lengths(n, stored);
    if let Some((name, got, want)) = lengths.iter().find(|(_, got, want)| got != want) {
        return Err(format!(
            "its particle field {name} holds {got} values, {want} expected"
        ));
    }
    // ids are 0 to n - 1, or with open boundaries distinct and below the next one to be given
    // (sorted, not marked in a table as long as the largest id: a damaged ledger may say 4e9)
    let mut ids = ps.id.clone();
    ids.sort_unstable();
    let bad = ids
        .iter()
        .enumerate()
        .find(|&(k, &id)| id as usize >= id_limit || (k > 0 && ids[k - 1] == id));
    if let Some((_, &id)) = bad {
        return Err(if id_limit == n {
            format!("its particle ids are not 0 to {} (id {id})", n - 1)
        } else {
            format!("its particle ids are not distinct and below {id_limit} (id {id})")
        });
    }
    if let Some(p) = ps.material.iter().position(|&m| m as usize >= materials) {
        return Err(format!(
            "particle {} has material index {}; the deck has {materials} materials",
            ps.id[p], ps.material[p]
        ));
    }
    if let Some(name) = ps.non_finite() {
        return Err(format!(
            "its field {name} holds a value that is not a finite number"
        ));
    }
    let fields: [(&str, &[f64]); 3] = [
        ("body_force", &s.body_force),
        ("node_pressure", &s.node_pressure),
        ("volume_over_density", &s.volume_over_density),
    ];
    for (name, f) in fields {
        if f.iter().any(|a| !a.is_finite()) {
            return Err(format!(
                "its field {name} holds a value that is not a finite number"
            ));
        }
    }
    let positive: [(&str, &[f64]); 3] = [
        ("mass", &ps.mass),
        ("volume0", &ps.volume0),
        ("jacobian", &ps.jacobian),
    ];
    for (name, f) in positive {
        if let Some(p) = f.iter().position(|a| !(a.is_finite() && *a > 0.0)) {
            return Err(format!("particle {} has {name} = {}", ps.id[p], f[p]));
        }
    }
    if let Some(p) = ps
        .half_width
        .iter()
        .position(|a| !(a.is_finite() && *a >= 0.0))
    {
        return Err(format!(
            "particle {} has half_width = {}",
            ps.id[p], ps.half_width[p]
        ));
    }
    for (p, x) in ps.x.chunks_exact(D).enumerate() {
        if !geo.contains(&Vector::<D>::from_column_slice(x)) {
            return Err(format!(
                "particle {} lies outside the grid, at {x:?}",
                ps.id[p]
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deck::Deck;

    /// The pieces' names alternate with the generation, and a run directory's cleaning knows
    /// them, and only them.
    #[test]
    fn pieces_are_named_in_two_sets() {
        let at = Path::new("out").join("checkpoint.bin");
        let names: Vec<String> = [(1, 1), (2, 1), (3, 12)]
            .iter()
            .map(|&(g, r)| {
                piece_path(&at, g, r)
                    .file_name()
                    .unwrap()
                    .to_string_lossy()
                    .into()
            })
            .collect();
        assert_eq!(
            names,
            [
                "checkpoint.bin.1.rank0001",
                "checkpoint.bin.0.rank0001",
                "checkpoint.bin.1.rank0012"
            ]
        );
        assert!(names.iter().all(|n| is_piece(n)));
        assert!(is_piece("checkpoint.bin.0.rank12345"));
        for other in [
            "checkpoint.bin",
            "checkpoint.bin.2.rank0001",
            "checkpoint.bin.0.rank1",
            "x.0.rank0001",
        ] {
            assert!(!is_piece(other), "{other}");
        }
    }

    /// A small projection run's simulation and a driver state for it.
    fn small() -> (Simulation<2>, Deck, DriverState) {
        let src = r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.1
cfl = 0.5
[grid]
size = [1.0, 1.0]
cell_size = 0.1
[[materials]]
name = "water"
density = 1000.0
[[bodies]]
material = "water"
shape = { type = "box", min = [0.0, 0.0], max = [0.5, 0.5] }
particles_per_cell = 2
"#;
        let mut deck = Deck::parse(src, "small.toml").unwrap();
        deck.validate("small.toml").unwrap();
        let driver = DriverState {
            next_frame: 0.01,
            next_checkpoint: 0.01,
            frames: 1,
            pvd: Vec::new(),
            iterations: (0, 0),
            wall_seconds: 0.0,
        };
        (Simulation::<2>::new(&deck).unwrap(), deck, driver)
    }

    /// A checkpoint whose checksum is right but whose content is not (a material index, an id,
    /// a position, a time out of range) is refused with a reason before anything is used.
    #[test]
    fn a_checkpoint_with_a_good_checksum_and_bad_content_is_refused() {
        let (mut sim, deck, driver) = small();
        let dir = std::env::temp_dir().join(format!("pmpm-ck-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("checkpoint.bin");
        write(&path, &deck, &sim, &driver, None).unwrap();
        let good = decode::<2>(&std::fs::read(&path).unwrap()).unwrap().0;
        if let Err(e) = read(&path, &deck, &mut sim, 0, 1) {
            panic!("the good checkpoint: {e}");
        }
        type Tamper = fn(&mut State<2>);
        let cases: [(&str, Tamper); 8] = [
            ("material index 7", |s| s.particles.material[3] = 7),
            ("ids are not 0 to", |s| {
                s.particles.id[1] = s.particles.id[0]
            }),
            ("lies outside the grid", |s| s.particles.x[4] = 1.5),
            ("its time is NaN", |s| s.time = f64::NAN),
            ("field v holds a value that is not", |s| {
                s.particles.v[0] = f64::INFINITY
            }),
            ("has jacobian = -1", |s| s.particles.jacobian[2] = -1.0),
            ("particle field velocity_gradient holds", |s| {
                s.particles.velocity_gradient.pop();
            }),
            ("its frame list names", |s| {
                s.driver.pvd.push((0.0, "\"/><x".into()));
                s.driver.frames += 1;
            }),
        ];
        for (why, tamper) in cases {
            let mut bad = decode::<2>(&std::fs::read(&path).unwrap()).unwrap().0;
            tamper(&mut bad);
            let bad_path = dir.join("bad.bin");
            std::fs::write(&bad_path, encode(&bad)).unwrap();
            let (mut fresh, _, _) = small();
            match read(&bad_path, &deck, &mut fresh, 0, 1) {
                Err(Error::Usage(m)) => assert!(m.contains(why), "{why}: {m}"),
                other => panic!("{why}: {:?}", other.map(|_| ())),
            }
            // nothing of the bad state reached the simulation
            assert_eq!(fresh.time, 0.0);
            assert_eq!(fresh.particles.material, vec![0; fresh.particles.len()]);
        }
        assert_eq!(good.particles.material.len(), sim.particles.len());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A water run stores neither F nor tau; the checkpoint of a build that stored them (full
    /// arrays) still resumes, and they are dropped; a tau of the wrong length is refused.
    #[test]
    fn a_checkpoint_with_every_field_resumes_in_a_lean_run() {
        let (sim, deck, driver) = small();
        assert_eq!(
            sim.particles.stored,
            Stored {
                deformation: false,
                stress: false
            }
        );
        assert!(sim.particles.deformation.is_empty() && sim.particles.tau.is_empty());
        let dir = std::env::temp_dir().join(format!("pmpm-ck-full-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("checkpoint.bin");
        write(&path, &deck, &sim, &driver, None).unwrap();
        let mut full = decode::<2>(&std::fs::read(&path).unwrap()).unwrap().0;
        let n = sim.particles.len();
        full.particles.deformation = [1.0, 0.0, 0.0, 1.0].repeat(n);
        full.particles.tau = vec![0.0; 4 * n];
        std::fs::write(&path, encode(&full)).unwrap();
        let (mut resumed, _, _) = small();
        if let Err(e) = read(&path, &deck, &mut resumed, 0, 1) {
            panic!("the full checkpoint: {e}");
        }
        assert!(resumed.particles.deformation.is_empty() && resumed.particles.tau.is_empty());
        assert_eq!(resumed.particles.x, sim.particles.x);
        full.particles.tau.pop();
        std::fs::write(&path, encode(&full)).unwrap();
        let (mut fresh, _, _) = small();
        match read(&path, &deck, &mut fresh, 0, 1) {
            Err(Error::Usage(m)) => assert!(m.contains("particle field tau holds"), "{m}"),
            other => panic!("a short tau: {:?}", other.map(|_| ())),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The file's bytes for an owned state, as `write` streams them (a deck without open
    /// boundaries or free bodies: the state, then the run's wall time so far).
    fn encode<const D: usize>(state: &State<D>) -> Vec<u8> {
        let mut payload = postcard::to_stdvec(state).unwrap();
        payload.extend(postcard::to_stdvec(&state.driver.wall_seconds).unwrap());
        let mut bytes = Vec::with_capacity(payload.len() + 24);
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&FORMAT.to_le_bytes());
        bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&payload);
        bytes
    }

    /// The streamed file holds exactly the bytes of the state it decodes to, serialised
    /// whole: the borrowed view writes the format the reader expects, field for field.
    #[test]
    fn a_streamed_checkpoint_is_the_encoding_of_its_state() {
        let (sim, deck, driver) = small();
        let dir = std::env::temp_dir().join(format!("pmpm-ck-stream-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("checkpoint.bin");
        write(&path, &deck, &sim, &driver, None).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let state = decode::<2>(&bytes).unwrap().0;
        assert_eq!(encode(&state), bytes);
        assert_eq!(state.particles.x, FieldValue::flatten(&sim.particles.x));
        assert_eq!(
            state.particles.velocity_gradient,
            FieldValue::flatten(&sim.particles.velocity_gradient)
        );
        assert_eq!(
            state.node_pressure,
            sim.stepper.projection().unwrap().previous
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_first_differing_key_is_named() {
        let a: toml::Value = "[simulation]\ncfl = 0.4\ngravity = [0.0, -9.81]\n"
            .parse::<toml::Table>()
            .unwrap()
            .into();
        let b: toml::Value = "[simulation]\ncfl = 0.4\ngravity = [0.0, -9.8]\n"
            .parse::<toml::Table>()
            .unwrap()
            .into();
        assert_eq!(
            first_difference("", &a, &b),
            Some((
                "simulation.gravity[1]".to_string(),
                "-9.81".to_string(),
                "-9.8".to_string()
            ))
        );
        assert_eq!(first_difference("", &a, &a), None);
    }
}
