//! Wall conditions on grid velocities (METHOD.md eq. 3 and 6): slip, no-slip, open, moving.
//!
//! A face's condition holds on its wall nodes and on the ghost nodes behind it, so that the
//! wide shape functions (GIMP, B-splines) see the wall too.

use crate::deck::{BoundaryKind, Deck};
use crate::grid::{GridGeometry, Vector};
use crate::shape::PAD;
use rayon::prelude::*;

/// The conditions of all faces and the nodes they act on.
#[derive(Debug, Clone)]
pub struct Boundary<const D: usize> {
    /// (kind, wall velocity) per face, in the order x_min, x_max, y_min, ...
    faces: Vec<(BoundaryKind, Vector<D>)>,
    /// (node, face) pairs, precomputed so that applying costs O(boundary nodes).
    nodes: Vec<(usize, usize)>,
}

impl<const D: usize> Boundary<D> {
    /// Conditions of a validated deck on a grid.
    pub fn new(deck: &Deck, geo: &GridGeometry<D>) -> Self {
        let faces: Vec<(BoundaryKind, Vector<D>)> = deck.grid.boundary.faces()[..2 * D]
            .iter()
            .map(|f| {
                let f = f.as_ref().expect("validated: every face filled in");
                let v = f
                    .velocity()
                    .map(Vector::<D>::from_column_slice)
                    .unwrap_or_else(Vector::<D>::zeros);
                (f.kind(), v)
            })
            .collect();
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
        nodes.retain(|&(_, f)| !matches!(faces[f].0, BoundaryKind::Open | BoundaryKind::Periodic));
        Self { faces, nodes }
    }

    /// Wraps particles across periodic faces and keeps them inside closed faces. Near a wall a particle's velocity is interpolated
    /// from nodes off the wall as well, so it can cross the wall by a fraction of a step; it is
    /// put back on the wall and its velocity into the wall removed (the particle-level form of
    /// v . n = 0). A particle further than a cell beyond a wall, or beyond an open face, is
    /// left where it is for the blow-up guard to report.
    pub fn confine(&self, geo: &GridGeometry<D>, x: &mut [Vector<D>], v: &mut [Vector<D>]) {
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
                } else if x[d] < lo[d] && x[d] > lo[d] - h && kmin != BoundaryKind::Open {
                    x[d] = lo[d];
                    v[d] = v[d].max(wmin[d]);
                } else if x[d] > hi[d] && x[d] < hi[d] + h && kmax != BoundaryKind::Open {
                    x[d] = hi[d];
                    v[d] = v[d].min(wmax[d]);
                }
            }
        });
    }

    /// Whether face `f` (x_min, x_max, y_min, ...) is open.
    pub fn is_open(&self, f: usize) -> bool {
        self.faces[f].0 == BoundaryKind::Open
    }

    /// Imposes only the normal part of the face conditions (v . n = v_wall . n on slip and
    /// no-slip faces alike): what the walls' flux through them is measured against.
    pub fn apply_normal(&self, v: &mut [Vector<D>]) {
        for &(i, f) in &self.nodes {
            let (kind, wall) = self.faces[f];
            let axis = f / 2;
            if matches!(kind, BoundaryKind::Slip | BoundaryKind::NoSlip) {
                v[i][axis] = wall[axis];
            }
        }
    }

    /// Imposes the face conditions on node velocities.
    pub fn apply(&self, v: &mut [Vector<D>]) {
        for &(i, f) in &self.nodes {
            let (kind, wall) = self.faces[f];
            let axis = f / 2;
            match kind {
                BoundaryKind::Slip => v[i][axis] = wall[axis],
                BoundaryKind::NoSlip => v[i] = wall,
                BoundaryKind::Open | BoundaryKind::Periodic => {}
            }
        }
    }
}
