//! The input deck of `docs/deck.md`: serde types, defaults and validation.
//!
//! A deck is read in two passes. [`Deck::parse`] turns TOML into the typed structs below, with
//! unknown keys, wrong types and unknown enum values reported against the key path and the line
//! and column TOML gives. [`Deck::validate`] then checks what types cannot say (signs, lengths,
//! bodies inside the grid, materials that exist, a stable fixed time step) and fills every
//! default in, so that the deck written to `run.toml` is the one that was run. [`limits`]
//! estimates what a checked deck will cost before anything is allocated.

pub mod limits;
pub mod room;

use crate::field::VectorField;
use crate::keys::{Check, Frame};
use serde::{Deserialize, Serialize};

// the option enums live with the code they choose
pub use crate::averaging::VolumetricAveraging;
pub use crate::pressure::free_surface::FreeSurface;
pub use crate::pressure::PoissonRhs;
pub use crate::pressure::PressureUnknowns;
pub use crate::pressure::Quadrature;
pub use crate::pressure::RigidFaces;
pub use crate::pressure::{DensityCorrection, Preconditioner, PressureSettings, Solver};
pub use crate::rigid::{RigidBodyDeck, RigidMotion, RigidSides, Spin};
pub use crate::scheme::{ProbeSample, Scheme};
pub use crate::shape::ShapeFunction;
pub use crate::transfer::StressUpdate;
pub use crate::transfer::Transfer;
use std::fmt;
use std::path::Path;

pub use crate::boundary::BoundaryKind;
pub use crate::damping::DampingZoneDeck;
pub use crate::error::DeckError;
pub use crate::flow::InflowDeck;
pub use crate::gauges::{GaugeDeck, GaugeKind, ProbeDeck};
pub use crate::geometry::{Numbers, ShapeDeck, ShapeKind};
pub use crate::material::Model;
pub use crate::material::{MaterialDeck, MAX_MATERIAL_PARAMETER};
pub use crate::particles::InitialStress;
pub use crate::wall_law::WallFriction;

const BOUNDARY_KINDS: &[&str] = &["slip", "no_slip", "open", "outflow", "periodic", "symmetry"];

/// One face's condition: a kind, and for a moving wall its velocity.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum BoundarySpec {
    /// `x_min = "slip"`
    Kind(BoundaryKind),
    /// `y_max = { type = "no_slip", velocity = [1.0, 0.0] }`
    Moving {
        /// Kind of the wall.
        #[serde(rename = "type")]
        kind: BoundaryKind,
        /// Wall velocity (numbers or expressions in x, y, z, t).
        velocity: VectorField,
    },
}

impl BoundarySpec {
    /// Kind of the face.
    pub fn kind(&self) -> BoundaryKind {
        match self {
            Self::Kind(k) | Self::Moving { kind: k, .. } => *k,
        }
    }
    /// Wall velocity, if the wall moves.
    pub fn velocity(&self) -> Option<&VectorField> {
        match self {
            Self::Kind(_) => None,
            Self::Moving { velocity, .. } => Some(velocity),
        }
    }
}

/// The table form of a face, `{ type = "no_slip", velocity = [...] }`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MovingWall {
    #[serde(rename = "type")]
    kind: BoundaryKind,
    velocity: Option<VectorField>,
}

impl<'de> Deserialize<'de> for BoundarySpec {
    // Hand-written so that both a string and a table are accepted with errors that say which
    // key is wrong (serde's untagged enums only say "did not match any variant").
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = BoundarySpec;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a boundary kind (\"slip\", \"no_slip\", \"open\", \"outflow\", \"periodic\") or a table { type = ..., velocity = [...] }")
            }
            fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<BoundarySpec, E> {
                BoundaryKind::from_name(s)
                    .map(BoundarySpec::Kind)
                    .ok_or_else(|| E::unknown_variant(s, BOUNDARY_KINDS))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                map: A,
            ) -> Result<BoundarySpec, A::Error> {
                // a derived struct, so that a wrong entry is reported against its own key
                // (`grid.boundary.y_max.type`), with the valid keys and values listed
                let w = MovingWall::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                Ok(match w.velocity {
                    Some(velocity) => BoundarySpec::Moving {
                        kind: w.kind,
                        velocity,
                    },
                    None => BoundarySpec::Kind(w.kind),
                })
            }
        }
        d.deserialize_any(V)
    }
}

/// The adaptive step's Courant number where a deck gives neither `dt` nor `cfl`.
pub const DEFAULT_CFL: f64 = 0.4;

/// `[simulation]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationDeck {
    /// 2 or 3.
    pub dimension: usize,
    /// `projection` or `explicit`.
    #[serde(default)]
    pub scheme: Scheme,
    /// Simulated time to reach (s).
    pub end_time: f64,
    /// Fixed time step (s); absent: adaptive with `cfl`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt: Option<f64>,
    /// Courant number of the adaptive step; [`DEFAULT_CFL`] where neither `dt` nor `cfl` is
    /// given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cfl: Option<f64>,
    /// Cap of the adaptive step (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_dt: Option<f64>,
    /// Body force per unit mass (m/s2), numbers or expressions in x, y, z, t; default 9.81
    /// down the last axis.
    #[serde(default)]
    pub gravity: VectorField,
    /// Velocity transfer; `validate` fills it in: `apic` for the projection, `flip` for the
    /// explicit scheme.
    #[serde(default)]
    pub transfer: Option<Transfer>,
    /// Share of FLIP for `transfer = "flip"` (default 0.99).
    #[serde(default = "default_flip_ratio")]
    pub flip_ratio: f64,
    /// Shape functions (default `linear`).
    #[serde(default)]
    pub shape_function: ShapeFunction,
    /// Strain rate from remapped node velocities (`musl`, default) or from v^{n+1} (`usl`).
    #[serde(default)]
    pub stress_update: StressUpdate,
    /// Volumetric strain rate of the explicit scheme: each particle's own (`none`, default) or
    /// averaged at the nodes (`nodal`), against volumetric locking.
    #[serde(default)]
    pub volumetric_averaging: VolumetricAveraging,
    /// Steps between sorts of the particles by cell (default 20; 0: never sort). Sorted
    /// particles visit the grid nodes in order in the transfers, which keeps them in cache.
    #[serde(default = "default_sort_interval")]
    pub sort_interval: usize,
    /// Linear damping of grid velocities (1/s), a settling aid: a = ... - damping * v.
    #[serde(default)]
    pub damping: f64,
    /// Adaptive steps (`cfl`) land exactly on the output frame times: the time left to the
    /// next frame is split into equal steps, which can halve a step before a frame. With false
    /// the step is the stable one (at most one frame interval) and a frame is written at the
    /// first step that reaches its time. Default: true for the explicit scheme, false for the projection, whose pressure
    /// holds a (rho / dt) div v^n part that cleans the last step's divergence, so that a sudden
    /// halving of dt shows as a pressure jump.
    #[serde(default)]
    pub land_on_frames: Option<bool>,
    /// Bounds [min, max] on each particle's volume ratio J = V / V0: a particle outside them
    /// stops the run. Without them a run stops where J <= 0 or a particle's volume passes
    /// [`MAX_PARTICLE_CELLS`] cells.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume_limits: Option<[f64; 2]>,
    /// The fluids' viscous stress: `implicit` (at the new velocity, after the pressure, no
    /// viscous step limit; projection only) or `explicit` (from the last step's strain rate,
    /// dt <= rho h^2 / (2 d mu)). `validate` fills it in: implicit for the projection,
    /// explicit for the explicit scheme.
    #[serde(default)]
    pub viscosity: Option<ViscosityTreatment>,
    /// Relative residual of the implicit viscous solve (default 1e-8).
    #[serde(default = "default_viscosity_tolerance")]
    pub viscosity_tolerance: f64,
    /// Iteration limit of the implicit viscous solve (default 2000): past it the run stops.
    #[serde(default = "default_viscosity_max_iterations")]
    pub viscosity_max_iterations: usize,
}

fn default_viscosity_tolerance() -> f64 {
    1e-8
}

fn default_viscosity_max_iterations() -> usize {
    2000
}

pub use crate::scheme::MAX_PARTICLE_CELLS;

pub use crate::viscosity::ViscosityTreatment;

/// The most frames, or checkpoints, a deck may ask for over its run: a million frames of even a
/// small run fill a disk.
pub const MAX_OUTPUTS: f64 = 1e6;

fn default_sort_interval() -> usize {
    20
}

fn default_flip_ratio() -> f64 {
    0.99
}

/// `[grid]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridDeck {
    /// Lower corner (default the origin).
    #[serde(default)]
    pub origin: Vec<f64>,
    /// Extents, a whole number of cells (validation rounds a size that is not up to the next
    /// whole cell).
    pub size: Vec<f64>,
    /// Cell size h.
    pub cell_size: f64,
    /// Face conditions (default `slip` on every face).
    #[serde(default)]
    pub boundary: BoundaryDeck,
    /// The sizes validation rounded up, as (axis, the size the deck gave); `check` says so.
    #[serde(skip)]
    pub rounded: Vec<(usize, f64)>,
}

impl SimulationDeck {
    /// The vertical axis: the one gravity (at t = 0, at the origin) points along most, or the
    /// last axis where there is no gravity (or it does not compile).
    pub fn vertical_axis(&self) -> usize {
        let g = self
            .gravity
            .compile()
            .map(|f| f.eval_t(0.0))
            .unwrap_or_default();
        let mut up = self.dimension - 1;
        let mut most = 0.0;
        for (d, g) in g.iter().enumerate().take(self.dimension) {
            if g.abs() > most {
                most = g.abs();
                up = d;
            }
        }
        up
    }
}

impl GridDeck {
    /// Cells per axis: the size over the cell size, rounded (validation holds it whole).
    pub fn cells(&self) -> Vec<usize> {
        self.size
            .iter()
            .map(|s| (s / self.cell_size).round() as usize)
            .collect()
    }
}

/// `[grid.boundary]`: one entry per face.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
#[allow(missing_docs)]
pub struct BoundaryDeck {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x_min: Option<BoundarySpec>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x_max: Option<BoundarySpec>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y_min: Option<BoundarySpec>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y_max: Option<BoundarySpec>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_min: Option<BoundarySpec>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_max: Option<BoundarySpec>,
    /// How the slip and no-slip faces hold the material: `"separating"` (it may leave them,
    /// the nodal projection's default) or `"bonded"` (v . n held both ways, the default of
    /// the cell projection and the explicit scheme);
    /// filled in by the checks. A `"symmetry"` face holds both ways whatever it says.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact: Option<WallContact>,
    /// The slip faces' shear: `"none"` (the default) or `"wall_law"`; filled in by the
    /// checks ([`crate::wall_law`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub friction: Option<WallFriction>,
}

/// `grid.boundary.contact`: whether the walls let the material go
/// ([`crate::boundary::Boundary::settle_contacts`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WallContact {
    /// The normal velocity one-sided: the wall pushes, never pulls.
    Separating,
    /// v . n = v_wall . n both ways: the material sticks to the wall's normal motion.
    Bonded,
}

/// Names of the axes, in messages.
use crate::keys::AXES;

pub use crate::keys::FACE_NAMES;

impl BoundaryDeck {
    /// The face entries in [`FACE_NAMES`] order.
    pub fn faces(&self) -> [&Option<BoundarySpec>; 6] {
        [
            &self.x_min,
            &self.x_max,
            &self.y_min,
            &self.y_max,
            &self.z_min,
            &self.z_max,
        ]
    }
    fn faces_mut(&mut self) -> [&mut Option<BoundarySpec>; 6] {
        [
            &mut self.x_min,
            &mut self.x_max,
            &mut self.y_min,
            &mut self.y_max,
            &mut self.z_min,
            &mut self.z_max,
        ]
    }
}

/// `[[bodies]]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyDeck {
    /// Name of a `[[materials]]` entry.
    pub material: String,
    /// Region filled with particles.
    pub shape: ShapeDeck,
    /// Particles per cell per direction (default 2).
    #[serde(default = "default_ppc")]
    pub particles_per_cell: usize,
    /// Initial velocity (default at rest), numbers or expressions in x, y, z.
    #[serde(default)]
    pub velocity: VectorField,
    /// Optional initial stress.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stress: Option<InitialStress>,
}

fn default_ppc() -> usize {
    2
}

/// Output file formats of particle frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Format {
    /// `.vtu` frames and `particles.pvd`.
    Vtk,
    /// `.csv` frames.
    Csv,
    /// `.vti` frames of the grid's nodes and `grid.pvd` ([`crate::grid_fields`]).
    Grid,
}

/// `[output]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct OutputDeck {
    /// Output directory (default `out/<deck name>`).
    #[serde(default)]
    pub directory: String,
    /// Time between frames (default end_time / 100).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub interval: Option<f64>,
    /// Frame formats (default both).
    #[serde(default = "default_formats")]
    pub formats: Vec<Format>,
    /// Points sampled every step into probes.csv.
    #[serde(default)]
    pub probes: Vec<ProbeDeck>,
    /// Gauges read into gauges.csv.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gauges: Vec<GaugeDeck>,
    /// Simulated seconds between rows of gauges.csv (default: every step).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gauge_interval: Option<f64>,
    /// Simulated seconds between checkpoints (`checkpoint.bin` in the output directory,
    /// overwritten each time; one is always written at the end). Default: the frame interval.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checkpoint_interval: Option<f64>,
}

fn default_formats() -> Vec<Format> {
    vec![Format::Vtk, Format::Csv]
}

/// `[pmpm]`: written into `run.toml`, accepted (and ignored) on input so that a run.toml runs again.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProgramInfo {
    /// Version of pmpm that wrote the file.
    pub version: String,
}

/// The whole deck.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Deck {
    /// `[pmpm]`, only in a `run.toml`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pmpm: Option<ProgramInfo>,
    /// `[about]`: the deck's title and where it comes from.
    pub about: Option<crate::about::AboutDeck>,
    /// `[simulation]`
    pub simulation: SimulationDeck,
    /// `[grid]`
    pub grid: GridDeck,
    /// `[pressure]`
    #[serde(default)]
    pub pressure: PressureSettings,
    /// `[[materials]]`
    pub materials: Vec<MaterialDeck>,
    /// `[[bodies]]`
    pub bodies: Vec<BodyDeck>,
    /// `[[rigid_bodies]]`: boxes moving at a prescribed velocity (pmpm).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rigid_bodies: Vec<RigidBodyDeck>,
    /// `[[inflows]]`: patches of wall faces through which material enters.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inflows: Vec<InflowDeck>,
    /// `[[damping_zones]]`: layers that absorb waves (pmpm).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub damping_zones: Vec<DampingZoneDeck>,
    /// `[output]`
    #[serde(default)]
    pub output: OutputDeck,
    /// The mesh files the shapes read, by path, with their length and CRC-32 as the check
    /// read them ([`crate::geometry::MeshSource::digest`]): a checkpoint records them, and a
    /// resume after a file changed is refused. Not a key of the deck.
    #[serde(skip)]
    pub mesh_files: std::collections::BTreeMap<String, String>,
    /// The triangles of the meshes the shapes read, all together (for the memory estimate).
    #[serde(skip)]
    pub mesh_triangles: usize,
}

fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(src.len());
    let before = &src[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |s| s.chars().count()) + 1;
    (line, col)
}

/// Names between backticks in a serde message, in order.
fn backticked(msg: &str) -> Vec<&str> {
    msg.split('`').skip(1).step_by(2).collect()
}

pub use crate::keys::nearest;

/// The values an enum of the deck accepts, in order (read from serde's own error message).
/// How a deck spells a setting's value, quoted (`"bspline2"`).
fn spelling<T: Serialize>(value: &T) -> String {
    toml::Value::try_from(value).map_or_else(|_| String::from("?"), |v| v.to_string())
}

fn variants<'de, T: Deserialize<'de>>() -> Vec<String> {
    use serde::de::IntoDeserializer;
    let probe: serde::de::value::StrDeserializer<'_, serde::de::value::Error> =
        "\u{1}".into_deserializer();
    match T::deserialize(probe) {
        Ok(_) => Vec::new(),
        Err(e) => backticked(&e.to_string())
            .into_iter()
            .skip(1)
            .map(String::from)
            .collect(),
    }
}

/// The values allowed for a key that takes one of a list of names, if it is one.
fn allowed_values(key: &str) -> Option<Vec<String>> {
    let last = key.rsplit('.').next().unwrap_or(key);
    let last = last.split('[').next().unwrap_or(last);
    Some(match last {
        "scheme" => variants::<Scheme>(),
        "transfer" => variants::<Transfer>(),
        "shape_function" => variants::<ShapeFunction>(),
        "stress_update" => variants::<StressUpdate>(),
        "viscosity" if key.starts_with("simulation") => variants::<ViscosityTreatment>(),
        "volumetric_averaging" => variants::<VolumetricAveraging>(),
        "solver" => variants::<Solver>(),
        "preconditioner" => variants::<Preconditioner>(),
        "free_surface" => variants::<FreeSurface>(),
        "density_correction" => variants::<DensityCorrection>(),
        "rhs" => variants::<PoissonRhs>(),
        "quadrature" => variants::<Quadrature>(),
        "unknowns" => variants::<PressureUnknowns>(),
        "rigid_faces" => variants::<RigidFaces>(),
        "friction" => variants::<WallFriction>(),
        "model" => variants::<Model>(),
        "formats" => variants::<Format>(),
        "stress" => variants::<InitialStress>(),
        "type" if key.contains(".shape.") => variants::<ShapeKind>(),
        "type" if key.contains("gauges") => variants::<GaugeKind>(),
        "type" => variants::<BoundaryKind>(),
        face if FACE_NAMES.contains(&face) => variants::<BoundaryKind>(),
        _ => return None,
    })
}

/// `"a", "b", "c"`
fn quoted_list<S: AsRef<str>>(names: &[S]) -> String {
    names
        .iter()
        .map(|v| format!("\"{}\"", v.as_ref()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Keys that hold a list of tables, each entry written `[[key]]`.
const TABLE_LISTS: [&str; 7] = [
    "materials",
    "bodies",
    "rigid_bodies",
    "inflows",
    "damping_zones",
    "output.probes",
    "output.gauges",
];

/// serde's "invalid type: GOT, expected EXPECTED" in a user's words.
fn type_message(key: &str, got: &str, expected: &str) -> String {
    // toml adds the type it read a large integer as: "integer `99999999999999999999` as i128"
    let got = if got.starts_with("integer ") {
        got.split(" as ").next().unwrap_or(got)
    } else {
        got
    };
    let value = backticked(got).first().map(|v| v.to_string());
    let got = match got.split([' ', '`']).next().unwrap_or("") {
        "integer" | "floating" | "boolean" => value.unwrap_or_else(|| got.to_string()),
        "string" => got.trim_start_matches("string ").to_string(),
        "sequence" => "a list".to_string(),
        "map" => "a table".to_string(),
        _ => got.to_string(),
    };
    if expected == "a sequence" && got == "a table" && TABLE_LISTS.contains(&key) {
        return format!(
            "must be a list of tables: write [[{key}]] (double brackets) above each entry, got [{key}]"
        );
    }
    let expected = match expected {
        "f64" | "f32" => "a number".to_string(),
        "usize" | "u64" | "u32" | "u16" | "u8" if key == "simulation.dimension" => {
            "2 or 3".to_string()
        }
        "usize" | "u64" | "u32" | "u16" | "u8" if key.ends_with(".particles_per_cell") => {
            "a whole number between 1 and 8".to_string()
        }
        "usize" | "u64" | "u32" | "u16" | "u8" => "a whole number (0, 1, 2, ...)".to_string(),
        "a boolean" => "true or false".to_string(),
        "a sequence" => "a list in square brackets".to_string(),
        "a string" => match allowed_values(key) {
            Some(v) => format!("one of {}", quoted_list(&v)),
            None => "a string in quotes".to_string(),
        },
        "struct ShapeDeck" => "a table { type = \"box\", min = [...], max = [...] } or { type = \"sphere\", center = [...], radius = ... }".to_string(),
        e if e.starts_with("struct ") => "a table".to_string(),
        e => e.to_string(),
    };
    format!("must be {expected}, got {got}")
}

/// Rewrites serde's messages into a user's words: the nearest key or value is suggested, the
/// allowed values listed, and types named as a deck's author knows them.
fn humanise(msg: &str, key: &mut String) -> String {
    let names = backticked(msg);
    if msg.starts_with("unknown field") && !names.is_empty() {
        let given = names[0];
        // serde_path_to_error already ends the path with the unknown key; a hand-written
        // visitor's error does not
        if key.rsplit('.').next() != Some(given) {
            if !key.is_empty() {
                key.push('.');
            }
            key.push_str(given);
        }
        let valid = &names[1..];
        let mut out = "unknown key".to_string();
        if let Some(n) = nearest(given, valid.iter().copied()) {
            out += &format!("; did you mean `{n}`?");
        }
        if !valid.is_empty() {
            out += &format!(" (valid keys: {})", valid.join(", "));
        }
        out
    } else if msg.starts_with("unknown variant") && !names.is_empty() {
        let given = names[0];
        let valid = &names[1..];
        let mut out = format!("unknown value \"{given}\"");
        if let Some(n) = nearest(given, valid.iter().copied()) {
            out += &format!("; did you mean \"{n}\"?");
        }
        out += &format!(" (allowed: {})", quoted_list(valid));
        out
    } else if msg.starts_with("missing field") && !names.is_empty() {
        let top = key.is_empty();
        if !top {
            key.push('.');
        }
        key.push_str(names[0]);
        match names[0] {
            "materials" | "bodies" if top => {
                format!("at least one [[{}]] entry is required", names[0])
            }
            table if top => format!("the [{table}] table is required but missing"),
            _ => "is required but missing".to_string(),
        }
    } else if let Some(rest) = msg
        .strip_prefix("invalid type: ")
        .or_else(|| msg.strip_prefix("invalid value: "))
    {
        match rest.trim().rsplit_once(", expected ") {
            Some((got, expected)) => type_message(key, got, expected),
            None => msg.trim().to_string(),
        }
    } else if msg.starts_with("wanted string or table") {
        // toml's word for a number or list where a name in quotes belongs
        match allowed_values(key) {
            Some(v) => format!("must be one of {} (in quotes)", quoted_list(&v)),
            None => "must be a string in quotes".to_string(),
        }
    } else if msg.starts_with("data did not match any variant of untagged enum Component") {
        "must be a number or an expression in quotes (in x, y, z, t)".to_string()
    } else {
        msg.trim().to_string()
    }
}

impl Deck {
    /// Whether material enters or leaves through the grid's faces (an outflow face or an
    /// Whether a rigid body moves freely (its state goes into the checkpoint).
    pub fn has_free_bodies(&self) -> bool {
        self.rigid_bodies
            .iter()
            .any(|b| b.motion == RigidMotion::Free)
    }

    /// The optional particle fields the deck's materials need
    /// ([`crate::material::stored`]): F only for a neo-Hookean solid, tau only where some
    /// stress is not a function of the rate alone.
    pub fn stored_fields(&self) -> crate::particles::Stored {
        let materials: Vec<_> = self
            .materials
            .iter()
            .map(crate::material::MaterialDeck::params)
            .collect();
        crate::material::stored(&materials)
    }

    /// Whether material leaves or enters through the grid's faces (an outflow face or an
    /// inflow): series.csv then has the mass balance's columns.
    pub fn has_open_flow(&self) -> bool {
        !self.inflows.is_empty()
            || self
                .grid
                .boundary
                .faces()
                .iter()
                .any(|f| f.as_ref().map(|f| f.kind()) == Some(BoundaryKind::Outflow))
    }

    /// Whether a run of this validated deck takes the implicit viscous solve: asked for (the
    /// projection's default) and some material it takes is viscous
    /// (an inviscid fluid's solve would change nothing).
    pub fn viscous_solve(&self) -> bool {
        let materials: Vec<_> = self.materials.iter().map(MaterialDeck::params).collect();
        self.simulation.viscosity == Some(ViscosityTreatment::Implicit)
            && crate::viscosity::any_viscous(&materials)
    }

    /// The region of `bodies[b]` of a validated deck (its mesh file is read again).
    pub fn body_solid(&self, b: usize) -> Result<crate::geometry::Solid, DeckError> {
        self.bodies[b]
            .shape
            .solid(self.simulation.dimension)
            .map_err(|e| DeckError {
                file: String::new(),
                key: format!("bodies[{b}].shape{}", e.key),
                line_col: None,
                message: e.message,
            })
    }

    /// Reads and validates a deck file. `file` is used in messages as the user named it.
    pub fn load(path: &Path) -> Result<Deck, DeckError> {
        let file = path.display().to_string();
        let src = std::fs::read_to_string(path).map_err(|e| DeckError {
            file: file.clone(),
            key: "(file)".into(),
            line_col: None,
            message: format!("cannot read the deck: {e}"),
        })?;
        let mut deck = Deck::parse(&src, &file)?;
        deck.validate(&file)?;
        if deck.output.directory.is_empty() {
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "run".into());
            deck.output.directory = format!("out/{stem}");
        }
        Ok(deck)
    }

    /// Parses TOML text into a deck (types only; see [`Deck::validate`]).
    pub fn parse(src: &str, file: &str) -> Result<Deck, DeckError> {
        let de = toml::Deserializer::parse(src).map_err(|e| {
            let mut message = e.message().trim().to_string();
            if message == "duplicate key" {
                // toml does not say which: it is the name where the error points
                let name: String = e
                    .span()
                    .and_then(|s| src.get(s.start..))
                    .unwrap_or("")
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || matches!(c, '_' | '-' | '.'))
                    .collect();
                if !name.is_empty() {
                    message = format!("duplicate key: `{name}` is given twice");
                }
            }
            DeckError {
                file: file.to_string(),
                key: "(syntax)".into(),
                line_col: e.span().map(|s| line_col(src, s.start)),
                message,
            }
        })?;
        serde_path_to_error::deserialize(de).map_err(|e| {
            let mut key = e.path().to_string();
            if key == "." {
                key.clear();
            }
            let inner = e.inner();
            let message = humanise(inner.message(), &mut key);
            if key.is_empty() {
                key = "(deck)".into();
            }
            DeckError {
                file: file.to_string(),
                key,
                line_col: inner.span().map(|s| line_col(src, s.start)),
                message,
            }
        })
    }

    /// Checks what the types cannot and fills in every default.
    pub fn validate(&mut self, file: &str) -> Result<(), DeckError> {
        let c = Check { file };
        crate::about::AboutDeck::check(&self.about, &c)?;
        self.check_simulation(&c)?;
        self.fill_pressure_defaults(&c)?;
        self.check_grid(&c)?;
        // the preconditioner's default follows the grid's size: written into the run's deck
        // (run.toml), and compared as such on a resume
        if self.pressure.preconditioner.is_none() {
            let cells = self.grid.cells().iter().product();
            self.pressure.preconditioner = Some(self.pressure.preconditioner(cells));
        }
        self.check_pressure(&c)?;
        MaterialDeck::check_all(
            &self.materials,
            self.simulation.scheme == Scheme::Explicit,
            &c,
        )?;
        self.check_friction(&c)?;
        self.check_cells_hold_solids(&c)?;
        self.check_bodies(&c)?;
        let solids = self.check_rigid_bodies(&c)?;
        let rigid: Vec<_> = self
            .rigid_bodies
            .iter()
            .map(|r| r.name.as_str())
            .zip(solids)
            .collect();
        InflowDeck::check_all(&self.inflows, &self.frame(), &rigid, &c)?;
        DampingZoneDeck::check_all(&self.damping_zones, &self.frame(), &c)?;
        self.check_output(&c)?;
        self.check_time_step(&c)?;
        self.check_inflow_room(&c)?;
        Ok(())
    }

    /// The `[simulation]` table: dimension, times, gravity, transfer and the scheme's defaults.
    fn check_simulation(&mut self, c: &Check) -> Result<(), DeckError> {
        let s = &mut self.simulation;
        let dim = s.dimension;
        if dim != 2 && dim != 3 {
            return Err(c.err("simulation.dimension", format!("must be 2 or 3, got {dim}")));
        }
        c.positive("simulation.end_time", s.end_time)?;
        if let Some(dt) = s.dt {
            c.positive("simulation.dt", dt)?;
            if s.cfl.is_some() {
                return Err(c.err(
                    "simulation.cfl",
                    "give either a fixed dt or an adaptive cfl, not both",
                ));
            }
        } else {
            // neither key: the adaptive step at its default Courant number, written into the
            // run's deck (run.toml) like every default
            let cfl = *s.cfl.get_or_insert(DEFAULT_CFL);
            if !(cfl > 0.0 && cfl <= 1.0) {
                return Err(c.err("simulation.cfl", format!("must be in (0, 1], got {cfl}")));
            }
        }
        if let Some(m) = s.max_dt {
            c.positive("simulation.max_dt", m)?;
        }
        s.land_on_frames.get_or_insert(s.scheme == Scheme::Explicit);
        if s.gravity.is_empty() {
            let mut g = vec![0.0; dim];
            g[dim - 1] = -9.81;
            s.gravity = VectorField::constant_from(&g);
        }
        c.field("simulation.gravity", &s.gravity, dim)?;
        if !(0.0..=1.0).contains(&s.flip_ratio) {
            return Err(c.err(
                "simulation.flip_ratio",
                format!("must be in [0, 1], got {}", s.flip_ratio),
            ));
        }
        c.non_negative("simulation.damping", s.damping)?;
        // APIC for the projection's fluids; FLIP for the explicit scheme, whose APIC with
        // linear shapes is unstable at free surfaces, and for solids, whose waves APIC's lagged
        // affine matrix lets grow under the musl remap (the command's `check::warnings`)
        if s.transfer.is_none() {
            let solid = self.materials.iter().any(MaterialDeck::is_solid);
            s.transfer = Some(if s.scheme == Scheme::Projection && !solid {
                Transfer::Apic
            } else {
                Transfer::Flip
            });
        }
        if let Some([lo, hi]) = s.volume_limits {
            if !(lo > 0.0 && lo < 1.0 && hi > 1.0 && hi.is_finite()) {
                return Err(c.err(
                "simulation.volume_limits",
                format!("must be [min, max] with 0 < min < 1 < max (bounds on a particle's volume ratio J = V / V0), got [{lo}, {hi}]"),
            ));
            }
        }
        let implicit = *s.viscosity.get_or_insert(match s.scheme {
            Scheme::Projection => ViscosityTreatment::Implicit,
            Scheme::Explicit => ViscosityTreatment::Explicit,
        }) == ViscosityTreatment::Implicit;
        if implicit && s.scheme == Scheme::Explicit {
            return Err(c.err(
                "simulation.viscosity",
                "\"implicit\" is for scheme = \"projection\": the explicit scheme's step is held far below the viscous limit by the speed of sound; remove the key or set it to \"explicit\"",
            ));
        }
        if !(s.viscosity_tolerance > 0.0 && s.viscosity_tolerance < 1.0) {
            return Err(c.err(
                "simulation.viscosity_tolerance",
                format!(
                    "must be in (0, 1) (a relative residual), got {}",
                    s.viscosity_tolerance
                ),
            ));
        }
        if s.viscosity_max_iterations == 0 {
            return Err(c.err("simulation.viscosity_max_iterations", "must be at least 1"));
        }
        if implicit && self.materials.len() > 64 {
            return Err(c.err(
                "simulation.viscosity",
                format!("\"implicit\" takes at most 64 materials, the deck has {}; merge materials or set it to \"explicit\"", self.materials.len()),
            ));
        }
        if s.volumetric_averaging != VolumetricAveraging::None && s.scheme != Scheme::Explicit {
            return Err(c.err(
                "simulation.volumetric_averaging",
                "is for scheme = \"explicit\" (against the locking of its equation of state); the projection's pressure already keeps one volume constraint per node: remove the key or set it to \"none\"",
            ));
        }
        Ok(())
    }

    /// The `[pressure]` defaults that depend on the scheme and the materials, and what one pressure per cell needs.
    fn fill_pressure_defaults(&mut self, c: &Check) -> Result<(), DeckError> {
        if self.pressure.free_surface.is_none() {
            self.pressure.free_surface = Some(FreeSurface::LevelSet);
        }
        // a fluid's particles packed to rest density from their positions, which also holds
        // their volumes: with a free surface (the dam break's interior fill at p99 1.02
        // where the correction of J alone lets it reach 2.75, docs/method.md) and where the
        // fluid fills its container (the container keeps the volume, but the particles bunch
        // and open gaps as it stirs; the cavity's and the vortex's velocities then follow the
        // reference more closely); a solid's J is its deformation (the strip footing's nodal
        // run threw a particle out of its heave with the correction)
        // the explicit scheme's J is its equation of state: "positions" would move the pressure
        // itself; it packs the particles with "particles", and does nothing by default
        let explicit = self.simulation.scheme == Scheme::Explicit;
        if explicit && self.pressure.density_correction == Some(DensityCorrection::Positions) {
            return Err(c.err(
                "pressure.density_correction",
                "\"positions\" applies to the projection: under the explicit scheme J is the equation of state's measure of the pressure, which a correction of J would overwrite; use \"particles\" (the particles packed to rest density, J left as it is) or \"none\"",
            ));
        }
        if self.pressure.density_correction.is_none() {
            let fluid = self.pressure.unknowns == PressureUnknowns::Nodes
                && !self.materials.iter().any(MaterialDeck::is_solid);
            // with a free surface, the packing where it is known to hold: linear shapes (with
            // the quadratic B-spline it moves a pool at rest, and GIMP has no pushes) and no
            // free rigid body (a floating box sat 3 % deep and bodies resting on the floor
            // stalled the pressure solve with it, causes not found: docs/method.md); the
            // correction of J alone elsewhere
            let packs = self.simulation.shape_function == ShapeFunction::Linear
                && !self
                    .rigid_bodies
                    .iter()
                    .any(|b| b.motion == crate::rigid::RigidMotion::Free);
            self.pressure.density_correction = Some(match self.pressure.free_surface {
                _ if explicit || !fluid => DensityCorrection::None,
                Some(FreeSurface::None) => DensityCorrection::Particles,
                _ if packs => DensityCorrection::Particles,
                _ => DensityCorrection::Positions,
            });
        }
        let vc = self.pressure.volume_correction;
        if !(0.0..1.0).contains(&vc) {
            return Err(c.err(
                "pressure.volume_correction",
                format!(
                    "must be >= 0 and < 1 (a fraction of the drift given back per step), got {vc}"
                ),
            ));
        }

        if self.pressure.unknowns == PressureUnknowns::Cells {
            let p = &self.pressure;
            let why = "with pressure.unknowns = \"cells\"";
            if p.beta != 0.0 {
                return Err(c.err(
                    "pressure.beta",
                    format!("must be 0 {why} (the cell pressure is solved whole, not as an increment), got {}", p.beta),
                ));
            }
            if vc != 0.0 {
                return Err(c.err(
                    "pressure.volume_correction",
                    format!("must be 0 {why}: each cell's divergence is already held at zero"),
                ));
            }
            if self.simulation.scheme == Scheme::Projection
                && self.simulation.stress_update == StressUpdate::Musl
            {
                return Err(c.err(
                    "simulation.stress_update",
                    format!("must be \"usl\" {why}: the cells hold the volume of v^(n+1), and the musl remap smooths that velocity before the strain rate is taken, so the volume drifts again (an elastic column lost 1e-4 of its volume in 0.4 s with linear shapes and 2e-3 with bspline2, sinking all the while)"),
                ));
            }
            if p.solver == Solver::Pcg && p.preconditioner == Some(Preconditioner::Multigrid) {
                return Err(c.err(
                    "pressure.preconditioner",
                    format!("must be \"jacobi\" or \"ic0\" {why} (the multigrid is built for the nodal Laplacian), or use solver = \"direct\""),
                ));
            }
        }
        Ok(())
    }

    /// `grid.boundary.friction`, filled in (after the materials: the law needs their fluid).
    fn check_friction(&mut self, c: &Check) -> Result<(), DeckError> {
        let dim = self.simulation.dimension;
        let b = &mut self.grid.boundary;
        let friction = *b.friction.get_or_insert(WallFriction::None);
        let slip = b.faces()[..2 * dim]
            .iter()
            .filter(|f| f.as_ref().map_or(BoundaryKind::Slip, |f| f.kind()) == BoundaryKind::Slip)
            .count();
        let materials: Vec<_> = self
            .materials
            .iter()
            .map(|m| (m.name.as_str(), m.model, m.density, m.viscosity))
            .collect();
        friction.check(c, &materials, slip)
    }

    /// `grid.boundary.contact`, filled in: separating under the nodal projection, whose last
    /// pressure tells a wall that pushes from one the water leaves. The cell projection's
    /// constraint is built for walls held both ways, and the explicit scheme, which decides by
    /// its ringing velocity alone, let a column at rest move (docs/method.md).
    fn check_contact(&mut self, c: &Check) -> Result<(), DeckError> {
        let projection = self.simulation.scheme == Scheme::Projection;
        let cells = projection && self.pressure.unknowns == PressureUnknowns::Cells;
        let contact = &mut self.grid.boundary.contact;
        match contact {
            Some(WallContact::Separating) if cells => Err(c.err(
                "grid.boundary.contact",
                "\"separating\" is not built for pressure.unknowns = \"cells\" yet: use \"bonded\", or unknowns = \"nodes\"",
            )),
            Some(_) => Ok(()),
            None => {
                *contact = Some(if projection && !cells {
                    WallContact::Separating
                } else {
                    WallContact::Bonded
                });
                Ok(())
            }
        }
    }

    /// The `[grid]` table: origin, size, cell size and the boundary faces.
    fn check_grid(&mut self, c: &Check) -> Result<(), DeckError> {
        let dim = self.simulation.dimension;
        let g = &mut self.grid;
        if g.origin.is_empty() {
            g.origin = vec![0.0; dim];
        }
        c.vector("grid.origin", &g.origin, dim)?;
        c.vector("grid.size", &g.size, dim)?;
        c.positive("grid.cell_size", g.cell_size)?;
        // a tank is given as it is: a size that is not a whole number of cells is covered by
        // the next whole number, and its upper wall stands there (`check` says where)
        g.rounded.clear();
        for d in 0..g.size.len() {
            let l = g.size[d];
            c.positive(&format!("grid.size[{d}]"), l)?;
            let n = l / g.cell_size;
            if (n - n.round()).abs() > 1e-6 * n.max(1.0) || n.round() < 1.0 {
                g.rounded.push((d, l));
                g.size[d] = n.ceil().max(1.0) * g.cell_size;
            }
        }
        // every node and particle index is a u32: refuse a grid that cannot be numbered (a
        // cell_size typed in the wrong unit would otherwise hang in setting up the particles)
        let cells: Vec<f64> = g.size.iter().map(|l| (l / g.cell_size).round()).collect();
        let nodes: f64 = cells
            .iter()
            .map(|n| n + 1.0 + 2.0 * crate::shape::PAD as f64)
            .product();
        if nodes >= u32::MAX as f64 {
            return Err(c.err(
                "grid.cell_size",
                format!(
                    "gives a grid of {} cells, too many: pmpm numbers at most {} grid nodes; use a larger cell_size",
                    cells
                        .iter()
                        .map(|n| if *n < 1e12 { format!("{n:.0}") } else { format!("{n:.1e}") })
                        .collect::<Vec<_>>()
                        .join(" x "),
                    u32::MAX
                ),
            ));
        }
        for (f, spec) in g.boundary.faces_mut().into_iter().enumerate() {
            let key = format!("grid.boundary.{}", FACE_NAMES[f]);
            if f >= 2 * dim {
                if spec.is_some() {
                    return Err(c.err(key, format!("there is no such face in {dim}D")));
                }
                continue;
            }
            let spec = spec.get_or_insert(BoundarySpec::Kind(BoundaryKind::Slip));
            match spec.kind() {
                BoundaryKind::Periodic if spec.velocity().is_some() => {
                    return Err(c.err(
                        format!("{key}.velocity"),
                        "a periodic face imposes nothing: a velocity needs \"slip\" or \"no_slip\"",
                    ))
                }
                BoundaryKind::Symmetry if spec.velocity().is_some() => {
                    return Err(c.err(
                        format!("{key}.velocity"),
                        "a symmetry plane stands still: a moving wall is \"slip\" or \"no_slip\"",
                    ))
                }
                BoundaryKind::Open | BoundaryKind::Outflow if spec.velocity().is_some() => {
                    return Err(c.err(
                        format!("{key}.velocity"),
                        "an open or outflow face imposes nothing: a velocity needs \"slip\" or \"no_slip\" (an inflow is an [[inflows]] entry)",
                    ))
                }
                _ => {}
            }
            if let Some(v) = spec.velocity() {
                c.field(&format!("{key}.velocity"), v, dim)?;
            }
        }

        self.check_contact(c)?;
        let g = &self.grid;
        let faces = g.boundary.faces();
        for d in 0..dim {
            let lo = faces[2 * d].as_ref().map(|f| f.kind());
            let hi = faces[2 * d + 1].as_ref().map(|f| f.kind());
            let periodic = |k: Option<BoundaryKind>| k == Some(BoundaryKind::Periodic);
            if periodic(lo) != periodic(hi) {
                let (set, other) = if periodic(lo) {
                    (2 * d, 2 * d + 1)
                } else {
                    (2 * d + 1, 2 * d)
                };
                return Err(c.err(
                    format!("grid.boundary.{}", FACE_NAMES[other]),
                    format!(
                        "must be \"periodic\" too: {} is periodic, and a periodic axis needs both faces",
                        FACE_NAMES[set]
                    ),
                ));
            }
            if periodic(lo)
                && self.simulation.scheme == Scheme::Projection
                && self.pressure.unknowns == PressureUnknowns::Cells
            {
                return Err(c.err(
                    format!("grid.boundary.{}", FACE_NAMES[2 * d]),
                    "a periodic axis is not built for pressure.unknowns = \"cells\" yet: use \"nodes\"",
                ));
            }
            let n = (g.size[d] / g.cell_size).round() as usize;
            if periodic(lo) && n < 2 * crate::shape::PAD + 1 {
                return Err(c.err(
                    format!("grid.size[{d}]"),
                    format!(
                        "a periodic axis needs at least {} cells, got {n}",
                        2 * crate::shape::PAD + 1
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The `[pressure]` table's numbers and the keys that do not go together.
    fn check_pressure(&self, c: &Check) -> Result<(), DeckError> {
        let p = &self.pressure;
        c.positive("pressure.tolerance", p.tolerance)?;
        if p.max_iterations == 0 {
            return Err(c.err("pressure.max_iterations", "must be > 0, got 0"));
        }
        if p.passes == 0 {
            return Err(c.err(
                "pressure.passes",
                "must be >= 1 (1: one solve per step), got 0",
            ));
        }
        if p.rigid_faces == Some(RigidFaces::Cut)
            && self.simulation.scheme == Scheme::Projection
            && !p.cut_cells_apply(self.simulation.shape_function)
        {
            return Err(c.err(
                "pressure.rigid_faces",
                format!(
                    "\"cut\" needs shape_function = \"linear\" or \"gimp\", free_surface = \"level_set\" and unknowns = \"nodes\" (this deck has {}, {}, {}); use \"nodes\" or leave the key out",
                    spelling(&self.simulation.shape_function),
                    spelling(&p.free_surface.unwrap_or_default()),
                    spelling(&p.unknowns)
                ),
            ));
        }
        if !(p.volume_fraction_tolerance > 0.0 && p.volume_fraction_tolerance < 1.0) {
            return Err(c.err(
                "pressure.volume_fraction_tolerance",
                format!("must be in (0, 1), got {}", p.volume_fraction_tolerance),
            ));
        }
        if !(0.0..=1.0).contains(&p.beta) {
            return Err(c.err(
                "pressure.beta",
                format!("must be in [0, 1], got {}", p.beta),
            ));
        }
        Ok(())
    }

    /// With the projection, `pressure.unknowns = "cells"` takes solids only.
    fn check_cells_hold_solids(&self, c: &Check) -> Result<(), DeckError> {
        if self.simulation.scheme == Scheme::Explicit
            || self.pressure.unknowns != PressureUnknowns::Cells
        {
            return Ok(());
        }
        for (i, m) in self.materials.iter().enumerate() {
            if m.params().wave_speed(false) <= 0.0 {
                return Err(c.err(
                    format!("materials[{i}].model"),
                    format!(
                        "\"{}\" is a fluid, and pressure.unknowns = \"cells\" is for solids: one pressure per cell leaves velocity modes that only a shear stiffness holds (a water column at rest stirs up to 0.07 m/s in 2 s); use unknowns = \"nodes\"",
                        m.name
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The `[[bodies]]`: shapes inside the grid, particles per cell, materials and velocities.
    fn check_bodies(&mut self, c: &Check) -> Result<(), DeckError> {
        let dim = self.simulation.dimension;
        if self.bodies.is_empty() {
            return Err(c.err("bodies", "at least one [[bodies]] entry is required"));
        }
        let frame = frame(&self.simulation, &self.grid, &self.materials);
        let (lo, hi) = (&frame.lo, &frame.hi);
        let mut lattice = 0.0;
        for (i, b) in self.bodies.iter_mut().enumerate() {
            let k = format!("bodies[{i}]");
            frame.material(&format!("{k}.material"), &b.material, c)?;
            b.shape
                .resolve_files(Path::new(c.file).parent().unwrap_or(Path::new("")));
            let solid = c.solid(&format!("{k}.shape"), &b.shape, dim)?;
            for m in solid.mesh_sources() {
                self.mesh_files.insert(m.path.clone(), m.digest());
            }
            self.mesh_triangles += solid.meshes().map(|m| m.triangles).sum::<usize>();
            let (mn, mx) = solid.bounds();
            let tol = 1e-9 * self.grid.cell_size;
            // a box or a sphere past the grid is a typing slip; a mesh, a half-space or a
            // rotated shape may reach past it on purpose, and is cut off there
            let plain = matches!(b.shape.kind, ShapeKind::Box | ShapeKind::Sphere)
                && b.shape.scale.is_none()
                && b.shape.rotate.is_none()
                && b.shape.translate.is_none();
            if let Some(d) =
                (0..dim).find(|&d| plain && (mn[d] < lo[d] - tol || mx[d] > hi[d] + tol))
            {
                return Err(c.err(
                    format!("{k}.shape"),
                    format!(
                        "extends outside the grid along {}: the body spans [{}, {}], the grid [{}, {}]",
                        AXES[d], mn[d], mx[d], lo[d], hi[d]
                    ),
                ));
            }
            let (mn, mx): (Vec<f64>, Vec<f64>) = (
                (0..dim).map(|d| mn[d].max(lo[d])).collect(),
                (0..dim).map(|d| mx[d].min(hi[d])).collect(),
            );
            if let Some(d) = (0..dim).find(|&d| mx[d] <= mn[d]) {
                return Err(c.err(
                    format!("{k}.shape"),
                    format!("lies outside the grid along {}", AXES[d]),
                ));
            }
            if !(1..=8).contains(&b.particles_per_cell) {
                return Err(c.err(
                    format!("{k}.particles_per_cell"),
                    format!("must be between 1 and 8, got {}", b.particles_per_cell),
                ));
            }
            // the lattice positions over the body's bounding box that are tried
            let spacing = self.grid.cell_size / b.particles_per_cell as f64;
            lattice += (0..dim)
                .map(|d| ((mx[d] - mn[d]) / spacing).ceil() + 2.0)
                .product::<f64>();
            if lattice >= u32::MAX as f64 {
                return Err(c.err(
                    k.clone(),
                    format!(
                        "the bodies would hold up to {lattice:.3e} particles, too many: pmpm numbers at most {} particles; use a larger cell_size or fewer particles_per_cell",
                        u32::MAX
                    ),
                ));
            }
            if b.velocity.is_empty() {
                b.velocity = VectorField::constant_from(&vec![0.0; dim]);
            }
            c.field(&format!("{k}.velocity"), &b.velocity, dim)?;
        }
        Ok(())
    }

    /// The `[[rigid_bodies]]` ([`RigidBodyDeck::check_all`]), and the mesh files they read.
    /// Gives each body's region.
    fn check_rigid_bodies(&mut self, c: &Check) -> Result<Vec<crate::geometry::Solid>, DeckError> {
        let dir = Path::new(c.file).parent().unwrap_or(Path::new(""));
        let frame = frame(&self.simulation, &self.grid, &self.materials);
        let solids = RigidBodyDeck::check_all(&mut self.rigid_bodies, dir, &frame, c)?;
        for solid in &solids {
            for m in solid.mesh_sources() {
                self.mesh_files.insert(m.path.clone(), m.digest());
            }
            self.mesh_triangles += solid.meshes().map(|m| m.triangles).sum::<usize>();
        }
        Ok(solids)
    }

    /// The `[output]` table: intervals, formats and probes.
    fn check_output(&mut self, c: &Check) -> Result<(), DeckError> {
        GaugeDeck::check_all(
            &self.output.gauges,
            self.output.gauge_interval,
            &self.frame(),
            c,
        )?;
        let interval = *self
            .output
            .interval
            .get_or_insert(self.simulation.end_time / 100.0);
        let o = &self.output;
        c.positive("output.interval", interval)?;
        let end = self.simulation.end_time;
        // a frame or a checkpoint per step of a runaway deck fills the disk and never ends
        let count = |key: &str, what: &str, every: f64| -> Result<(), DeckError> {
            let n = end / every;
            if n > MAX_OUTPUTS {
                return Err(c.err(
                    key,
                    format!(
                        "gives {n:.3e} {what} over end_time = {end:.6e} s, more than \
                         {MAX_OUTPUTS:.0e}: raise it to at least {:.3e} s",
                        end / MAX_OUTPUTS
                    ),
                ));
            }
            Ok(())
        };
        count("output.interval", "frames", interval)?;
        if let Some(ci) = o.checkpoint_interval {
            c.positive("output.checkpoint_interval", ci)?;
            count("output.checkpoint_interval", "checkpoints", ci)?;
        }
        ProbeDeck::check_all(&o.probes, &self.frame(), c)?;
        Ok(())
    }

    /// A material the implicit viscous solve takes must keep its inertia above round-off next
    /// to its viscous stiffness over the longest step the run can take (a fixed dt, else an
    /// output interval): past 2 D mu dt / (rho h^2) = 1 / eps the solve's matrix is singular
    /// in double precision (it does not converge, and the run stopped as if it blew up).
    fn check_implicit_viscosity(&self, c: &Check) -> Result<(), DeckError> {
        let s = &self.simulation;
        let dt =
            s.dt.unwrap_or_else(|| self.output.interval.unwrap_or(s.end_time).min(s.end_time));
        let (limit, i) = self.lifted_viscous_limit();
        let stiffness = dt / limit;
        if stiffness * f64::EPSILON <= 1.0 {
            return Ok(());
        }
        let m = &self.materials[i];
        Err(c.err(
            format!("materials[{i}].{}", m.viscosity_key()),
            format!(
                "\"{}\" is too viscous for the implicit viscous solve: its largest viscosity mu = {} Pa s gives 2 D mu dt / (rho h^2) = {} over a step of up to {} s, past 1 / eps = {:.1e}, where the material's inertia is lost to round-off and the solve is singular; lower it (a rigid body models a solid that does not deform)",
                m.name,
                crate::limits::short(crate::material::Constitutive::max_viscosity(&m.params().law)),
                crate::limits::short(stiffness),
                crate::limits::short(dt),
                1.0 / f64::EPSILON
            ),
        ))
    }

    /// A fixed `simulation.dt` against the explicit limits.
    fn check_time_step(&self, c: &Check) -> Result<(), DeckError> {
        self.check_implicit_viscosity(c)?;
        let explicit = self.simulation.scheme == Scheme::Explicit;
        if let Some(dt) = self.simulation.dt {
            let (wave, viscous) = self.dt_limits();
            if dt > wave {
                return Err(c.err(
                    "simulation.dt",
                    format!(
                        "{dt} s is above the explicit stability limit h / c = {wave:.3e} s \
                         (h = {}, fastest {} c = {:.4} m/s); lower dt or use cfl",
                        self.grid.cell_size,
                        if explicit {
                            "sound speed"
                        } else {
                            "shear wave speed sqrt(G / rho)"
                        },
                        self.max_wave_speed()
                    ),
                ));
            }
            if dt > viscous.0 {
                let m = &self.materials[viscous.1];
                return Err(c.err(
                    "simulation.dt",
                    format!(
                        "{dt} s is above the viscous stability limit h^2 rho / (2 D mu) = \
                         {:.3e} s of material \"{}\" (largest viscosity mu = {:.4e} Pa s); \
                         lower dt or use cfl",
                        viscous.0,
                        m.name,
                        crate::material::Constitutive::max_viscosity(&m.params().law)
                    ),
                ));
            }
        }
        Ok(())
    }

    /// What the sections' checks and builds read of the rest of the deck
    /// ([`crate::keys::Frame`]).
    pub(crate) fn frame(&self) -> Frame<'_> {
        frame(&self.simulation, &self.grid, &self.materials)
    }

    /// The gauges the run reads, of a validated deck.
    pub fn gauges(&self) -> Vec<crate::gauges::Gauge> {
        crate::gauges::Gauge::build(&self.output.gauges, &self.frame())
    }

    /// The grid's lower and upper corners.
    pub fn domain(&self) -> (Vec<f64>, Vec<f64>) {
        let g = &self.grid;
        let hi = g.origin.iter().zip(&g.size).map(|(o, s)| o + s).collect();
        (g.origin.clone(), hi)
    }

    /// Rigid body `b`'s shape on this deck's grid ([`RigidBodyDeck::shape_on_grid`]); None
    /// when it holds no volume there or is not a valid shape.
    pub fn rigid_shape(&self, b: &RigidBodyDeck) -> Option<crate::rigid::Shaped> {
        let (lo, hi) = self.domain();
        let (dim, h) = (self.simulation.dimension, self.grid.cell_size);
        b.shape_on_grid(dim, h, (&lo, &hi), self.simulation.end_time)
    }

    /// Largest wave speed the scheme integrates explicitly, over the materials: the sound
    /// speed sqrt((K + 4 G / 3) / rho) with `explicit`, the shear wave sqrt(G / rho) with the
    /// projection.
    pub fn max_wave_speed(&self) -> f64 {
        let explicit = self.simulation.scheme == Scheme::Explicit;
        self.materials
            .iter()
            .map(|m| m.params().wave_speed(explicit))
            .fold(0.0, f64::max)
    }

    /// Step limits at rest: h / c (Courant number 1, c from [`Deck::max_wave_speed`]), and the
    /// explicit viscous update's with the material that sets it.
    pub fn dt_limits(&self) -> (f64, (f64, usize)) {
        let h = self.grid.cell_size;
        let c = self.max_wave_speed();
        let wave = if c > 0.0 { h / c } else { f64::INFINITY };
        let viscous = self
            .materials
            .iter()
            .enumerate()
            .filter(|(_, m)| !self.implicit_viscosity(m))
            .map(|(i, m)| {
                let p = m.params();
                (p.viscous_dt_limit(h, self.simulation.dimension), i)
            })
            .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a });
        (wave, viscous)
    }

    /// Whether the implicit viscous solve takes material `m`'s stress, so that its viscous
    /// limit does not bound the step.
    pub fn implicit_viscosity(&self, m: &MaterialDeck) -> bool {
        self.simulation.viscosity == Some(ViscosityTreatment::Implicit)
            && crate::viscosity::is_implicit(&m.params().law)
    }

    /// The explicit viscous limit h^2 rho / (2 D mu) that the implicit solve lifts: the
    /// smallest over the materials it takes, and which (infinite without any).
    pub fn lifted_viscous_limit(&self) -> (f64, usize) {
        let h = self.grid.cell_size;
        self.materials
            .iter()
            .enumerate()
            .filter(|(_, m)| self.implicit_viscosity(m))
            .map(|(i, m)| (m.params().viscous_dt_limit(h, self.simulation.dimension), i))
            .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a })
    }

    /// The smaller of [`Deck::dt_limits`].
    pub fn dt_limit(&self) -> f64 {
        let (wave, viscous) = self.dt_limits();
        wave.min(viscous.0)
    }

    /// The deck as run, every default filled in, with the program's version.
    pub fn to_run_toml(&self) -> String {
        let mut deck = self.clone();
        deck.pmpm = Some(ProgramInfo {
            version: env!("CARGO_PKG_VERSION").to_string(),
        });
        let body =
            toml::to_string_pretty(&deck).unwrap_or_else(|e| format!("# not written: {e}\n"));
        format!("# The deck as run by pmpm, every default filled in.\n{body}")
    }
}

/// [`Deck::frame`] from the sections it reads (borrowed apart from the others).
fn frame<'a>(
    simulation: &SimulationDeck,
    grid: &GridDeck,
    materials: &'a [MaterialDeck],
) -> Frame<'a> {
    let faces = grid
        .boundary
        .faces()
        .map(|f| f.as_ref().map_or(BoundaryKind::Slip, |s| s.kind()).name());
    Frame {
        dim: simulation.dimension,
        lo: grid.origin.clone(),
        hi: grid
            .origin
            .iter()
            .zip(&grid.size)
            .map(|(o, s)| o + s)
            .collect(),
        cell_size: grid.cell_size,
        up: simulation.vertical_axis(),
        end_time: simulation.end_time,
        faces,
        materials: materials.iter().map(|m| m.name.as_str()).collect(),
    }
}
