//! How a shaped rigid body moves: along a prescribed path (its velocity and angular velocity
//! given as functions of t), or freely, as a two-way coupled body whose mass and inertia come
//! from its shape and density and which the material's force and torque and gravity move.

use super::shaped::{Pose, GAUSS};
use crate::field::CompiledField;
use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

/// A body's motion.
#[derive(Debug, Clone)]
pub enum Motion {
    /// Velocity and angular velocity as functions of t (None: at rest); the pose at t is their
    /// integral from 0.
    Prescribed {
        /// Velocity (m/s) of the reference point.
        velocity: Option<CompiledField>,
        /// Angular velocity (rad/s): one component about z in 2D, three in 3D.
        spin: Option<CompiledField>,
    },
    /// Moved by the force and torque on it and by gravity.
    Free(Free),
}

/// A free body's mass, inertia and the degrees of freedom it keeps.
#[derive(Debug, Clone)]
pub struct Free {
    /// Mass (kg; kg/m in 2D).
    pub mass: f64,
    /// Inertia about the reference point in the deck's frame (kg m^2; kg m in 2D).
    pub inertia: Matrix3<f64>,
    /// Gravity (m/s^2).
    pub gravity: Vector3<f64>,
    /// Per translation axis, whether it is held (the velocity along it stays as it started).
    pub held_axes: [bool; 3],
    /// Whether the rotation is held.
    pub held_rotation: bool,
    /// Dimension (2 or 3).
    pub dim: usize,
    /// The added mass the coupling assumes ([`Free::advance`]) (kg; kg/m in 2D).
    pub added_mass: f64,
    /// The added inertia it assumes (kg m^2; kg m in 2D).
    pub added_inertia: f64,
}

/// The state a free body carries from step to step, as the checkpoint stores it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FreeState {
    /// Reference point (m).
    pub centre: [f64; 3],
    /// Rotation matrix, column by column.
    pub rotation: [f64; 9],
    /// Velocity (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (rad/s).
    pub omega: [f64; 3],
    /// The velocity of the step before.
    pub last_velocity: [f64; 3],
    /// The angular velocity of the step before.
    pub last_omega: [f64; 3],
    /// In 2D, the angle turned since the start ([`Pose::turned`]).
    pub turned: f64,
}

impl FreeState {
    /// The state of a body at `p` whose velocities the step before were `last`.
    pub fn new(p: &Pose, last: &(Vector3<f64>, Vector3<f64>)) -> Self {
        let mut rotation = [0.0; 9];
        rotation.copy_from_slice(p.rotation.as_slice());
        Self {
            centre: p.centre.into(),
            rotation,
            velocity: p.velocity.into(),
            omega: p.omega.into(),
            last_velocity: last.0.into(),
            last_omega: last.1.into(),
            turned: p.turned,
        }
    }

    /// The pose, and the velocities of the step before.
    pub fn pose(&self) -> (Pose, (Vector3<f64>, Vector3<f64>)) {
        (
            Pose {
                centre: self.centre.into(),
                rotation: Matrix3::from_column_slice(&self.rotation),
                velocity: self.velocity.into(),
                omega: self.omega.into(),
                turned: self.turned,
            },
            (self.last_velocity.into(), self.last_omega.into()),
        )
    }
}

/// The integral from 0 to `t` of `f`: three-point Gauss quadrature on 512 equal panels, exact
/// for a polynomial of degree 5 on each panel and within round-off for any smooth function
/// over a run. A pure function of t, so that a resumed run places its bodies where the
/// straight run did, bit for bit.
pub fn integral(f: impl Fn(f64) -> Vector3<f64>, t: f64) -> Vector3<f64> {
    const PANELS: usize = 512;
    let half = 0.5 * t / PANELS as f64;
    let mut sum = Vector3::zeros();
    for k in 0..PANELS {
        let mid = (2 * k + 1) as f64 * half;
        for (g, w) in GAUSS {
            sum += f(mid + g * half) * (w * half);
        }
    }
    sum
}

/// A field of t as a 3-vector: the velocity's components in order; an angular velocity of one
/// component (2D) about z.
fn at(f: &CompiledField, t: f64, spin: bool) -> Vector3<f64> {
    let v = f.eval_t(t);
    if spin && f.len() == 1 {
        Vector3::new(0.0, 0.0, v[0])
    } else {
        v
    }
}

impl Motion {
    /// The pose at time `t` of a body prescribed to move from `start` (its pose at t = 0):
    /// the reference point displaced by the velocity's integral, and turned by the rotation
    /// vector that is the angular velocity's integral (exact for a fixed axis, the hinge of
    /// a gate or the shaft of a blade).
    pub fn pose_at(&self, start: &Pose, t: f64) -> Option<Pose> {
        let Motion::Prescribed { velocity, spin } = self else {
            return None;
        };
        let mut pose = *start;
        if let Some(f) = velocity {
            pose.velocity = at(f, t, false);
            pose.centre = start.centre
                + if f.is_constant() {
                    pose.velocity * t
                } else {
                    integral(|s| at(f, s, false), t)
                };
        }
        if let Some(f) = spin {
            pose.omega = at(f, t, true);
            let turn = if f.is_constant() {
                pose.omega * t
            } else {
                integral(|s| at(f, s, true), t)
            };
            pose.rotation = Rotation3::new(turn).into_inner() * start.rotation;
            pose.turned = start.turned + turn[2];
        }
        Some(pose)
    }

    /// Whether the body turns (a column of rigid_bodies.csv for its angle and torque).
    pub fn turns(&self) -> bool {
        match self {
            Motion::Prescribed { spin, .. } => spin.is_some(),
            Motion::Free(f) => !f.held_rotation,
        }
    }
}

impl Free {
    /// One step of the body's motion under `force` and `torque` (about its reference point,
    /// which is its centroid) and gravity, semi-implicit Euler: the velocities first, then the
    /// pose with the new velocities. The rotation turns by exp(dt omega) and is brought back to
    /// a rotation each step (round-off would drift it). `last` holds the velocities of the step
    /// before, and takes the ones the step started with.
    ///
    /// The force lags the motion by a step: the material's reaction to the velocity the body
    /// held over the step, m_a (V^n - V^{n-1}) / dt for an added mass m_a, is in it, and with
    /// m (V^{n+1} - V^n) = dt F alone an error grows by -m_a / m a step, so a body lighter than
    /// the water it moves (a floating box) blows up. With an assumed added mass m^ on both
    /// sides,
    ///
    /// ```text
    /// (m + m^) (V^{n+1} - V^n) = dt (F + m g) + m^ (V^n - V^{n-1}),
    /// ```
    ///
    /// the error grows by (m^ - m_a) / (m + m^), below 1 for any m^ > (m_a - m) / 2, and the
    /// motion is unchanged to O(dt) (for a smooth motion V^n - V^{n-1} = V^{n+1} - V^n + O(dt^2),
    /// which gives (m + m_a) dV/dt = F_rest + m g); the rest state, F + m g = 0, is exact.
    /// (The artificial added mass of partitioned fluid-structure coupling; Causin, Gerbeau &
    /// Nobile 2005 give the instability, Idelsohn et al. 2009 the remedy.) The same holds for
    /// the rotation with an added inertia.
    pub fn advance(
        &self,
        pose: &mut Pose,
        last: &mut (Vector3<f64>, Vector3<f64>),
        force: Vector3<f64>,
        torque: Vector3<f64>,
        dt: f64,
    ) {
        let (v0, w0) = (pose.velocity, pose.omega);
        let prev = std::mem::replace(last, (v0, w0));
        // the first step has no step before (NaN): no lagged reaction to take out, and none
        // assumed (a body dropped from rest then falls at g from the first step)
        let first = prev.0[0].is_nan();
        let (ma, ia) = if first {
            (0.0, 0.0)
        } else {
            (self.added_mass, self.added_inertia)
        };
        let prev = if first { (v0, w0) } else { prev };
        let push = force + self.gravity * self.mass;
        for d in 0..self.dim {
            if !self.held_axes[d] {
                pose.velocity[d] += (dt * push[d] + ma * (v0[d] - prev.0[d])) / (self.mass + ma);
            }
        }
        pose.centre += pose.velocity * dt;
        if self.held_rotation {
            return;
        }
        if self.dim == 2 {
            pose.omega[2] +=
                (dt * torque[2] + ia * (w0[2] - prev.1[2])) / (self.inertia[(2, 2)] + ia);
            pose.turned += pose.omega[2] * dt;
        } else {
            // Euler's equations in the world frame, I dw/dt = tau - w x (I w), I = R I0 R^T,
            // with the added inertia on both sides
            let r = pose.rotation;
            let inertia = r * self.inertia * r.transpose();
            let gyro = pose.omega.cross(&(inertia * pose.omega));
            let lhs = inertia + Matrix3::identity() * ia;
            if let Some(inv) = lhs.try_inverse() {
                pose.omega += inv * ((torque - gyro) * dt + (w0 - prev.1) * ia);
            }
        }
        let turn = Rotation3::new(pose.omega * dt);
        let mut r = Rotation3::from_matrix_unchecked(turn.into_inner() * pose.rotation);
        r.renormalize();
        pose.rotation = r.into_inner();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn free(added: f64) -> Free {
        Free {
            mass: 2.0,
            inertia: Matrix3::identity(),
            gravity: Vector3::new(0.0, -9.81, 0.0),
            held_axes: [true, false, false],
            held_rotation: true,
            dim: 2,
            added_mass: added,
            added_inertia: 0.0,
        }
    }

    /// Without a force a free body falls at g from the first step whatever added mass the
    /// coupling assumes, and the axis it holds keeps its velocity.
    #[test]
    fn a_free_body_falls_at_g() {
        let f = free(50.0);
        let mut pose = Pose::at(Vector3::zeros());
        pose.velocity = Vector3::new(1.0, 0.0, 0.0);
        let mut last = (Vector3::repeat(f64::NAN), Vector3::repeat(f64::NAN));
        for _ in 0..10 {
            f.advance(
                &mut pose,
                &mut last,
                Vector3::zeros(),
                Vector3::zeros(),
                0.01,
            );
        }
        assert!(
            (pose.velocity[1] + 0.981).abs() < 1e-12,
            "{}",
            pose.velocity
        );
        assert_eq!(pose.velocity[0], 1.0);
        // semi-implicit Euler: y = -g dt^2 (1 + 2 + ... + 10)
        assert!((pose.centre[1] + 9.81e-4 * 55.0).abs() < 1e-12);
    }

    /// In 2D the angle turned grows past pi, turn after turn: 15 rad after 5 s at 3 rad/s,
    /// prescribed or free (no torque, no friction).
    #[test]
    fn the_angle_turned_is_not_wrapped() {
        let spin = crate::field::VectorField::constant_from(&[3.0])
            .compile()
            .unwrap();
        let prescribed = Motion::Prescribed {
            velocity: None,
            spin: Some(spin),
        };
        let at5 = prescribed
            .pose_at(&Pose::at(Vector3::zeros()), 5.0)
            .unwrap();
        assert!((at5.turned - 15.0).abs() < 1e-12, "{}", at5.turned);
        let f = Free {
            held_rotation: false,
            gravity: Vector3::zeros(),
            ..free(0.0)
        };
        let mut pose = Pose::at(Vector3::zeros());
        pose.omega = Vector3::new(0.0, 0.0, 3.0);
        let mut last = (Vector3::repeat(f64::NAN), Vector3::repeat(f64::NAN));
        for _ in 0..500 {
            let (force, torque) = (Vector3::zeros(), Vector3::zeros());
            f.advance(&mut pose, &mut last, force, torque, 0.01);
        }
        assert!((pose.turned - 15.0).abs() < 1e-9, "{}", pose.turned);
    }

    /// A body whose force lags its velocity by a step, F = k (x0 - x) - m_a dV/dt as the
    /// material's reaction: with m_a = 4 m the plain update blows up; with the assumed added
    /// mass it comes to rest where k (x0 - x) = m g.
    #[test]
    fn the_assumed_added_mass_keeps_a_light_body_stable() {
        let run = |assumed: f64| {
            let f = free(assumed);
            let (k, ma, dt) = (2000.0, 8.0, 0.002);
            let mut pose = Pose::at(Vector3::zeros());
            let mut last = (Vector3::repeat(f64::NAN), Vector3::repeat(f64::NAN));
            let mut before = 0.0;
            for _ in 0..4000 {
                let v = pose.velocity[1];
                let react = if last.0[1].is_nan() {
                    0.0
                } else {
                    -ma * (v - before) / dt
                };
                before = v;
                let force =
                    Vector3::new(0.0, -k * pose.centre[1] + react, 0.0) - pose.velocity * 50.0;
                f.advance(&mut pose, &mut last, force, Vector3::zeros(), dt);
            }
            pose.centre[1]
        };
        let rest = -2.0 * 9.81 / 2000.0;
        assert!(!(run(0.0) - rest).abs().is_finite() || (run(0.0) - rest).abs() > 1.0);
        assert!((run(10.0) - rest).abs() < 1e-9, "{}", run(10.0));
    }
}
