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
