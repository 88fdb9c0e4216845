//! Rigid bodies moving at a prescribed velocity through the material: a footing pushed into
//! clay, a penetrometer, a gate lifted from a dam. Each is an axis-aligned box; its grid
//! nodes inside the box as it is now take its velocity, as no-slip wall nodes take a wall's,
//! and the nodes less than a cell ahead of the faces it moves towards take the velocity's
//! component along the motion: they push the material the body is reaching. With smooth sides
//! ([`RigidSides::Smooth`]) the nodes on the faces that do not lead the motion, or less than a
//! cell inside them, take only the velocity's normal component, as slip wall nodes do.
//!
//! With cut cells (`pressure.rigid_faces = "cut"`, the nodal projection with the level-set
//! free surface and linear or GIMP shape functions) the faces act where they lie: no rows are
//! held ahead; a node less than a cell inside a face holds a ghost normal velocity, which
//! puts the body's on the face where the node is less than half a cell inside it and goes
//! over continuously to the body's own a cell inside (no node switches between held and free
//! as a face moves past it: the switch stirred the water under a heaving box); the
//! pressure's right-hand side takes the jump of the normal velocity across the face
//! ([`RigidBodies::add_face_flux`]); the cells a face cuts are integrated over their open
//! part, exactly ([`RigidBodies::open_part`]). A face less than a quarter cell (`SNAP`) past a
//! node row acts on that row.
//!
//! The force: on a body's nodes the grid momentum without the body would be, at the step's
//! end, P = sum_i (m_i v_i^n + dt f_i) (the predictor of P2G's velocity and forces, the
//! explicit scheme's pressure in f), plus with the projection dt f^p_i, the pressure's force
//! on the node as the corrector applies it. The body sets its nodes' held components to the
//! values it holds, so the impulse it gives the material over the step is
//! I = sum_i m_i V_i - P - dt sum_i f^p_i over those components, and the force on the body is
//! -I / dt: the material's stress, weight and inertia at the body's nodes. With the projection,
//! the pressure on the wet faces, int p n dS, is added: the corrector's gradient form pushes the
//! material away from a face with it, whichever nodes carry the push.

mod contact;
mod motion;
mod settings;
mod shaped;

pub use motion::{Free, FreeState, Motion};
pub use settings::{motion_times, RigidBodyDeck, RigidMotion, Spin};
pub use shaped::{Pose, Reach, Shaped};

use crate::grid::NodeKind;
use crate::grid::{Grid, GridGeometry, Vector};
use crate::particles::Particles;
use crate::shape::{ShapeFunction, Stencil, PAD};
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use shaped::{from3, to3, SurfacePoint};
use std::sync::Arc;

/// How a rigid body holds the material on its faces that do not lead its motion: the faces
/// whose outward normal does not point along its velocity (a footing's vertical sides and its
/// top; every face of a body at rest).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RigidSides {
    /// Their nodes take the body's whole velocity (no slip), as the leading faces' do.
    #[default]
    Rough,
    /// Their nodes take only the velocity's component along the face's normal: the material
    /// slides along them, as along a slip wall. The leading faces stay rough.
    Smooth,
}

/// With cut cells, the least distance (in cells) between a face and the nearest node outside
/// it for that node to stay free. A node closer than this holds the face's normal velocity,
/// and the sliver between it and the face counts as the body's (in the cells' quadrature
/// too): the face acts on the node row, at most SNAP h from where it lies. A node whose only
/// material is such a sliver has a mass that goes to zero with it, and its free velocity
/// blew up (a dam break against a block whose face lay 0.01 to 0.1 h past a node row stopped
/// on a pressure solve with NaN when the surge reached it); integrated, the sliver coupled the
/// row to the nodes inside the body, massless and read as air, and set still water moving.
const SNAP: f64 = 0.25;

/// One rigid body as the settings give it: an axis-aligned box moving at a constant velocity.
#[derive(Debug, Clone)]
pub struct RigidBox<const D: usize> {
    /// Lower corner (m).
    pub lo: Vector<D>,
    /// Upper corner (m).
    pub hi: Vector<D>,
    /// Velocity (m/s) at t = 0.
    pub velocity: Vector<D>,
    /// The velocity as a function of time, when it varies (a gate lifted at a given pace).
    pub motion: Option<crate::field::CompiledField>,
    /// How it holds the material on its trailing faces.
    pub sides: RigidSides,
    /// A body of any shape, or one that turns (the `shaped` module); None: the box above.
    pub shaped: Option<ShapedBody>,
    /// A box that moves freely (without turning): its mass and what it keeps still; it
    /// starts at `velocity` and `motion` is None.
    pub free: Option<Free>,
}

/// A world box (lower, upper corner).
type Bounds = (Vector3<f64>, Vector3<f64>);

/// A rigid body of any shape: its shape, its motion, and its pose at t = 0.
#[derive(Debug, Clone)]
pub struct ShapedBody {
    /// Its shape and what follows from it.
    pub shape: Arc<Shaped>,
    /// How it moves.
    pub motion: Motion,
    /// Its pose at t = 0.
    pub start: Pose,
}

/// What a shaped body holds at its last pose, kept while it does not move (a fixed obstacle's
/// nodes, cover and surface are found once).
#[derive(Debug, Clone, Default)]
struct Cache<const D: usize> {
    pose: Option<Pose>,
    nodes: Vec<(usize, u8, Vector<D>)>,
    cover: Vec<(usize, f64)>,
    surface: Vec<SurfacePoint<D>>,
}

/// The integral of a velocity given as a function of t from 0 to `t`: three-point Gauss
/// quadrature on 512 equal panels, exact for a velocity that is a polynomial of degree 5 on
/// each panel and within round-off for any smooth one over a run. A pure function of t, so
/// that a resumed run places its bodies where the straight run did, bit for bit.
fn displacement<const D: usize>(f: &crate::field::CompiledField, t: f64) -> Vector<D> {
    const PANELS: usize = 512;
    const GAUSS: [(f64, f64); 3] = [
        (-0.774_596_669_241_483_4, 5.0 / 9.0),
        (0.0, 8.0 / 9.0),
        (0.774_596_669_241_483_4, 5.0 / 9.0),
    ];
    let half = 0.5 * t / PANELS as f64;
    let mut sum = Vector::<D>::zeros();
    for k in 0..PANELS {
        let mid = (2 * k + 1) as f64 * half;
        for (g, w) in GAUSS {
            sum += f.eval(&Vector::<D>::zeros(), mid + g * half) * (w * half);
        }
    }
    sum
}

/// Relative tolerance (in cells) of the node-to-face comparisons.
const EPS: f64 = 1e-9;

/// One body's faces at the current time and the nodes it may hold ([`RigidBodies::set_time`]).
struct Span<const D: usize> {
    face_lo: Vector<D>,
    face_hi: Vector<D>,
    /// Per axis, whether the lower and upper faces can meet material (not on or beyond a wall).
    live_lo: [bool; D],
    live_hi: [bool; D],
    /// First and last node index (with the padding) of the range.
    first: [usize; D],
    last: [isize; D],
}

/// The rigid bodies and the nodes each holds now.
#[derive(Debug, Clone, Default)]
pub struct RigidBodies<const D: usize> {
    /// Lower corner at t = 0.
    lo: Vec<Vector<D>>,
    /// Upper corner at t = 0.
    hi: Vec<Vector<D>>,
    /// Velocity (m/s) at the time of [`RigidBodies::set_time`].
    velocity: Vec<Vector<D>>,
    /// Per body, its velocity as a function of t when it varies (None: constant).
    motion: Vec<Option<crate::field::CompiledField>>,
    /// Per body, its displacement at the time of [`RigidBodies::set_time`].
    offset: Vec<Vector<D>>,
    /// Time of the positions below.
    time: f64,
    /// Whether the faces that do not lead the motion are smooth.
    smooth: Vec<bool>,
    /// (node, body, held) triples of the nodes inside each body now; `held` has bit d set
    /// where the body sets the velocity's component d.
    nodes: Vec<(usize, usize, u8)>,
    /// Per node, the body that holds it (`usize::MAX`: none) and the components it holds.
    owner: Vec<(usize, u8)>,
    /// Per body, its nodes' range in cells from the origin (lower, upper), to skip the
    /// particles far from it.
    reach: Vec<(Vector<D>, Vector<D>)>,
    /// Per body, the momentum its nodes would have at the step's end without it.
    free_momentum: Vec<Vector<D>>,
    /// Per body, the force the material exerted on it over the last step (N; N/m in 2D).
    force: Vec<Vector<D>>,
    /// Per particle, the body [`RigidBodies::push_out`] put it out of this step (`u32::MAX`:
    /// none), and the impulse that took.
    hit: Vec<u32>,
    impulse: Vec<Vector<D>>,
    /// Cut cells: the nodal projection with the level-set free surface sees each face where it
    /// lies ([`RigidBodies::add_face_flux`]), and the nodes less than a cell inside a face
    /// leave its normal velocity free.
    cut: bool,
    /// Quadrature points on the faces that can meet the material, at the time of
    /// [`RigidBodies::set_time`].
    faces: Vec<FacePoint<D>>,
    /// Cut cells: (node, V, axis, the node beyond the face along the axis, c) for each node
    /// less than half a cell inside a face, whose normal component takes the ghost value
    /// V + c (V - v_beyond) that puts the body's velocity V (its component along the axis,
    /// over the step: a free box's own has moved on at the step's end) on the face
    /// ([`RigidBodies::apply`]).
    ghosts: Vec<(usize, f64, usize, usize, f64)>,
    /// Scratch: the Gauss points along each tangential axis of a face, (position, weight).
    lines: [Vec<(f64, f64)>; 2],
    /// Per body, its shape and motion when it is not a box ([`shaped`]).
    shaped: Vec<Option<ShapedBody>>,
    /// Per box, its mass when it moves freely: then `velocity` is its velocity over the step
    /// after the time of `set_time` (the force of the step before moved it), `offset` its
    /// displacement at that time, and `last` holds its velocity the step before.
    free_box: Vec<Option<Free>>,
    /// Per shaped body, its pose now (a free body's: at the end of the last step), and a free
    /// body's velocity and angular velocity the step before ([`Free::advance`]).
    pose: Vec<Pose>,
    last: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// Per shaped body, its nodes, cover and surface at its last pose.
    cache: Vec<Cache<D>>,
    /// The velocity each of `nodes` holds (a turning body's varies from node to node).
    node_velocity: Vec<Vector<D>>,
    /// The shaped bodies' cover and surface points now.
    shaped_cover: Vec<(usize, f64)>,
    surface: Vec<SurfacePoint<D>>,
    /// Per body, the torque about its reference point over the last step (N m; N in 2D,
    /// about z), and the torque of the momentum its nodes would reach without it.
    torque: Vec<Vector3<f64>>,
    free_torque: Vec<Vector3<f64>>,
    /// Scratch of [`RigidBodies::push_out`]: each shaped body's pose at the step's end and
    /// the box that holds it there.
    ends: Vec<Option<(Pose, Bounds)>>,
    /// Scratch of [`RigidBodies::end_step`]: the free bodies' velocities after their step,
    /// before the contact and the walls; the bodies as the contact sees them; and the
    /// surface points of a pair it tests.
    stepped: Vec<Vector3<f64>>,
    contact_scratch: Vec<contact::Body>,
    contact_points: (contact::Points, contact::Points),
    /// Scratch of [`RigidBodies::push_out`]: per body, the force and torque of the pushes.
    push_force: Vec<Vector<D>>,
    push_torque: Vec<Vector3<f64>>,
    /// The ranks whose particles' pushes are added up ([`crate::comm`]).
    pub comm: crate::comm::Ranks,
    /// Over ranks with the grid in slabs ([`crate::slabs`]): the axis and the node layers
    /// this rank owns, whose nodes alone it adds to the bodies' sums over nodes (the ranks'
    /// sums then added up). `None` where each rank holds the whole grid.
    pub owned_layers: Option<(usize, std::ops::Range<usize>)>,
}

/// A quadrature point on a rigid body's face.
#[derive(Debug, Clone, Copy)]
struct FacePoint<const D: usize> {
    x: Vector<D>,
    /// The area (in 2D the length) it stands for.
    weight: f64,
    /// The face's normal axis, and the sign of the normal out of the material into the body
    /// (+1 on a lower face).
    axis: usize,
    sign: f64,
    body: usize,
}

impl<const D: usize> RigidBodies<D> {
    /// The fastest body's speed (0 without bodies): for a turning body, the speed of its
    /// point farthest from the axis.
    pub fn max_speed(&self) -> f64 {
        (0..self.len())
            .map(|b| match &self.shaped[b] {
                Some(s) => {
                    let p = &self.pose[b];
                    p.velocity.norm() + p.omega.norm() * s.shape.radius()
                }
                None => self.velocity[b].norm(),
            })
            .fold(0.0, f64::max)
    }

    /// The bodies, seen by the projection where their faces lie when `cut` (cut cells) or
    /// through the nodes they hold.
    pub fn new(bodies: &[RigidBox<D>], cut: bool) -> Self {
        let n = bodies.len();
        Self {
            lo: bodies.iter().map(|b| b.lo).collect(),
            hi: bodies.iter().map(|b| b.hi).collect(),
            velocity: bodies.iter().map(|b| b.velocity).collect(),
            motion: bodies.iter().map(|b| b.motion.clone()).collect(),
            offset: vec![Vector::<D>::zeros(); n],
            smooth: bodies
                .iter()
                .map(|b| b.sides == RigidSides::Smooth)
                .collect(),
            time: f64::NAN,
            nodes: Vec::new(),
            owner: Vec::new(),
            reach: vec![(Vector::<D>::zeros(), Vector::<D>::zeros()); n],
            free_momentum: vec![Vector::<D>::zeros(); n],
            force: vec![Vector::<D>::zeros(); n],
            hit: Vec::new(),
            impulse: Vec::new(),
            cut,
            faces: Vec::new(),
            ghosts: Vec::new(),
            lines: [Vec::new(), Vec::new()],
            shaped: bodies.iter().map(|b| b.shaped.clone()).collect(),
            free_box: bodies.iter().map(|b| b.free.clone()).collect(),
            pose: bodies
                .iter()
                .map(|b| {
                    b.shaped
                        .as_ref()
                        .map_or(Pose::at(Vector3::zeros()), |s| s.start)
                })
                .collect(),
            // no step before the first ([`Free::advance`])
            last: vec![(Vector3::repeat(f64::NAN), Vector3::repeat(f64::NAN)); n],
            cache: vec![Cache::default(); n],
            node_velocity: Vec::new(),
            shaped_cover: Vec::new(),
            surface: Vec::new(),
            torque: vec![Vector3::zeros(); n],
            free_torque: vec![Vector3::zeros(); n],
            ends: Vec::new(),
            stepped: Vec::new(),
            contact_scratch: Vec::new(),
            contact_points: Default::default(),
            push_force: Vec::new(),
            push_torque: Vec::new(),
            comm: crate::comm::Ranks::default(),
            owned_layers: None,
        }
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.lo.is_empty()
    }

    /// Number of bodies.
    pub fn len(&self) -> usize {
        self.lo.len()
    }

    /// Displacement of body `b` at time `t`: v t at a constant velocity, else the velocity's
    /// integral from 0 to t (`displacement`); a shaped body's reference point's (a free
    /// body's now, whatever `t`).
    pub fn displacement(&self, b: usize, t: f64) -> Vector<D> {
        if let Some(s) = &self.shaped[b] {
            return from3(&(self.pose_now(b, t).centre - s.start.centre));
        }
        if self.free_box[b].is_some() {
            let since = if self.time.is_nan() {
                0.0
            } else {
                t - self.time
            };
            return self.offset[b] + self.velocity[b] * since;
        }
        match &self.motion[b] {
            None => self.velocity[b] * t,
            Some(_) if t == self.time => self.offset[b],
            Some(f) => displacement(f, t),
        }
    }

    /// Centre of body `b`'s box at time `t`; a shaped body's reference point (its centroid
    /// unless the deck gives the centre it turns about).
    pub fn centre(&self, b: usize, t: f64) -> Vector<D> {
        if self.shaped[b].is_some() {
            return from3(&self.pose_now(b, t).centre);
        }
        (self.lo[b] + self.hi[b]) * 0.5 + self.displacement(b, t)
    }

    /// Velocity of body `b` at the time of [`RigidBodies::set_time`] (a free body's at the
    /// end of the last step).
    pub fn velocity(&self, b: usize) -> Vector<D> {
        if self.shaped[b].is_some() {
            return from3(&self.pose[b].velocity);
        }
        self.velocity[b]
    }

    /// The force the material exerted on body `b` over the last step.
    pub fn force(&self, b: usize) -> Vector<D> {
        self.force[b]
    }

    /// The torque the material exerted on body `b` about its reference point over the last
    /// step (about z in 2D).
    pub fn torque(&self, b: usize) -> Vector3<f64> {
        self.torque[b]
    }

    /// Whether body `b` turns (its angle, angular velocity and torque are written).
    pub fn turns(&self, b: usize) -> bool {
        self.shaped[b].as_ref().is_some_and(|s| s.motion.turns())
    }

    /// The pose of shaped body `b` at time `t`: a prescribed one's at t, a free one's now.
    pub fn pose_now(&self, b: usize, t: f64) -> Pose {
        let s = self.shaped[b].as_ref().expect("a shaped body");
        if t == self.time {
            return self.pose[b];
        }
        s.motion.pose_at(&s.start, t).unwrap_or(self.pose[b])
    }

    /// Whether body `b` moves freely.
    pub fn is_free(&self, b: usize) -> bool {
        self.free_box[b].is_some()
            || matches!(&self.shaped[b], Some(s) if matches!(s.motion, Motion::Free(_)))
    }

    /// The free bodies' state at time `t` (the end of the last step), in body order, for the
    /// checkpoint.
    pub fn free_states(&self, t: f64) -> Vec<FreeState> {
        (0..self.len())
            .filter(|&b| self.is_free(b))
            .map(|b| {
                if self.shaped[b].is_some() {
                    FreeState::new(&self.pose[b], &self.last[b])
                } else {
                    let mut p = Pose::at(to3(&self.displacement(b, t)));
                    p.velocity = to3(&self.velocity[b]);
                    FreeState::new(&p, &self.last[b])
                }
            })
            .collect()
    }

    /// Puts back the free bodies' state from the checkpoint (as many as [`free_states`] gave).
    ///
    /// [`free_states`]: RigidBodies::free_states
    pub fn set_free_states(&mut self, states: &[FreeState]) {
        let mut it = states.iter();
        for b in 0..self.len() {
            if !self.is_free(b) {
                continue;
            }
            if let Some(s) = it.next() {
                let (pose, last) = s.pose();
                self.last[b] = last;
                if self.shaped[b].is_some() {
                    self.pose[b] = pose;
                    self.cache[b].pose = None;
                } else {
                    self.offset[b] = from3(&pose.centre);
                    self.velocity[b] = from3(&pose.velocity);
                }
            }
        }
        self.time = f64::NAN;
    }

    /// Box of body `b` at the time of [`RigidBodies::set_time`].
    fn bounds(&self, b: usize) -> (Vector<D>, Vector<D>) {
        let d = match self.motion[b] {
            None if self.free_box[b].is_none() => self.velocity[b] * self.time,
            _ => self.offset[b],
        };
        (self.lo[b] + d, self.hi[b] + d)
    }

    /// Moves the bodies to time `t` and finds their nodes (a node on a body's face is the
    /// body's; nodes beyond the walls stay the walls') and the quadrature points on their faces.
    pub fn set_time(&mut self, t: f64, geo: &GridGeometry<D>) {
        if self.is_empty() || t == self.time {
            return;
        }
        let before = self.time;
        self.time = t;
        for b in 0..self.len() {
            if let Some(f) = &self.motion[b] {
                self.velocity[b] = f.eval(&Vector::<D>::zeros(), t);
                self.offset[b] = displacement(f, t);
            }
            if self.free_box[b].is_some() && !before.is_nan() {
                // the free box's step: its new velocity over the time since
                self.offset[b] += self.velocity[b] * (t - before);
            }
        }
        for &(i, _, _) in &self.nodes {
            self.owner[i] = (usize::MAX, 0);
        }
        self.owner.resize(geo.node_count(), (usize::MAX, 0));
        self.nodes.clear();
        self.node_velocity.clear();
        self.ghosts.clear();
        self.shaped_cover.clear();
        self.surface.clear();
        for b in 0..self.len() {
            if self.shaped[b].is_some() {
                self.place_shaped(b, t, geo);
                continue;
            }
            let Some(span) = self.span(b, geo) else {
                continue;
            };
            self.reach[b] = (
                Vector::<D>::from_fn(|d, _| span.first[d] as f64 - PAD as f64),
                Vector::<D>::from_fn(|d, _| span.last[d] as f64 - PAD as f64),
            );
            let mut idx = span.first;
            'nodes: loop {
                let i = geo.flat(&idx);
                let mut h = self.held(b, &span, &idx, geo);
                if self.cut {
                    h |= self.ghost_normals(b, &span, &idx, geo);
                }
                self.nodes.push((i, b, h));
                self.node_velocity.push(self.velocity[b]);
                self.owner[i] = (b, h);
                for d in 0..D {
                    if (idx[d] as isize) < span.last[d] {
                        idx[d] += 1;
                        continue 'nodes;
                    }
                    idx[d] = span.first[d];
                }
                break;
            }
        }
        self.place_face_points(geo);
    }

    /// Moves shaped body `b` to its pose at `t` (a free body stays at its own) and takes its
    /// nodes, cover and surface there, found afresh when it has moved.
    fn place_shaped(&mut self, b: usize, t: f64, geo: &GridGeometry<D>) {
        let s = self.shaped[b].as_ref().expect("a shaped body");
        if let Some(p) = s.motion.pose_at(&s.start, t) {
            self.pose[b] = p;
        }
        let pose = self.pose[b];
        self.velocity[b] = from3(&pose.velocity);
        let cache = &mut self.cache[b];
        if cache.pose != Some(pose) {
            cache.nodes.clear();
            cache.cover.clear();
            cache.surface.clear();
            s.shape.nodes(&pose, geo, &mut cache.nodes);
            s.shape.cover(&pose, geo, &mut cache.cover);
            s.shape.surface(&pose, b, &mut cache.surface);
            cache.pose = Some(pose);
        }
        for &(i, h, v) in &cache.nodes {
            self.nodes.push((i, b, h));
            self.node_velocity.push(v);
            self.owner[i] = (b, h);
        }
        self.shaped_cover.extend_from_slice(&cache.cover);
        self.surface.extend_from_slice(&cache.surface);
        let (lo, hi) = s.shape.world_bounds(&pose);
        self.reach[b] = (
            from3(&((lo - to3(&geo.origin)) / geo.h)),
            from3(&((hi - to3(&geo.origin)) / geo.h)),
        );
    }

    /// The faces of body `b` now, which of them can meet material, and the range of nodes it
    /// holds (none when the range is empty).
    fn span(&self, b: usize, geo: &GridGeometry<D>) -> Option<Span<D>> {
        let eps = EPS;
        let (grid_lo, grid_hi) = (geo.origin, geo.upper());
        let (face_lo, face_hi) = self.bounds(b);
        let (mut lo, mut hi) = (face_lo, face_hi);
        // ahead of a moving face, the nodes up to a cell from it (but not a whole cell)
        // push the material with the body: a node row stays where it is while the body
        // passes, and material a body pushes would otherwise move away from the last row
        // inside it and lose contact until the face reaches the next row. Half a cell is
        // not enough with the nodal pressure: a plate pushed into water then bears a third
        // to a half of its hydrostatic load (the water under it packs into a layer a cell
        // below the face, the cell between reads as a free surface and takes p = 0; the
        // notes of src/validation/footing.rs). With cut cells the face's flux pushes the
        // material instead.
        let lead = if self.cut {
            0.0
        } else {
            geo.h * (1.0 - 2.0 * eps)
        };
        // a face on a wall, or beyond it, meets no material
        let live_lo: [bool; D] = std::array::from_fn(|d| face_lo[d] > grid_lo[d] + eps * geo.h);
        let live_hi: [bool; D] = std::array::from_fn(|d| face_hi[d] < grid_hi[d] - eps * geo.h);
        for d in 0..D {
            let v = self.velocity[b][d];
            if self.cut {
                // the nodes within SNAP of a face outside it hold its normal (`held`)
                if live_lo[d] {
                    lo[d] -= SNAP * geo.h;
                }
                if live_hi[d] {
                    hi[d] += SNAP * geo.h;
                }
            } else if v < 0.0 {
                lo[d] -= lead;
            } else if v > 0.0 {
                hi[d] += lead;
            }
        }
        // a body wholly past the grid (a gate lifted out of it) holds no node: clamped to
        // the grid, its range would be the last row of nodes, which it would hold
        if (0..D).any(|d| {
            (lo[d] - geo.origin[d]) / geo.h - eps > geo.cells[d] as f64
                || (hi[d] - geo.origin[d]) / geo.h + eps < 0.0
        }) {
            return None;
        }
        let first: [usize; D] = std::array::from_fn(|d| {
            let s = ((lo[d] - geo.origin[d]) / geo.h - eps).ceil().max(0.0);
            PAD + (s as usize).min(geo.cells[d])
        });
        let last: [isize; D] = std::array::from_fn(|d| {
            let s = ((hi[d] - geo.origin[d]) / geo.h + eps).floor();
            PAD as isize + (s as isize).min(geo.cells[d] as isize)
        });
        (0..D)
            .all(|d| last[d] >= first[d] as isize)
            .then_some(Span {
                face_lo,
                face_hi,
                live_lo,
                live_hi,
                first,
                last,
            })
    }

    /// The components body `b` holds on the node `idx` of its span. Ahead of a leading face,
    /// the components along which it leads: the body pushes the material there, but has not
    /// reached it and does not drag it sideways. On or inside the box, all; but with smooth
    /// sides, a node on faces that do not lead or less than a cell inside them (and on no
    /// leading face) holds their normals only. With cut cells a node on a face or less than a
    /// cell inside it leaves that face's normal to the pressure (rough sides hold the other
    /// components, smooth ones none) for its ghost value ([`RigidBodies::ghost_normals`]); a
    /// node outside a face but within SNAP of it holds the normal.
    fn held(&self, b: usize, span: &Span<D>, idx: &[usize; D], geo: &GridGeometry<D>) -> u8 {
        let eps = EPS;
        let all = (1u8 << D) - 1;
        let v = self.velocity[b];
        let (cut, smooth) = (self.cut, self.smooth[b]);
        let (face_lo, face_hi) = (span.face_lo, span.face_hi);
        let (mut normals, mut ahead, mut leading) = (0u8, 0u8, false);
        let xn = geo.node_position(idx);
        for d in 0..D {
            let x = xn[d];
            if (x - face_lo[d]) / geo.h < -eps || (face_hi[d] - x) / geo.h < -eps {
                ahead |= 1 << d;
                continue;
            }
            let (in_lo, in_hi) = ((x - face_lo[d]) / geo.h, (face_hi[d] - x) / geo.h);
            if cut {
                if (span.live_lo[d] && in_lo < 1.0 - eps) || (span.live_hi[d] && in_hi < 1.0 - eps)
                {
                    normals |= 1 << d;
                }
            } else if (in_lo < eps && v[d] < 0.0) || (in_hi < eps && v[d] > 0.0) {
                leading = true;
            } else if (in_lo < 1.0 - eps && v[d] >= 0.0) || (in_hi < 1.0 - eps && v[d] <= 0.0) {
                // on a face that does not lead, or in the first row of nodes inside it (a face
                // midway between node rows, as the docs advise, has no node on it)
                normals |= 1 << d;
            }
        }
        if ahead != 0 {
            return ahead;
        }
        if cut {
            return if smooth && normals != 0 {
                0
            } else {
                all & !normals
            };
        }
        if !smooth || leading || normals == 0 {
            all
        } else {
            normals
        }
    }

    /// With cut cells, the normals a node less than a cell inside a face of body `b` holds by a
    /// ghost value of the normal component (the nearer face where the body is thinner than two
    /// cells); each such node is recorded in `ghosts`. A node at a from the face, the node
    /// beyond it outside, holds v = V + c (V - v_beyond): with c = a / (h - a) up to half a
    /// cell the linear interpolation between the two puts V on the face; past it c falls as
    /// (h - a) / a to 0 a cell inside, where the node holds V as the body's other nodes do (c
    /// above 1 would amplify the outside node's velocity; a node left free there, as this
    /// once did, jumped between the pressure's value and V as the face moved).
    fn ghost_normals(
        &mut self,
        b: usize,
        span: &Span<D>,
        idx: &[usize; D],
        geo: &GridGeometry<D>,
    ) -> u8 {
        let eps = EPS;
        let i = geo.flat(idx);
        let xn = geo.node_position(idx);
        let mut h = 0u8;
        for d in 0..D {
            let below =
                (span.live_lo[d] && idx[d] > 0).then(|| (xn[d] - span.face_lo[d], idx[d] - 1));
            let above = (span.live_hi[d] && idx[d] + 1 < geo.nodes[d])
                .then(|| (span.face_hi[d] - xn[d], idx[d] + 1));
            let near = match (below, above) {
                (Some(l), Some(u)) => Some(if l.0 <= u.0 { l } else { u }),
                (l, u) => l.or(u),
            };
            if let Some((a, beyond)) = near {
                if a >= -eps * geo.h && a < (1.0 - eps) * geo.h {
                    let mut out = *idx;
                    out[d] = beyond;
                    let a = a.max(0.0);
                    let c = (a / (geo.h - a)).min((geo.h - a) / a.max(1e-300));
                    self.ghosts
                        .push((i, self.velocity[b][d], d, geo.flat(&out), c));
                    h |= 1 << d;
                }
            }
        }
        h
    }

    /// The quadrature points of the faces that can meet the material: on each face inside the
    /// grid, not on a wall, and not inside another body, three Gauss-Legendre points per cell
    /// along each tangential axis (exact for the products of shape functions and velocities
    /// the flux and the force integrate, up to the fifth degree).
    fn place_face_points(&mut self, geo: &GridGeometry<D>) {
        const GAUSS: [(f64, f64); 3] = [
            (-0.774_596_669_241_483_4, 5.0 / 9.0),
            (0.0, 8.0 / 9.0),
            (0.774_596_669_241_483_4, 5.0 / 9.0),
        ];
        self.faces.clear();
        let (grid_lo, grid_hi) = (geo.origin, geo.upper());
        let tol = 1e-9 * geo.h;
        let mut lines = std::mem::take(&mut self.lines);
        for b in 0..self.len() {
            if self.shaped[b].is_some() {
                continue;
            }
            let (lo, hi) = self.bounds(b);
            for axis in 0..D {
                for (plane, sign) in [(lo[axis], 1.0), (hi[axis], -1.0)] {
                    if plane <= grid_lo[axis] + tol || plane >= grid_hi[axis] - tol {
                        continue;
                    }
                    // the Gauss points along each tangential axis, cell by cell
                    let mut empty = false;
                    for (k, e) in (0..D).filter(|&e| e != axis).enumerate() {
                        let line = &mut lines[k];
                        line.clear();
                        let (a, z) = (lo[e].max(grid_lo[e]), hi[e].min(grid_hi[e]));
                        empty |= z <= a;
                        let mut s = a;
                        while s < z {
                            let next_line = grid_lo[e]
                                + (((s - grid_lo[e]) / geo.h + 1e-9).floor() + 1.0) * geo.h;
                            let t = next_line.min(z);
                            let (mid, half) = (0.5 * (s + t), 0.5 * (t - s));
                            for (g, w) in GAUSS {
                                line.push((mid + g * half, w * half));
                            }
                            s = t;
                        }
                    }
                    if empty {
                        continue;
                    }
                    let counts: [usize; 2] =
                        std::array::from_fn(|k| if k + 1 < D { lines[k].len() } else { 1 });
                    let total = counts[0] * counts[1];
                    for n in 0..total {
                        let mut x = Vector::<D>::zeros();
                        x[axis] = plane;
                        let (mut weight, mut rem) = (1.0, n);
                        for (k, e) in (0..D).filter(|&e| e != axis).enumerate() {
                            let (pos, w) = lines[k][rem % counts[k]];
                            rem /= counts[k];
                            x[e] = pos;
                            weight *= w;
                        }
                        // a face inside another body meets no material
                        let covered = (0..self.len()).any(|o| {
                            let (olo, ohi) = self.bounds(o);
                            o != b
                                && self.shaped[o].is_none()
                                && (0..D).all(|d| x[d] > olo[d] - tol && x[d] < ohi[d] + tol)
                        });
                        if !covered {
                            self.faces.push(FacePoint {
                                x,
                                weight,
                                axis,
                                sign,
                                body: b,
                            });
                        }
                    }
                }
            }
        }
        self.lines = lines;
    }

    /// Whether `x` lies inside a body, at the time of [`RigidBodies::set_time`].
    pub fn contains(&self, x: &Vector<D>) -> bool {
        (0..self.len()).any(|b| match &self.shaped[b] {
            Some(s) => s.shape.holds(&self.pose[b], &to3(x)),
            None => {
                let (lo, hi) = self.bounds(b);
                (0..D).all(|d| x[d] > lo[d] && x[d] < hi[d])
            }
        })
    }

    /// Box `b` as the cut cells see it: each face less than SNAP past a node row moved onto
    /// that row, as [`RigidBodies::held`] moves it (the sliver between counts as the body's).
    fn snapped(&self, b: usize, geo: &GridGeometry<D>) -> (Vector<D>, Vector<D>) {
        let (mut lo, mut hi) = self.bounds(b);
        for d in 0..D {
            let row = |x: f64| (x - geo.origin[d]) / geo.h;
            let below = row(lo[d]).floor();
            if row(lo[d]) - below < SNAP {
                lo[d] = geo.origin[d] + below * geo.h;
            }
            let above = row(hi[d]).ceil();
            if above - row(hi[d]) < SNAP {
                hi[d] = geo.origin[d] + above * geo.h;
            }
        }
        (lo, hi)
    }

    /// The part of the box [lo, hi] that the box bodies (not the shaped ones) leave open, their
    /// faces snapped (`RigidBodies::snapped`) to the node rows: its volume and centroid, exact
    /// for one body (overlapping bodies are taken one by one, their common part counted once
    /// per body, the volume clamped at zero).
    pub fn open_part(
        &self,
        geo: &GridGeometry<D>,
        lo: &Vector<D>,
        hi: &Vector<D>,
    ) -> (f64, Vector<D>) {
        let whole: f64 = (0..D).map(|d| hi[d] - lo[d]).product();
        let centre = (lo + hi) * 0.5;
        let (mut volume, mut moment) = (whole, centre * whole);
        for b in 0..self.len() {
            if self.shaped[b].is_some() {
                continue;
            }
            let (blo, bhi) = self.snapped(b, geo);
            let (mut v, mut c) = (1.0, Vector::<D>::zeros());
            for d in 0..D {
                let (a, z) = (lo[d].max(blo[d]), hi[d].min(bhi[d]));
                v *= (z - a).max(0.0);
                c[d] = 0.5 * (a + z);
            }
            volume -= v;
            moment -= c * v;
        }
        if volume <= 1e-12 * whole {
            return (0.0, centre);
        }
        (volume, moment / volume)
    }

    /// Whether a box body (not a shaped one) overlaps the cell whose lower corner is `lower`.
    pub fn box_meets_cell(&self, lower: &Vector<D>, h: f64) -> bool {
        (0..self.len()).any(|b| {
            self.shaped[b].is_none() && {
                let (lo, hi) = self.bounds(b);
                (0..D).all(|d| hi[d] > lower[d] && lo[d] < lower[d] + h)
            }
        })
    }

    /// Whether the projection sees the bodies' faces where they lie (cut cells).
    pub fn cuts_cells(&self) -> bool {
        self.cut && !self.is_empty()
    }

    /// The bodies' flux in the projection's right-hand side (cut cells). The weak condition
    /// on node i's row, over the material and the bodies together, is
    ///
    /// ```text
    /// int_fluid N_i div v dV + int_faces N_i (V_b - v) . n dS = 0
    /// ```
    ///
    /// with n out of the material into the body: the jump of the normal velocity across a
    /// face counts as a source, so the pressure makes the material's normal velocity the
    /// body's where the face lies, anywhere in a cell (Batty, Bertails & Bridson 2007, in the
    /// weak form). The assembly integrates the first term; this adds the second,
    /// -(1/dt) sum_g w_g N_i(x_g) (V_b - v(x_g)) . n_g, over the face points the level set
    /// `phi` reads as wet, to the right-hand sides `rhs` of the rows `row_of` numbers (each
    /// node's row + 1, 0 where it has none).
    pub fn add_face_flux(
        &self,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
        v: &[Vector<D>],
        phi: Option<&[f64]>,
        dt: f64,
        (row_of, rhs): (&[u32], &mut [f64]),
    ) {
        // serial: the points are few, and a fixed order keeps the bits on any thread count
        for f in &self.faces {
            if !wet(geo, phi, &f.x) {
                continue;
            }
            let st = Stencil::<D>::new(shape, &geo.to_cells(&f.x), geo.h, 0.0);
            let mut vn = 0.0;
            st.for_each(|nw| vn += nw.n * v[geo.flat(&nw.node)][f.axis]);
            let jump = f.sign * (self.velocity[f.body][f.axis] - vn) * f.weight / dt;
            st.for_each(|nw| {
                // (row + 1 stored, 0 off the unknowns: pressure::Unknowns::row_of)
                let r = row_of[geo.canonical(geo.flat(&nw.node))].wrapping_sub(1);
                if r != u32::MAX {
                    rhs[r as usize] -= nw.n * jump;
                }
            });
        }
    }

    /// Sets the bodies' nodes to the bodies' velocities (the components they hold).
    pub fn apply(&self, v: &mut [Vector<D>]) {
        for (&(i, _, h), set) in self.nodes.iter().zip(&self.node_velocity) {
            for d in 0..D {
                if h & (1 << d) != 0 {
                    v[i][d] = set[d];
                }
            }
        }
        // with cut cells, a node less than half a cell inside a face (at a from it) takes the
        // normal velocity that puts the body's on the face between it and the node beyond,
        // ((h - a) v_i + a v_beyond) / h = V
        for &(i, body, d, beyond, c) in &self.ghosts {
            v[i][d] = body + c * (body - v[beyond][d]);
        }
    }

    /// Sets bit d of `bits[i]` where [`Self::hold_still`] zeroes component d of node i.
    pub fn held_components(&self, bits: &mut [u8]) {
        for &(i, _, h) in &self.nodes {
            bits[i] |= h;
        }
    }

    /// Zeroes the components the bodies hold on their nodes.
    pub fn hold_still(&self, u: &mut [Vector<D>]) {
        for &(i, _, h) in &self.nodes {
            for d in 0..D {
                if h & (1 << d) != 0 {
                    crate::pages::store(&mut u[i][d], 0.0);
                }
            }
        }
    }

    /// Puts back outside the bodies, at the step's end (`dt` after [`RigidBodies::set_time`]),
    /// the particles that the step carried into one: a particle inside a box is reflected
    /// across the face it is nearest to by as much as it went past it, and its velocity
    /// relative to the body's into that face is removed, as the walls' `confine` does at a
    /// wall. The grid holds a body's velocity on its nodes, not on its faces, so
    /// the velocity a particle interpolates between the last node outside and the first inside
    /// carries it up to half a cell into the body (a 3D dam break left a hundred particles
    /// inside a column). A face whose reflection would leave the grid (a face on a wall, or a
    /// gate lifted a hair off the floor) is no way out. The momentum the particles lose joins
    /// the body's force of the step.
    pub fn push_out(
        &mut self,
        geo: &GridGeometry<D>,
        dt: f64,
        x: &mut [Vector<D>],
        v: &mut [Vector<D>],
        mass: &[f64],
    ) {
        if self.is_empty() {
            return;
        }
        self.update_ends(dt);
        let grid = (geo.origin, geo.upper());
        let n = x.len();
        let (mut hits, mut impulses) = (
            std::mem::take(&mut self.hit),
            std::mem::take(&mut self.impulse),
        );
        hits.resize(n, u32::MAX);
        impulses.resize(n, Vector::<D>::zeros());
        let this = &*self;
        (
            x.par_iter_mut(),
            v.par_iter_mut(),
            mass.par_iter(),
            hits.par_iter_mut(),
            impulses.par_iter_mut(),
        )
            .into_par_iter()
            .for_each(|(x, v, &m, hit, impulse)| {
                *hit = u32::MAX;
                for b in 0..this.len() {
                    let Some((d, sign, body)) = this.put_out(b, geo, grid, dt, x) else {
                        continue;
                    };
                    if (v[d] - body) * sign < 0.0 {
                        // the impulse the body gives the particle, the particle's push on it
                        *impulse = Vector::<D>::zeros();
                        impulse[d] = m * (v[d] - body) / dt;
                        *hit = b as u32;
                        v[d] = body;
                    }
                    // a particle is inside one body at most (bodies that overlap are one
                    // obstacle to it)
                    break;
                }
            });
        // the impulses summed in particle order: the same bits on any number of threads; over
        // several ranks each rank's sums apart, then added up
        let distributed = self.comm.is_distributed();
        let (mut force, mut torque) = if distributed {
            let (mut f, mut t) = (
                std::mem::take(&mut self.push_force),
                std::mem::take(&mut self.push_torque),
            );
            f.clear();
            f.resize(self.len(), Vector::<D>::zeros());
            t.clear();
            t.resize(self.len(), Vector3::zeros());
            (f, t)
        } else {
            (
                std::mem::take(&mut self.force),
                std::mem::take(&mut self.torque),
            )
        };
        for ((&b, i), x) in hits.iter().zip(&impulses).zip(x.iter()) {
            if b != u32::MAX {
                let b = b as usize;
                force[b] += *i;
                if let Some((pose, _)) = &self.ends[b] {
                    torque[b] += (to3(x) - pose.centre).cross(&to3(i));
                }
            }
        }
        if distributed {
            self.comm.sum_all(&mut [
                bytemuck::cast_slice_mut(&mut force),
                bytemuck::cast_slice_mut(&mut torque),
            ]);
            for b in 0..self.len() {
                self.force[b] += force[b];
                self.torque[b] += torque[b];
            }
            (self.push_force, self.push_torque) = (force, torque);
        } else {
            (self.force, self.torque) = (force, torque);
        }
        (self.hit, self.impulse) = (hits, impulses);
    }

    /// Where each shaped body is at the end of a step of `dt`, with its bounds (unbounded
    /// along the axes past D), for [`RigidBodies::push_out`].
    fn update_ends(&mut self, dt: f64) {
        let mut ends = std::mem::take(&mut self.ends);
        ends.clear();
        for b in 0..self.len() {
            ends.push(self.shaped[b].as_ref().map(|s| {
                let pose = match s.motion {
                    Motion::Free(_) => self.pose[b],
                    Motion::Prescribed { .. } => s
                        .motion
                        .pose_at(&s.start, self.time + dt)
                        .expect("prescribed"),
                };
                let (mut lo, mut hi) = s.shape.world_bounds(&pose);
                for d in D..3 {
                    (lo[d], hi[d]) = (f64::NEG_INFINITY, f64::INFINITY);
                }
                (pose, (lo, hi))
            }));
        }
        self.ends = ends;
    }

    /// Moves a particle at `x` that lies inside body `b` at the end of a step of `dt` (on the
    /// grid `geo`, whose corners are `(lo_grid, hi_grid)`) out through one face, and gives
    /// that face's axis d, its outward sign and the body's velocity along d there; None where the particle is outside or the body has no way out for it.
    /// A box's way out is its face of least depth whose reflection stays inside the grid (a
    /// face on a wall, or one so near it that the reflection would cross it, is none).
    fn put_out(
        &self,
        b: usize,
        geo: &GridGeometry<D>,
        (lo_grid, hi_grid): (Vector<D>, Vector<D>),
        dt: f64,
        x: &mut Vector<D>,
    ) -> Option<(usize, f64, f64)> {
        if let Some((pose, (lo, hi))) = &self.ends[b] {
            let s = self.shaped[b].as_ref().expect("a shaped body");
            let mut y = to3(x);
            if (0..D).any(|d| y[d] <= lo[d] || y[d] >= hi[d]) || !s.shape.holds(pose, &y) {
                return None;
            }
            let grid_box = (to3(&lo_grid), to3(&hi_grid));
            let (d, sign) = s.shape.put_out(pose, geo.h, grid_box, &mut y)?;
            *x = from3(&y);
            return Some((d, sign, pose.velocity_at(&y)[d]));
        }
        let eps = 1e-9 * geo.h;
        let (mut lo, mut hi) = self.bounds(b);
        let shift = self.velocity[b] * dt;
        lo += shift;
        hi += shift;
        if (0..D).any(|d| x[d] <= lo[d] || x[d] >= hi[d]) {
            return None;
        }
        // (depth, axis, outward sign, new coordinate) of the way out
        let mut best: Option<(f64, usize, f64, f64)> = None;
        for d in 0..D {
            for (face, sign) in [(lo[d], -1.0), (hi[d], 1.0)] {
                let depth = sign * (face - x[d]);
                let to = face + sign * depth.min(0.5 * (hi[d] - lo[d]));
                if to <= lo_grid[d] + eps || to >= hi_grid[d] - eps {
                    continue;
                }
                if best.is_none_or(|(bd, ..)| depth < bd) {
                    best = Some((depth, d, sign, to));
                }
            }
        }
        let (_, d, sign, to) = best?;
        x[d] = to;
        Some((d, sign, self.velocity[b][d]))
    }

    /// Adds to each cell's volume fraction the part of it a body covers, so that the
    /// free-surface detection reads a body as it reads a wall: the material against it is
    /// not at a free surface.
    pub fn cover(&self, geo: &GridGeometry<D>, fraction: &mut [f64]) {
        for &(c, share) in &self.shaped_cover {
            fraction[c] += share;
        }
        for b in 0..self.len() {
            if self.shaped[b].is_some() {
                continue;
            }
            let (lo, hi) = self.bounds(b);
            let cl = geo.to_cells(&lo);
            let ch = geo.to_cells(&hi);
            let first: [usize; D] = std::array::from_fn(|d| {
                PAD + (cl[d].floor().max(0.0) as usize).min(geo.cells[d] - 1)
            });
            let last: [usize; D] = std::array::from_fn(|d| {
                PAD + ((ch[d].ceil() - 1.0).max(0.0) as usize).min(geo.cells[d] - 1)
            });
            if (0..D).any(|d| ch[d] <= 0.0 || cl[d] >= geo.cells[d] as f64) {
                continue;
            }
            for_each_cell(first, last, |idx| {
                let mut part = 1.0;
                for d in 0..D {
                    let c0 = idx[d] as f64 - PAD as f64;
                    part *= (ch[d].min(c0 + 1.0) - cl[d].max(c0)).clamp(0.0, 1.0);
                }
                fraction[geo.flat(idx)] += part;
            });
        }
    }

    /// With cut cells, fills the open part of each cell a box's face cuts as full as the cell
    /// beyond the face, on the material's side, is filled, where its own particles fill it
    /// less. Particles seeded on a lattice stop up to a particle's spacing short of a face (none
    /// sits in a narrower sliver), and a cut cell at the free surface read as partly empty: the
    /// level set put the water line against the face too low, the projection's divergence
    /// weighed the cell less than its matrix, and still water around a box held across the
    /// surface at a face between node rows began to move (and pushed a floating box sideways).
    /// `solid` is the share of each cell the bodies cover ([`RigidBodies::cover`]), `fraction`
    /// the particles' volume fraction of each cell.
    pub fn fill_cut_cells(&self, geo: &GridGeometry<D>, solid: &[f64], fraction: &mut [f64]) {
        if !self.cut {
            return;
        }
        let cells = geo.cells;
        for b in 0..self.len() {
            if self.shaped[b].is_some() {
                continue;
            }
            let (lo, hi) = self.bounds(b);
            let (cl, ch) = (geo.to_cells(&lo), geo.to_cells(&hi));
            if (0..D).any(|e| ch[e] <= 0.0 || cl[e] >= cells[e] as f64) {
                continue;
            }
            for d in 0..D {
                // the face's cells, and the side of the material beyond them
                for (plane, out) in [(cl[d], -1isize), (ch[d], 1)] {
                    let k = plane.floor();
                    let beyond = k as isize + out;
                    if plane - k < EPS || k < 0.0 || beyond < 0 || beyond >= cells[d] as isize {
                        continue;
                    }
                    let range = |e: usize| -> (usize, usize) {
                        if e == d {
                            (PAD + k as usize, PAD + k as usize)
                        } else {
                            let first = (cl[e].floor().max(0.0) as usize).min(cells[e] - 1);
                            let last = ((ch[e].ceil() - 1.0).max(0.0) as usize).min(cells[e] - 1);
                            (PAD + first, PAD + last)
                        }
                    };
                    let first: [usize; D] = std::array::from_fn(|e| range(e).0);
                    let last: [usize; D] = std::array::from_fn(|e| range(e).1);
                    for_each_cell(first, last, |idx| {
                        let mut next = *idx;
                        next[d] = (PAD as isize + beyond) as usize;
                        let (c, n) = (geo.flat(idx), geo.flat(&next));
                        let open = 1.0 - solid[c].clamp(0.0, 1.0);
                        let open_beyond = 1.0 - solid[n].clamp(0.0, 1.0);
                        if open > 0.0 && open_beyond > 0.5 {
                            let full = (fraction[n] / open_beyond).clamp(0.0, 1.0);
                            fraction[c] = fraction[c].max(open * full);
                        }
                    });
                }
            }
        }
    }

    /// After P2G: the momentum the bodies' nodes would reach over `dt` without them (no
    /// damping: damping is not a force the body feels).
    pub fn begin_step(&mut self, grid: &Grid<D>, dt: f64) {
        self.free_momentum.fill(Vector::<D>::zeros());
        self.free_torque.fill(Vector3::zeros());
        for &(i, b, h) in &self.nodes {
            if !self.owns(i, &grid.geo) {
                continue;
            }
            let p = masked(grid.velocity[i] * grid.mass[i] + grid.force[i] * dt, h);
            self.free_momentum[b] += p;
            if self.shaped[b].is_some() {
                let m = self.arm(b, i, &grid.geo).cross(&to3(&p));
                self.free_torque[b] += m;
            }
        }
        if self.sliced() {
            self.comm.sum_all(&mut [
                bytemuck::cast_slice_mut(&mut self.free_momentum),
                bytemuck::cast_slice_mut(&mut self.free_torque),
            ]);
        }
    }

    /// Whether this rank adds node `i` to the bodies' sums over nodes: every node on one
    /// process, the nodes of its own layers over ranks with the grid in slabs (the sums of
    /// particles there are whole on it: [`crate::slabs`]).
    #[inline]
    fn owns(&self, i: usize, geo: &GridGeometry<D>) -> bool {
        match &self.owned_layers {
            Some((axis, layers)) if self.comm.is_distributed() => {
                layers.contains(&geo.layer(i, *axis))
            }
            _ => true,
        }
    }

    /// Whether this is a rank of a run with the grid in slabs (not rank 0 writing on its own,
    /// with every particle, between steps).
    fn sliced(&self) -> bool {
        self.owned_layers.is_some() && self.comm.is_distributed()
    }

    /// The arm from shaped body `b`'s reference point to node `i`.
    fn arm(&self, b: usize, i: usize, geo: &GridGeometry<D>) -> Vector3<f64> {
        to3(&geo.node_position(&geo.multi(i))) - self.pose[b].centre
    }

    /// After the step's pressure: the force and torque on each body, and the free bodies
    /// moved by them over the step, then parted from the bodies they reached
    /// (the `contact` module) and held inside the grid. Contact and walls take turns (three passes): a
    /// body parted from another onto a wall is put back and parted again.
    pub fn end_step(&mut self, grid: &Grid<D>, dt: f64, pressure: PressureForce<'_, D>) {
        if self.is_empty() {
            return;
        }
        self.measure(grid, dt, pressure);
        for b in 0..self.len() {
            if let Some(free) = &self.free_box[b] {
                // the box's own velocity moves it from the next set_time on
                let mut pose = Pose::at(Vector3::zeros());
                pose.velocity = to3(&self.velocity[b]);
                free.advance(
                    &mut pose,
                    &mut self.last[b],
                    to3(&self.force[b]),
                    Vector3::zeros(),
                    dt,
                );
                self.velocity[b] = from3(&pose.velocity);
            }
            if let Some(ShapedBody {
                motion: Motion::Free(free),
                ..
            }) = &self.shaped[b]
            {
                free.advance(
                    &mut self.pose[b],
                    &mut self.last[b],
                    to3(&self.force[b]),
                    self.torque[b],
                    dt,
                );
            }
        }
        let mut stepped = std::mem::take(&mut self.stepped);
        stepped.clear();
        stepped.extend((0..self.len()).map(|b| self.free_velocity(b)));
        for pass in 0..3 {
            if !self.contacts(dt, grid.geo.h) && pass > 0 {
                break;
            }
            self.hold_in_grid(&grid.geo, dt);
        }
        // what the contact and the walls took from a body's velocity is no acceleration the
        // material's reaction lags: the next step's added-mass term must not give it back
        // (it did: a ball that sank onto the floor bounced off it, higher each time)
        for (b, v) in stepped.iter().enumerate() {
            let change = self.free_velocity(b) - v;
            self.last[b].0 += change;
        }
        self.stepped = stepped;
    }

    /// The velocity of free body `b` (zero for the others).
    fn free_velocity(&self, b: usize) -> Vector3<f64> {
        if self.free_box[b].is_some() {
            to3(&self.velocity[b])
        } else if self.is_free(b) {
            self.pose[b].velocity
        } else {
            Vector3::zeros()
        }
    }

    /// The first free body whose position or velocity is not a finite number.
    pub fn runaway(&self) -> Option<usize> {
        (0..self.len()).find(|&b| {
            self.is_free(b)
                && !(self.free_velocity(b).iter().all(|c| c.is_finite())
                    && self.centre(b, self.time).iter().all(|c| c.is_finite())
                    && self.pose[b].omega.iter().all(|c| c.is_finite()))
        })
    }

    /// The walls hold the free bodies: a box's step that would take a face past one ends on
    /// it; a shaped body whose surface passed one is put back on it, its velocity into it
    /// stopped.
    fn hold_in_grid(&mut self, geo: &GridGeometry<D>, dt: f64) {
        let (glo, ghi) = (geo.origin, geo.upper());
        for b in 0..self.len() {
            if self.free_box[b].is_some() {
                let (lo, hi) = self.bounds(b);
                for d in 0..D {
                    let v = self.velocity[b][d];
                    if lo[d] + v * dt < glo[d] {
                        self.velocity[b][d] = (glo[d] - lo[d]) / dt;
                    } else if hi[d] + v * dt > ghi[d] {
                        self.velocity[b][d] = (ghi[d] - hi[d]) / dt;
                    }
                }
            }
            if let Some(ShapedBody {
                shape,
                motion: Motion::Free(_),
                ..
            }) = &self.shaped[b]
            {
                let pose = &mut self.pose[b];
                let (lo, hi) = shape.extent(pose);
                let (glo, ghi) = (to3(&glo), to3(&ghi));
                for d in 0..D {
                    if lo[d] < glo[d] {
                        pose.centre[d] += glo[d] - lo[d];
                        pose.velocity[d] = pose.velocity[d].max(0.0);
                    } else if hi[d] > ghi[d] {
                        pose.centre[d] -= hi[d] - ghi[d];
                        pose.velocity[d] = pose.velocity[d].min(0.0);
                    }
                }
            }
        }
    }

    /// The start of [`RigidBodies::measure`]'s sums over nodes: minus the momentum the
    /// bodies' nodes held before the step, on one process; over slabs nothing (each rank's
    /// nodes are summed apart and added up first, [`RigidBodies::add_up_node_sums`]).
    fn start_node_sums(&mut self, sliced: bool) {
        for (b, f) in self.force.iter_mut().enumerate() {
            *f = if sliced {
                Vector::<D>::zeros()
            } else {
                -self.free_momentum[b]
            };
        }
        for (b, m) in self.torque.iter_mut().enumerate() {
            *m = if sliced {
                Vector3::zeros()
            } else {
                -self.free_torque[b]
            };
        }
    }

    /// Over slabs: the ranks' sums over their own nodes added up, then the momentum before
    /// the step taken off.
    fn add_up_node_sums(&mut self) {
        self.comm.sum_all(&mut [
            bytemuck::cast_slice_mut(&mut self.force),
            bytemuck::cast_slice_mut(&mut self.torque),
        ]);
        for (b, f) in self.force.iter_mut().enumerate() {
            *f -= self.free_momentum[b];
        }
        for (b, m) in self.torque.iter_mut().enumerate() {
            *m -= self.free_torque[b];
        }
    }

    /// Before the last wall conditions of the step: the force on each body. With the
    /// projection the pressure's force on the bodies' nodes is added in the weak form (see
    /// [`PressureForce`]).
    fn measure(&mut self, grid: &Grid<D>, dt: f64, pressure: PressureForce<'_, D>) {
        let sliced = self.sliced();
        self.start_node_sums(sliced);
        for (k, &(i, b, h)) in self.nodes.iter().enumerate() {
            if !self.owns(i, &grid.geo) {
                continue;
            }
            // with cut cells the value the node holds (a ghost value on a face's normal), which
            // the projection's last pass has set
            let set = if self.cut && self.shaped[b].is_none() {
                grid.velocity_new[i]
            } else {
                self.node_velocity[k]
            };
            let p = masked(set * grid.mass[i], h);
            self.force[b] += p;
            if self.shaped[b].is_some() {
                let m = self.arm(b, i, &grid.geo).cross(&to3(&p));
                self.torque[b] += m;
            }
        }
        if sliced {
            self.add_up_node_sums();
        }
        for f in &mut self.force {
            *f /= -dt;
        }
        for m in &mut self.torque {
            *m /= -dt;
        }
        let (ps, shape, node_pressure, phi, kinds) = match pressure {
            PressureForce::None => return,
            PressureForce::Nodal(f) => {
                for &(i, b, h) in &self.nodes {
                    self.force[b] += masked(f[i], h);
                    if self.shaped[b].is_some() {
                        let m = self.arm(b, i, &grid.geo).cross(&to3(&masked(f[i], h)));
                        self.torque[b] += m;
                    }
                }
                return;
            }
            PressureForce::Particles {
                particles,
                shape,
                pressure,
                level_set,
                kinds,
            } => (particles, shape, pressure, level_set, kinds),
        };
        self.pressure_force(&grid.geo, sliced, (ps, shape, node_pressure), (phi, kinds));
    }

    /// The pressure's force on the bodies under the nodal projection (measured after the
    /// bodies' momentum): over its particles next to them and over their wet faces.
    fn pressure_force(
        &mut self,
        geo: &GridGeometry<D>,
        sliced: bool,
        (ps, shape, node_pressure): (&Particles<D>, ShapeFunction, &[f64]),
        (phi, kinds): (Option<&[f64]>, &[NodeKind]),
    ) {
        // over slabs each rank's particles' and faces' sum apart (a face the rank's whose slab
        // holds it, where the free surface is that rank's), then added up over the ranks
        let whole = sliced.then(|| {
            let mut f = std::mem::take(&mut self.push_force);
            let mut t = std::mem::take(&mut self.push_torque);
            f.clear();
            f.resize(self.len(), Vector::<D>::zeros());
            t.clear();
            t.resize(self.len(), Vector3::zeros());
            std::mem::swap(&mut self.force, &mut f);
            std::mem::swap(&mut self.torque, &mut t);
            (f, t)
        });
        self.pressure_on(geo, sliced, (ps, shape, node_pressure), (phi, kinds));
        if let Some((mut f, mut t)) = whole {
            self.comm.sum_all(&mut [
                bytemuck::cast_slice_mut(&mut self.force),
                bytemuck::cast_slice_mut(&mut self.torque),
            ]);
            for b in 0..self.len() {
                f[b] += self.force[b];
                t[b] += self.torque[b];
            }
            std::mem::swap(&mut self.force, &mut f);
            std::mem::swap(&mut self.torque, &mut t);
            (self.push_force, self.push_torque) = (f, t);
        }
    }

    /// The pressure's force on the bodies, added to `force` and `torque`: from the particles
    /// next to them and from the wet faces (over slabs, those of this rank's slab).
    fn pressure_on(
        &mut self,
        geo: &GridGeometry<D>,
        sliced: bool,
        (ps, shape, node_pressure): (&Particles<D>, ShapeFunction, &[f64]),
        (phi, kinds): (Option<&[f64]>, &[NodeKind]),
    ) {
        // the pressure's force on the components the bodies hold, as the corrector applied it:
        // f_i = -sum_p V_p N_ip (grad p)_p. Serial: the particles near the bodies are few, and
        // a fixed order keeps the sum's bits the same on any number of threads.
        for p in 0..ps.len() {
            let xc = geo.to_cells(&ps.x[p]);
            let near = (0..self.len()).any(|b| {
                let (lo, hi) = &self.reach[b];
                (0..D).all(|d| xc[d] > lo[d] - 2.0 && xc[d] < hi[d] + 2.0)
            });
            if !near {
                continue;
            }
            let stencil = Stencil::<D>::new(shape, &xc, geo.h, ps.half_width[p]);
            let mut grad_p = Vector::<D>::zeros();
            stencil.for_each(|nw| grad_p += nw.grad * node_pressure[geo.flat(&nw.node)]);
            let vol = ps.volume0[p];
            stencil.for_each(|nw| {
                let i = geo.flat(&nw.node);
                let (b, h) = self.owner[i];
                if b != usize::MAX && h != 0 {
                    let f = masked(grad_p * (vol * nw.n), h);
                    self.force[b] -= f;
                    if self.shaped[b].is_some() {
                        let arm = to3(&geo.node_position(&geo.multi(i))) - self.pose[b].centre;
                        self.torque[b] -= arm.cross(&to3(&f));
                    }
                }
            });
        }
        // and the pressure on the faces, int_faces p n dS (n into the body): the corrector's
        // gradient form pushes the material with -int grad p dV, whose part on a body's side is
        // this, the face's reaction; over the wet faces only, where the level set reads water
        let mine = |x: &Vector<D>| match &self.owned_layers {
            Some((axis, layers)) if sliced => {
                let layer = ((x[*axis] - geo.origin[*axis]) / geo.h).floor() + PAD as f64;
                layers.contains(&(layer.max(0.0) as usize))
            }
            _ => true,
        };
        for f in &self.faces {
            if !mine(&f.x) || !wet(geo, phi, &f.x) {
                continue;
            }
            if let Some(p) = surface_pressure(geo, node_pressure, kinds, &f.x) {
                self.force[f.body][f.axis] += f.sign * p * f.weight;
            }
        }
        // and on the shaped bodies' wet surfaces, at the rays' crossings
        // (a part of a body outside the domain meets no material)
        for f in &self.surface {
            if !geo.contains(&f.x) || !mine(&f.x) || !wet(geo, phi, &f.x) {
                continue;
            }
            if let Some(p) = surface_pressure(geo, node_pressure, kinds, &f.x) {
                let push = f.push * p;
                self.force[f.body] += push;
                self.torque[f.body] += (to3(&f.x) - self.pose[f.body].centre).cross(&to3(&push));
            }
        }
    }
}

/// Whether the level set `phi` (at the nodes, negative in the material), interpolated linearly
/// to `x`, reads it as in the material; without a level set, every point.
fn wet<const D: usize>(geo: &GridGeometry<D>, phi: Option<&[f64]>, x: &Vector<D>) -> bool {
    let Some(phi) = phi else {
        return true;
    };
    let st = Stencil::<D>::new(ShapeFunction::Linear, &geo.to_cells(x), geo.h, 0.0);
    let mut value = 0.0;
    st.for_each(|nw| value += nw.n * phi[geo.flat(&nw.node)]);
    value <= 0.0
}

/// The pressure at `x` on a shaped body's surface, from the nodes less than two cells from
/// it that carry one (the material's interior and free-surface nodes): the value at `x` of the
/// plane fitted to them by least squares, weighted by a tent of two cells, or their weighted
/// mean where they do not span a plane. The fit extrapolates: the nodes that carry a pressure
/// lie up to a cell from the surface, on the material's side, and their mean would miss the
/// hydrostatic pressure at the surface by up to rho g h (a floating box's draft by a cell).
/// None where no node carries a pressure.
fn surface_pressure<const D: usize>(
    geo: &GridGeometry<D>,
    pressure: &[f64],
    kinds: &[NodeKind],
    x: &Vector<D>,
) -> Option<f64> {
    use nalgebra::{Matrix4, Vector4};
    let xc = geo.to_cells(x);
    let base: [isize; D] = std::array::from_fn(|d| xc[d].floor() as isize - 1);
    let (mut a, mut rhs) = (Matrix4::<f64>::zeros(), Vector4::<f64>::zeros());
    let (mut wsum, mut psum) = (0.0, 0.0);
    for k in 0..4usize.pow(D as u32) {
        let mut rem = k;
        let mut idx = [0usize; D];
        let mut basis = Vector4::<f64>::zeros();
        basis[0] = 1.0;
        let mut w = 1.0;
        let mut inside = true;
        for d in 0..D {
            let c = base[d] + (rem % 4) as isize;
            rem /= 4;
            if c < 0 || c > geo.cells[d] as isize {
                inside = false;
                break;
            }
            idx[d] = PAD + c as usize;
            let dx = c as f64 - xc[d];
            w *= (1.0 - dx.abs() / 2.0).max(0.0);
            basis[1 + d] = dx;
        }
        if !inside || w <= 0.0 {
            continue;
        }
        let i = geo.flat(&idx);
        if !matches!(
            kinds[geo.canonical(i)],
            NodeKind::Interior | NodeKind::FreeSurface
        ) {
            continue;
        }
        a += basis * basis.transpose() * w;
        rhs += basis * (w * pressure[i]);
        wsum += w;
        psum += w * pressure[i];
    }
    if wsum <= 0.0 {
        return None;
    }
    for d in D..3 {
        a[(1 + d, 1 + d)] = 1.0;
    }
    // a plane only where the nodes span one well (the smallest eigenvalue of the normalised
    // moments not far below the largest): else their weighted mean
    let eig = (a / wsum).symmetric_eigenvalues();
    let (lo, hi) = eig
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &e| (l.min(e), h.max(e)));
    if lo > 1e-3 * hi {
        if let Some(c) = a.cholesky() {
            return Some(c.solve(&rhs)[0]);
        }
    }
    Some(psum / wsum)
}

/// Calls `f` with each cell index from `first` to `last` (both included, per axis), the first
/// axis fastest.
fn for_each_cell<const D: usize>(
    first: [usize; D],
    last: [usize; D],
    mut f: impl FnMut(&[usize; D]),
) {
    let mut idx = first;
    'cells: loop {
        f(&idx);
        for d in 0..D {
            if idx[d] < last[d] {
                idx[d] += 1;
                continue 'cells;
            }
            idx[d] = first[d];
        }
        break;
    }
}

/// The components of `v` that `held` names (bit d: component d), the others zero.
fn masked<const D: usize>(v: Vector<D>, held: u8) -> Vector<D> {
    Vector::<D>::from_fn(|d, _| if held & (1 << d) != 0 { v[d] } else { 0.0 })
}

/// How the projection's pressure reaches the rigid bodies' force.
pub enum PressureForce<'a, const D: usize> {
    /// The explicit scheme: the pressure is in the particle stress, already in the nodes'
    /// force.
    None,
    /// The nodal projection: the particles, the shape functions, the nodes' new pressure and
    /// the level set of the free surface, where there is one. The force is the pressure on
    /// the bodies' wet faces, int p n dS, plus on the components the bodies hold the
    /// corrector's share, -sum_p V_p N_ip (grad p)_p, which the holding takes away from the
    /// material. (The corrector's gradient form spreads the faces' push over the nodes near
    /// them; only its sum over them, the face integral, is the body's.)
    Particles {
        /// The particles (positions, half-widths, volumes).
        particles: &'a Particles<D>,
        /// The shape functions.
        shape: ShapeFunction,
        /// The nodes' pressure p^{n+1}.
        pressure: &'a [f64],
        /// The free surface's level set at the nodes.
        level_set: Option<&'a [f64]>,
        /// Each node's role in the pressure solve.
        kinds: &'a [NodeKind],
    },
    /// The cell projection: the weak force sum_c p_c D_cj per node, the corrector's own.
    Nodal(&'a [Vector<D>]),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geo() -> GridGeometry<2> {
        GridGeometry::new(Vector::<2>::zeros(), 0.1, [10, 10])
    }

    fn bodies(lo: [f64; 2], hi: [f64; 2], v: [f64; 2]) -> RigidBodies<2> {
        RigidBodies::new(
            &[RigidBox {
                lo: Vector::<2>::from(lo),
                hi: Vector::<2>::from(hi),
                velocity: Vector::<2>::from(v),
                motion: None,
                sides: RigidSides::Rough,
                shaped: None,
                free: None,
            }],
            false,
        )
    }

    /// The flat index of the node at (x, y) of [`geo`].
    fn node_at(g: &GridGeometry<2>, x: f64, y: f64) -> usize {
        g.flat(&[
            PAD + (x / 0.1).round() as usize,
            PAD + (y / 0.1).round() as usize,
        ])
    }

    #[test]
    fn a_box_holds_the_nodes_inside_it_as_it_moves() {
        let g = geo();
        let mut r = bodies([0.0, 0.8], [0.3, 1.2], [0.0, -1.0]);
        r.set_time(0.0, &g);
        // x nodes 0..=3; y nodes 8..=10 (the grid's top is 1.0), and none ahead: row 7 is a
        // whole cell below the face
        assert_eq!(r.nodes.len(), 4 * 3);
        r.set_time(0.05, &g);
        // face at 0.75: row 7 (0.7) is less than a cell ahead of it
        assert_eq!(r.nodes.len(), 4 * 4);
        r.set_time(0.1, &g);
        // face at 0.7: rows 7..=10, row 6 a whole cell ahead
        assert_eq!(r.nodes.len(), 4 * 4);
        for &(i, _, _) in &r.nodes {
            let x = g.node_position(&g.multi(i));
            assert!(x[0] <= 0.3 + 1e-12 && x[1] >= 0.65 - 1e-12);
        }
        // at rest, only the nodes inside
        let mut r = bodies([0.0, 0.75], [0.3, 1.0], [0.0, 0.0]);
        r.set_time(0.0, &g);
        assert_eq!(r.nodes.len(), 4 * 3);
    }

    #[test]
    fn smooth_sides_hold_only_the_normal_velocity() {
        let g = geo();
        let mut r = bodies([0.0, 0.72], [0.3, 1.0], [0.0, -1.0]);
        r.smooth = vec![true];
        r.set_time(0.0, &g);
        let node = |x: f64, y: f64| node_at(&g, x, y);
        let held = |x: f64, y: f64| r.nodes.iter().find(|n| n.0 == node(x, y)).map(|n| n.2);
        // inside: the whole velocity
        assert_eq!(held(0.1, 0.9), Some(0b11));
        // ahead of the leading face (the base at 0.72 leads; row 0.7 is less than a cell
        // ahead of it), also below a side: its normal, y, the push
        assert_eq!(held(0.1, 0.7), Some(0b10));
        assert_eq!(held(0.3, 0.7), Some(0b10));
        // on the sides x = 0 and x = 0.3, above the base: their normal, x, only
        assert_eq!(held(0.3, 0.8), Some(0b01));
        assert_eq!(held(0.0, 0.9), Some(0b01));
        // on the trailing face (the top, y = 1.0): its normal, y
        assert_eq!(held(0.1, 1.0), Some(0b10));
        // the corner of a side and the top: both normals
        assert_eq!(held(0.3, 1.0), Some(0b11));
        assert_eq!(held(0.4, 0.9), None);
        let mut v = vec![Vector::<2>::new(5.0, 5.0); g.node_count()];
        r.apply(&mut v);
        assert_eq!(v[node(0.3, 0.8)], Vector::<2>::new(0.0, 5.0));
        assert_eq!(v[node(0.1, 0.7)], Vector::<2>::new(5.0, -1.0));
        // at rest with its faces midway between node rows: no node lies on a face, and the
        // first row inside each face holds that face's normal only
        let mut r = bodies([0.05, 0.05], [0.45, 0.45], [0.0, 0.0]);
        r.smooth = vec![true];
        r.set_time(0.0, &g);
        let held = |x: f64, y: f64| r.nodes.iter().find(|n| n.0 == node(x, y)).map(|n| n.2);
        assert_eq!(held(0.1, 0.2), Some(0b01));
        assert_eq!(held(0.4, 0.3), Some(0b01));
        assert_eq!(held(0.2, 0.1), Some(0b10));
        assert_eq!(held(0.3, 0.4), Some(0b10));
        assert_eq!(held(0.2, 0.3), Some(0b11));
        // rough (the default): every node in the box the whole velocity; ahead, the push
        let mut r = bodies([0.0, 0.72], [0.3, 1.0], [0.0, -1.0]);
        r.set_time(0.0, &g);
        for n in &r.nodes {
            let y = g.node_position(&g.multi(n.0))[1];
            assert_eq!(n.2, if y < 0.72 { 0b10 } else { 0b11 }, "y = {y}");
        }
    }

    #[test]
    fn cut_cells_hold_a_face_normal_by_a_ghost_value() {
        let g = geo();
        // a block at rest on the floor; the nodes x = 0.4, 0.6 and y = 0.4 lie 0.7 h inside
        // its sides and top
        let mut r = bodies([0.33, 0.0], [0.67, 0.47], [0.0, 0.0]);
        r.cut = true;
        r.set_time(0.0, &g);
        let node = |x: f64, y: f64| node_at(&g, x, y);
        let held = |r: &RigidBodies<2>, x: f64, y: f64| {
            r.nodes.iter().find(|n| n.0 == node(x, y)).map(|n| n.2)
        };
        // the first row inside the left side: its normal, x, by a ghost value; the rough side
        // holds y; so on the floor, which is a wall and no face to the material; under the top;
        // at the corner; and deeper than a cell from every face
        for (x, y) in [(0.4, 0.2), (0.4, 0.0), (0.5, 0.4), (0.6, 0.4), (0.5, 0.2)] {
            assert_eq!(held(&r, x, y), Some(0b11), "({x}, {y})");
        }
        // 0.7 h inside, past half a cell: c = (h - a) / a = 3 / 7, v = V + c (V - v_beyond)
        let mut v = vec![Vector::<2>::new(-2.0, 0.0); g.node_count()];
        r.apply(&mut v);
        let ghost = v[node(0.4, 0.2)][0];
        assert!((ghost - 3.0 / 7.0 * 2.0).abs() < 1e-12, "{ghost}");
        // and a node a cell or more inside holds the body's velocity
        assert_eq!(v[node(0.5, 0.2)][0], 0.0);
        // the faces' points: the sides (0.47 m each) and the top (0.34 m), not the floor
        let length = |r: &RigidBodies<2>, axis: usize, sign: f64| -> f64 {
            r.faces
                .iter()
                .filter(|f| f.axis == axis && f.sign == sign)
                .map(|f| f.weight)
                .sum()
        };
        assert!((length(&r, 0, 1.0) - 0.47).abs() < 1e-12);
        assert!((length(&r, 0, -1.0) - 0.47).abs() < 1e-12);
        assert!((length(&r, 1, -1.0) - 0.34).abs() < 1e-12);
        assert_eq!(length(&r, 1, 1.0), 0.0);
        // smooth sides hold only the ghost normal in the first row
        let mut r = bodies([0.33, 0.0], [0.67, 0.47], [0.0, 0.0]);
        (r.cut, r.smooth) = (true, vec![true]);
        r.set_time(0.0, &g);
        assert_eq!(held(&r, 0.4, 0.2), Some(0b01));
        assert_eq!(held(&r, 0.5, 0.2), Some(0b11));
        // a side 0.3 h from the first node inside (x = 0.37, node 0.4): that node holds the
        // ghost value V + c (V - v_beyond), c = 0.3 / 0.7, which puts V on the face
        let mut r = bodies([0.37, 0.0], [0.67, 0.47], [1.0, 0.0]);
        r.cut = true;
        r.set_time(0.0, &g);
        assert_eq!(held(&r, 0.4, 0.2), Some(0b11));
        let mut v = vec![Vector::<2>::new(-2.0, 0.0); g.node_count()];
        r.apply(&mut v);
        let ghost = v[node(0.4, 0.2)][0];
        let on_face = (0.7 * ghost + 0.3 * v[node(0.3, 0.2)][0]) / 1.0;
        assert!((ghost - (1.0 + 3.0 / 7.0 * 3.0)).abs() < 1e-12, "{ghost}");
        assert!((on_face - 1.0).abs() < 1e-12, "{on_face}");
    }

    #[test]
    fn the_cover_is_the_overlap_of_box_and_cell() {
        let g = geo();
        let r = {
            let mut r = bodies([0.0, 0.75], [0.25, 1.0], [0.0, 0.0]);
            r.set_time(0.0, &g);
            r
        };
        let mut f = vec![0.0; g.node_count()];
        r.cover(&g, &mut f);
        let cell = |i: usize, j: usize| f[g.flat(&[i + PAD, j + PAD])];
        assert!((cell(0, 9) - 1.0).abs() < 1e-12);
        assert!((cell(0, 7) - 0.5).abs() < 1e-12);
        assert!((cell(2, 7) - 0.25).abs() < 1e-12);
        assert!((cell(2, 9) - 0.5).abs() < 1e-12);
        assert_eq!(cell(3, 9), 0.0);
        assert_eq!(cell(0, 6), 0.0);
        let total: f64 = f.iter().sum();
        assert!((total - 0.25 * 0.25 / 0.01).abs() < 1e-12);
    }

    #[test]
    fn push_out_reflects_a_particle_out_of_a_body_and_counts_its_impulse() {
        let g = geo();
        // a block on the floor, x in [0.3, 0.6], y in [0, 0.5], at rest
        let mut r = bodies([0.3, 0.0], [0.6, 0.5], [0.0, 0.0]);
        r.set_time(0.0, &g);
        let dt = 0.01;
        let mut x = vec![
            Vector::<2>::new(0.32, 0.2),  // 0.02 past the left face, moving in
            Vector::<2>::new(0.40, 0.02), // nearest the floor face, which is no way out
            Vector::<2>::new(0.29, 0.2),  // outside
        ];
        let mut v = vec![Vector::<2>::new(1.0, 0.0); 3];
        let mass = [2.0, 1.0, 1.0];
        r.push_out(&g, dt, &mut x, &mut v, &mass);
        assert!((x[0] - Vector::<2>::new(0.28, 0.2)).norm() < 1e-12);
        assert_eq!(v[0], Vector::<2>::new(0.0, 0.0));
        // out through the left face (depth 0.1) rather than the floor (0.02)
        assert!((x[1] - Vector::<2>::new(0.2, 0.02)).norm() < 1e-12);
        assert_eq!(x[2], Vector::<2>::new(0.29, 0.2));
        assert_eq!(v[2], Vector::<2>::new(1.0, 0.0));
        // the particles' momentum into the body, m v / dt, pushes it along +x
        assert!((r.force[0] - Vector::<2>::new((2.0 + 1.0) / dt, 0.0)).norm() < 1e-9);
        // a gate lifted a hair off the floor: reflected through its base, a particle 0.003 above
        // the floor would land below it, so it leaves through the nearest side instead
        let mut r = bodies([0.3, 0.001], [0.6, 0.5], [0.0, 0.0]);
        r.set_time(0.0, &g);
        let mut x = vec![Vector::<2>::new(0.35, 0.004)];
        let mut v = vec![Vector::<2>::zeros()];
        r.push_out(&g, dt, &mut x, &mut v, &[1.0]);
        assert!((x[0] - Vector::<2>::new(0.25, 0.004)).norm() < 1e-12);
        // a moving body is met where it is at the step's end
        let mut r = bodies([0.3, 0.2], [0.6, 0.5], [1.0, 0.0]);
        r.set_time(0.0, &g);
        let mut x = vec![Vector::<2>::new(0.305, 0.3)];
        let mut v = vec![Vector::<2>::zeros()];
        r.push_out(&g, dt, &mut x, &mut v, &[1.0]);
        // the left face is at 0.31 after the step: 0.305 is outside it
        assert_eq!(x[0], Vector::<2>::new(0.305, 0.3));
        let mut x = vec![Vector::<2>::new(0.315, 0.3)];
        r.push_out(&g, dt, &mut x, &mut v, &[1.0]);
        assert!((x[0] - Vector::<2>::new(0.305, 0.3)).norm() < 1e-12);
        // the body moves away from it (its trailing face): its velocity is its own
        assert_eq!(v[0], Vector::<2>::zeros());
    }

    /// A body whose velocity is an expression of t is where the velocity's integral puts it:
    /// a gate lifted at v = 2 t has risen t^2 (to round-off), and it holds the nodes inside it
    /// then with its velocity then.
    #[test]
    fn a_body_moved_by_an_expression_of_time_is_where_its_integral_puts_it() {
        let f = crate::field::VectorField(vec![
            crate::field::Component::Number(0.0),
            crate::field::Component::Expression("2*t".into()),
        ])
        .compile()
        .unwrap();
        let mut b = bodies([0.45, 0.0], [0.55, 0.3], [0.0, 0.0]);
        b.motion[0] = Some(f);
        let g = geo();
        b.set_time(0.5, &g);
        let u = b.displacement(0, 0.5);
        assert!(u[0] == 0.0 && (u[1] - 0.25).abs() < 1e-14, "{u}");
        assert_eq!(b.velocity(0), Vector::<2>::new(0.0, 1.0));
        assert!((b.centre(0, 0.5)[1] - 0.4).abs() < 1e-14);
        // the body now spans y = 0.25 to 0.55: the node (0.5, 0.1) is out of it, (0.5, 0.3) in
        let node = |y: usize| g.flat(&[PAD + 5, PAD + y]);
        assert!(b.nodes.iter().all(|&(i, _, _)| i != node(1)));
        assert!(b.nodes.iter().any(|&(i, _, _)| i == node(3)));
        let mut v = vec![Vector::<2>::zeros(); g.node_count()];
        b.apply(&mut v);
        assert_eq!(v[node(3)], Vector::<2>::new(0.0, 1.0));
    }

    /// A body lifted wholly out of the grid holds no node (clamped into the grid, its range
    /// was the top row of nodes, which it held and pulled the water with).
    #[test]
    fn a_body_past_the_grid_holds_no_node() {
        let mut b = bodies([0.45, 1.2], [0.55, 1.5], [0.0, 1.0]);
        let g = geo();
        b.set_time(0.0, &g);
        assert!(b.nodes.is_empty(), "{:?}", b.nodes);
        // lowered back into the grid it holds nodes again
        b.set_time(-0.5, &g);
        assert!(!b.nodes.is_empty());
    }
}
