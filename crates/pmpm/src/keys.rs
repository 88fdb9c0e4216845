//! The deck's checks' helpers: a validation error at a key path of one file, and the checks
//! each section's keys share (numbers, vectors, fields of expressions). A section's own checks
//! live beside its code and take a [`Check`]; the deck calls them in turn.

use crate::error::DeckError;
use crate::field::{Component, VectorField};

/// Small builder of validation errors against one file.
pub(crate) struct Check<'a> {
    /// The deck's file, for the messages.
    pub(crate) file: &'a str,
}

impl Check<'_> {
    /// An error at `key`.
    pub(crate) fn err(&self, key: impl Into<String>, message: impl Into<String>) -> DeckError {
        DeckError {
            file: self.file.to_string(),
            key: key.into(),
            line_col: None,
            message: message.into(),
        }
    }
    /// `v` is a finite number above 0.
    pub(crate) fn positive(&self, key: &str, v: f64) -> Result<(), DeckError> {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(self.err(key, format!("must be > 0, got {v}")))
        }
    }
    /// `v` is a finite number at least 0.
    pub(crate) fn non_negative(&self, key: &str, v: f64) -> Result<(), DeckError> {
        if v.is_finite() && v >= 0.0 {
            Ok(())
        } else {
            Err(self.err(key, format!("must be >= 0, got {v}")))
        }
    }
    /// A vector has `dim` components.
    pub(crate) fn components(&self, key: &str, n: usize, dim: usize) -> Result<(), DeckError> {
        if n == dim {
            return Ok(());
        }
        Err(self.err(
            key,
            format!("must have {dim} components (dimension = {dim}), got {n}"),
        ))
    }

    /// A vector field: `dim` components, finite numbers, expressions that parse.
    pub(crate) fn field(&self, key: &str, v: &VectorField, dim: usize) -> Result<(), DeckError> {
        self.components(key, v.len(), dim)?;
        for c in &v.0 {
            if let Component::Number(x) = c {
                if !x.is_finite() {
                    return Err(self.err(key, format!("components must be finite, got {x}")));
                }
            }
        }
        for (k, comp) in v.0.iter().enumerate() {
            // exmex reads `{name}` as a variable of any name, which the names check of
            // field.rs does not see (and then panics on)
            if let Component::Expression(text) = comp {
                if text.contains(['{', '}']) {
                    return Err(self.err(
                        key,
                        format!("bad expression: {key}[{k}] = \"{text}\": braces {{ }} are not allowed; use ( ) and the variables x, y, z, t"),
                    ));
                }
            }
        }
        v.compile()
            .map_err(|e| self.err(key, format!("bad expression: {key}{}", plain_exmex(&e))))?;
        // an expression without x, y, z or t is a number: it must be a finite one ("sqrt(-1)",
        // "1/0" would only show as a blow-up of the run)
        for (k, comp) in v.0.iter().enumerate() {
            if let Component::Expression(text) = comp {
                let one = VectorField(vec![comp.clone()]).compile().map_err(|e| {
                    self.err(key, format!("bad expression: {key}[{k}] = \"{text}\": {e}"))
                })?;
                if !one.is_constant() {
                    continue;
                }
                let x = one.eval::<1>(&crate::grid::Vector::<1>::zeros(), 0.0)[0];
                if !x.is_finite() {
                    return Err(self.err(
                        key,
                        format!("bad expression: {key}[{k}] = \"{text}\": gives {x}, not a finite number"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The name of entry `i` of a list whose names head CSV columns (gauges, probes, rigid
    /// bodies; `names` the list's, in order): non-empty, without commas, quotes or line
    /// breaks, and not that of an earlier entry.
    pub(crate) fn column_name<'n>(
        &self,
        key: &str,
        i: usize,
        names: impl Iterator<Item = &'n str>,
    ) -> Result<(), DeckError> {
        let all: Vec<&str> = names.collect();
        let name = all[i];
        if name.is_empty() || name.contains([',', '"', '\n']) {
            return Err(self.err(
                key,
                "must be non-empty, without commas or quotes (it heads CSV columns)",
            ));
        }
        if all[..i].contains(&name) {
            return Err(self.err(key, format!("\"{name}\" is used twice")));
        }
        Ok(())
    }

    /// A shape that builds (reading any mesh), errors at `key` and the keys below.
    pub(crate) fn solid(
        &self,
        key: &str,
        shape: &crate::geometry::ShapeDeck,
        dim: usize,
    ) -> Result<crate::geometry::Solid, DeckError> {
        shape
            .solid(dim)
            .map_err(|e| self.err(format!("{key}{}", e.key), e.message))
    }

    /// `v` has `dim` finite components.
    pub(crate) fn vector(&self, key: &str, v: &[f64], dim: usize) -> Result<(), DeckError> {
        self.components(key, v.len(), dim)?;
        if let Some(x) = v.iter().find(|x| !x.is_finite()) {
            return Err(self.err(key, format!("components must be finite, got {x}")));
        }
        Ok(())
    }
}

/// exmex's parse errors in plain words where they are written for its developers.
fn plain_exmex(msg: &str) -> String {
    // field.rs writes `[k] = "text": why`
    let split = msg.find("\": ").map(|i| (&msg[..i + 1], &msg[i + 3..]));
    match split {
        Some((head, why)) if why.contains("we always need one more node than op") => {
            format!("{head}: an operator or a function lacks a value, or two values have no operator between them")
        }
        Some((head, why)) if why.starts_with("wlog ") => format!("{head}: {}", &why[5..]),
        _ => msg.to_string(),
    }
}

/// A number in a message: as it is when short, else in scientific form with 3 digits (a
/// bulk modulus of 1e308 must not print 300 digits).
pub fn short(x: f64) -> String {
    let plain = format!("{x}");
    if plain.len() <= 12 {
        plain
    } else if x.abs() >= 1e6 || (x != 0.0 && x.abs() < 1e-4) {
        format!("{x:.3e}")
    } else {
        format!("{x:.6}")
    }
}

/// The names of the axes, as the deck writes them.
pub(crate) const AXES: [&str; 3] = ["x", "y", "z"];

/// Face names in the order axis 0 min, axis 0 max, axis 1 min, ...
pub const FACE_NAMES: [&str; 6] = ["x_min", "x_max", "y_min", "y_max", "z_min", "z_max"];

/// Other names a person may type for a key (left), and the key they mean (right).
const SYNONYMS: &[(&str, &str)] = &[
    ("rho", "density"),
    ("mu", "viscosity"),
    ("k", "bulk_modulus"),
    ("ppc", "particles_per_cell"),
    ("h", "cell_size"),
    ("dx", "cell_size"),
    ("g", "gravity"),
    ("courant", "cfl"),
    ("time_step", "dt"),
    ("timestep", "dt"),
    ("t_end", "end_time"),
    ("tend", "end_time"),
];

/// The valid name nearest to `given`, if it is near enough to be a likely typo: a known other
/// name for it, a name that `given` begins (`dens` for `density`), or one within a few edits.
pub fn nearest<'a>(given: &str, valid: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let valid: Vec<&str> = valid.into_iter().collect();
    let lower = given.to_lowercase();
    if let Some(&(_, to)) = SYNONYMS.iter().find(|(from, _)| *from == lower) {
        if let Some(v) = valid.iter().find(|v| **v == to) {
            return Some(v);
        }
    }
    if lower.len() >= 3 {
        if let Some(v) = valid
            .iter()
            .filter(|v| v.starts_with(&lower))
            .min_by_key(|v| v.len())
        {
            return Some(v);
        }
    }
    valid
        .iter()
        .map(|v| (strsim::damerau_levenshtein(&lower, v), *v))
        .filter(|(d, v)| *d <= 3.max(v.len() / 3) && *d < v.len().max(given.len()))
        .min_by_key(|(d, _)| *d)
        .map(|(_, v)| v)
}

/// What a section's check and build read of the rest of the deck: the grid's box and cell,
/// the run's dimension and vertical axis, each face's condition and the materials' names. The
/// deck makes one once its grid is checked and hands it to each section, so that a section's
/// module needs nothing of the deck's.
pub(crate) struct Frame<'a> {
    /// 2 or 3.
    pub(crate) dim: usize,
    /// The grid's lower corner.
    pub(crate) lo: Vec<f64>,
    /// The grid's upper corner.
    pub(crate) hi: Vec<f64>,
    /// The grid's cell size h.
    pub(crate) cell_size: f64,
    /// The vertical axis (against gravity).
    pub(crate) up: usize,
    /// The run's end time (s).
    pub(crate) end_time: f64,
    /// Each face's condition as the deck names it ("slip" where it gives none), in
    /// [`FACE_NAMES`] order.
    pub(crate) faces: [&'static str; 6],
    /// The `[[materials]]`' names, in order.
    pub(crate) materials: Vec<&'a str>,
}

impl Frame<'_> {
    /// The index in [`FACE_NAMES`] of a face named at `key`, one of this run's dimension.
    pub(crate) fn face(&self, key: &str, name: &str, c: &Check) -> Result<usize, DeckError> {
        let names = &FACE_NAMES[..2 * self.dim];
        names.iter().position(|n| *n == name).ok_or_else(|| {
            c.err(
                key,
                format!(
                    "must be one of {} (dimension = {}), got \"{name}\"",
                    names.join(", "),
                    self.dim
                ),
            )
        })
    }

    /// Whether face `f` is a wall (slip or no-slip) that holds the material.
    pub(crate) fn is_wall(&self, f: usize) -> bool {
        matches!(self.faces[f], "slip" | "no_slip")
    }

    /// A material named at `key` (`...material`) is one of the deck's, with the nearest name
    /// as a hint.
    pub(crate) fn material(&self, key: &str, name: &str, c: &Check) -> Result<(), DeckError> {
        if self.materials.contains(&name) {
            return Ok(());
        }
        let mut msg = format!("no material named \"{name}\"");
        if let Some(n) = nearest(name, self.materials.iter().copied()) {
            msg += &format!("; did you mean \"{n}\"?");
        }
        msg += &format!(
            " (defined: {})",
            self.materials
                .iter()
                .map(|m| format!("\"{m}\""))
                .collect::<Vec<_>>()
                .join(", ")
        );
        Err(c.err(key, msg))
    }
}

/// A point as `0.1, 0.2` in a message.
pub(crate) fn point(x: &[f64]) -> String {
    x.iter().map(|c| short(*c)).collect::<Vec<_>>().join(", ")
}
