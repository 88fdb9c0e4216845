//! Assembly of the pressure Poisson equation (docs/method.md, step 4) with particle quadrature:
//!
//! ```text
//! sum_j L_ij p_j = -(1/dt) sum_p V_p N_ip (div v*)_p,   L_ij = sum_p (V_p / rho_p) G_ip . G_jp
//! ```
//!
//! for the interior nodes i; free-surface nodes hold p = 0 and are dropped from the rows and
//! the columns, so the matrix stays symmetric. Each row is gathered from the particles of the
//! cells around its node (a node-parallel loop that writes only its own row): no per-thread
//! copies of the matrix, and the same bits for any thread count.

use super::free_surface::NodeKind;
use crate::grid::{CellBins, GridGeometry, Vector};
use crate::linalg::{EllMatrix, Slots};
use crate::shape::{ShapeFunction, Stencil, PAD};
use rayon::prelude::*;

/// Largest row: (2K - 1)^D slots, K = 4 (cubic B-spline), D = 3.
pub(super) const MAX_SLOTS: usize = 343;

/// Slots per row for a shape function: the (2K - 1)^D nodes a node can share a particle with.
pub fn row_width<const D: usize>(shape: ShapeFunction) -> usize {
    (2 * shape.width() - 1).pow(D as u32)
}

/// Range of cells (per direction, padded indices, inclusive) whose particles can have node
/// `i` in their stencil: a particle in cell c touches nodes c - 1 ..= c + 2 at most (c ..= c + 1
/// for linear shape functions).
#[inline]
pub fn cell_range(shape: ShapeFunction, i: usize, nodes: usize) -> (usize, usize) {
    let (below, above) = if shape == ShapeFunction::Linear {
        (1, 0)
    } else {
        (2, 1)
    };
    (i.saturating_sub(below), (i + above).min(nodes - 2))
}

/// Calls `f(p)` for every particle in the cells that can reach node `node`.
#[inline]
pub fn for_particles_near<const D: usize>(
    geo: &GridGeometry<D>,
    bins: &CellBins,
    shape: ShapeFunction,
    node: &[usize; D],
    mut f: impl FnMut(usize),
) {
    let ranges: [(usize, usize); D] =
        std::array::from_fn(|d| cell_range(shape, node[d], geo.nodes[d]));
    let mut c = ranges.map(|r| r.0);
    loop {
        for &p in bins.particles(geo.flat(&c)) {
            f(p as usize);
        }
        let mut d = 0;
        loop {
            if d == D {
                return;
            }
            c[d] += 1;
            if c[d] <= ranges[d].1 {
                break;
            }
            c[d] = ranges[d].0;
            d += 1;
        }
    }
}

/// What the assembly reads of the particles.
pub struct ParticleQuadrature<'a, const D: usize> {
    /// Positions.
    pub x: &'a [Vector<D>],
    /// GIMP half-widths (in cells).
    pub half_width: &'a [f64],
    /// Quadrature volumes V_p.
    pub volume: &'a [f64],
    /// V_p / rho_p.
    pub volume_over_density: &'a [f64],
    /// (div v*)_p.
    pub divergence: &'a [f64],
    /// w_p: the part of v* the wall conditions removed, interpolated to the particle.
    pub velocity: &'a [Vector<D>],
    /// Add the wall flux (1/dt) sum_p V_p G_ip . w_p to the right-hand side.
    pub flux: bool,
    /// The points sorted by cell.
    pub bins: &'a CellBins,
    /// Points at fixed places in their cells (the cell quadrature's Gauss points): the
    /// places' tables, and each point's cell (padded multi-index, less PAD). Point p is place
    /// p mod the number of places.
    pub templates: Option<(&'a ReferenceCell<D>, &'a [[u32; D]])>,
}

/// The cell quadrature's places in a cell, tabulated once: for each place its stencil in the
/// domain's first cell, N_a and G_a of its K^D nodes, and the products G_a . G_b.
///
/// Every Gauss point sits at one of 2^D places of its cell, and a translation moves a
/// B-spline or linear stencil without changing its weights, so a row of L is a sum over the
/// points around its node of c_p (G_a . G_b)(place): table lookups, where evaluating each
/// point's stencil once per node it touches was the assembly's largest cost. The products
/// are computed as the stencil computes them, so L is the same to the bit.
#[derive(Debug, Clone, Default)]
pub struct ReferenceCell<const D: usize> {
    /// The stencil of each place in the first cell.
    pub stencils: Vec<Stencil<D>>,
    /// K^D.
    nodes: usize,
    /// Per place and node a (the stencil's order, axis 0 fastest): N_a and G_a.
    n: Vec<f64>,
    grad: Vec<Vector<D>>,
    /// Per place, node a and node b: G_a . G_b.
    products: Vec<f64>,
    /// Per node b: sum_d b_d (2K - 1)^d, its place in a row's slots up to a shift.
    slot: Vec<usize>,
}

impl<const D: usize> ReferenceCell<D> {
    /// The tables of the places whose stencils (in the first cell) are `stencils`.
    pub fn new(stencils: Vec<Stencil<D>>) -> Self {
        let Some(first) = stencils.first() else {
            return Self::default();
        };
        let w = first.width;
        let nodes = w.pow(D as u32);
        let span = 2 * w - 1;
        let (mut n, mut grad) = (Vec::new(), Vec::new());
        for st in &stencils {
            st.for_each(|nw| {
                n.push(nw.n);
                grad.push(nw.grad);
            });
        }
        let mut products = Vec::with_capacity(stencils.len() * nodes * nodes);
        for g in grad.chunks(nodes) {
            for ga in g {
                products.extend(g.iter().map(|gb| ga.dot(gb)));
            }
        }
        let slot = (0..nodes)
            .map(|b| {
                let (mut rem, mut s, mut scale) = (b, 0, 1);
                for _ in 0..D {
                    s += (rem % w) * scale;
                    rem /= w;
                    scale *= span;
                }
                s
            })
            .collect();
        Self {
            stencils,
            nodes,
            n,
            grad,
            products,
            slot,
        }
    }

    /// Whether no places are tabulated yet.
    pub fn is_empty(&self) -> bool {
        self.stencils.is_empty()
    }

    /// Node `node`'s index a in the stencil of point `p` at place `p mod places` of `cell`
    /// (padded multi-index less PAD), if the stencil holds it, and the place.
    #[inline]
    fn local(&self, p: usize, cell: &[u32; D], node: &[usize; D]) -> Option<(usize, usize)> {
        let place = p % self.stencils.len();
        let st = &self.stencils[place];
        let (mut a, mut stride) = (0, 1);
        for d in 0..D {
            let r = node[d].wrapping_sub(st.k[d].base + cell[d] as usize);
            if r >= st.width {
                return None;
            }
            a += r * stride;
            stride *= st.width;
        }
        Some((place, a))
    }
}

impl<const D: usize> ParticleQuadrature<'_, D> {
    /// Point p's share of node i's source, V_p N_ip (div v*)_p, less V_p G_ip . w_p with the
    /// flux form; `n_i` and `g_i` are N_ip and G_ip.
    #[inline]
    fn source(&self, p: usize, n_i: f64, g_i: &Vector<D>) -> f64 {
        let s = self.volume[p] * n_i * self.divergence[p];
        if self.flux {
            s - self.volume[p] * g_i.dot(&self.velocity[p])
        } else {
            s
        }
    }

    /// The stencil of point `p`, evaluated where it lies (points without tabulated places).
    #[inline]
    fn stencil(&self, geo: &GridGeometry<D>, shape: ShapeFunction, p: usize) -> Stencil<D> {
        Stencil::<D>::new(shape, &geo.to_cells(&self.x[p]), geo.h, self.half_width[p])
    }

    /// Adds point p's share of row `node` (padded multi-index): c_p G_i . G_j to the slot of
    /// each node j of its stencil in `acc`, and its share of the source to `source`.
    #[inline]
    fn add_to_row(
        &self,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
        p: usize,
        node: &[usize; D],
        acc: &mut [f64],
        source: &mut f64,
    ) {
        let c = self.volume_over_density[p];
        if let Some((t, cells)) = self.templates {
            let Some((place, a)) = t.local(p, &cells[p], node) else {
                return;
            };
            let k = place * t.nodes + a;
            *source += self.source(p, t.n[k], &t.grad[k]);
            // slot of node b relative to the row's node: (b - a + K - 1) per direction
            let w = t.stencils[place].width;
            let span = 2 * w - 1;
            let centre = (0..D).fold(0, |s, _| s * span + (w - 1));
            let shift = centre - t.slot[a];
            let products = &t.products[k * t.nodes..(k + 1) * t.nodes];
            for (g, s) in products.iter().zip(&t.slot) {
                acc[s + shift] += c * g;
            }
            return;
        }
        let st = self.stencil(geo, shape, p);
        let Some(o) = st.offset_of(node) else {
            return;
        };
        let (n_i, g_i) = st.at(&o);
        *source += self.source(p, n_i, &g_i);
        let w = st.width;
        let span = 2 * w - 1;
        st.for_each(|nw| {
            // slot of node j relative to node i: (j - i + w - 1) per direction
            let mut s = 0;
            for d in (0..D).rev() {
                s = s * span + (nw.node[d] + w - 1 - node[d]);
            }
            acc[s] += c * g_i.dot(&nw.grad);
        });
    }

    /// Point p's share of row `node`'s source alone.
    #[inline]
    fn add_to_source(
        &self,
        geo: &GridGeometry<D>,
        shape: ShapeFunction,
        p: usize,
        node: &[usize; D],
        source: &mut f64,
    ) {
        let weight = match self.templates {
            Some((t, cells)) => t.local(p, &cells[p], node).map(|(place, a)| {
                let k = place * t.nodes + a;
                (t.n[k], t.grad[k])
            }),
            None => {
                let st = self.stencil(geo, shape, p);
                st.offset_of(node).map(|o| st.at(&o))
            }
        };
        if let Some((n_i, g_i)) = weight {
            *source += self.source(p, n_i, &g_i);
        }
    }
}

/// The rows of a Poisson system as the assembly reads them: which nodes are unknowns and
/// which free surface (`kinds`, with its level set `phi` where the free surface is
/// ghost-fluid), each node's row and each row's node, and the values `dirichlet` the
/// free-surface nodes hold.
pub struct Rows<'a> {
    /// Each node's kind.
    pub kinds: &'a [NodeKind],
    /// The level set of the ghost-fluid free surface, per node.
    pub phi: Option<&'a [f64]>,
    /// Each node's row (`u32::MAX` where it is not an unknown) and each row's node.
    pub unknowns: &'a super::Unknowns,
    /// The value a free-surface node holds.
    pub dirichlet: &'a [f64],
}

/// Whether this rank assembles row `row` (every row on one process; over ranks those of
/// `Unknowns::assembled`).
#[inline]
fn assembles(unknowns: &super::Unknowns, row: u32) -> bool {
    unknowns
        .assembled
        .as_ref()
        .is_none_or(|near| near.contains(&(row as usize)))
}

/// Assembles the rows of the interior nodes (`rows.unknowns.node_of_row`) into `a` and the
/// right-hand side into `rhs`. `row_of[i]` is node i's row, or `u32::MAX` if it is not an
/// unknown; the free-surface nodes hold the values `dirichlet[i]` (moved to the right-hand
/// side).
///
/// With a level set `phi` (the ghost-fluid free surface), the value of a column j outside the
/// fluid is the ghost value p_i + (d_j - p_i) / theta_ij that puts d_j where phi crosses zero
/// between i and j ([`super::free_surface::theta`]): L_ij (1 - 1/theta) joins the diagonal
/// and L_ij d_j / theta the right-hand side (Gibou, Fedkiw, Cheng & Kang 2002). The diagonal
/// only grows (L_ij <= 0 for full-cell quadrature), so L stays symmetric positive definite.
/// A column inside a rigid body ([`NodeKind::Solid`]) takes the row's own value: L_ij joins
/// the diagonal, which keeps the row diagonally dominant (weakly, as a Neumann row is).
pub fn assemble<const D: usize>(
    geo: &GridGeometry<D>,
    shape: ShapeFunction,
    q: &ParticleQuadrature<D>,
    rows: &Rows,
    dt: f64,
    a: &mut EllMatrix,
    rhs: &mut Slots<f64>,
) {
    let (bins, kinds, phi, dirichlet) = (q.bins, rows.kinds, rows.phi, rows.dirichlet);
    let (unknowns, node_of_row) = (rows.unknowns, &rows.unknowns.node_of_row);
    let w = shape.width();
    let span = 2 * w - 1;
    let slots = row_width::<D>(shape);
    a.reshape(node_of_row.len(), slots);
    rhs.fit(node_of_row.len());
    a.cols
        .par_chunks_mut(slots)
        .zip(a.vals.par_chunks_mut(slots))
        .zip(rhs.par_iter_mut())
        .zip(node_of_row.par_iter())
        .for_each(|(((cols, vals), b), &i)| {
            let row = unknowns.row(i as usize);
            if !assembles(unknowns, row) {
                // another rank's row: zero, written only where it is not already, so that
                // its pages stay uncommitted
                crate::pages::store(b, 0.0);
                return;
            }
            let node = geo.multi(i as usize);
            let mut acc = [0.0f64; MAX_SLOTS];
            let mut source = 0.0;
            // across a periodic direction the node's images gather too
            geo.for_each_image(&node, |image| {
                for_particles_near(geo, bins, shape, &image, |p| {
                    q.add_to_row(geo, shape, p, &image, &mut acc, &mut source);
                });
            });
            let mut known = 0.0;
            let mut ghost_diagonal = 0.0;
            let centre = (0..D).fold(0, |s, _| s * span + (w - 1));
            for (s, (col, val)) in cols.iter_mut().zip(vals.iter_mut()).enumerate() {
                // node j from the slot
                let mut rem = s;
                let mut j = [0usize; D];
                let mut valid = true;
                for d in 0..D {
                    let off = rem % span;
                    rem /= span;
                    let mut jd = (node[d] + off).wrapping_sub(w - 1);
                    if geo.periodic[d] {
                        let r = (node[d] + off) as isize - (w - 1) as isize - PAD as isize;
                        jd = PAD + r.rem_euclid(geo.cells[d] as isize) as usize;
                    }
                    valid &= jd < geo.nodes[d];
                    j[d] = jd;
                }
                let jf = if valid {
                    geo.canonical(geo.flat(&j))
                } else {
                    0
                };
                if valid && kinds[jf] == NodeKind::Interior && acc[s] != 0.0 {
                    *col = unknowns.row(jf);
                    *val = acc[s];
                } else {
                    let t = match phi {
                        Some(phi) if valid && acc[s] < 0.0 => {
                            super::free_surface::theta(phi[i as usize], phi[jf])
                        }
                        _ => 1.0,
                    };
                    if valid && kinds[jf] == NodeKind::Solid {
                        // inside a rigid body: p_j = p_i
                        ghost_diagonal += acc[s];
                    } else if t < 1.0 {
                        ghost_diagonal += acc[s] * (1.0 - 1.0 / t);
                        known += acc[s] * dirichlet[jf] / t;
                    } else if valid && kinds[jf] == NodeKind::FreeSurface {
                        known += acc[s] * dirichlet[jf];
                    }
                    // free-surface (p = 0) and empty columns drop out
                    *col = row;
                    *val = 0.0;
                }
            }
            vals[centre] += ghost_diagonal;
            *b = -source / dt - known;
        });
}

/// The right-hand side of [`assemble`] alone, -(1/dt) times the source, for rows whose
/// free-surface values are all 0 (a further pass of the projection solves for an increment that
/// vanishes there, so no column moves a known value across).
pub fn right_hand_side<const D: usize>(
    geo: &GridGeometry<D>,
    shape: ShapeFunction,
    q: &ParticleQuadrature<D>,
    unknowns: &super::Unknowns,
    dt: f64,
    rhs: &mut Slots<f64>,
) {
    let bins = q.bins;
    let node_of_row = &unknowns.node_of_row;
    rhs.fit(node_of_row.len());
    rhs.par_iter_mut()
        .zip(node_of_row.par_iter())
        .enumerate()
        .for_each(|(r, (b, &i))| {
            if !assembles(unknowns, r as u32) {
                crate::pages::store(b, 0.0);
                return;
            }
            let node = geo.multi(i as usize);
            let mut source = 0.0;
            geo.for_each_image(&node, |image| {
                for_particles_near(geo, bins, shape, &image, |p| {
                    q.add_to_source(geo, shape, p, &image, &mut source);
                });
            });
            *b = -source / dt;
        });
}
