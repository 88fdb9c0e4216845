//! Contact between rigid bodies where at least one moves freely: a block that sinks onto an
//! obstacle, floating boxes that drift together, a paddle that strikes a floating body.
//!
//! After the free bodies' step, each pair of bodies whose boxes overlap is tested where both
//! will be at the step's end. The contact is the part of each body's surface inside the other:
//! a shaped body's rays' crossings, a box's faces sampled every half cell, each point with its
//! push (the normal into its body times its share of the surface). The pushes of the first
//! body's points inside the second, less those of the second's inside the first, sum to the
//! area-weighted normal of the contact (int n dS over the overlapped surface), which points
//! the way that parts the bodies. The bodies are moved apart along it by the least distance
//! that leaves no point of either inside the other (bisected to a ten-thousandth of a cell),
//! shared in inverse proportion to their masses (a prescribed body does not give way), and the
//! part of their relative velocity at the contact's centre that closes along the normal is
//! taken away, shared the same way. The contact is plastic and frictionless and gives no
//! torque, as the walls' hold ([`super::RigidBodies::end_step`]); it is a contact of the
//! bodies' geometry only, at the resolution of the surface points (a third to a half of a
//! cell), with no material between them resolved.

use super::shaped::{to3, Pose, Shaped};
use super::{Motion, RigidBodies};
use nalgebra::Vector3;
use std::sync::Arc;

/// Surface points and their pushes (the normal into the body times the point's share).
pub(super) type Points = Vec<(Vector3<f64>, Vector3<f64>)>;

/// A body as the contact sees it, where it will be at the step's end.
#[derive(Debug, Clone)]
pub(super) struct Body {
    /// Its shape (None: a box between `lo` and `hi`).
    shape: Option<Arc<Shaped>>,
    /// A shaped body's pose; a box's velocity is `pose.velocity`.
    pose: Pose,
    lo: Vector3<f64>,
    hi: Vector3<f64>,
    /// 1 / mass of a free body; 0 for one whose motion is prescribed.
    inv_mass: f64,
    /// The translations a free body holds (the contact does not move it along them).
    held: [bool; 3],
    /// How far the contact has moved it.
    moved: Vector3<f64>,
}

impl Body {
    /// Whether the world point `x` lies inside the body (strictly, for a box: a box resting
    /// on another's face does not overlap it).
    fn holds(&self, x: &Vector3<f64>, dim: usize) -> bool {
        match &self.shape {
            Some(s) => s.holds(&self.pose, x),
            None => (0..dim).all(|d| self.lo[d] < x[d] && x[d] < self.hi[d]),
        }
    }

    /// The box that holds the body.
    fn bounds(&self) -> (Vector3<f64>, Vector3<f64>) {
        match &self.shape {
            Some(s) => s.world_bounds(&self.pose),
            None => (self.lo, self.hi),
        }
    }

    /// The surface points and their pushes that `keep` accepts, into `out` (emptied first): a
    /// shaped body's rays' crossings; for a box, the midpoints of a lattice of spacing at
    /// most h / 2 on each face.
    fn points(&self, dim: usize, h: f64, keep: impl Fn(&Vector3<f64>) -> bool, out: &mut Points) {
        out.clear();
        if let Some(s) = &self.shape {
            out.extend(s.surface_world(&self.pose).filter(|(x, _)| keep(x)));
            return;
        }
        for axis in 0..dim {
            // the axes across the face (one in 2D, two in 3D) and the points along each
            let across = match axis {
                0 => [1, 2],
                1 => [0, 2],
                _ => [0, 1],
            };
            let across = &across[..dim - 1];
            let mut counts = [1usize; 2];
            for (j, &e) in across.iter().enumerate() {
                counts[j] = ((self.hi[e] - self.lo[e]) / (0.5 * h)).ceil().max(1.0) as usize;
            }
            let total: usize = counts[..dim - 1].iter().product();
            let area: f64 = across.iter().map(|&e| self.hi[e] - self.lo[e]).product();
            for (side, sign) in [(self.lo[axis], 1.0), (self.hi[axis], -1.0)] {
                for k in 0..total {
                    let mut x = Vector3::zeros();
                    x[axis] = side;
                    let mut rem = k;
                    for (j, &e) in across.iter().enumerate() {
                        let step = (self.hi[e] - self.lo[e]) / counts[j] as f64;
                        x[e] = self.lo[e] + ((rem % counts[j]) as f64 + 0.5) * step;
                        rem /= counts[j];
                    }
                    if keep(&x) {
                        let mut push = Vector3::zeros();
                        push[axis] = sign * area / total as f64;
                        out.push((x, push));
                    }
                }
            }
        }
    }

    /// The velocity of the body's point at `x`.
    fn velocity_at(&self, x: &Vector3<f64>) -> Vector3<f64> {
        match &self.shape {
            Some(_) => self.pose.velocity_at(x),
            None => self.pose.velocity,
        }
    }

    /// Moves a free body by `by` and changes its velocity by `dv`, on the axes it keeps.
    fn give(&mut self, mut by: Vector3<f64>, mut dv: Vector3<f64>) {
        for d in 0..3 {
            if self.held[d] {
                (by[d], dv[d]) = (0.0, 0.0);
            }
        }
        self.moved += by;
        self.pose.centre += by;
        self.lo += by;
        self.hi += by;
        self.pose.velocity += dv;
    }
}

/// The contact between `a` and `b`: the normal that parts them (the way `a` goes), the least
/// distance along it that does, and the contact's centre; None when they do not overlap, or
/// when no distance up to their size parts them (one started inside the other).
fn separation(
    a: &Body,
    b: &Body,
    dim: usize,
    h: f64,
    scratch: &mut (Points, Points),
) -> Option<(Vector3<f64>, f64, Vector3<f64>)> {
    // only the points near the other's box can meet it (within two cells: the parting is
    // a cell or less a step), which keeps a large body's surface out of the tests
    let ((alo, ahi), (blo, bhi)) = (a.bounds(), b.bounds());
    let near = |x: &Vector3<f64>, lo: &Vector3<f64>, hi: &Vector3<f64>| {
        (0..dim).all(|d| x[d] > lo[d] - 2.0 * h && x[d] < hi[d] + 2.0 * h)
    };
    let (pa, pb) = scratch;
    a.points(dim, h, |x| near(x, &blo, &bhi), pa);
    b.points(dim, h, |x| near(x, &alo, &ahi), pb);
    let (pa, pb) = (&*pa, &*pb);
    let (mut normal, mut centre, mut count) = (Vector3::zeros(), Vector3::zeros(), 0usize);
    for (x, push) in pa {
        if b.holds(x, dim) {
            normal += push;
            centre += x;
            count += 1;
        }
    }
    for (x, push) in pb {
        if a.holds(x, dim) {
            normal -= push;
            centre += x;
            count += 1;
        }
    }
    if count == 0 || normal.norm() == 0.0 {
        return None;
    }
    let normal = normal.normalize();
    let clear = |s: f64| {
        !pa.iter().any(|(x, _)| b.holds(&(x + normal * s), dim))
            && !pb.iter().any(|(x, _)| a.holds(&(x - normal * s), dim))
    };
    let reach = (ahi - alo).norm() + (bhi - blo).norm();
    let (mut lo, mut hi) = (0.0, h / 8.0);
    while !clear(hi) {
        lo = hi;
        hi *= 2.0;
        if hi > reach {
            return None;
        }
    }
    while hi - lo > 1e-4 * h {
        let mid = 0.5 * (lo + hi);
        if clear(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some((normal, hi, centre / count as f64))
}

impl<const D: usize> RigidBodies<D> {
    /// Body `b` as the contact sees it, where it will be at the end of the step of `dt` that
    /// started at the time of [`RigidBodies::set_time`] (a free body has been moved there).
    fn contact_body(&self, b: usize, dt: f64) -> Body {
        let t = self.time + dt;
        let (inv_mass, held) = match (&self.shaped[b], &self.free_box[b]) {
            (
                Some(super::ShapedBody {
                    motion: Motion::Free(f),
                    ..
                }),
                _,
            )
            | (None, Some(f)) => (1.0 / f.mass, f.held_axes),
            _ => (0.0, [true; 3]),
        };
        let mut body = Body {
            shape: None,
            pose: Pose::at(Vector3::zeros()),
            lo: Vector3::zeros(),
            hi: Vector3::zeros(),
            inv_mass,
            held,
            moved: Vector3::zeros(),
        };
        match &self.shaped[b] {
            Some(s) => {
                body.shape = Some(Arc::clone(&s.shape));
                body.pose = s.motion.pose_at(&s.start, t).unwrap_or(self.pose[b]);
            }
            None => {
                let shift = self.displacement(b, t);
                body.lo = to3(&(self.lo[b] + shift));
                body.hi = to3(&(self.hi[b] + shift));
                body.pose.velocity = to3(&match &self.motion[b] {
                    Some(f) => f.eval(&crate::grid::Vector::<D>::zeros(), t),
                    None => self.velocity[b],
                });
            }
        }
        body
    }

    /// After the free bodies' step over `dt`: parts each pair of overlapping bodies of which
    /// one at least is free (see the module's text). Returns whether any moved.
    pub(super) fn contacts(&mut self, dt: f64, h: f64) -> bool {
        let n = self.len();
        if n < 2 || !(0..n).any(|b| self.is_free(b)) {
            return false;
        }
        // the scratch list, kept between steps (no allocation in the step loop)
        let mut bodies = std::mem::take(&mut self.contact_scratch);
        bodies.clear();
        bodies.extend((0..n).map(|b| self.contact_body(b, dt)));
        let mut any = false;
        for a in 0..n {
            for b in a + 1..n {
                let (ia, ib) = (bodies[a].inv_mass, bodies[b].inv_mass);
                if ia + ib == 0.0 {
                    continue;
                }
                let ((alo, ahi), (blo, bhi)) = (bodies[a].bounds(), bodies[b].bounds());
                if (0..D).any(|d| alo[d] >= bhi[d] || blo[d] >= ahi[d]) {
                    continue;
                }
                let Some((normal, s, at)) =
                    separation(&bodies[a], &bodies[b], D, h, &mut self.contact_points)
                else {
                    continue;
                };
                any = true;
                let (wa, wb) = (ia / (ia + ib), ib / (ia + ib));
                let closing =
                    (bodies[a].velocity_at(&at) - bodies[b].velocity_at(&at)).dot(&normal);
                let stop = normal * closing.min(0.0);
                bodies[a].give(normal * (s * wa), -stop * wa);
                bodies[b].give(-normal * (s * wb), stop * wb);
            }
        }
        for (b, body) in bodies.iter().enumerate() {
            if body.inv_mass == 0.0 {
                continue;
            }
            if self.shaped[b].is_some() {
                self.pose[b] = body.pose;
            } else {
                // a free box moves over the next step by its velocity: the distance the
                // contact moved it joins that step
                let v = body.pose.velocity + body.moved / dt;
                self.velocity[b] = super::shaped::from3(&v);
            }
        }
        self.contact_scratch = bodies;
        any
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::ShapeDeck;

    fn boxed(lo: [f64; 2], hi: [f64; 2], inv_mass: f64) -> Body {
        Body {
            shape: None,
            pose: Pose::at(Vector3::zeros()),
            lo: Vector3::new(lo[0], lo[1], 0.0),
            hi: Vector3::new(hi[0], hi[1], 0.0),
            inv_mass,
            held: [false; 3],
            moved: Vector3::zeros(),
        }
    }

    #[test]
    fn two_boxes_part_along_the_normal_of_their_overlap_by_its_depth() {
        let h = 0.01;
        // a small box sunk 3.3 mm into the top of a wide one, and off its centre
        let (a, b) = (
            boxed([0.42, 0.2967], [0.48, 0.3567], 1.0),
            boxed([0.3, 0.2], [0.6, 0.3], 0.0),
        );
        let (n, s, at) = separation(&a, &b, 2, h, &mut Default::default()).expect("they overlap");
        assert!((n - Vector3::y()).norm() < 1e-12, "normal {n}");
        assert!(s >= 0.0033 - 1e-12 && s < 0.0033 + 1e-4 * h, "depth {s}");
        assert!((at[1] - 0.3).abs() < 0.0034, "centre {at}");
        // touching faces do not overlap
        let c = boxed([0.42, 0.3], [0.48, 0.36], 1.0);
        assert!(separation(&c, &b, 2, h, &mut Default::default()).is_none());
    }

    #[test]
    fn a_disc_on_a_box_corner_is_pushed_away_from_the_corner() {
        let h = 0.01;
        let mut deck = ShapeDeck::empty(crate::geometry::ShapeKind::Sphere);
        deck.center = Some(vec![0.62, 0.32]);
        deck.radius = Some(0.05);
        let solid = deck.solid(2).unwrap();
        let clip = (Vector3::zeros(), Vector3::new(1.0, 1.0, 0.0));
        let shape = Arc::new(
            Shaped::new(solid, 2, clip, None, h, crate::rigid::Reach::everywhere()).unwrap(),
        );
        let disc = Body {
            shape: Some(shape),
            pose: Pose::at(Vector3::new(0.62, 0.32, 0.0)),
            lo: Vector3::zeros(),
            hi: Vector3::zeros(),
            inv_mass: 1.0,
            held: [false; 3],
            moved: Vector3::zeros(),
        };
        // the corner (0.6, 0.3) is 0.0283 m from the centre: 21.7 mm inside the disc
        let block = boxed([0.3, 0.2], [0.6, 0.3], 0.0);
        let (n, s, _) =
            separation(&disc, &block, 2, h, &mut Default::default()).expect("they overlap");
        let diagonal = Vector3::new(1.0, 1.0, 0.0).normalize();
        assert!(n.dot(&diagonal) > 0.99, "normal {n}");
        // parted along n the corner must leave the disc: at least r - |c - corner| along
        // the diagonal, to the rays' resolution
        let depth = 0.05 - (0.02f64.hypot(0.02));
        assert!(
            s > depth * 0.95 && s < depth * 1.1,
            "depth {s} against {depth}"
        );
    }
}
