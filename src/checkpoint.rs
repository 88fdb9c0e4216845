//! Checkpoints: the full state of a run in one file, from which `pmpm run DECK --resume FILE`
//! goes on as if it had never stopped (the same frames, bit for bit, on the same thread count).
//!
//! The file is `PMPMCKPT`, a format version (u32), the CRC-32 of the payload (u32), the payload's
//! length (u64), then the payload: the state, serialised with postcard. It is written to a
//! temporary name and renamed, so a run killed while writing leaves the previous checkpoint
//! whole. A resumed run must use the same deck, except for the keys a user may change on resume
//! ([`RESUMABLE_KEYS`]); anything else is refused with the first key that differs.

use crate::deck::Deck;
use crate::error::Error;
use crate::grid::Vector;
use crate::particles::Matrix;
use crate::scheme::Simulation;
use serde::{Deserialize, Serialize};
use std::path::Path;

const MAGIC: &[u8; 8] = b"PMPMCKPT";
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
}

/// The payload.
#[derive(Serialize, Deserialize)]
struct State {
    version: String,
    dimension: usize,
    /// The deck, as TOML, with the resumable keys removed.
    deck: String,
    time: f64,
    steps: u64,
    pressure_iterations: usize,
    driver: DriverState,
    id: Vec<u32>,
    x: Vec<f64>,
    v: Vec<f64>,
    mass: Vec<f64>,
    volume0: Vec<f64>,
    jacobian: Vec<f64>,
    deformation: Vec<f64>,
    pressure: Vec<f64>,
    tau: Vec<f64>,
    velocity_gradient: Vec<f64>,
    affine: Vec<f64>,
    material: Vec<u16>,
    half_width: Vec<f64>,
    /// The body force at the particles (empty when it is constant).
    body_force: Vec<f64>,
    /// The projection's node pressure p^n and per-particle V / rho (empty for the explicit
    /// scheme).
    node_pressure: Vec<f64>,
    volume_over_density: Vec<f64>,
}

fn flat_vectors<const D: usize>(v: &[Vector<D>]) -> Vec<f64> {
    v.iter().flat_map(|a| a.iter().copied()).collect()
}

fn flat_matrices<const D: usize>(m: &[Matrix<D>]) -> Vec<f64> {
    m.iter().flat_map(|a| a.iter().copied()).collect()
}

fn vectors<const D: usize>(f: &[f64]) -> Vec<Vector<D>> {
    f.chunks_exact(D)
        .map(Vector::<D>::from_column_slice)
        .collect()
}

fn matrices<const D: usize>(f: &[f64]) -> Vec<Matrix<D>> {
    f.chunks_exact(D * D)
        .map(Matrix::<D>::from_column_slice)
        .collect()
}

/// The deck as a TOML tree without the keys a resume may change.
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
    t
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

/// Writes the state of `sim` and of the driver to `path` (through a temporary file).
pub fn write<const D: usize>(
    path: &Path,
    sim: &Simulation<D>,
    driver: &DriverState,
) -> Result<(), Error> {
    let ps = &sim.particles;
    let projection = sim.projection.as_ref();
    let state = State {
        version: env!("CARGO_PKG_VERSION").to_string(),
        dimension: D,
        deck: fingerprint(&sim.deck).to_string(),
        time: sim.time,
        steps: sim.steps,
        pressure_iterations: sim.pressure_iterations,
        driver: driver.clone(),
        id: ps.id.clone(),
        x: flat_vectors(&ps.x),
        v: flat_vectors(&ps.v),
        mass: ps.mass.clone(),
        volume0: ps.volume0.clone(),
        jacobian: ps.jacobian.clone(),
        deformation: flat_matrices(&ps.deformation),
        pressure: ps.pressure.clone(),
        tau: flat_matrices(&ps.tau),
        velocity_gradient: flat_matrices(&ps.velocity_gradient),
        affine: flat_matrices(&ps.affine),
        material: ps.material.clone(),
        half_width: ps.half_width.clone(),
        body_force: sim.body_force_values().map_or(Vec::new(), flat_vectors),
        node_pressure: projection.map_or(Vec::new(), |p| p.previous.clone()),
        volume_over_density: projection.map_or(Vec::new(), |p| p.volume_over_density().to_vec()),
    };
    let payload = postcard::to_stdvec(&state).map_err(|e| {
        Error::io(
            path,
            std::io::Error::other(format!("cannot encode the checkpoint: {e}")),
        )
    })?;
    let mut bytes = Vec::with_capacity(payload.len() + 24);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&FORMAT.to_le_bytes());
    bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
    bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&payload);
    crate::output::write_atomic(path, |w| std::io::Write::write_all(w, &bytes))
        .map_err(|e| Error::io(path, e))
}

/// Why a checkpoint file cannot be used, as the user should read it.
fn refuse(path: &Path, why: impl std::fmt::Display) -> Error {
    Error::Usage(format!(
        "{}: cannot resume from this file: {why}",
        path.display()
    ))
}

/// Reads a checkpoint into `sim` (set up from the same deck) and returns the driver's state.
/// A file that is not a checkpoint, is damaged, or was written by another deck, another
/// dimension or another particle count is refused with a message that says which.
pub fn read<const D: usize>(path: &Path, sim: &mut Simulation<D>) -> Result<DriverState, Error> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    if bytes.len() < 24 || &bytes[..8] != MAGIC {
        return Err(refuse(path, "it is not a pmpm checkpoint"));
    }
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let format = word(8);
    if format != FORMAT {
        return Err(refuse(
            path,
            format!("it has format {format}, this pmpm reads format {FORMAT}"),
        ));
    }
    let crc = word(12);
    let len = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes"));
    let payload = &bytes[24..];
    if payload.len() as u64 != len {
        return Err(refuse(
            path,
            format!(
                "it is truncated or damaged ({} bytes of state, {len} expected)",
                payload.len()
            ),
        ));
    }
    if crc32fast::hash(payload) != crc {
        return Err(refuse(path, "it is damaged (checksum mismatch)"));
    }
    let s: State = postcard::from_bytes(payload)
        .map_err(|e| refuse(path, format!("it cannot be decoded ({e})")))?;
    if s.dimension != D {
        return Err(refuse(
            path,
            format!("it holds a {}D run, the deck is {D}D", s.dimension),
        ));
    }
    let theirs: toml::Table = s
        .deck
        .parse()
        .map_err(|e| refuse(path, format!("its deck cannot be read ({e})")))?;
    let ours = fingerprint(&sim.deck);
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
    let n = sim.particles.len();
    if s.id.len() != n {
        return Err(refuse(
            path,
            format!("it holds {} particles, the deck makes {n}", s.id.len()),
        ));
    }
    let ps = &mut sim.particles;
    ps.id = s.id;
    ps.x = vectors(&s.x);
    ps.v = vectors(&s.v);
    ps.mass = s.mass;
    ps.volume0 = s.volume0;
    ps.jacobian = s.jacobian;
    ps.deformation = matrices(&s.deformation);
    ps.pressure = s.pressure;
    ps.tau = matrices(&s.tau);
    ps.velocity_gradient = matrices(&s.velocity_gradient);
    ps.affine = matrices(&s.affine);
    ps.material = s.material;
    ps.half_width = s.half_width;
    let lengths = [
        ps.x.len(),
        ps.v.len(),
        ps.mass.len(),
        ps.volume0.len(),
        ps.jacobian.len(),
        ps.deformation.len(),
        ps.pressure.len(),
        ps.tau.len(),
        ps.velocity_gradient.len(),
        ps.affine.len(),
        ps.material.len(),
        ps.half_width.len(),
    ];
    if lengths.iter().any(|&l| l != n) {
        return Err(refuse(path, "its particle arrays have different lengths"));
    }
    sim.time = s.time;
    sim.steps = s.steps;
    sim.pressure_iterations = s.pressure_iterations;
    if let Some(f) = sim.body_force_values_mut() {
        if s.body_force.len() != n * D {
            return Err(refuse(path, "it holds no body force values"));
        }
        *f = vectors(&s.body_force);
    }
    if let Some(p) = sim.projection.as_mut() {
        if s.volume_over_density.len() != n {
            return Err(refuse(path, "it holds no projection state"));
        }
        p.previous = s.node_pressure;
        p.restore_volume_over_density(s.volume_over_density);
    }
    Ok(s.driver)
}

#[cfg(test)]
mod tests {
    use super::*;

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
