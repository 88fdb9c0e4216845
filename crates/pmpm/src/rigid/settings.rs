//! The `[[rigid_bodies]]` deck section: each body's shape, motion and contact, as the deck
//! gives them, and its shape on the grid.

use super::{Reach, RigidSides, Shaped};
use crate::field::{Component, VectorField};
use crate::geometry::ShapeDeck;
use serde::{Deserialize, Serialize};

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
}

impl RigidBodyDeck {
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
}
