//! The `[[rigid_bodies]]` deck section: each body's shape, motion and contact, as the deck
//! gives them, their checks, and each body's shape on the grid.

use super::{Reach, RigidSides, Shaped};
use crate::error::DeckError;
use crate::field::{Component, VectorField};
use crate::geometry::{ShapeDeck, Solid};
use crate::keys::{point, Check, Frame, AXES};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// `[[rigid_bodies]]`: a body that moves through the material along a prescribed path (a
/// footing, a gate, a paddle, a mixer's blade) or freely under the material's push and gravity
/// (a floating box); its nodes take its velocity and the force on it is written to
/// rigid_bodies.csv.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigidBodyDeck {
    /// Name, for the columns of rigid_bodies.csv.
    pub name: String,
    /// Its shape at t = 0 (docs/deck.md, "Shapes").
    pub shape: ShapeDeck,
    /// "prescribed" (default: moved by `velocity` and `angular_velocity`) or "free".
    #[serde(default)]
    pub motion: RigidMotion,
    /// Velocity (m/s): numbers, or expressions of t (a gate lifted at a given pace); default
    /// at rest. A free body's velocity at t = 0 (numbers).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<VectorField>,
    /// Angular velocity (rad/s) about `centre`: in 2D one number or expression of t
    /// (counter-clockwise), in 3D a vector of them. A free body's at t = 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angular_velocity: Option<Spin>,
    /// The point it turns about at t = 0 (default: its centroid; a free body turns about its
    /// centroid).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub centre: Option<Vec<f64>>,
    /// A free body's density (kg/m^3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<f64>,
    /// A free body's motions that are held: any of "x", "y", "z" (its velocity along the
    /// axis stays as it started) and "rotation".
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fixed: Vec<String>,
    /// Contact on the faces that do not lead the motion (a footing's sides).
    #[serde(default)]
    pub sides: RigidSides,
}

/// How a rigid body moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RigidMotion {
    /// Along the path `velocity` and `angular_velocity` give.
    #[default]
    Prescribed,
    /// Moved by the material's force and torque and by gravity.
    Free,
}

/// An angular velocity: one component (2D) or a vector (3D).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Spin {
    /// About z (2D).
    About(Component),
    /// A vector (3D).
    Vector(VectorField),
}

impl Spin {
    /// As a field of one component (2D) or three.
    pub fn field(&self) -> VectorField {
        match self {
            Spin::About(c) => VectorField(vec![c.clone()]),
            Spin::Vector(v) => v.clone(),
        }
    }
}

impl RigidBodyDeck {
    /// The `[[rigid_bodies]]` (their mesh files' paths resolved against `dir`, the deck's
    /// folder): names that head CSV columns, once each; shapes that build; a box's corners
    /// and velocity, or the general path's motion; free bodies apart from the others. Gives
    /// each body's region, in order.
    pub(crate) fn check_all(
        bodies: &mut [RigidBodyDeck],
        dir: &Path,
        frame: &Frame,
        c: &Check,
    ) -> Result<Vec<Solid>, DeckError> {
        for r in bodies.iter_mut() {
            r.shape.resolve_files(dir);
        }
        let mut solids = Vec::with_capacity(bodies.len());
        for (i, r) in bodies.iter().enumerate() {
            let k = format!("rigid_bodies[{i}]");
            c.column_name(
                &format!("{k}.name"),
                i,
                bodies.iter().map(|e| e.name.as_str()),
            )?;
            let solid = c.solid(&format!("{k}.shape"), &r.shape, frame.dim)?;
            if r.is_shaped()
                || r.motion == RigidMotion::Free
                || r.density.is_some()
                || !r.fixed.is_empty()
                || r.centre.is_some()
            {
                r.check_shaped(&k, &solid, frame, c)?;
            }
            if !r.is_shaped() {
                r.check_box(&k, frame, c)?;
            }
            solids.push(solid);
        }
        check_free_apart(bodies, &solids, frame, c)?;
        Ok(solids)
    }

    /// A box moved by its velocity alone (key `k`): both corners, apart along every axis, and
    /// its velocity.
    fn check_box(&self, k: &str, frame: &Frame, c: &Check) -> Result<(), DeckError> {
        let dim = frame.dim;
        let (Some(mn), Some(mx)) = (&self.shape.min, &self.shape.max) else {
            return Err(c.err(format!("{k}.shape"), "a box needs both min and max"));
        };
        c.vector(&format!("{k}.shape.min"), mn, dim)?;
        c.vector(&format!("{k}.shape.max"), mx, dim)?;
        if let Some(d) = (0..dim).find(|&d| mx[d] <= mn[d]) {
            return Err(c.err(
                format!("{k}.shape.max"),
                format!("must exceed min along {}: {} <= {}", AXES[d], mx[d], mn[d]),
            ));
        }
        self.check_velocity(k, dim, frame.end_time, c)
    }

    /// A rigid body of the general path: its motion's keys, and a shape that holds a volume
    /// and, unless it stands still, is bounded.
    fn check_shaped(
        &self,
        k: &str,
        solid: &Solid,
        frame: &Frame,
        c: &Check,
    ) -> Result<(), DeckError> {
        let r = self;
        let dim = frame.dim;
        if r.sides == RigidSides::Smooth && r.is_shaped() {
            return Err(c.err(
                format!("{k}.sides"),
                "\"smooth\" is for a box that does not turn (an axis-aligned box moved by velocity alone); this body is held rough",
            ));
        }
        r.check_motion(k, dim, frame.end_time, c)?;
        let free = r.motion == RigidMotion::Free;
        let Some(shape) =
            r.shape_on_grid(dim, frame.cell_size, (&frame.lo, &frame.hi), frame.end_time)
        else {
            return Err(c.err(
                format!("{k}.shape"),
                "holds no volume inside the grid (a shape thinner than a quarter cell, or one wholly outside)",
            ));
        };
        let (mn, mx) = solid.bounds();
        let moves = free || r.velocity.is_some() || r.angular_velocity.is_some();
        if moves && (0..dim).any(|d| !mn[d].is_finite() || !mx[d].is_finite()) {
            return Err(c.err(
                format!("{k}.shape"),
                "is unbounded (a half-space): only a body at rest may be, cut off at the grid",
            ));
        }
        if free {
            // the walls hold a free body inside the grid; one that starts across a wall
            // would be thrown in at the first step
            let (lo, hi) = (&frame.lo, &frame.hi);
            let (a, z) = shape.extent(&super::Pose::at(shape.reference()));
            let tol = 1e-9 * frame.cell_size;
            if let Some(d) = (0..dim).find(|&d| a[d] < lo[d] - tol || z[d] > hi[d] + tol) {
                return Err(c.err(
                    format!("{k}.shape"),
                    format!(
                        "of a free body must lie inside the grid: it reaches {} = [{:.4}, {:.4}] against the grid's [{}, {}]",
                        AXES[d], a[d], z[d], lo[d], hi[d]
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Whether it turns: its angle, angular velocity and torque are written.
    pub fn turns(&self) -> bool {
        match self.motion {
            RigidMotion::Free => !self.fixed.iter().any(|f| f == "rotation"),
            RigidMotion::Prescribed => self.angular_velocity.is_some(),
        }
    }

    /// Whether it takes the general path of [`crate::rigid`] (any shape, turning, or free to
    /// turn) rather than the axis-aligned box's, whose faces cut the cells where they lie (a
    /// box that moves freely without turning keeps the box's path).
    pub fn is_shaped(&self) -> bool {
        !self.shape.is_plain_box() || self.turns()
    }

    /// Its shape on a grid of cell size `h` over the domain `lo`..`hi` (cut to the grid, grown
    /// by a cell, where it is unbounded), with its volume, centroid, inertia and surface, for a
    /// run to `end_time`; None when it holds no volume there or is not a valid shape.
    pub fn shape_on_grid(
        &self,
        dim: usize,
        h: f64,
        (lo, hi): (&[f64], &[f64]),
        end_time: f64,
    ) -> Option<Shaped> {
        use nalgebra::Vector3;
        let v3 = |x: &[f64]| Vector3::from_fn(|d, _| x.get(d).copied().unwrap_or(0.0));
        let clip = (v3(lo).add_scalar(-h), v3(hi).add_scalar(h));
        let solid = self.shape.solid(dim).ok()?;
        // the pressure on the surface is read from the nodes up to two cells away
        let reach = Reach {
            grid: (clip.0.add_scalar(-2.0 * h), clip.1.add_scalar(2.0 * h)),
            travel: self.travel(end_time),
            turns: self.angular_velocity.is_some() || self.motion == RigidMotion::Free,
        };
        Shaped::new(solid, dim, clip, self.centre.as_deref().map(v3), h, reach)
    }

    /// How far its reference point may travel over a run to `end` (m): none at rest; for a
    /// prescribed velocity V(t), the end time times the greatest |V| at 4096 times over the
    /// run, doubled (a velocity that peaks between the times); infinite for a free body and for
    /// a velocity that is not finite somewhere.
    fn travel(&self, end: f64) -> f64 {
        if self.motion == RigidMotion::Free {
            return f64::INFINITY;
        }
        let Some(Ok(v)) = self.velocity.as_ref().map(|f| f.compile()) else {
            return 0.0;
        };
        const TIMES: usize = 4096;
        let fastest = (0..=TIMES)
            .map(|k| v.eval_t(end * k as f64 / TIMES as f64).norm())
            .fold(0.0, |a: f64, s| {
                if s.is_finite() {
                    a.max(s)
                } else {
                    f64::INFINITY
                }
            });
        2.0 * fastest * end
    }

    /// Its `velocity` (key `k`.velocity): `dim` components, numbers or expressions of t only,
    /// finite over a run to `end_time`.
    pub(crate) fn check_velocity(
        &self,
        k: &str,
        dim: usize,
        end_time: f64,
        c: &Check,
    ) -> Result<(), DeckError> {
        let Some(v) = &self.velocity else {
            return Ok(());
        };
        let key = format!("{k}.velocity");
        c.field(&key, v, dim)?;
        time_only(
            &v.compile().expect("checked above"),
            &key,
            "moves",
            end_time,
            c,
        )
    }

    /// The keys of its motion on the general path (key `k`): `angular_velocity` (one component
    /// in 2D, three in 3D, of t only, finite over a run to `end_time`), `velocity`, `centre`
    /// (only for a body that turns about it), and the keys only one kind of motion takes.
    pub(crate) fn check_motion(
        &self,
        k: &str,
        dim: usize,
        end_time: f64,
        c: &Check,
    ) -> Result<(), DeckError> {
        if let Some(w) = &self.angular_velocity {
            let key = format!("{k}.angular_velocity");
            let f = w.field();
            let want = if dim == 2 { 1 } else { 3 };
            if f.len() != want {
                return Err(c.err(
                    key,
                    if dim == 2 {
                        "in 2D is one number or expression of t (rad/s, counter-clockwise)"
                            .to_string()
                    } else {
                        format!(
                            "in 3D is a vector of 3 numbers or expressions of t, got {}",
                            f.len()
                        )
                    },
                ));
            }
            let g = f.compile().map_err(|e| c.err(key.clone(), e))?;
            time_only(&g, &key, "turns", end_time, c)?;
        }
        self.check_velocity(k, dim, end_time, c)?;
        let free = self.motion == RigidMotion::Free;
        if let Some(x) = &self.centre {
            c.vector(&format!("{k}.centre"), x, dim)?;
            if !free && self.angular_velocity.is_none() {
                return Err(c.err(
                    format!("{k}.centre"),
                    "is the point a turning body turns about: give angular_velocity, or remove centre",
                ));
            }
        }
        motion_keys(self, k, dim, c)?;
        Ok(())
    }
}

/// The keys of rigid body `r` (key `k`) that only one kind of motion takes: a free body's
/// density, its velocities at t = 0 as numbers, and the motions it holds (`fixed`); none of
/// them for a prescribed body.
fn motion_keys(r: &RigidBodyDeck, k: &str, dim: usize, c: &Check) -> Result<(), DeckError> {
    if r.motion == RigidMotion::Free {
        match r.density {
            None => {
                return Err(c.err(
                    format!("{k}.density"),
                    "a free body needs its density (kg/m^3)",
                ))
            }
            Some(rho) => c.positive(&format!("{k}.density"), rho)?,
        }
        if r.centre.is_some() {
            return Err(c.err(
                format!("{k}.centre"),
                "a free body turns about its centroid: remove centre",
            ));
        }
        for (key, given) in [
            (
                "velocity",
                r.velocity.as_ref().map(|v| v.numbers().is_none()),
            ),
            (
                "angular_velocity",
                r.angular_velocity
                    .as_ref()
                    .map(|w| w.field().numbers().is_none()),
            ),
        ] {
            if given == Some(true) {
                return Err(c.err(
                    format!("{k}.{key}"),
                    "of a free body is its value at t = 0: numbers, not expressions",
                ));
            }
        }
        let names: &[&str] = if dim == 2 {
            &["x", "y", "rotation"]
        } else {
            &["x", "y", "z", "rotation"]
        };
        for (j, f) in r.fixed.iter().enumerate() {
            if !names.contains(&f.as_str()) {
                return Err(c.err(
                    format!("{k}.fixed[{j}]"),
                    format!("must be one of {}, got \"{f}\"", names.join(", ")),
                ));
            }
        }
        if !r.turns() && r.angular_velocity.is_some() {
            return Err(c.err(
                format!("{k}.angular_velocity"),
                "is given for a body held from turning (fixed holds \"rotation\"): remove one of them",
            ));
        }
    } else {
        if r.density.is_some() {
            return Err(c.err(
                format!("{k}.density"),
                "is for motion = \"free\" (a prescribed body's motion does not depend on its mass)",
            ));
        }
        if !r.fixed.is_empty() {
            return Err(c.err(format!("{k}.fixed"), "is for motion = \"free\""));
        }
    }
    Ok(())
}

/// Samples of a run's time span [0, end_time] at which a prescribed rigid body's motion is
/// looked at (its ends and 2047 points between): where it must be finite, and the fastest it
/// goes for the step estimate.
pub fn motion_times(end_time: f64) -> impl Iterator<Item = f64> {
    const N: usize = 2048;
    (0..=N).map(move |k| end_time * k as f64 / N as f64)
}

/// A rigid body moves and turns as a whole: the field `f` of `key` may depend on t only (no
/// expression names x, y or z), and is a finite number over the run, [0, end_time] (what it
/// gives after the end is never used).
fn time_only(
    f: &crate::field::CompiledField,
    key: &str,
    verb: &str,
    end_time: f64,
    c: &Check,
) -> Result<(), DeckError> {
    if f.uses_position() {
        return Err(c.err(
            key,
            format!("may depend on t only (a rigid body {verb} as a whole): remove x, y and z from the expressions"),
        ));
    }
    for t in motion_times(end_time) {
        let v = f.eval_at(&[], t);
        if v.iter().any(|x| !x.is_finite()) {
            return Err(c.err(
                key,
                format!(
                    "is not a finite number at t = {} s, within the run (simulation.end_time = {} s): {v:?}",
                    crate::keys::short(t),
                    crate::keys::short(end_time)
                ),
            ));
        }
    }
    Ok(())
}

/// A free body starts apart from every other rigid body: the contact parts bodies that
/// meet as they move, not one placed through another.
fn check_free_apart(
    bodies: &[RigidBodyDeck],
    solids: &[Solid],
    frame: &Frame,
    c: &Check,
) -> Result<(), DeckError> {
    let (lo, hi) = (&frame.lo, &frame.hi);
    let free = |r: &RigidBodyDeck| r.motion == RigidMotion::Free;
    for (b, rb) in bodies.iter().enumerate() {
        for (a, ra) in bodies[..b].iter().enumerate() {
            if !(free(ra) || free(rb)) {
                continue;
            }
            if let Some(x) = solids[a].common_point(&solids[b], (lo, hi)) {
                let (f, o) = if free(rb) { (b, a) } else { (a, b) };
                return Err(c.err(
                    format!("rigid_bodies[{f}].shape"),
                    format!(
                        "the free body \"{}\" overlaps rigid_bodies[{o}] (\"{}\") at t = 0 (for example at ({})): a free body must start apart from the other bodies (the contact parts bodies that meet, not one placed inside another); place them apart",
                        bodies[f].name,
                        bodies[o].name,
                        point(&x)
                    ),
                ));
            }
        }
    }
    Ok(())
}
