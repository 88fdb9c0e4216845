//! The projection over ranks (docs/distributed.md).
//!
//! Each rank runs the projection's stages on its slab and on the window around it
//! ([`crate::slabs::Decomposition::window`]): its own particles, the neighbours' particles in
//! the layers next to the cut (ghosts, [`crate::slabs::GHOST_LAYERS`]), and the sums of the
//! neighbours' own particles copied onto the window's nodes and cells
//! ([`Ranks::add_sums`], [`Ranks::take_owners`]). The
//! stages read no further than the window from a node of the slab, so on the slab's nodes
//! every rank finds the free surface, the Gauss points and the rows of the system that one
//! process finds. Each rank numbers the unknowns of its own node layers and assembles their
//! rows; the rows beside its slab that the solver reads come from the neighbours that
//! assembled them ([`Ranks::swap_beside`]). Every rank's rows in
//! rank order are the system's (node order, the last axis slowest), the solve is spread over
//! the ranks ([`crate::linalg::spread`]), and the neighbours swap the solution's rows of the
//! layers next to each cut ([`Ranks::gather`]), so that the stages after it read the pressure
//! on the window's nodes too.
//!
//! This first stage keeps the whole numbering on every rank: an exchange of every row's node
//! each step (4 bytes a row). A numbering of each rank's own rows with the others' offsets
//! would make it fall with the ranks.

use super::assemble::MAX_SLOTS;
use super::Unknowns;
use crate::comm::Comm;
use crate::grid::GridGeometry;
use crate::linalg::{EllMatrix, Partition};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::Arc;

/// Node layers beside a rank's own whose rows of the matrix it takes from its neighbours
/// ([`Ranks::swap_beside`]): the solver reads its neighbours' rows that far (the multigrid's
/// Galerkin product reads the fine rows of its coarse rows' children, a layer or two past
/// the slab). A rank assembles only its own rows, so the stages that feed the assembly need
/// see no further past the slab than its own rows read.
pub const BESIDE: usize = 4;

/// Zero in `values` (one a node, or a cell numbered like its lower-corner node) outside the
/// node layers `layers` along `axis`: a rank's own share, before a sum over the ranks gives
/// each node its owner's value.
pub fn keep_layers<const D: usize>(
    geo: &GridGeometry<D>,
    axis: usize,
    layers: &Range<usize>,
    values: &mut [f64],
) {
    // the nodes come in blocks of `nodes[axis]` runs of `strides[axis]` nodes, one run a
    // layer: the runs outside `layers` are zeroed whole (a test a run, not a division a node)
    let (run, count) = (geo.strides[axis], geo.nodes[axis]);
    let (lo, hi) = (layers.start.min(count) * run, layers.end.min(count) * run);
    values.par_chunks_mut(run * count).for_each(|block| {
        let (below, rest) = block.split_at_mut(lo);
        let above = &mut rest[hi.max(lo) - lo..];
        (below.par_iter_mut().chain(above.par_iter_mut()))
            .with_min_len(4096)
            .for_each(|v| crate::pages::store(v, 0.0));
    });
}

/// The solution `x` (this rank's rows and its neighbours' beside them, after
/// [`Ranks::gather`]) on the nodes of its rows:
/// over ranks only those within [`Ranks::reach`] layers of this rank's own,
/// as far as the stages read past the slab, and zero farther out ([`keep_layers`]), so that
/// a rank writes its share of the fluid's nodes, not all of them.
pub fn scatter_rows<const D: usize>(
    ranks: Option<&Ranks>,
    geo: &GridGeometry<D>,
    unknowns: &Unknowns,
    x: &[f64],
    nodes: &mut [f64],
) {
    let rows = match ranks {
        None => 0..unknowns.node_of_row.len(),
        Some(r) => {
            let (own, reach) = (r.layers(), r.reach);
            let layers = own.start.saturating_sub(reach)..own.end + reach;
            keep_layers(geo, r.axis, &layers, nodes);
            r.rows_on(geo, unknowns, layers)
        }
    };
    for r in rows {
        nodes[unknowns.node_of_row[r] as usize] = x[r];
    }
}

/// How many of `n` particles a sum added up over the ranks counts: on one process all, over
/// ranks this rank's own (the ghosts after them are counted by their own ranks).
pub fn own_of(ranks: Option<&Ranks>, n: usize) -> usize {
    ranks.map_or(n, |r| r.own.min(n))
}

/// How the projection of a rank of a run spread over ranks shares its work.
pub struct Ranks {
    /// The ranks, and the node layers along `axis` each one owns (its slab's).
    pub partition: Partition,
    /// The axis the grid is cut along.
    pub axis: usize,
    /// The layers past the slab the stages read ([`crate::slabs::projection_reach`]).
    reach: usize,
    /// While ghosts are lent, how many of the particles are this rank's own: those after
    /// them are ghosts, which count in no sum that is added up over the ranks. `usize::MAX`
    /// while none are lent ([`Ranks::ghosts_gone`]): every particle is the rank's own, also
    /// those a migration brought in.
    pub own: usize,
    /// The first row of each rank, and the row count (ranks + 1 bounds).
    starts: Vec<usize>,
    /// Each rank's row count, and every rank's rows' nodes gathered ([`Ranks::join`]):
    /// buffers kept from step to step.
    counts: Vec<f64>,
    gathered: Vec<u8>,
    /// The rows sent and received by [`Ranks::swap_beside`] and [`Ranks::gather`], kept
    /// likewise.
    swapped: std::sync::Mutex<(Vec<f64>, Vec<f64>)>,
}

impl Ranks {
    /// The projection of rank `comm.rank()` with the grid cut at `cuts` (padded layers along
    /// `axis`, ranks + 1 bounds, as [`crate::slabs::Decomposition::cuts`]), its stages
    /// reading `reach` layers past the slab ([`crate::slabs::Decomposition::reach`]).
    pub fn new(comm: Arc<dyn Comm>, axis: usize, cuts: Vec<usize>, reach: usize) -> Self {
        Self {
            partition: Partition { comm, cuts },
            axis,
            reach,
            own: usize::MAX,
            starts: Vec::new(),
            counts: Vec::new(),
            gathered: Vec::new(),
            swapped: std::sync::Mutex::new((Vec::new(), Vec::new())),
        }
    }

    fn comm(&self) -> &dyn Comm {
        &*self.partition.comm
    }

    /// The layers past the slab the stages read ([`crate::slabs::Decomposition::reach`]).
    pub fn reach(&self) -> usize {
        self.reach
    }

    /// The node layers along the cut axis this rank owns.
    pub fn layers(&self) -> Range<usize> {
        let (r, cuts) = (self.comm().rank(), &self.partition.cuts);
        cuts[r]..cuts[r + 1]
    }

    /// After this rank numbered the unknowns of its own layers (with `free` free-surface
    /// nodes there): every rank's rows, in rank order, become the numbering on every rank,
    /// of which this rank assembles those of its layers (`Unknowns::assembled`). Returns the
    /// free-surface nodes of every rank.
    pub fn join<const D: usize>(
        &mut self,
        geo: &GridGeometry<D>,
        unknowns: &mut Unknowns,
        free: usize,
    ) -> usize {
        let comm = self.partition.comm.clone();
        let mine = unknowns.node_of_row.len();
        let mut all = std::mem::take(&mut self.gathered);
        comm.all_gather(bytemuck::cast_slice(&unknowns.node_of_row), &mut all);
        self.counts.clear();
        self.counts.resize(comm.size(), 0.0);
        self.counts[comm.rank()] = mine as f64;
        comm.sum(&mut self.counts);
        self.starts.clear();
        self.starts.push(0);
        for &c in &self.counts {
            let last = *self.starts.last().unwrap_or(&0);
            self.starts.push(last + c as usize);
        }
        unknowns.node_of_row.clear();
        unknowns
            .node_of_row
            .extend(all.chunks_exact(4).map(bytemuck::pod_read_unaligned::<u32>));
        self.gathered = all;
        crate::pages::reset(&mut unknowns.row_of);
        for (r, &i) in unknowns.node_of_row.iter().enumerate() {
            unknowns.row_of[i as usize] = r as u32 + 1;
        }
        let layers = self.layers();
        unknowns.assembled = Some(self.rows_on(geo, unknowns, layers));
        comm.sum_scalar(free as f64) as usize
    }

    /// The rows of `unknowns` on the node layers `layers` along the cut (the rows are in
    /// layer order along it).
    fn rows_on<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        unknowns: &Unknowns,
        layers: Range<usize>,
    ) -> Range<usize> {
        let below = |l: usize| {
            let layer = |&i: &u32| geo.layer(i as usize, self.axis);
            unknowns.node_of_row.partition_point(|i| layer(i) < l)
        };
        below(layers.start)..below(layers.end.max(layers.start))
    }

    /// The rows of `a` on the [`BESIDE`] node layers either side of this rank's, columns
    /// and values, from the neighbours that assembled them (after [`Ranks::order_slots`]):
    /// the same bits as this rank would assemble there, without the stages' data that far
    /// past its slab. Two rounds, pairs of neighbours swapping at once, as the slabs' sums.
    pub fn swap_beside<const D: usize>(
        &mut self,
        geo: &GridGeometry<D>,
        unknowns: &Unknowns,
        a: &mut EllMatrix,
    ) {
        let (rank, size) = (self.comm().rank(), self.comm().size());
        for (upper, peer) in crate::comm::neighbour_rounds(rank, size) {
            let (send, recv) = self.beside(geo, unknowns, (upper, peer), BESIDE);
            let (out, back) = self.swapped.get_mut().unwrap_or_else(|e| e.into_inner());
            let comm = &*self.partition.comm;
            crate::linalg::spread::swap_rows(comm, peer, a, (&send, &recv), (out, back));
        }
    }

    /// The rows this rank sends its neighbour `peer` (above it if `upper`) and those it
    /// receives from it in a swap of the `depth` node layers either side of their cut: its
    /// own rows on its layers next to the cut, and the neighbour's on the neighbour's. Each
    /// side is clipped to the slab of the rank that sends it, so that both agree on its length
    /// however thin a slab is (slabs are at least the window wide, wider than any depth
    /// swapped, so nothing is clipped in a run).
    fn beside<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        unknowns: &Unknowns,
        (upper, peer): (bool, usize),
        depth: usize,
    ) -> (Range<usize>, Range<usize>) {
        let (lo, hi) = (self.layers().start, self.layers().end);
        let cuts = &self.partition.cuts;
        let (send, recv) = if upper {
            (
                hi.saturating_sub(depth).max(lo)..hi,
                hi..(hi + depth).min(cuts[peer + 1]),
            )
        } else {
            (
                lo..(lo + depth).min(hi),
                lo.saturating_sub(depth).max(cuts[peer])..lo,
            )
        };
        (
            self.rows_on(geo, unknowns, send),
            self.rows_on(geo, unknowns, recv),
        )
    }

    /// Over ranks cut along another axis than the last, the slots of every row of `a` (an
    /// offset a slot, the first axis fastest: [`super::assemble::assemble`]; the solver reads
    /// this rank's rows and those of its halo, which come from the neighbours ordered) put
    /// in the axis order of the solver's layout, the cut axis last (`describe_layout`): the
    /// multigrid reads a slot's offset along the layout's axes. Only the rows `rows` this
    /// rank assembled (`Unknowns::assembled`) are touched: the others' pages stay
    /// uncommitted.
    pub fn order_slots<const D: usize>(&self, a: &mut EllMatrix, span: usize, rows: Range<usize>) {
        if self.axis == D - 1 {
            return;
        }
        // the axes in the layout's order, the cut axis last (on the stack, as the targets: no
        // allocation a step)
        let mut order = [self.axis; D];
        for (k, d) in (0..D).filter(|&d| d != self.axis).enumerate() {
            order[k] = d;
        }
        // slot s (offsets o_d, axis d with stride span^d) goes to sum_k o_(order k) span^k
        let mut target = [0usize; MAX_SLOTS];
        for (s, t) in target[..a.width].iter_mut().enumerate() {
            let offset = |d: usize| (s / span.pow(d as u32)) % span;
            *t = (0..D).map(|k| offset(order[k]) * span.pow(k as u32)).sum();
        }
        let target = &target[..a.width];
        let w = a.width;
        let slots = rows.start * w..rows.end * w;
        a.cols[slots.clone()]
            .par_chunks_mut(w)
            .zip(a.vals[slots].par_chunks_mut(w))
            .for_each(|(c, v)| {
                // (copies on the stack: no allocation a row)
                let (mut c0, mut v0) = ([0u32; MAX_SLOTS], [0.0f64; MAX_SLOTS]);
                c0[..w].copy_from_slice(c);
                v0[..w].copy_from_slice(v);
                for (s, &t) in target.iter().enumerate() {
                    c[t] = c0[s];
                    v[t] = v0[s];
                }
            });
    }

    /// This rank's rows of the last numbering ([`Ranks::join`]).
    pub fn own_rows(&self) -> Range<usize> {
        let r = self.comm().rank();
        match self.starts.get(r..r + 2) {
            Some(s) => s[0]..s[1],
            None => 0..0,
        }
    }

    /// The rows of `x` on the [`Ranks::reach`] node layers either side of
    /// this rank's own, from the neighbours that solved them (each rank holds its own on
    /// entry): as far as [`scatter_rows`] reads. A swap with each neighbour, in pieces
    /// ([`crate::comm::pieces`]), where an all-gather would bring every row of the system to
    /// every rank each solve; the rows farther out keep what they held.
    pub fn gather<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        unknowns: &Unknowns,
        x: &mut [f64],
    ) {
        let (rank, size) = (self.comm().rank(), self.comm().size());
        let mut buffers = self.swapped.lock().unwrap_or_else(|e| e.into_inner());
        let (out, back) = &mut *buffers;
        for (upper, peer) in crate::comm::neighbour_rounds(rank, size) {
            let (send, recv) = self.beside(geo, unknowns, (upper, peer), self.reach);
            for (s, r) in crate::comm::pieces(send.len(), recv.len(), 1) {
                out.clear();
                out.extend_from_slice(&x[send.start + s.start..send.start + s.end]);
                back.clear();
                back.resize(r.len(), 0.0);
                self.comm().swap(peer, out, back);
                x[recv.start + r.start..recv.start + r.end].copy_from_slice(back);
            }
        }
    }

    /// The norm of `b` over every rank's own rows.
    pub fn norm(&self, b: &[f64]) -> f64 {
        let own: f64 = b[self.own_rows()].iter().map(|b| b * b).sum();
        self.comm().sum_scalar(own).sqrt()
    }

    /// The ghosts dropped: every particle is this rank's own until the next are lent.
    pub fn ghosts_gone(&mut self) {
        self.own = usize::MAX;
    }

    /// Sums of this rank's own particles onto the nodes (one `T` a node) added up with its
    /// neighbours' on the layers they share, and copied onto the window's nodes from their
    /// owners, as P2G's sums are ([`crate::slabs::Sliced`]): every node of the slab and the
    /// window then holds the sum over every rank's particles.
    pub fn add_sums<T: bytemuck::Pod>(&self, sums: &mut [T]) {
        self.comm().add_nodes(&mut [bytemuck::cast_slice_mut(sums)]);
    }

    /// Values of the cells (one a cell, numbered like its lower-corner node) that each rank
    /// finds exactly on its own layers (a cell's value from the particles in it), taken on
    /// every cell of the slab and the window from the rank that owns it: the others zeroed,
    /// then the sums onto the nodes, which copy the window's layers (one exchange for all of
    /// `arrays`).
    pub fn take_owners<const D: usize>(&self, geo: &GridGeometry<D>, arrays: &mut [&mut [f64]]) {
        let layers = self.layers();
        for values in arrays.iter_mut() {
            keep_layers(geo, self.axis, &layers, values);
        }
        self.comm().add_nodes(arrays);
    }

    /// `values` (one a node) on the nodes of this rank's slab under the cuts `new` and of the
    /// window around it (`new.window` layers, at least the stages' reach), each from the rank
    /// whose slab holds the node now, where it is exact; zero elsewhere. An all-to-all of
    /// each rank's own nodes to the ranks that will need them, where a sum of the whole array
    /// over the ranks would commit it whole on every rank (and MPI's buffers with it). Run
    /// only at a new cut: it visits every node, and its buffers are not kept.
    pub fn hand_over<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        new: &crate::slabs::Decomposition,
        values: &mut [f64],
    ) {
        let (rank, size) = (self.comm().rank(), self.comm().size());
        let (axis, cuts) = (self.axis, &self.partition.cuts);
        let now = |i: usize| {
            cuts.partition_point(|&c| c <= geo.layer(i, axis))
                .clamp(1, size)
                - 1
        };
        // the ranks that will need node i: those whose new slab reaches it with its window
        let reach = new.window.max(new.reach);
        let needs = |i: usize| {
            let l = geo.layer(i, new.axis);
            let first = new.cuts.partition_point(|&c| c + reach <= l).clamp(1, size) - 1;
            let last = new
                .cuts
                .partition_point(|&c| c < l + reach + 1)
                .clamp(1, size)
                - 1;
            first..last + 1
        };
        let own = |i: usize| now(i) == rank;
        // each rank's values in node order, rank after rank
        let mut counts = vec![0usize; size];
        for i in (0..values.len()).filter(|&i| own(i)) {
            for q in needs(i) {
                counts[q] += 8;
            }
        }
        let mut at = starts(&counts);
        let mut send = vec![0u8; counts.iter().sum()];
        for i in (0..values.len()).filter(|&i| own(i)) {
            for q in needs(i) {
                send[at[q]..at[q] + 8].copy_from_slice(&values[i].to_ne_bytes());
                at[q] += 8;
            }
        }
        let (mut recv, mut recv_counts) = (Vec::new(), Vec::new());
        self.comm()
            .exchange(&send, &counts, &mut recv, &mut recv_counts);
        let mut from = starts(&recv_counts);
        for (i, v) in values.iter_mut().enumerate() {
            let value = if needs(i).contains(&rank) {
                let s = now(i);
                let bytes = &recv[from[s]..from[s] + 8];
                from[s] += 8;
                f64::from_ne_bytes(bytes.try_into().expect("8 bytes"))
            } else {
                0.0
            };
            crate::pages::store(v, value);
        }
    }

    /// The sum over every rank of `value`.
    pub fn sum(&self, value: f64) -> f64 {
        self.comm().sum_scalar(value)
    }

    /// The least over every rank of `value`.
    pub fn min(&self, value: f64) -> f64 {
        let mut v = [value];
        self.comm().min(&mut v);
        v[0]
    }
}

/// Where each of the pieces of `counts` starts when they lie one after the other.
fn starts(counts: &[usize]) -> Vec<usize> {
    counts
        .iter()
        .scan(0, |at, &c| {
            *at += c;
            Some(*at - c)
        })
        .collect()
}

/// The mean density sum m / sum V of the particles: on one process of every particle, over
/// ranks of every rank's own (not its ghosts).
pub fn mean_density(mass: &[f64], volume: &[f64], ranks: Option<&Ranks>) -> f64 {
    match ranks {
        None => mass.iter().sum::<f64>() / volume.iter().sum::<f64>(),
        Some(r) => {
            let own = own_of(Some(r), mass.len());
            let m = r.sum(mass[..own].iter().sum());
            m / r.sum(volume[..own].iter().sum())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Vector;
    use crate::slabs::Decomposition;

    /// Cut anew, along the same axis or another, each rank holds on the nodes of its new slab
    /// and window the values that the ranks whose old slabs hold them held there (what one
    /// process holds), and zero elsewhere, whatever it held outside its old slab.
    #[test]
    fn a_new_cut_hands_each_rank_its_new_slabs_values() {
        let geo = GridGeometry::<2>::new(Vector::<2>::new(0.0, 0.0), 1.0, [26, 30]);
        let n = geo.node_count();
        let exact = |i: usize| 1.0 + i as f64;
        let old_cuts = vec![0, 12, 24, geo.nodes[1]];
        for new in [
            Decomposition {
                axis: 1,
                cuts: vec![0, 8, 20, geo.nodes[1]],
                window: 3,
                reach: 6,
            },
            Decomposition {
                axis: 0,
                cuts: vec![0, 9, 18, geo.nodes[0]],
                window: 8,
                reach: 4,
            },
        ] {
            let out = crate::comm::threads::run(3, |comm| {
                let r = Ranks::new(comm, 1, old_cuts.clone(), 6);
                let mine = r.layers();
                let mut values: Vec<f64> = (0..n)
                    .map(|i| match mine.contains(&geo.multi(i)[1]) {
                        true => exact(i),
                        false => -7.0,
                    })
                    .collect();
                r.hand_over(&geo, &new, &mut values);
                values
            });
            let reach = new.window.max(new.reach);
            for (rank, values) in out.iter().enumerate() {
                let lo = new.cuts[rank].saturating_sub(reach);
                let hi = new.cuts[rank + 1] + reach;
                for (i, &v) in values.iter().enumerate() {
                    let l = geo.layer(i, new.axis);
                    let want = if (lo..hi).contains(&l) { exact(i) } else { 0.0 };
                    assert_eq!(v, want, "axis {}, rank {rank}, node {i}", new.axis);
                }
            }
        }
    }
}
