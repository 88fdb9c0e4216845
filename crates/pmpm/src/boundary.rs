//! Wall conditions on grid velocities (docs/method.md, steps 2 and 6): slip, no-slip, open, moving; and
//! the nodes of rigid bodies ([`crate::rigid`]), which take the body's velocity.
//!
//! A face's condition holds on its wall nodes and on the ghost nodes behind it, so that the
//! wide shape functions (GIMP, B-splines) see the wall too; under the nodal projection a ghost
//! node's normal component mirrors the node as far inside ([`Boundary::apply`]). Walls only
//! push (`grid.boundary.contact = "separating"`, the projection's default;
//! [`Boundary::settle_contacts`]) or hold v . n both ways (`"bonded"`, the explicit scheme's
//! default, and a `"symmetry"` face always).

use serde::{Deserialize, Serialize};

use crate::grid::{GridGeometry, Vector};
use crate::pages::store;
use crate::particles::Particles;
use crate::shape::PAD;
use crate::wall_law::WallLaw;
use rayon::prelude::*;

/// The speed away from a wall, relative to the fastest wall node's, above which a node leaves
/// it ([`Boundary::settle_contacts`]).
const SEPARATION_FLOOR: f64 = 1e-6;

/// The fraction of a step of the body force, |g| dt, that a node's v^n must move away from its
/// wall by for its material to count as leaving ([`Boundary::settle_contacts`]). Water that
/// left a lid a step before moves at about |g| dt, and a B-spline column at rest carries
/// 1e-4 m/s of noise at its side walls against |g| dt = 0.05 m/s: any fraction from 0.02 to
/// 0.8 told the two apart in the test suite's cases, and a half sits within that.
const LEAVING: f64 = 0.5;

/// The scales that tell material leaving a wall from the solve's noise about p = 0
/// ([`Boundary::settle_contacts`]).
#[derive(Debug, Clone, Copy)]
pub struct Leaving {
    /// A step of the body force, |g| dt (m/s).
    pub speed: f64,
    /// The weight of one cell of the densest material on a unit of wall, rho |g| h (Pa): the
    /// least pressure difference the grid resolves in a column at rest.
    pub weight: f64,
}

/// Kind of a boundary face.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BoundaryKind {
    /// v . n = v_wall . n
    Slip,
    /// v = v_wall
    NoSlip,
    /// Nothing imposed.
    Open,
    /// Open, and the particles that cross it leave the run: their mass and volume are counted
    /// out in series.csv (a channel's end, a spillway).
    Outflow,
    /// Periodic on both faces of the axis.
    Periodic,
    /// A mirror plane: v . n = 0 both ways, no friction, whatever `grid.boundary.contact`
    /// says (the material on the other side is the mirror image, which never parts from it).
    Symmetry,
}

impl BoundaryKind {
    /// The kind the deck names `s`.
    pub fn from_name(s: &str) -> Option<Self> {
        Some(match s {
            "slip" => Self::Slip,
            "no_slip" => Self::NoSlip,
            "open" => Self::Open,
            "outflow" => Self::Outflow,
            "periodic" => Self::Periodic,
            "symmetry" => Self::Symmetry,
            _ => return None,
        })
    }

    /// The name the deck gives the kind.
    pub fn name(self) -> &'static str {
        match self {
            Self::Slip => "slip",
            Self::NoSlip => "no_slip",
            Self::Open => "open",
            Self::Outflow => "outflow",
            Self::Periodic => "periodic",
            Self::Symmetry => "symmetry",
        }
    }

    /// A wall: slip, no-slip or a symmetry plane, which hold the normal velocity.
    pub fn is_wall(self) -> bool {
        matches!(self, Self::Slip | Self::NoSlip | Self::Symmetry)
    }

    /// Open or outflow: nothing held on the velocity, p = 0 beyond the face.
    pub fn is_open(self) -> bool {
        matches!(self, Self::Open | Self::Outflow)
    }
}

/// The held-components mark of a node on an inflow's buffer
/// ([`Boundary::hold_buffers_components`]): every bit, every component held, which no
/// wall's mark reaches (a wall sets one bit per axis it holds, at most three).
pub const BUFFER_HELD: u8 = u8::MAX;

/// The conditions of all faces and the nodes they act on.
#[derive(Debug, Clone)]
pub struct Boundary<const D: usize> {
    /// (kind, wall velocity) per face, in the order x_min, x_max, y_min, ...
    faces: Vec<(BoundaryKind, Vector<D>)>,
    /// (node, face) pairs, precomputed so that applying costs O(boundary nodes).
    nodes: Vec<(usize, usize)>,
    /// Per pair, the node mirrored across the face (`usize::MAX` for a node on the face).
    mirror: Vec<usize>,
    /// Per pair, the node on the face that the pair's node lies behind (itself on the face).
    face_node: Vec<usize>,
    /// Whether the slip and no-slip faces let the material go ([`Boundary::settle_contacts`]).
    separating: bool,
    /// Per pair, the axes whose walls its node's material leaves this step, over all the
    /// node's pairs (bit d: axis d; empty: every pair holds). A pair whose own axis is among
    /// them holds only the normal motion into its wall.
    released: Vec<u8>,
    /// Per pair, whether its face node's material already moved away from the wall at the
    /// step's start faster than a step of the body force gives ([`Boundary::settle_contacts`]).
    leaving: Vec<bool>,
    /// The pressure a leaving node's last solve must exceed to hold it, rho |g| h
    /// ([`Leaving::weight`]).
    leaving_weight: f64,
    /// Wall velocities given by expressions in x, y, z, t, per face (None: constant).
    fields: Vec<Option<crate::field::CompiledField>>,
    /// Per (node, face) pair, the wall velocity at the node now (only with `fields`).
    node_wall: Vec<Vector<D>>,
    /// Node positions of the pairs (only with `fields` or inflows).
    node_x: Vec<Vector<D>>,
    /// Time of `node_wall`.
    time: f64,
    /// Rigid bodies moving through the material: their nodes take their velocity.
    pub rigid: crate::rigid::RigidBodies<D>,
    /// Inflow patches ([`crate::flow`]).
    pub inflows: Vec<crate::flow::Inflow<D>>,
    /// Per (node, face) pair, the inflow whose patch holds it (`u32::MAX`: none; empty
    /// without inflows). Such a node holds the inflow's velocity, every component.
    inflow_of: Vec<u32>,
    /// The nodes of the inflows' buffers: on a patch, behind it and in the first rows in
    /// front of it, which the particles in a buffer read from ([`Boundary::hold_buffers`]).
    buffer_nodes: Vec<usize>,
    /// The slip walls' shear (`grid.boundary.friction`; None: they slide freely), the
    /// share of its wall each pair's node rubs on (0: none, not a face node of a slip wall
    /// within the grid), and the mass below which a node is empty.
    friction: Option<(WallLaw, Vec<f64>, f64)>,
}

impl<const D: usize> Boundary<D> {
    /// The faces' conditions on a grid: (kind, wall velocity at the origin at t = 0) per face
    /// in the order x_min, x_max, y_min, ..., the wall velocities given by expressions that
    /// vary, and the rigid bodies. `mirrors`: under the nodal projection a ghost node behind a
    /// face mirrors the node as far inside it ([`Boundary::apply`]); the explicit scheme and
    /// the cell projection hold it at the wall's value instead (the cell pressure's constraint
    /// is solved with those values, and a mirror that followed the corrected velocity would
    /// undo it, and an elastic block lose volume).
    pub fn new(
        faces: Vec<(BoundaryKind, Vector<D>)>,
        fields: Vec<Option<crate::field::CompiledField>>,
        mirrors: bool,
        rigid: crate::rigid::RigidBodies<D>,
        geo: &GridGeometry<D>,
    ) -> Self {
        let mut nodes = Vec::new();
        for flat in 0..geo.node_count() {
            let idx = geo.multi(flat);
            for d in 0..D {
                if idx[d] <= PAD {
                    nodes.push((flat, 2 * d));
                }
                if idx[d] >= PAD + geo.cells[d] {
                    nodes.push((flat, 2 * d + 1));
                }
            }
        }
        nodes.retain(|&(_, f)| {
            !matches!(
                faces[f].0,
                BoundaryKind::Open | BoundaryKind::Outflow | BoundaryKind::Periodic
            )
        });
        let mirror = nodes
            .iter()
            .map(|&(i, f)| {
                if !mirrors {
                    return usize::MAX;
                }
                let mut idx = geo.multi(i);
                let d = f / 2;
                let face = if f % 2 == 0 { PAD } else { PAD + geo.cells[d] };
                if idx[d] == face {
                    return usize::MAX;
                }
                idx[d] = (2 * face).saturating_sub(idx[d]).min(geo.nodes[d] - 1);
                geo.flat(&idx)
            })
            .collect();
        let face_node = nodes
            .iter()
            .map(|&(i, f)| {
                let mut idx = geo.multi(i);
                let d = f / 2;
                idx[d] = if f % 2 == 0 { PAD } else { PAD + geo.cells[d] };
                geo.flat(&idx)
            })
            .collect();
        let varying = fields.iter().any(|f| f.is_some());
        let node_x = if varying {
            nodes
                .iter()
                .map(|&(i, _)| geo.node_position(&geo.multi(i)))
                .collect()
        } else {
            Vec::new()
        };
        let mut b = Self {
            node_wall: vec![Vector::<D>::zeros(); if varying { nodes.len() } else { 0 }],
            faces,
            nodes,
            mirror,
            face_node,
            separating: false,
            released: Vec::new(),
            leaving: Vec::new(),
            leaving_weight: 0.0,
            fields,
            node_x,
            time: f64::NAN,
            rigid,
            inflows: Vec::new(),
            inflow_of: Vec::new(),
            buffer_nodes: Vec::new(),
            friction: None,
        };
        b.set_time(0.0, geo);
        b
    }

    /// The same conditions with inflow patches on slip or no-slip faces: the face's nodes on
    /// a patch, and the ghost nodes behind them, hold its velocity. `rows`: the rows of nodes
    /// in front of a patch that a particle less than a cell from it reads from.
    pub fn with_inflows(
        mut self,
        inflows: Vec<crate::flow::Inflow<D>>,
        rows: usize,
        geo: &GridGeometry<D>,
    ) -> Self {
        if inflows.is_empty() {
            return self;
        }
        for inflow in &inflows {
            let axis = inflow.face / 2;
            for flat in 0..geo.node_count() {
                let idx = geo.multi(flat);
                let row = if inflow.face % 2 == 0 {
                    idx[axis] as isize - PAD as isize
                } else {
                    (PAD + geo.cells[axis]) as isize - idx[axis] as isize
                };
                if row <= rows as isize && inflow.covers(&geo.node_position(&idx), geo.h) {
                    self.buffer_nodes.push(flat);
                }
            }
        }
        self.inflow_of = self
            .nodes
            .iter()
            .map(|&(i, f)| {
                let x = geo.node_position(&geo.multi(i));
                inflows
                    .iter()
                    .position(|q| q.face == f && q.covers(&x, geo.h))
                    .map_or(u32::MAX, |q| q as u32)
            })
            .collect();
        if self.node_x.is_empty() {
            self.node_x = self
                .nodes
                .iter()
                .map(|&(i, _)| geo.node_position(&geo.multi(i)))
                .collect();
            self.node_wall = vec![Vector::<D>::zeros(); self.nodes.len()];
        }
        self.inflows = inflows;
        self.time = f64::NAN;
        self.set_time(0.0, geo);
        self
    }

    /// The same conditions with walls that let the material go (`on`), or that hold it both
    /// ways ([`Boundary::settle_contacts`]).
    pub fn with_separation(mut self, on: bool) -> Self {
        self.separating = on;
        self
    }

    /// The same conditions with the slip walls' shear given by `law` ([`crate::wall_law`]),
    /// on nodes above `mass_epsilon`. Each face node of a slip wall rubs on its share of the
    /// wall: h^(D-1), halved for each edge of the wall it sits on (a corner of a 2D floor
    /// holds half a cell of it, an edge node of a 3D floor half, a corner a quarter), and
    /// none for a node beyond the wall's edges (a ghost node behind another face). Along a
    /// periodic axis the wall has no edge, and an image node rubs as the node it copies.
    pub fn with_friction(
        mut self,
        law: Option<WallLaw>,
        geo: &GridGeometry<D>,
        mass_epsilon: f64,
    ) -> Self {
        self.friction = law.map(|law| {
            let shares = (self.nodes.iter().enumerate())
                .map(|(k, &(i, f))| {
                    if self.face_node[k] != i || self.faces[f].0 != BoundaryKind::Slip {
                        return 0.0;
                    }
                    let idx = geo.multi(i);
                    let mut share = law.area();
                    for d in (0..D).filter(|&d| d != f / 2) {
                        if self.faces[2 * d].0 == BoundaryKind::Periodic {
                            continue;
                        }
                        let (first, last) = (PAD, PAD + geo.cells[d]);
                        if idx[d] < first || idx[d] > last {
                            return 0.0;
                        }
                        if idx[d] == first || idx[d] == last {
                            share *= 0.5;
                        }
                    }
                    share
                })
                .collect();
            (law, shares, mass_epsilon)
        });
        self
    }

    /// Step 2: the slip walls' shear on v* ([`crate::wall_law`]), from each face node's slide
    /// at the step's start (`before`, v^n), on the nodes with material (`mass`) that the wall
    /// holds this step; a released node's material is leaving the wall and feels none. At an
    /// edge the walls rub one after the other, each on what the last left.
    pub fn rub(&self, v: &mut [Vector<D>], before: &[Vector<D>], mass: &[f64], dt: f64) {
        let Some((law, shares, eps)) = &self.friction else {
            return;
        };
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            let share = shares[k];
            let rubs = share > 0.0 && mass[i] > *eps && self.kind(k, f) == BoundaryKind::Slip;
            if rubs && !self.released(k) {
                let wall = self.wall(k, f);
                law.rub(&mut v[i], &before[i], (mass[i], share), f / 2, &wall, dt);
            }
        }
    }

    /// The fastest node on a wall face (m/s) in `v`: the scale of what counts as round-off in
    /// [`Boundary::settle_contacts`].
    pub fn face_speed(&self, v: &[Vector<D>]) -> f64 {
        self.face_node
            .iter()
            .map(|&j| v[j].norm())
            .fold(0.0, f64::max)
    }

    /// Decides which face nodes the walls hold this step, from the node velocities `v` (v^n,
    /// then v* of the step, before any condition holds them) and, under the projection, the
    /// last solve's node pressure. A wall's contact is a complementarity condition
    /// (Signorini): v . n >= v_wall . n into the material, a reaction that only pushes, and
    /// one of the two at its bound. Chorin's projection carries the wall's reaction in the
    /// pressure, so a face node is released only where both say it leaves: its v moves away
    /// from the wall (by more than round-off) and either the last pressure there did not push
    /// (p <= 0) or its material already moved away at the step's start (v^n, the call given
    /// `leaving`) faster than half a step of the body force and the last pressure there
    /// pushed by less than one cell's weight ([`Leaving`]): once off, the solve's noise about
    /// p = 0 does not put it back on, and a jet that runs along a wall under pressure, whose
    /// v^n carries a little motion off it from the particles, stays on. A released node's
    /// [`Boundary::apply`] removes only motion into the wall, a no-slip wall keeps its grip
    /// along it, and a ghost node behind it continues the face node's normal velocity
    /// linearly instead of mirroring the wall's. A column at rest (v* = g dt into the floor,
    /// its weight on the side walls) is held exactly as before; water under a lid (v* = g dt
    /// away from it, the lid's tension in the last solve) falls from it as free water. Without `pressure` (the explicit scheme, whose v*
    /// carries the stress already) the velocity alone decides. Inflow patches always hold.
    ///
    /// `speed` is the fastest face node's ([`Boundary::face_speed`], over every rank).
    pub fn settle_contacts(
        &mut self,
        v: &[Vector<D>],
        speed: f64,
        pressure: Option<&[f64]>,
        leaving: Option<Leaving>,
    ) {
        if !self.separating {
            return;
        }
        self.released.resize(self.nodes.len(), 0);
        self.leaving.resize(self.nodes.len(), false);
        // a node leaves its wall only by more than round-off: the transfers leave 1e-12 of the
        // flow's speed on a wall node's normal, and a channel or a filled box released by it
        // grew a cross flow
        let floor = SEPARATION_FLOOR * speed;
        for (k, &(_, f)) in self.nodes.iter().enumerate() {
            let wall = self.faces[f].0;
            // (a symmetry plane never lets go: its other side is the mirror image)
            let face = matches!(self.inflow_of.get(k), None | Some(&u32::MAX))
                && matches!(wall, BoundaryKind::Slip | BoundaryKind::NoSlip);
            let (axis, w) = (f / 2, self.wall(k, f)[f / 2]);
            let j = self.face_node[k];
            let off = if f % 2 == 0 {
                v[j][axis] - w
            } else {
                w - v[j][axis]
            };
            if let Some(Leaving { speed, weight }) = leaving {
                // without a body force there is no step to measure by: the pressure decides
                self.leaving[k] = speed > 0.0 && off > floor.max(LEAVING * speed);
                self.leaving_weight = weight;
            }
            // a wall the pressure pressed on last step holds, unless its material already
            // moves away faster than a step of the body force gives and the push was below
            // what the grid resolves: the water leaves a side wall only once nothing pushes
            // it there, and a sheet that has left stays off whatever the pressure's noise
            // about zero says
            let pushed = pressure
                .is_some_and(|p| p[j] > 0.0 && (!self.leaving[k] || p[j] > self.leaving_weight));
            self.released[k] = u8::from(face && off > floor && !pushed) << axis;
        }
        // over each node's pairs (consecutive; at most one per axis): a no-slip wall's grip
        // must not hold a component another wall at the node released
        let mut start = 0;
        while start < self.nodes.len() {
            let i = self.nodes[start].0;
            let end = start + self.nodes[start..].iter().take_while(|p| p.0 == i).count();
            let axes = self.released[start..end].iter().fold(0, |m, &a| m | a);
            self.released[start..end].fill(axes);
            start = end;
        }
    }

    /// Whether the walls may let the material go (`grid.boundary.contact = "separating"`).
    pub fn separates(&self) -> bool {
        self.separating
    }

    /// Every wall holds both ways this step.
    pub fn hold_all(&mut self) {
        self.released.clear();
    }

    /// Whether pair k is released this step ([`Boundary::settle_contacts`]).
    #[inline]
    fn released(&self, k: usize) -> bool {
        let axis = self.nodes[k].1 / 2;
        self.released.get(k).is_some_and(|&m| m >> axis & 1 == 1)
    }

    /// A released pair's condition: the normal motion of node component `vn` into face `f`'s
    /// wall (at `wall`) removed, motion away kept.
    #[inline]
    fn one_sided(vn: &mut f64, f: usize, wall: f64) {
        let into = if f % 2 == 0 { *vn < wall } else { *vn > wall };
        if into {
            store(vn, wall);
        }
    }

    /// The kind of pair k (node, face): an inflow's node is held as on a no-slip wall.
    #[inline]
    fn kind(&self, k: usize, f: usize) -> BoundaryKind {
        match self.inflow_of.get(k) {
            Some(&q) if q != u32::MAX => BoundaryKind::NoSlip,
            _ => self.faces[f].0,
        }
    }

    /// Evaluates the wall velocities given by expressions at time `t`: at every wall node, and
    /// at each face's centre for the particles that [`Boundary::confine`] puts back.
    pub fn set_time(&mut self, t: f64, geo: &GridGeometry<D>) {
        self.rigid.set_time(t, geo);
        if self.node_wall.is_empty() || t == self.time {
            return;
        }
        self.time = t;
        for (k, &(_, f)) in self.nodes.iter().enumerate() {
            self.node_wall[k] = match (&self.fields[f], self.inflow_of.get(k)) {
                (_, Some(&q)) if q != u32::MAX => {
                    self.inflows[q as usize].velocity_at(&self.node_x[k], t)
                }
                (Some(c), _) => c.eval(&self.node_x[k], t),
                (None, _) => self.faces[f].1,
            };
        }

        let centre = (geo.origin + geo.upper()) * 0.5;
        for f in 0..2 * D {
            if let Some(c) = &self.fields[f] {
                let mut x = centre;
                x[f / 2] = if f % 2 == 0 {
                    geo.origin[f / 2]
                } else {
                    geo.upper()[f / 2]
                };
                self.faces[f].1 = c.eval(&x, t);
            }
        }
    }

    /// The fastest wall or rigid body: a lid or a body that drives a flow from rest sets the
    /// flow's speed before any particle has it.
    pub fn max_wall_speed(&self) -> f64 {
        let faces = self
            .faces
            .iter()
            .filter(|(kind, _)| kind.is_wall())
            .map(|(_, v)| v.norm());
        let nodes = self.node_wall.iter().map(|v| v.norm());
        faces.chain(nodes).fold(self.rigid.max_speed(), f64::max)
    }

    /// The wall velocity of pair k (node, face).
    #[inline]
    fn wall(&self, k: usize, f: usize) -> Vector<D> {
        if self.node_wall.is_empty() {
            self.faces[f].1
        } else {
            self.node_wall[k]
        }
    }

    /// Wraps particles across periodic faces and keeps them inside closed faces. Near a wall a particle's velocity is interpolated
    /// from nodes off the wall as well, so it can cross the wall by a fraction of a step; it is
    /// reflected back inside by as much as it crossed, and its velocity into the wall removed (the particle-level form of
    /// v . n = 0). A particle further than a cell beyond a wall, or beyond an open face, is
    /// left where it is for the blow-up guard to report. Then the rigid bodies put back the
    /// particles the step carried into them ([`crate::rigid::RigidBodies::push_out`]).
    pub fn confine(&mut self, geo: &GridGeometry<D>, dt: f64, ps: &mut Particles<D>) {
        self.confine_to_walls(geo, &mut ps.x, &mut ps.v);
        self.rigid.push_out(geo, dt, &mut ps.x, &mut ps.v, &ps.mass);
    }

    /// The walls' part of [`Boundary::confine`].
    fn confine_to_walls(&self, geo: &GridGeometry<D>, x: &mut [Vector<D>], v: &mut [Vector<D>]) {
        let lo = geo.origin;
        let hi = geo.upper();
        let h = geo.h;
        let faces = &self.faces;
        x.par_iter_mut().zip(v.par_iter_mut()).for_each(|(x, v)| {
            for d in 0..D {
                let (kmin, wmin) = faces[2 * d];
                let (kmax, wmax) = faces[2 * d + 1];
                if kmin == BoundaryKind::Periodic {
                    // wrap into [lo, hi)
                    let l = hi[d] - lo[d];
                    let mut r = (x[d] - lo[d]).rem_euclid(l);
                    if r >= l {
                        r = 0.0;
                    }
                    x[d] = lo[d] + r;
                } else if x[d] < lo[d] && x[d] > lo[d] - h && !kmin.is_open() {
                    // reflected back by the distance it went past: a particle put on the wall
                    // itself stays on it (the wall nodes hold its normal velocity at zero), and
                    // a splash running along a wall packed its particles into that line
                    x[d] = (2.0 * lo[d] - x[d]).min(hi[d]);
                    v[d] = v[d].max(wmin[d]);
                } else if x[d] > hi[d] && x[d] < hi[d] + h && !kmax.is_open() {
                    x[d] = (2.0 * hi[d] - x[d]).max(lo[d]);
                    v[d] = v[d].min(wmax[d]);
                }
            }
        });
    }

    /// Whether face `f` (x_min, x_max, y_min, ...) is open (an outflow face is).
    pub fn is_open(&self, f: usize) -> bool {
        self.faces[f].0.is_open()
    }

    /// Whether face `f` lets particles out of the run.
    pub fn is_outflow(&self, f: usize) -> bool {
        self.faces[f].0 == BoundaryKind::Outflow
    }

    /// Imposes only the normal part of the face conditions (v . n = v_wall . n on slip and
    /// no-slip faces alike): what the walls' flux through them is measured against.
    pub fn apply_normal(&self, v: &mut [Vector<D>]) {
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            let (kind, wall) = (self.kind(k, f), self.wall(k, f));
            let axis = f / 2;
            if self.released(k) {
                Self::one_sided(&mut v[i][axis], f, wall[axis]);
            } else if kind.is_wall() {
                store(&mut v[i][axis], wall[axis]);
            }
        }
        // a rigid body's velocity, the components its nodes hold: a node inside it is on no
        // face with one normal
        self.rigid.apply(v);
        self.mirror_ghosts(v);
    }

    /// Zeroes a node displacement's normal component on the slip and no-slip faces, and the
    /// components a rigid body holds on its nodes: a correction that moves the particles must
    /// not move them through a wall or into a body. A face node that separating walls released
    /// this step ([`Boundary::settle_contacts`]) is held here too: the correction moves no
    /// particle off a wall either, which is the step's to do.
    pub fn hold_still(&self, u: &mut [Vector<D>]) {
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            if self.kind(k, f).is_wall() {
                store(&mut u[i][f / 2], 0.0);
            }
        }
        self.rigid.hold_still(u);
    }

    /// Sets bit d of `bits[i]` where [`Self::hold_still`] zeroes component d of node i.
    pub fn held_components(&self, bits: &mut [u8]) {
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            if self.kind(k, f).is_wall() {
                bits[i] |= 1 << (f / 2);
            }
        }
        self.rigid.held_components(bits);
    }

    /// Zeroes a node displacement on the inflows' buffers: the density correction must not
    /// move the particles there, which enter at the inflow's pace
    /// ([`crate::flow::Inflow::hold_buffer`]; moved back towards the face, they let 11 % less
    /// material in).
    pub fn hold_buffers(&self, u: &mut [Vector<D>]) {
        for &i in &self.buffer_nodes {
            store(&mut u[i], Vector::<D>::zeros());
        }
    }

    /// Sets `bits[i]` to [`BUFFER_HELD`] (every bit) on the inflows' buffer nodes, where
    /// [`Self::hold_buffers`] zeroes the displacement.
    pub fn hold_buffers_components(&self, bits: &mut [u8]) {
        for &i in &self.buffer_nodes {
            bits[i] = BUFFER_HELD;
        }
    }

    /// Zeroes the velocity components the faces and rigid bodies prescribe (the normal on a
    /// slip face, every component on a no-slip one, ghost nodes behind them included): a mask
    /// of the free components when applied to ones.
    pub fn mask_held(&self, mask: &mut [Vector<D>]) {
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            let kind = self.kind(k, f);
            if self.released(k) {
                if kind == BoundaryKind::NoSlip {
                    // the grip along the wall, on the axes no wall at the node released
                    for c in (0..D).filter(|&c| self.released[k] & (1 << c) == 0) {
                        store(&mut mask[i][c], 0.0);
                    }
                }
                continue;
            }
            // (written only where it changes: a wall node without mass stays uncommitted)
            match kind {
                BoundaryKind::Slip | BoundaryKind::Symmetry => store(&mut mask[i][f / 2], 0.0),
                BoundaryKind::NoSlip => store(&mut mask[i], Vector::<D>::zeros()),
                BoundaryKind::Open | BoundaryKind::Outflow | BoundaryKind::Periodic => {}
            }
        }
        self.rigid.hold_still(mask);
    }

    /// Imposes the face conditions on node velocities: the walls' values (a slip face's
    /// normal, a no-slip face's every component) on the face nodes and the ghost nodes behind
    /// them, only the normal motion into the wall removed where the wall lets go this step
    /// ([`Boundary::settle_contacts`]), the rigid bodies' velocities on their nodes, and then,
    /// under the nodal projection, the ghost nodes' normal components mirrored about the wall.
    pub fn apply(&self, v: &mut [Vector<D>]) {
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            let (kind, wall) = (self.kind(k, f), self.wall(k, f));
            if self.released(k) {
                // the normal one-sided; a no-slip wall's grip stays while the node has mass
                // by it
                if kind == BoundaryKind::NoSlip {
                    for c in (0..D).filter(|&c| self.released[k] & (1 << c) == 0) {
                        store(&mut v[i][c], wall[c]);
                    }
                }
                Self::one_sided(&mut v[i][f / 2], f, wall[f / 2]);
                continue;
            }
            match kind {
                // (stores that leave an empty node's zeros unwritten, see crate::pages)
                BoundaryKind::Slip | BoundaryKind::Symmetry => store(&mut v[i][f / 2], wall[f / 2]),
                BoundaryKind::NoSlip => store(&mut v[i], wall),
                BoundaryKind::Open | BoundaryKind::Outflow | BoundaryKind::Periodic => {}
            }
        }
        self.rigid.apply(v);
        self.mirror_ghosts(v);
    }

    /// Under the nodal projection, the normal component of a ghost node behind a slip or
    /// no-slip face (a node the wide shape functions, B-splines and GIMP, reach) takes the
    /// reflection 2 v_wall - v_mirror of the node as far inside, so that the normal velocity
    /// they interpolate is the wall's on the face itself. Held at the wall's value, a ghost
    /// node leaves the quadratic B-spline an eighth of the inner node's velocity there: water
    /// at rest sank into the floor under the projection. A no-slip face's tangential components
    /// stay at the wall's value on its ghost nodes: mirrored, a moving lid's corner with a side
    /// wall threw a cavity's particle out to 4 cells. A second pass over the pairs, after every
    /// wall and body has set its values, so that a corner reads its mirror's final value
    /// whatever the order of the faces.
    fn mirror_ghosts(&self, v: &mut [Vector<D>]) {
        for (k, &(i, f)) in self.nodes.iter().enumerate() {
            let m = self.mirror[k];
            if m == usize::MAX || !self.kind(k, f).is_wall() {
                continue;
            }
            let axis = f / 2;
            // a released face node's own velocity continued linearly, else the wall's mirrored
            let about = if self.released(k) {
                v[self.face_node[k]][axis]
            } else {
                self.wall(k, f)[axis]
            };
            let reflected = 2.0 * about - v[m][axis];
            store(&mut v[i][axis], reflected);
        }
    }
}
