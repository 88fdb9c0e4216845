//! Geometric multigrid V-cycle, the preconditioner of the conjugate gradient
//! (`preconditioner = "multigrid"`): the cost of a solve grows about linearly with the number of
//! unknowns, where Jacobi-PCG's iteration count grows with the grid's width.
//!
//! The levels follow the background grid (in the spirit of McAdams, Sifakis & Teran 2010, "A
//! parallel multigrid Poisson solver for fluids simulation on large grids"), but the unknowns
//! here are the nodes of the finite-element Poisson matrix (docs/method.md, step 4), not MAC cells,
//! and its rows are only the fluid's interior nodes. So each coarse operator is the Galerkin
//! product A_c = P^T A P with P the multilinear interpolation from the coarse nodes (every
//! other fine node) to the fine ones: it sees the free surface, the walls and the density jumps
//! through A itself, stays symmetric positive (semi-)definite, and needs no geometry beyond
//! the node index of each row. Smoothing is weighted Jacobi, the same sweeps before and after
//! the coarse correction, so the V-cycle is a symmetric positive definite operator as the
//! conjugate gradient needs; the coarsest level is solved exactly by a dense Cholesky
//! factorisation. Written by hand: no well-kept Rust crate offers a multigrid preconditioner
//! on this storage, and an algebraic one would rebuild its hierarchy from scratch every step
//! where the geometry gives it for free. Every loop gathers per output row in a fixed order,
//! so a solve repeats bitwise for a given thread count; all buffers are kept between steps.
//! Over ranks every loop runs on the rank's own rows of its level, after its neighbours' rows
//! have come ([`super::spread`]); on one process a level's share is every row.

use super::spread::{Halo, Share};
use super::{EllMatrix, Preconditioner, Slots, System};
use rayon::prelude::*;
use std::ops::Range;

/// Jacobi weight of the smoother: D^-1 A of the bilinear (trilinear) element Laplacian has its
/// largest eigenvalue at 1.5 (about 1.8 in 3D), so 0.6 damps the high frequencies and keeps
/// omega lambda below 2 (a convergent, symmetric smoother).
const OMEGA: f64 = 0.6;
/// Smoothing sweeps before and after the coarse correction.
const SWEEPS: usize = 2;
/// Coarsen until a level has at most this many unknowns, then factorise it: few enough that
/// the dense factorisation (n^3 / 3 operations, at every set-up) costs little beside the
/// Galerkin products; the coarse levels in between cost the V-cycle no iterations.
const COARSEST: usize = 64;
/// Largest level solved by the dense factorisation when coarsening stops early (a periodic
/// axis with an odd number of cells); above it, the coarsest level is only smoothed.
const DENSE_LIMIT: usize = 600;

/// Where the unknowns sit on the grid, for the geometric coarsening. Filled by the projection
/// for every system (the rows change with the fluid); [`GridLayout::EMPTY`] for rows that sit
/// on no grid (the multigrid is then a Jacobi sweep and the coarsest solve).
#[derive(Debug, Clone, Default)]
pub struct GridLayout {
    /// 2 or 3.
    pub dim: usize,
    /// Nodes per axis (padded indices 0..nodes).
    pub nodes: [usize; 3],
    /// First node of the domain per axis, and its number of cells (a periodic axis wraps a
    /// node n to offset + (n - offset) mod cells).
    pub offset: [usize; 3],
    /// Cells per axis.
    pub cells: [usize; 3],
    /// Periodic axes.
    pub periodic: [bool; 3],
    /// How far (in nodes, per axis) a row couples: shape-function width - 1.
    pub reach: usize,
    /// The node (padded multi-index) of each row.
    pub index: Vec<[u32; 3]>,
}

impl GridLayout {
    /// No grid: no row has a place.
    pub const EMPTY: GridLayout = GridLayout {
        dim: 0,
        nodes: [0; 3],
        offset: [0; 3],
        cells: [0; 3],
        periodic: [false; 3],
        reach: 0,
        index: Vec::new(),
    };

    fn node_count(&self) -> usize {
        self.nodes[..self.dim].iter().product()
    }

    fn flat(&self, n: &[usize; 3]) -> usize {
        let mut f = 0;
        for d in (0..self.dim).rev() {
            f = f * self.nodes[d] + n[d];
        }
        f
    }

    /// The canonical node of a (possibly wrapped) index, or None off the grid.
    fn canonical(&self, n: [isize; 3]) -> Option<[usize; 3]> {
        let mut out = [0usize; 3];
        for d in 0..self.dim {
            let mut v = n[d];
            if self.periodic[d] {
                let o = self.offset[d] as isize;
                v = o + (v - o).rem_euclid(self.cells[d] as isize);
            }
            if v < 0 || v >= self.nodes[d] as isize {
                return None;
            }
            out[d] = v as usize;
        }
        Some(out)
    }

    /// Slot of column node `j` in the row of node `i`, for rows `2 reach + 1` wide per axis
    /// (the numbering [`slot_table`] tabulates; the tests check the two agree).
    #[cfg(test)]
    fn slot(&self, i: &[u32; 3], j: &[u32; 3]) -> usize {
        let span = 2 * self.reach + 1;
        let mut s = 0;
        for d in (0..self.dim).rev() {
            let mut diff = j[d] as isize - i[d] as isize;
            if self.periodic[d] {
                let c = self.cells[d] as isize;
                diff = (diff + c / 2).rem_euclid(c) - c / 2;
            }
            s = s * span + (diff + self.reach as isize) as usize;
        }
        s
    }
}

/// One coarse level: its operator, its unknowns' layout, the links to the finer level, and
/// work vectors.
#[derive(Debug, Default)]
struct Level {
    layout: GridLayout,
    a: EllMatrix,
    inverse_diagonal: Slots<f64>,
    /// Row + 1 of each node (0: not an unknown), on zeroed pages ([`crate::pages`]).
    row_of: Vec<u32>,
    /// Per row of the finer level, its 2^D parents here and their weights (weight 0: unused).
    parents: Slots<u32>,
    parent_weights: Slots<f64>,
    /// Per row here, its 3^D children on the finer level and their weights.
    children: Slots<u32>,
    child_weights: Slots<f64>,
    /// The Galerkin product's slot table ([`slot_table`]), and the dimension and the fine and
    /// coarse reaches it was built for (it depends on nothing else).
    slots: Vec<u32>,
    slots_for: [usize; 3],
    x: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
    /// This rank's rows, over ranks ([`super::spread`]).
    share: Share,
}

/// The multigrid preconditioner.
#[derive(Debug, Default)]
pub struct Multigrid {
    fine_n: usize,
    fine_inverse_diagonal: Slots<f64>,
    fine_r: Slots<f64>,
    /// The finest level's [`Level::row_of`].
    fine_row_of: Vec<u32>,
    levels: Vec<Level>,
    used: usize,
    /// Dense Cholesky factor of the coarsest level (row-major lower triangle), if factorised.
    factor: Vec<f64>,
    dense: bool,
    /// This rank's rows of the finest level (every row on one process).
    fine_share: Share,
    /// Over ranks, the exchanges ([`super::spread`]); `None` on one process.
    halo: Option<Halo>,
    /// Over ranks, with no coarser level: the finest matrix summed whole, for its dense solve,
    /// and the share that sums it.
    fine_whole: EllMatrix,
    fine_gather: Share,
}

impl Multigrid {
    /// Number of levels of the last setup, the finest included.
    pub fn levels(&self) -> usize {
        self.used + 1
    }

    /// Per coarse level of the last setup, whether it is cut into slabs and whether it is the
    /// first one summed whole ([`super::spread`]).
    #[cfg(test)]
    pub(super) fn coarse_shares(&self) -> Vec<(bool, bool)> {
        self.levels[..self.used]
            .iter()
            .map(|l| (l.share.slab, l.share.gather))
            .collect()
    }

    /// Unknowns per level of the last setup, finest first.
    pub fn sizes(&self) -> Vec<usize> {
        std::iter::once(self.fine_n)
            .chain(self.levels[..self.used].iter().map(|l| l.a.n))
            .collect()
    }
}

/// D^-1 on the rows `rows` (those a rank smooths; the others are left as they were).
fn inverse_diagonal(a: &EllMatrix, d: &mut Slots<f64>, rows: Range<usize>) {
    d.fit(a.n);
    d[rows.clone()]
        .par_iter_mut()
        .enumerate()
        .for_each(|(k, d)| {
            let diagonal = a.diagonal_of(rows.start + k);
            *d = if diagonal > 0.0 { 1.0 / diagonal } else { 0.0 };
        });
}

/// Builds `coarse` from the finer level (`fine_layout`, `fine_a`, `fine_row_of`); false when
/// the grid cannot be coarsened (a periodic axis with an odd or too small number of cells).
fn coarsen(
    (fine_layout, fine_a, fine_row_of): (&GridLayout, &EllMatrix, &[u32]),
    fine_share: &Share,
    coarse: &mut Level,
    halo: &mut Option<Halo>,
) -> bool {
    let Some(mut lay) = coarse_layout(fine_layout) else {
        return false;
    };
    let n_fine = fine_layout.index.len();
    let n_coarse = number_rows(fine_layout, &mut lay, coarse);
    if n_coarse == 0 || n_coarse * 10 > n_fine * 9 {
        coarse.layout = lay;
        return false;
    }
    let (dim, rank) = (lay.dim, halo.as_ref().map_or(0, |h| h.comm.rank()));
    coarse.share = fine_share.coarser(&lay.index, dim, lay.nodes[dim - 1], lay.reach, rank);
    // a rank reads the parents of its fine rows and of their columns, and the children of
    // its coarse rows
    let near = fine_share.near(&fine_layout.index, dim, fine_layout.reach + 2);
    link_parents(fine_layout, &lay, coarse, near);
    link_children(fine_layout, fine_row_of, &lay, coarse);
    let key = [lay.dim, fine_layout.reach, lay.reach];
    if coarse.slots.is_empty() || coarse.slots_for != key {
        slot_table(fine_layout, &lay, &mut coarse.slots);
        coarse.slots_for = key;
    }
    galerkin(fine_a, &lay, coarse);
    if let Some(h) = halo {
        h.swap_matrix(&coarse.share, &mut coarse.a);
        h.gather_matrix(&coarse.share, &mut coarse.a);
    }
    let span = coarse.share.span.clone();
    inverse_diagonal(&coarse.a, &mut coarse.inverse_diagonal, span);
    for v in [&mut coarse.x, &mut coarse.b, &mut coarse.r] {
        v.resize(n_coarse, 0.0);
    }
    coarse.layout = lay;
    true
}

/// The coarse grid's nodes (every other fine node) and reach, without its rows; `None` where a
/// periodic axis cannot be halved.
fn coarse_layout(fine_layout: &GridLayout) -> Option<GridLayout> {
    let dim = fine_layout.dim;
    // a coarse row reaches the coarse nodes whose fine images are within reach + 2 fine nodes
    let reach = (fine_layout.reach + 2) / 2;
    let mut lay = GridLayout {
        dim,
        reach,
        ..Default::default()
    };
    for d in 0..dim {
        lay.nodes[d] = fine_layout.nodes[d] / 2 + 1;
        lay.offset[d] = fine_layout.offset[d] / 2;
        lay.periodic[d] = fine_layout.periodic[d];
        lay.cells[d] = fine_layout.cells[d].div_ceil(2);
        if lay.periodic[d]
            && (fine_layout.cells[d] % 2 != 0
                || fine_layout.offset[d] % 2 != 0
                || lay.cells[d] < 2 * reach + 2)
        {
            return None;
        }
    }
    Some(lay)
}

/// Parent `k` (of 2^D) of the fine node `n` on the coarse layout, with its weight: n even ->
/// n / 2 (weight 1, only k's bit 0), odd -> (n -+ 1) / 2 (1/2 each).
fn parent_node(lay: &GridLayout, n: &[u32; 3], k: usize) -> Option<([usize; 3], f64)> {
    let mut p = [0isize; 3];
    let mut w = 1.0;
    for d in 0..lay.dim {
        let v = n[d] as isize;
        let bit = (k >> d) & 1;
        if v % 2 == 0 {
            if bit == 1 {
                return None;
            }
            p[d] = v / 2;
        } else {
            p[d] = (v - 1) / 2 + bit as isize;
            w *= 0.5;
        }
    }
    lay.canonical(p).map(|c| (c, w))
}

/// Numbers the coarse nodes that are parents of fine rows, in node order: `coarse.row_of` and
/// the layout's index. Returns the number of coarse rows.
fn number_rows(fine_layout: &GridLayout, lay: &mut GridLayout, coarse: &mut Level) -> usize {
    let corners = 1usize << lay.dim;
    // (on zeroed pages, row + 1 a node: the nodes without a row stay uncommitted)
    crate::pages::fit(&mut coarse.row_of, lay.node_count());
    crate::pages::reset(&mut coarse.row_of);
    for n in &fine_layout.index {
        for k in 0..corners {
            if let Some((c, _)) = parent_node(lay, n, k) {
                coarse.row_of[lay.flat(&c)] = u32::MAX;
            }
        }
    }
    let mut index = std::mem::take(&mut coarse.layout.index);
    index.clear();
    let mut rows = 0u32;
    for (f, r) in coarse.row_of.iter_mut().enumerate() {
        if *r == u32::MAX {
            rows += 1;
            *r = rows;
            let mut rem = f;
            let mut idx = [0u32; 3];
            // axis 0 varies fastest
            for (d, v) in idx.iter_mut().enumerate().take(lay.dim) {
                *v = (rem % lay.nodes[d]) as u32;
                rem /= lay.nodes[d];
            }
            index.push(idx);
        }
    }
    lay.index = index;
    rows as usize
}

/// The 2^D parents (coarse rows) and weights of each fine row in `rows`: the prolongation P.
fn link_parents(
    fine_layout: &GridLayout,
    lay: &GridLayout,
    coarse: &mut Level,
    rows: Range<usize>,
) {
    let corners = 1usize << lay.dim;
    let n_fine = fine_layout.index.len();
    coarse.parents.fit(n_fine * corners);
    coarse.parent_weights.fit(n_fine * corners);
    let row_of = &coarse.row_of;
    let slots = rows.start * corners..rows.end * corners;
    coarse.parents[slots.clone()]
        .par_chunks_mut(corners)
        .zip(coarse.parent_weights[slots].par_chunks_mut(corners))
        .zip(fine_layout.index[rows].par_iter())
        .for_each(|((ps, ws), n)| {
            for k in 0..corners {
                match parent_node(lay, n, k) {
                    Some((c, w)) => {
                        ps[k] = row_of[lay.flat(&c)].wrapping_sub(1);
                        ws[k] = w;
                    }
                    None => {
                        ps[k] = 0;
                        ws[k] = 0.0;
                    }
                }
            }
        });
}

/// Each coarse row's children (this rank's rows), the fine nodes 2 I + delta with delta in
/// {-1, 0, 1}^D, and their weights: the restriction P^T.
fn link_children(
    fine_layout: &GridLayout,
    fine_row_of: &[u32],
    lay: &GridLayout,
    coarse: &mut Level,
) {
    let dim = lay.dim;
    let n_coarse = lay.index.len();
    let kids = 3usize.pow(dim as u32);
    coarse.children.fit(n_coarse * kids);
    coarse.child_weights.fit(n_coarse * kids);
    let own = coarse.share.owned.clone();
    let slots = own.start * kids..own.end * kids;
    coarse.children[slots.clone()]
        .par_chunks_mut(kids)
        .zip(coarse.child_weights[slots].par_chunks_mut(kids))
        .zip(lay.index[own].par_iter())
        .for_each(|((cs, ws), i)| {
            for k in 0..kids {
                let mut rem = k;
                let mut n = [0isize; 3];
                let mut w = 1.0;
                for d in 0..dim {
                    let delta = (rem % 3) as isize - 1;
                    rem /= 3;
                    n[d] = 2 * i[d] as isize + delta;
                    if delta != 0 {
                        w *= 0.5;
                    }
                }
                let row = fine_layout.canonical(n).map_or(u32::MAX, |c| {
                    fine_row_of[fine_layout.flat(&c)].wrapping_sub(1)
                });
                if row == u32::MAX {
                    cs[k] = 0;
                    ws[k] = 0.0;
                } else {
                    cs[k] = row;
                    ws[k] = w;
                }
            }
        });
}

/// The coarse slot, per child k (of 3^D), fine slot s and parent corner q (of 2^D), of the
/// parent q of the fine row's column in slot s: `table[(k * fine width + s) * 2^D + q]`
/// (`u32::MAX` where that corner is no parent). The rows' slots are geometric (slot s holds the
/// node at offset s - reach per axis, axis 0 fastest, as [`GridLayout::slot`] numbers them),
/// and the child k of coarse node I is the fine node 2 I + delta_k, so the column's fine
/// offset from 2 I, and with it its parents' offsets from I, depend on k, s and q alone: the
/// Galerkin product looks its slots up instead of working each one out from the nodes.
fn slot_table(fine_layout: &GridLayout, lay: &GridLayout, table: &mut Vec<u32>) {
    let dim = lay.dim;
    let (corners, kids) = (1usize << dim, 3usize.pow(dim as u32));
    let fine_span = 2 * fine_layout.reach + 1;
    let fine_width = fine_span.pow(dim as u32);
    let span = 2 * lay.reach + 1;
    table.clear();
    table.resize(kids * fine_width * corners, u32::MAX);
    for k in 0..kids {
        for s in 0..fine_width {
            for q in 0..corners {
                let (mut slot, mut stride) = (0usize, 1usize);
                let mut valid = true;
                for d in 0..dim {
                    let delta = (k / 3usize.pow(d as u32) % 3) as isize - 1;
                    let off = (s / fine_span.pow(d as u32) % fine_span) as isize
                        - fine_layout.reach as isize;
                    // the column's fine offset from 2 I, and its parent's coarse offset from I
                    let v = delta + off;
                    let bit = ((q >> d) & 1) as isize;
                    let p = if v % 2 == 0 {
                        valid &= bit == 0;
                        v / 2
                    } else {
                        (v - 1).div_euclid(2) + bit
                    };
                    valid &= p.unsigned_abs() <= lay.reach;
                    slot += (p + lay.reach as isize) as usize * stride;
                    stride *= span;
                }
                if valid {
                    table[(k * fine_width + s) * corners + q] = slot as u32;
                }
            }
        }
    }
}

/// The Galerkin operator A_c = P^T A P, gathered per coarse row (this rank's).
fn galerkin(fine_a: &EllMatrix, lay: &GridLayout, coarse: &mut Level) {
    let corners = 1usize << lay.dim;
    let kids = 3usize.pow(lay.dim as u32);
    let n_coarse = lay.index.len();
    let span = 2 * lay.reach + 1;
    let width = span.pow(lay.dim as u32);
    coarse.a.reshape(n_coarse, width);
    let (children, child_weights) = (&coarse.children, &coarse.child_weights);
    let (parents, parent_weights) = (&coarse.parents, &coarse.parent_weights);
    let fw = fine_a.width;
    let table = &coarse.slots;
    debug_assert_eq!(
        table.len(),
        kids * fw * corners,
        "rows' slots are not geometric"
    );
    let own = coarse.share.owned.clone();
    let slots = own.start * width..own.end * width;
    coarse.a.cols[slots.clone()]
        .par_chunks_mut(width)
        .zip(coarse.a.vals[slots].par_chunks_mut(width))
        .enumerate()
        .for_each(|(k, (cols, vals))| {
            let row = own.start + k;
            // slots start unused (column = row, value 0)
            cols.fill(row as u32);
            vals.fill(0.0);
            for k in 0..kids {
                let wr = child_weights[row * kids + k];
                if wr == 0.0 {
                    continue;
                }
                let r = children[row * kids + k] as usize;
                for s in 0..fw {
                    let a = fine_a.vals[r * fw + s];
                    if a == 0.0 {
                        continue;
                    }
                    let c = fine_a.cols[r * fw + s] as usize;
                    for q in 0..corners {
                        let wc = parent_weights[c * corners + q];
                        if wc == 0.0 {
                            continue;
                        }
                        let slot = table[(k * fw + s) * corners + q] as usize;
                        cols[slot] = parents[c * corners + q];
                        vals[slot] += wr * a * wc;
                    }
                }
            }
        });
}

/// A level's operator and smoother on this rank's rows: A, D^-1, the share.
#[derive(Clone, Copy)]
struct Op<'a> {
    a: &'a EllMatrix,
    inverse_diagonal: &'a [f64],
    share: &'a Share,
}

/// The neighbours' rows of `v` on a slab level, before a loop reads them.
fn swap(halo: &mut Option<Halo>, share: &Share, v: &mut [f64]) {
    if let Some(h) = halo {
        h.swap(share, v);
    }
}

/// `sweeps` weighted-Jacobi sweeps on A x = b; `zero_start`: x starts at 0 (the first sweep is
/// then x = omega D^-1 b). `r` is a work vector.
fn smooth(
    op: Op,
    b: &[f64],
    x: &mut [f64],
    r: &mut [f64],
    (sweeps, zero_start): (usize, bool),
    halo: &mut Option<Halo>,
) {
    let s = op.share.span.clone();
    let d = &op.inverse_diagonal[s.clone()];
    let b_own = &b[s.clone()];
    let mut first = 0;
    if zero_start {
        x[s.clone()]
            .par_iter_mut()
            .zip(b_own.par_iter().zip(d.par_iter()))
            .for_each(|(x, (b, d))| *x = OMEGA * d * b);
        first = 1;
    }
    for _ in first..sweeps {
        swap(halo, op.share, x);
        op.a.matvec_rows(x, &mut r[s.clone()], s.start);
        x[s.clone()]
            .par_iter_mut()
            .zip(r[s.clone()].par_iter().zip(b_own.par_iter()))
            .zip(d.par_iter())
            .for_each(|((x, (r, b)), d)| *x += OMEGA * d * (b - r));
    }
}

/// r = b - A x.
fn residual(op: Op, b: &[f64], x: &mut [f64], r: &mut [f64], halo: &mut Option<Halo>) {
    let s = op.share.span.clone();
    swap(halo, op.share, x);
    op.a.matvec_rows(x, &mut r[s.clone()], s.start);
    r[s.clone()]
        .par_iter_mut()
        .zip(b[s].par_iter())
        .for_each(|(r, b)| *r = b - *r);
}

/// Dense Cholesky of `a` (n x n, taken from the ELL rows) plus `shift` on the diagonal, into
/// `l` (row-major lower triangle). The shift (1e-6 of the mean diagonal) keeps a pure-Neumann
/// level, singular by a constant, positive definite; the conjugate gradient removes that
/// constant anyway. A few lines by hand: the coarsest level is small, and it keeps the step
/// free of allocation.
fn cholesky(a: &EllMatrix, l: &mut Vec<f64>) -> bool {
    let n = a.n;
    l.clear();
    l.resize(n * n, 0.0);
    let mut mean = 0.0;
    for r in 0..n {
        for s in 0..a.width {
            let c = a.cols[r * a.width + s] as usize;
            l[r * n + c] += a.vals[r * a.width + s];
            if c == r {
                mean += a.vals[r * a.width + s];
            }
        }
    }
    let shift = 1e-6 * mean / n.max(1) as f64;
    for r in 0..n {
        l[r * n + r] += shift;
    }
    for j in 0..n {
        let mut d = l[j * n + j];
        for k in 0..j {
            d -= l[j * n + k] * l[j * n + k];
        }
        if d <= 0.0 || !d.is_finite() {
            return false;
        }
        let d = d.sqrt();
        l[j * n + j] = d;
        for i in j + 1..n {
            let mut s = l[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            l[i * n + j] = s / d;
        }
    }
    true
}

fn cholesky_solve(l: &[f64], n: usize, b: &[f64], x: &mut [f64]) {
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = x[i];
        for k in i + 1..n {
            s -= l[k * n + i] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
}

impl Multigrid {
    /// Over ranks, the finest level's share of the rows and the exchanges; every row on one
    /// process.
    fn spread_over(&mut self, system: &System) {
        let n = system.matrix.n;
        match system.partition.filter(|p| p.is_spread()) {
            Some(p) => {
                let l = system.layout;
                // the conjugate gradient has checked that the rows cut into slabs
                self.fine_share = Share::finest(l, p).unwrap_or_else(|| Share::whole(n));
                Halo::over(&mut self.halo, &p.comm);
            }
            None => {
                self.fine_share = Share::whole(n);
                self.halo = None;
            }
        }
    }

    /// The coarse levels, until one has at most [`COARSEST`] unknowns or the grid cannot be
    /// coarsened; returns how many.
    fn coarsen_all(&mut self, a: &EllMatrix, layout: &GridLayout) -> usize {
        let mut used = 0;
        if layout.index.len() != a.n || a.n <= COARSEST {
            return used;
        }
        // the finest level's node -> row map, from the layout (row + 1 a node, on zeroed
        // pages: the nodes without a row stay uncommitted)
        let row_of = &mut self.fine_row_of;
        crate::pages::fit(row_of, layout.node_count());
        crate::pages::reset(row_of);
        for (r, n) in layout.index.iter().enumerate() {
            row_of[layout.flat(&[n[0] as usize, n[1] as usize, n[2] as usize])] = r as u32 + 1;
        }
        loop {
            if used == self.levels.len() {
                self.levels.push(Level::default());
            }
            let (finer, rest) = self.levels.split_at_mut(used);
            let coarse = &mut rest[0];
            let ok = if used == 0 {
                let fine = (layout, a, &self.fine_row_of[..]);
                coarsen(fine, &self.fine_share, coarse, &mut self.halo)
            } else {
                let f = &finer[used - 1];
                coarsen(
                    (&f.layout, &f.a, &f.row_of),
                    &f.share,
                    coarse,
                    &mut self.halo,
                )
            };
            if !ok {
                break;
            }
            used += 1;
            if coarse.a.n <= COARSEST {
                break;
            }
        }
        used
    }

    /// The coarsest level whole on every rank (over ranks its rows summed from the ranks'),
    /// and its dense factor where it is small enough.
    fn factorise_coarsest(&mut self, a: &EllMatrix) {
        let last = match (self.used, &mut self.halo) {
            (0, Some(h)) if a.n <= DENSE_LIMIT.max(COARSEST) => {
                self.fine_gather.clone_from(&self.fine_share);
                self.fine_gather.make_whole(a.n);
                self.fine_whole.clone_from(a);
                h.gather_matrix(&self.fine_gather, &mut self.fine_whole);
                &self.fine_whole
            }
            // (over ranks, a finest level too large for the dense solve is only smoothed)
            (0, _) => a,
            (used, halo) => {
                let lv = &mut self.levels[used - 1];
                if let Some(h) = halo.as_mut().filter(|_| lv.share.slab) {
                    lv.share.make_whole(lv.a.n);
                    h.gather_matrix(&lv.share, &mut lv.a);
                    let span = lv.share.span.clone();
                    inverse_diagonal(&lv.a, &mut lv.inverse_diagonal, span);
                }
                &lv.a
            }
        };
        self.dense = last.n <= DENSE_LIMIT.max(COARSEST) && cholesky(last, &mut self.factor);
    }

    /// The V-cycle's way down from the first coarse level (its right-hand side restricted):
    /// smooth, restrict the residual; the coarsest level solved.
    fn descend(&mut self) {
        for l in 0..self.used {
            let (upper, lower) = self.levels.split_at_mut(l + 1);
            let lv = &mut upper[l];
            let op = Op {
                a: &lv.a,
                inverse_diagonal: &lv.inverse_diagonal,
                share: &lv.share,
            };
            if l + 1 < self.used {
                smooth(
                    op,
                    &lv.b,
                    &mut lv.x,
                    &mut lv.r,
                    (SWEEPS, true),
                    &mut self.halo,
                );
                residual(op, &lv.b, &mut lv.x, &mut lv.r, &mut self.halo);
                restrict(&mut lv.r, &lv.share, &mut lower[0], &mut self.halo);
            } else if self.dense {
                cholesky_solve(&self.factor, lv.a.n, &lv.b, &mut lv.x);
            } else {
                let sweeps = (4 * SWEEPS, true);
                smooth(op, &lv.b, &mut lv.x, &mut lv.r, sweeps, &mut self.halo);
            }
        }
    }
}

impl Preconditioner for Multigrid {
    fn spreads(&self) -> bool {
        true
    }

    fn setup(&mut self, system: &System) {
        let (a, layout) = (system.matrix, system.layout);
        self.fine_n = a.n;
        self.spread_over(system);
        let span = self.fine_share.span.clone();
        inverse_diagonal(a, &mut self.fine_inverse_diagonal, span);
        self.fine_r.fit(a.n);
        self.used = self.coarsen_all(a, layout);
        self.factorise_coarsest(a);
    }

    fn apply(&mut self, a: &EllMatrix, r: &[f64], z: &mut [f64]) {
        let fine = Op {
            a,
            inverse_diagonal: &self.fine_inverse_diagonal,
            share: &self.fine_share,
        };
        if self.used == 0 {
            if !self.dense {
                let sweeps = (2 * SWEEPS, true);
                smooth(fine, r, z, &mut self.fine_r, sweeps, &mut self.halo);
            } else if let Some(h) = &mut self.halo {
                self.fine_r.copy_from_slice(r);
                h.gather(&self.fine_gather, &mut self.fine_r);
                cholesky_solve(&self.factor, a.n, &self.fine_r, z);
            } else {
                cholesky_solve(&self.factor, a.n, r, z);
            }
            return;
        }
        // down: smooth, restrict the residual
        smooth(fine, r, z, &mut self.fine_r, (SWEEPS, true), &mut self.halo);
        residual(fine, r, z, &mut self.fine_r, &mut self.halo);
        restrict(
            &mut self.fine_r,
            &self.fine_share,
            &mut self.levels[0],
            &mut self.halo,
        );
        self.descend();
        // up: prolong the correction, smooth
        let fine = Op {
            a,
            inverse_diagonal: &self.fine_inverse_diagonal,
            share: &self.fine_share,
        };
        for l in (0..self.used).rev() {
            let (finer, rest) = self.levels.split_at_mut(l);
            let coarse = &mut rest[0];
            if l == 0 {
                prolong(coarse, z, &self.fine_share, &mut self.halo);
                smooth(
                    fine,
                    r,
                    z,
                    &mut self.fine_r,
                    (SWEEPS, false),
                    &mut self.halo,
                );
            } else {
                let f = &mut finer[l - 1];
                prolong(coarse, &mut f.x, &f.share, &mut self.halo);
                let op = Op {
                    a: &f.a,
                    inverse_diagonal: &f.inverse_diagonal,
                    share: &f.share,
                };
                smooth(
                    op,
                    &f.b,
                    &mut f.x,
                    &mut f.r,
                    (SWEEPS, false),
                    &mut self.halo,
                );
            }
        }
    }
}

/// coarse.b = P^T r (gathered per coarse row), r on the finer level of share `fine`.
fn restrict(r: &mut [f64], fine: &Share, coarse: &mut Level, halo: &mut Option<Halo>) {
    swap(halo, fine, r);
    let kids = coarse.children.len() / coarse.a.n.max(1);
    let (children, weights) = (&coarse.children, &coarse.child_weights);
    let own = coarse.share.owned.clone();
    coarse.b[own.clone()]
        .par_iter_mut()
        .enumerate()
        .for_each(|(k, b)| {
            let i = own.start + k;
            *b = (0..kids)
                .map(|k| weights[i * kids + k] * r[children[i * kids + k] as usize])
                .sum();
        });
    if let Some(h) = halo {
        h.gather(&coarse.share, &mut coarse.b);
    }
}

/// x += P coarse.x (gathered per fine row), x on the finer level of share `fine`.
fn prolong(coarse: &mut Level, x: &mut [f64], fine: &Share, halo: &mut Option<Halo>) {
    swap(halo, &coarse.share, &mut coarse.x);
    let corners = coarse.parents.len() / x.len().max(1);
    let (parents, weights, xc) = (&coarse.parents, &coarse.parent_weights, &coarse.x);
    let s = fine.span.clone();
    x[s.clone()].par_iter_mut().enumerate().for_each(|(k, x)| {
        let r = s.start + k;
        *x += (0..corners)
            .map(|k| weights[r * corners + k] * xc[parents[r * corners + k] as usize])
            .sum::<f64>();
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::{LinearSolver, Pcg};

    /// The bilinear-element Laplacian on an n x n cell grid, unknowns at the interior nodes
    /// (p = 0 on the boundary), nodes at padded indices 2 ..= n + 2.
    fn laplacian(n: usize) -> (EllMatrix, GridLayout) {
        laplacian_periodic(n, false)
    }

    /// The same, periodic along x when `periodic` (then the n nodes 2 ..= n + 1 of a row are
    /// all unknowns, and node n + 2 is node 2's image).
    fn laplacian_periodic(n: usize, periodic: bool) -> (EllMatrix, GridLayout) {
        let pad = 2;
        let m = n - 1; // unknowns per axis
        let mx = if periodic { n } else { m };
        let mut a = EllMatrix::default();
        a.reshape(mx * m, 9);
        let row = |i: usize, j: usize| (j * mx + i) as u32;
        for j in 0..m {
            for i in 0..mx {
                let r = row(i, j) as usize;
                let mut s = 0;
                for dj in -1isize..=1 {
                    for di in -1isize..=1 {
                        let (mut ii, jj) = (i as isize + di, j as isize + dj);
                        if periodic {
                            ii = ii.rem_euclid(n as isize);
                        }
                        let inside = ii >= 0 && jj >= 0 && ii < mx as isize && jj < m as isize;
                        let v = if di == 0 && dj == 0 {
                            8.0 / 3.0
                        } else {
                            -1.0 / 3.0
                        };
                        if inside {
                            a.cols[r * 9 + s] = row(ii as usize, jj as usize);
                            a.vals[r * 9 + s] = v;
                        } else {
                            a.cols[r * 9 + s] = r as u32;
                            a.vals[r * 9 + s] = 0.0;
                        }
                        s += 1;
                    }
                }
            }
        }
        let first_x = if periodic { pad } else { pad + 1 };
        let layout = GridLayout {
            dim: 2,
            nodes: [n + 1 + 2 * pad, n + 1 + 2 * pad, 1],
            offset: [pad, pad, 0],
            cells: [n, n, 0],
            periodic: [periodic, false, false],
            reach: 1,
            index: (0..mx * m)
                .map(|r| [(first_x + r % mx) as u32, (pad + 1 + r / mx) as u32, 0])
                .collect(),
        };
        (a, layout)
    }

    /// Every slot the Galerkin products fill from their table holds the column the nodes
    /// place there ([`GridLayout::slot`]), on every level, with and without a periodic axis.
    #[test]
    fn galerkin_slots_are_the_nodes_slots() {
        for periodic in [false, true] {
            let (a, layout) = laplacian_periodic(64, periodic);
            let mg = set_up(&a, &layout);
            // a periodic axis coarsens while its first node's index is even: once from PAD = 2
            assert!(mg.levels() >= 2, "levels {:?}", mg.sizes());
            let mut filled = 0;
            for level in &mg.levels[..mg.used] {
                let (lay, c) = (&level.layout, &level.a);
                for r in 0..c.n {
                    for s in 0..c.width {
                        let col = c.cols[r * c.width + s] as usize;
                        if c.vals[r * c.width + s] != 0.0 {
                            assert_eq!(s, lay.slot(&lay.index[r], &lay.index[col]));
                            filled += 1;
                        }
                    }
                }
            }
            assert!(filled > 1000, "{filled} slots filled");
        }
    }

    /// The multigrid set up for a non-singular system.
    fn set_up(a: &EllMatrix, layout: &GridLayout) -> Multigrid {
        let mut mg = Multigrid::default();
        mg.setup(&System {
            matrix: a,
            layout,
            singular: false,
            partition: None,
        });
        mg
    }

    fn pseudo_random(n: usize, seed: u64) -> Vec<f64> {
        let mut rnd = crate::test_random(seed);
        (0..n).map(|_| rnd() - 0.5).collect()
    }

    fn dot(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    /// The V-cycle is a symmetric positive definite operator (what the conjugate gradient
    /// needs), with several levels.
    #[test]
    fn v_cycle_is_symmetric_positive_definite() {
        let (a, layout) = laplacian(64);
        let mut mg = set_up(&a, &layout);
        assert!(mg.levels() >= 3, "levels {:?}", mg.sizes());
        let n = a.n;
        let (x, y) = (pseudo_random(n, 1), pseudo_random(n, 2));
        let (mut mx, mut my) = (vec![0.0; n], vec![0.0; n]);
        mg.apply(&a, &x, &mut mx);
        mg.apply(&a, &y, &mut my);
        let (xmy, ymx) = (dot(&x, &my), dot(&y, &mx));
        assert!(
            (xmy - ymx).abs() <= 1e-12 * xmy.abs().max(ymx.abs()),
            "x.My = {xmy}, y.Mx = {ymx}"
        );
        assert!(dot(&x, &mx) > 0.0 && dot(&y, &my) > 0.0);
    }

    /// Iterations to 1e-8: about constant with multigrid from 32^2 to 256^2 cells (at most 1.5
    /// times), where Jacobi's grow with the width.
    #[test]
    fn multigrid_iterations_do_not_grow_with_the_grid() {
        let mut counts = Vec::new();
        for n in [32, 256] {
            let (a, layout) = laplacian(n);
            let b = pseudo_random(a.n, 7);
            let mut its = [0usize; 2];
            for (k, pc) in [true, false].into_iter().enumerate() {
                let mut solver = if pc {
                    LinearSolver::Pcg(Pcg::new(Box::<Multigrid>::default()))
                } else {
                    LinearSolver::Pcg(Pcg::new(Box::<crate::linalg::Jacobi>::default()))
                };
                let system = System {
                    matrix: &a,
                    layout: &layout,
                    singular: false,
                    partition: None,
                };
                let params = crate::linalg::SolveParams {
                    tolerance: 1e-8,
                    max_iterations: 5000,
                };
                let mut x = vec![0.0; a.n];
                its[k] = solver
                    .solve(&system, &b, &mut x, params)
                    .unwrap()
                    .iterations;
            }
            counts.push(its);
        }
        println!("iterations [multigrid, jacobi] at 32^2, 256^2: {counts:?}");
        assert!(counts[1][0] as f64 <= 1.5 * counts[0][0] as f64);
        assert!(counts[1][1] > 4 * counts[0][1]);
    }
}
