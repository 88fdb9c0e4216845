//! The grid cut into slabs, one a rank, for a run spread over ranks (docs/distributed.md).
//!
//! Along one axis the grid's cell layers are cut into as many slabs as the run has ranks,
//! weighted by particles (a one-dimensional recursive bisection). Each rank holds the
//! particles whose cells lie in its slab, and its node arrays hold values only where its own
//! particles reach ([`crate::pages`] keeps the rest uncommitted: cut along the last axis, the
//! slowest of the node numbering, a rank's grid memory follows its slab; cut along another,
//! a slab touches a short run of every row, and so most pages). A particle in padded cell layer c reaches node layers c - 1 to c + 2
//! along each axis (every shape function's stencil, [`crate::shape`]), so the nodes that two
//! ranks' particles share are the three layers about each cut: after a sum of particles onto
//! the grid each pair of neighbours swaps those layers and adds ([`Sliced`]), and every node a
//! rank's particles reach then holds the whole sum. The grid's work is node by node, so each
//! rank then does it on its own nodes, and the nodes they share come out the same bits on
//! both (a + b and b + a round alike).
//!
//! The exchange is exact only while no node is reached by three ranks, so a slab is at least
//! [`MIN_WIDTH`] layers wide. After the move each particle goes to the rank of the slab it is
//! in now ([`Migration`]), and every [`REBALANCE_EVERY`] steps the ranks cut again where the
//! largest share has drifted more than a tenth above the mean and new cuts would lower it by
//! a twentieth of the mean ([`Decomposition::rebalanced`]).
//!
//! Written by hand: the exchange is the distributed run's heart and follows pmpm's node
//! numbering and its per-thread bands of sums; a general partitioner (ParMETIS, Zoltan) would
//! cut a graph pmpm does not hold.

use crate::comm::Comm;
use crate::grid::GridGeometry;
use crate::particles::Particles;
use crate::shape::{ShapeFunction, PAD};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// Node layers below a particle's cell layer that its stencil reaches.
const BELOW: usize = 1;
/// Node layers above a particle's cell layer that its stencil reaches.
const ABOVE: usize = 2;
/// The fewest cell layers a slab may have: fewer, and a node could be reached by three ranks.
pub const MIN_WIDTH: usize = BELOW + ABOVE;
/// Steps between the checks of the ranks' balance.
pub const REBALANCE_EVERY: u64 = 10;
/// The drift of the largest share above the mean that a check lets pass.
pub const DRIFT: f64 = 0.1;

/// Where the grid is cut: the axis, and the padded cell layers each rank holds (rank r holds
/// layers `cuts[r]..cuts[r + 1]`; the first and last slabs hold the ghost layers too).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Decomposition {
    /// The axis the slabs are cut along.
    pub axis: usize,
    /// The slabs' bounds, one more than the ranks.
    pub cuts: Vec<usize>,
    /// The window each rank sees past its slab, in cell layers: 0 where it works only the
    /// nodes its particles reach (the explicit scheme), else the projection's
    /// ([`window_of`]): the neighbours' particles and node sums that near its slab come to
    /// it ([`Migration::lend_ghosts`], [`Sliced`]), and every slab is at least this wide.
    #[serde(default)]
    pub window: usize,
    /// The layers of the window the stages after the bubble closing read
    /// ([`projection_reach`]); a checkpoint written before the reach followed the shape
    /// function reads back the widest ([`WIDEST_REACH`]).
    #[serde(default = "widest_reach")]
    pub reach: usize,
}

/// The cell layers past its slab that a rank of the projection sees ([`Decomposition::window`]):
/// the farther of the bubble closing's reach and [`projection_reach`], the stages' that read
/// the free surface (the level set, the Gauss points of the cells next to an unknown, the
/// assembly, the corrector). A gap of up to `bubble_cells` cells that holds one of the rank's
/// own cells spans at most as many layers, so it lies in the window; one that runs out of the
/// window is larger, and stays open, as it does on one process. The window's own cells take
/// their closing from their owners (`free_surface::Surface::spread_over`), so the window need
/// not also hold a gap past each of them.
/// Only the cells' raw volume fractions come onto the whole window; every other sum stops at
/// the stages' reach ([`Decomposition::sums_window`]).
pub fn window_of(bubble_cells: usize, shape: ShapeFunction) -> usize {
    bubble_cells.max(projection_reach(shape))
}

/// The cell layers past its slab whose particles a rank is lent as ghosts where the stages
/// read particles there only one by one: the packing's pushes between pairs of particles
/// closer than their rest spacing (at most a cell), with a layer to spare. Every sum of
/// particles onto the grid the stages take (the cells' fractions and densities, the
/// corrector's and the packing's node sums) is one of each rank's own particles, added up
/// over the ranks and copied onto the window's nodes ([`Sliced`]), so the window's cells
/// need no particles. Where the quadrature's points are the particles (`quadrature =
/// "particle"` without the level set) or a solid's surface stress is averaged from its
/// particles, the ghosts fill the whole window ([`Decomposition::window`]).
pub const GHOST_LAYERS: usize = 2;

/// The cell layers the projection's stages after the bubble closing read past a rank's slab
/// to assemble its own rows (the neighbours' rows the solver reads come from them:
/// `pressure::ranks::Ranks::swap_beside`), for `shape`: the columns' level set and kinds, the
/// cells whose Gauss points reach an own node, the velocities and level set those points
/// read, each as far as a stencil reaches, and a layer to spare. A stencil of w nodes a
/// direction needs w + 1 layers: with linear shapes (w = 2) 3 is the least at which a dam
/// break over three ranks agrees with one process to round-off and 2 is not, with the cubic
/// B-spline (w = 4) 5 is and 4 is not (`distributed::tests`); the spare layer makes w + 2.
/// Every layer of the window past this reach costs each rank a layer of every stage's node
/// work and memory, twice on a slab with two neighbours.
pub fn projection_reach(shape: ShapeFunction) -> usize {
    shape.width() + 2
}

/// The widest [`projection_reach`], the cubic B-spline's: the reach of a checkpoint's cut
/// written before the reach followed the shape function.
pub const WIDEST_REACH: usize = 6;

fn widest_reach() -> usize {
    WIDEST_REACH
}

impl Decomposition {
    /// How many ranks it is cut for.
    pub fn ranks(&self) -> usize {
        self.cuts.len() - 1
    }

    /// Whether these are cuts of `geo` for `ranks` ranks (a checkpoint's, read back).
    pub fn fits<const D: usize>(&self, geo: &GridGeometry<D>, ranks: usize) -> bool {
        self.axis < D
            && !geo.periodic[self.axis]
            && self.cuts.len() == ranks + 1
            && self.cuts.first() == Some(&0)
            && self.cuts.last() == Some(&geo.nodes[self.axis])
            && self
                .cuts
                .windows(2)
                .all(|w| w[1] >= w[0] + least_width(self.window))
    }

    /// The rank whose slab holds padded cell layer `layer`.
    #[inline]
    pub fn owner(&self, layer: usize) -> usize {
        let r = self.cuts.partition_point(|&c| c <= layer);
        r.clamp(1, self.ranks()) - 1
    }

    /// The rank whose slab holds the point `x`.
    #[inline]
    pub fn owner_of<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        x: &crate::grid::Vector<D>,
    ) -> usize {
        self.owner(layer_of(geo, self.axis, x))
    }

    /// The best cut of the particles counted in `counts` (per axis, per padded cell layer)
    /// for `ranks` ranks: along the last axis, not periodic, whose largest share is within
    /// half of [`DRIFT`] of the mean of the least; `None` where no axis has room for `ranks`
    /// slabs. With a `window` ([`Decomposition::window`]), slabs at least as wide.
    pub fn plan<const D: usize>(
        geo: &GridGeometry<D>,
        counts: &Counts,
        ranks: usize,
        (window, reach): (usize, usize),
    ) -> Option<Self> {
        let cuts: Vec<(f64, Self)> = (0..D)
            .filter(|&a| !geo.periodic[a])
            .filter_map(|axis| {
                let cuts = cut(counts.axis(axis), ranks, least_width(window))?;
                let d = Self {
                    axis,
                    cuts,
                    window,
                    reach,
                };
                Some((d.largest_share(counts), d))
            })
            .collect();
        let least = cuts.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
        // the last axis where it shares nearly as well: a slab across the slowest axis of the
        // node numbering is one run of memory, and only its pages are committed
        let mean = counts.total() / ranks as f64;
        cuts.into_iter()
            .rev()
            .find(|c| c.0 <= least + 0.5 * DRIFT * mean)
            .map(|(_, d)| d)
    }

    /// The new cuts where the largest share of `counts` has drifted more than [`DRIFT`]
    /// above the mean and new cuts lower it by half as much: along the same axis where they can,
    /// else the best cut ([`Decomposition::plan`]); `None` where these cuts stay.
    pub fn rebalanced<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        counts: &Counts,
    ) -> Option<Self> {
        let now = self.largest_share(counts);
        let mean = counts.total() / self.ranks() as f64;
        if now <= (1.0 + DRIFT) * mean {
            return None;
        }
        let better = |d: &Self| d.largest_share(counts) <= now - 0.5 * DRIFT * mean;
        // the same axis where it is cut well enough (fewer particles move), else the best
        let width = least_width(self.window);
        let along = cut(counts.axis(self.axis), self.ranks(), width).map(|cuts| Self {
            axis: self.axis,
            cuts,
            window: self.window,
            reach: self.reach,
        });
        let sight = (self.window, self.reach);
        along
            .filter(better)
            .or_else(|| Self::plan(geo, counts, self.ranks(), sight).filter(better))
    }

    /// The most particles one slab holds.
    fn largest_share(&self, counts: &Counts) -> f64 {
        let c = counts.axis(self.axis);
        self.cuts
            .windows(2)
            .map(|w| c[w[0]..w[1]].iter().sum::<f64>())
            .fold(0.0, f64::max)
    }

    /// The nodes (flat) that rank `rank` shares with its lower and its upper neighbour: the
    /// node layers c - 1 to c + 1 about each of its cuts c (empty at the grid's ends).
    pub fn shared_nodes<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        rank: usize,
    ) -> [Vec<u32>; 2] {
        let layers = |cut: usize| cut - BELOW..cut + ABOVE;
        let nodes_in = |range: std::ops::Range<usize>| -> Vec<u32> {
            (0..geo.node_count())
                .filter(|&f| range.contains(&geo.layer(f, self.axis)))
                .map(|f| f as u32)
                .collect()
        };
        let lower = (rank > 0).then(|| nodes_in(layers(self.cuts[rank])));
        let upper = (rank + 1 < self.ranks()).then(|| nodes_in(layers(self.cuts[rank + 1])));
        [lower.unwrap_or_default(), upper.unwrap_or_default()]
    }

    /// The layers of the window onto which every sum onto the nodes is copied
    /// ([`Sliced`]): the stages' reach ([`Decomposition::reach`]), where the window is wider for
    /// the bubble closing, which alone reads that far (the cells' raw volume fractions,
    /// [`Comm::add_nodes_wide`]).
    pub fn sums_window(&self) -> usize {
        self.window.min(self.reach)
    }

    /// The nodes (flat) of a window `w` layers deep that rank `rank` sends its lower and its
    /// upper neighbour (the `w` node layers of its own slab next to each cut) and those it
    /// receives from them (as many of theirs past the cut); all empty for `w` = 0.
    pub fn window_nodes<const D: usize>(
        &self,
        geo: &GridGeometry<D>,
        rank: usize,
        w: usize,
    ) -> [[Vec<u32>; 2]; 2] {
        let nodes_in = |range: std::ops::Range<usize>| -> Vec<u32> {
            (0..geo.node_count())
                .filter(|&f| range.contains(&geo.layer(f, self.axis)))
                .map(|f| f as u32)
                .collect()
        };
        let (lo, hi) = (self.cuts[rank], self.cuts[rank + 1]);
        let top = geo.nodes[self.axis];
        let lower = (rank > 0 && w > 0).then(|| {
            let send = nodes_in(lo..(lo + w).min(hi));
            let receive = nodes_in(lo.saturating_sub(w)..lo);
            [send, receive]
        });
        let upper = (rank + 1 < self.ranks() && w > 0).then(|| {
            let send = nodes_in(hi.saturating_sub(w).max(lo)..hi);
            let receive = nodes_in(hi..(hi + w).min(top));
            [send, receive]
        });
        [lower.unwrap_or_default(), upper.unwrap_or_default()]
    }
}

/// The fewest cell layers a slab may have with `window` ([`Decomposition::window`]): a
/// neighbour's window reaches no further than the next slab.
pub fn least_width(window: usize) -> usize {
    window.max(MIN_WIDTH)
}

/// The cuts of `counts` (particles per layer) into `ranks` slabs of at least `width` layers,
/// each cut at the layer boundary where the running count comes nearest its share of the
/// total; `None` where the layers are too few.
fn cut(counts: &[f64], ranks: usize, width: usize) -> Option<Vec<usize>> {
    let n = counts.len();
    if n < ranks * width {
        return None;
    }
    let total: f64 = counts.iter().sum();
    let mut cuts = vec![0; ranks + 1];
    cuts[ranks] = n;
    let (mut layer, mut running) = (0, 0.0);
    for r in 1..ranks {
        let target = total * r as f64 / ranks as f64;
        while layer < n && running < target {
            running += counts[layer];
            layer += 1;
        }
        // the nearer of the layers about the share's end
        if layer > 0 && target - (running - counts[layer - 1]) < running - target {
            layer -= 1;
            running -= counts[layer];
        }
        let (least, most) = (cuts[r - 1] + width, n - (ranks - r) * width);
        cuts[r] = layer.clamp(least, most);
    }
    Some(cuts)
}

/// The padded cell layer of `x` along `axis`, as [`GridGeometry::cell_of`] clamps it.
#[inline]
fn layer_of<const D: usize>(
    geo: &GridGeometry<D>,
    axis: usize,
    x: &crate::grid::Vector<D>,
) -> usize {
    let c = ((x[axis] - geo.origin[axis]) / geo.h).floor() + PAD as f64;
    (c.max(0.0) as usize).min(geo.nodes[axis] - 2)
}

/// Particles per padded cell layer along every axis, one after the other.
#[derive(Debug, Clone, Default)]
pub struct Counts {
    values: Vec<f64>,
    starts: Vec<usize>,
}

impl Counts {
    /// The counts of the particles at `x`, summed over `comm`'s ranks.
    pub fn of<const D: usize>(
        &mut self,
        comm: &dyn Comm,
        geo: &GridGeometry<D>,
        x: &[crate::grid::Vector<D>],
    ) {
        self.reset(geo);
        for x in x {
            self.add(geo, x);
        }
        comm.sum(&mut self.values);
    }

    /// No particle yet, on the grid `geo`.
    pub fn reset<const D: usize>(&mut self, geo: &GridGeometry<D>) {
        self.starts.clear();
        let mut at = 0;
        for d in 0..D {
            self.starts.push(at);
            at += geo.nodes[d];
        }
        self.starts.push(at);
        self.values.clear();
        self.values.resize(at, 0.0);
    }

    /// Counts one more particle, at `x` (on this rank: [`Counts::of`] sums over ranks).
    #[inline]
    pub fn add<const D: usize>(&mut self, geo: &GridGeometry<D>, x: &crate::grid::Vector<D>) {
        for d in 0..D {
            self.values[self.starts[d] + layer_of(geo, d, x)] += 1.0;
        }
    }

    fn axis(&self, d: usize) -> &[f64] {
        &self.values[self.starts[d]..self.starts[d + 1]]
    }

    /// The particles counted.
    pub fn total(&self) -> f64 {
        self.axis(0).iter().sum()
    }
}

/// The ranks of a run whose grid is cut into slabs: every collective is `world`'s, and the
/// sums onto the nodes ([`Comm::add_nodes`]) swap only the layers each pair of neighbours
/// shares.
pub struct Sliced {
    world: Arc<dyn Comm>,
    /// The nodes shared with the lower and the upper neighbour.
    shared: [Vec<u32>; 2],
    /// With a window ([`Decomposition::sums_window`]), the nodes sent to and received from
    /// the lower and the upper neighbour after the sums, so that every node of the window
    /// holds its owner's sum.
    window: [[Vec<u32>; 2]; 2],
    /// Where the whole window ([`Decomposition::window`]) is deeper, its nodes likewise
    /// ([`Comm::add_nodes_wide`]); else empty.
    wide: [[Vec<u32>; 2]; 2],
    nodes: usize,
    /// The swap's buffers (out, in), kept from step to step.
    buffers: Mutex<(Vec<f64>, Vec<f64>)>,
}

impl Sliced {
    /// `world`'s ranks with the grid `geo` cut as `d` says.
    pub fn new<const D: usize>(
        world: Arc<dyn Comm>,
        geo: &GridGeometry<D>,
        d: &Decomposition,
    ) -> Self {
        Self {
            shared: d.shared_nodes(geo, world.rank()),
            window: d.window_nodes(geo, world.rank(), d.sums_window()),
            wide: if d.window > d.sums_window() {
                d.window_nodes(geo, world.rank(), d.window)
            } else {
                Default::default()
            },
            world,
            nodes: geo.node_count(),
            buffers: Mutex::new((Vec::new(), Vec::new())),
        }
    }
}

impl Comm for Sliced {
    fn rank(&self) -> usize {
        self.world.rank()
    }
    fn size(&self) -> usize {
        self.world.size()
    }
    fn sum(&self, values: &mut [f64]) {
        self.world.sum(values)
    }
    fn sum_all(&self, arrays: &mut [&mut [f64]]) {
        self.world.sum_all(arrays)
    }
    fn max(&self, values: &mut [f64]) {
        self.world.max(values)
    }
    fn min(&self, values: &mut [f64]) {
        self.world.min(values)
    }
    fn gather(&self, bytes: &[u8]) -> Vec<Vec<u8>> {
        self.world.gather(bytes)
    }
    fn broadcast(&self, bytes: &mut Vec<u8>) {
        self.world.broadcast(bytes)
    }
    fn all_gather(&self, bytes: &[u8], all: &mut Vec<u8>) {
        self.world.all_gather(bytes, all)
    }
    fn swap(&self, peer: usize, send: &[f64], recv: &mut [f64]) {
        self.world.swap(peer, send, recv)
    }
    fn send_bytes(&self, to: usize, bytes: &[u8]) {
        self.world.send_bytes(to, bytes)
    }
    fn receive_bytes(&self, from: usize) -> Vec<u8> {
        self.world.receive_bytes(from)
    }
    fn exchange(
        &self,
        send: &[u8],
        counts: &[usize],
        recv: &mut Vec<u8>,
        recv_counts: &mut Vec<usize>,
    ) {
        self.world.exchange(send, counts, recv, recv_counts)
    }

    /// Two rounds of swaps, so that no rank waits on a chain: first the pairs (0, 1), (2, 3),
    /// ..., then (1, 2), (3, 4), ...; each rank adds its neighbour's sums to its own on the
    /// layers they share. With a window, two more rounds copy each neighbour's sums onto the
    /// window's nodes (those of the shared layers come back the same bits).
    fn add_nodes(&self, arrays: &mut [&mut [f64]]) {
        self.add_over(arrays, &self.window);
    }

    fn add_nodes_wide(&self, arrays: &mut [&mut [f64]]) {
        let wide = self
            .wide
            .iter()
            .any(|w| !w[0].is_empty() || !w[1].is_empty());
        self.add_over(arrays, if wide { &self.wide } else { &self.window });
    }
}

impl Sliced {
    /// [`Comm::add_nodes`], the sums copied onto the nodes of `window`. Each swap goes in
    /// pieces ([`crate::comm::pieces`]), a piece all the arrays' values at a run of the nodes.
    fn add_over(&self, arrays: &mut [&mut [f64]], window: &[[Vec<u32>; 2]; 2]) {
        let mut guard = self.buffers.lock().unwrap_or_else(|e| e.into_inner());
        let (out, into) = &mut *guard;
        let width: usize = arrays.iter().map(|a| a.len() / self.nodes).sum();
        for (upper, peer) in self.rounds() {
            let shared = &self.shared[usize::from(upper)];
            for (piece, _) in crate::comm::pieces(shared.len(), shared.len(), width) {
                let nodes = &shared[piece];
                self.pack(arrays, nodes, out);
                into.resize(out.len(), 0.0);
                self.world.swap(peer, out, into);
                self.unpack(arrays, nodes, into, |v, theirs| {
                    if theirs != 0.0 {
                        *v += theirs;
                    }
                });
            }
        }
        for (upper, peer) in self.rounds() {
            let [send, receive] = &window[usize::from(upper)];
            for (sent, received) in crate::comm::pieces(send.len(), receive.len(), width) {
                self.pack(arrays, &send[sent], out);
                into.resize(width * received.len(), 0.0);
                self.world.swap(peer, out, into);
                // (written only where it changes: an empty node's page stays uncommitted)
                self.unpack(arrays, &receive[received], into, crate::pages::store);
            }
        }
    }

    /// `into`, packed as [`Sliced::pack`] packs, put into the arrays' values at `nodes` with
    /// `put(value, theirs)`.
    fn unpack(
        &self,
        arrays: &mut [&mut [f64]],
        nodes: &[u32],
        into: &[f64],
        put: impl Fn(&mut f64, f64),
    ) {
        let mut theirs = into.iter();
        for a in arrays.iter_mut() {
            let k = a.len() / self.nodes;
            for &i in nodes {
                for (v, &t) in a[i as usize * k..(i as usize + 1) * k]
                    .iter_mut()
                    .zip(&mut theirs)
                {
                    put(v, t);
                }
            }
        }
    }

    /// The arrays' values at `nodes` into `out`, array by array.
    fn pack(&self, arrays: &[&mut [f64]], nodes: &[u32], out: &mut Vec<f64>) {
        out.clear();
        for a in arrays {
            let k = a.len() / self.nodes;
            for &i in nodes {
                out.extend_from_slice(&a[i as usize * k..(i as usize + 1) * k]);
            }
        }
    }

    /// The two rounds of a swap with the neighbours ([`crate::comm::neighbour_rounds`]).
    fn rounds(&self) -> impl Iterator<Item = (bool, usize)> {
        crate::comm::neighbour_rounds(self.rank(), self.size())
    }
}

/// The particles that left a rank's slab, sent to the ranks that hold them now; its buffers
/// are kept from step to step.
#[derive(Debug, Default)]
pub struct Migration {
    staying: Vec<u32>,
    leaving: Vec<Vec<u32>>,
    send: Vec<u8>,
    counts: Vec<usize>,
    recv: Vec<u8>,
    recv_counts: Vec<usize>,
    /// Where each sender's particles start among those that arrive.
    starts: Vec<usize>,
}

impl Migration {
    /// Sends every particle of `ps` outside this rank's slab of `d` to the rank whose slab
    /// holds it, and takes in those the others send: the particles that stay keep their order,
    /// and those that arrive follow in the senders' rank order (a fixed order for a given rank
    /// count). Whether any particle moved, on any rank; an error (on every rank alike) where
    /// one exchange cannot carry them.
    pub fn run<const D: usize>(
        &mut self,
        comm: &dyn Comm,
        geo: &GridGeometry<D>,
        d: &Decomposition,
        ps: &mut Particles<D>,
    ) -> Result<bool, String> {
        let (rank, size) = (comm.rank(), comm.size());
        self.staying.clear();
        self.clear_leaving(size);
        for (p, x) in ps.x.iter().enumerate() {
            match d.owner_of(geo, x) {
                r if r == rank => self.staying.push(p as u32),
                r => self.leaving[r].push(p as u32),
            }
        }
        let moving = ps.len() - self.staying.len();
        if !comm.any(moving > 0) {
            return Ok(false);
        }
        // those that stay kept, each sender's particles appended in rank order
        self.swap(comm, ps, moving > 0, "crossed between ranks")?;
        Ok(true)
    }

    /// Copies to each neighbour the particles of this rank's slab in the `layers` cell
    /// layers next to their cut (at most its window: [`Decomposition::window`]), and appends the
    /// neighbours' copies to `ps`, in the senders' rank order: ghosts, which the projection's
    /// stages read as the particles around the slab and which are dropped after them
    /// (`ps.truncate` to the count returned, this rank's own particles, which stay first).
    pub fn lend_ghosts<const D: usize>(
        &mut self,
        comm: &dyn Comm,
        geo: &GridGeometry<D>,
        (d, layers): (&Decomposition, usize),
        ps: &mut Particles<D>,
    ) -> Result<usize, String> {
        let (rank, size) = (comm.rank(), comm.size());
        let layers = layers.min(d.window);
        self.clear_leaving(size);
        let (lo, hi) = (d.cuts[rank], d.cuts[rank + 1]);
        for (p, x) in ps.x.iter().enumerate() {
            let layer = layer_of(geo, d.axis, x);
            if rank > 0 && layer < lo + layers {
                self.leaving[rank - 1].push(p as u32);
            }
            if rank + 1 < size && layer + layers >= hi {
                self.leaving[rank + 1].push(p as u32);
            }
        }
        let own = ps.len();
        self.swap(comm, ps, false, "lie near the ranks' cuts")?;
        Ok(own)
    }

    /// An empty list of the particles to send for each of `size` ranks.
    fn clear_leaving(&mut self, size: usize) {
        self.leaving.resize(size, Vec::new());
        for l in &mut self.leaving {
            l.clear();
        }
    }

    /// Sends the particles of `leaving` to each rank and appends those the others send, in
    /// the senders' rank order, keeping first only the places `staying` where `keep` holds:
    /// all to all, one field at a time ([`Particles::for_each_stored_field`]), each in pieces
    /// of at most [`crate::comm::PIECE`] values' bytes a rank, each piece's particles put in
    /// their place among those appended. An error, on every rank alike and before anything
    /// moves, where a piece from every rank would be more than one exchange carries, naming
    /// the particles sent as those that `what`.
    fn swap<const D: usize>(
        &mut self,
        comm: &dyn Comm,
        ps: &mut Particles<D>,
        keep: bool,
        what: &str,
    ) -> Result<(), String> {
        let mut widest = 1;
        ps.for_each_stored_field(|f| widest = widest.max(f.value_size()));
        let per = (crate::comm::PIECE * 8 / widest).max(1);
        // MPI's counts are 32-bit: the pieces a rank receives at once, one from each other
        // rank, stay under 2 GiB
        if (per * widest * (comm.size() - 1)) as f64 > i32::MAX as f64 {
            return Err(format!(
                "the particles that {what} would arrive from {} ranks at once, more than one \
                 exchange carries (2 GiB)",
                comm.size() - 1
            ));
        }
        // how many particles each rank sends this one, and where they go among the arrivals
        self.send.clear();
        self.counts.clear();
        for l in &self.leaving {
            self.send.extend_from_slice(&(l.len() as u64).to_le_bytes());
            self.counts.push(8);
        }
        comm.exchange(
            &self.send,
            &self.counts,
            &mut self.recv,
            &mut self.recv_counts,
        );
        self.starts.clear();
        let mut arriving = 0;
        for n in self.recv.chunks_exact(8) {
            self.starts.push(arriving);
            arriving += u64::from_le_bytes(n.try_into().unwrap_or_default()) as usize;
        }
        let most = self.leaving.iter().map(|l| l.len().div_ceil(per)).max();
        let rounds = comm.max_scalar(most.unwrap_or(0) as f64) as usize;
        // the arrivals are put after the particles there were, and kept with those that stay
        let before = ps.len();
        if keep {
            self.staying
                .extend(before as u32..(before + arriving) as u32);
        }
        let Self {
            staying,
            leaving,
            send,
            counts,
            recv,
            recv_counts,
            starts,
        } = self;
        ps.for_each_stored_field(|field| {
            field.grow(arriving);
            for round in 0..rounds {
                let piece = |n: usize| (round * per).min(n)..((round + 1) * per).min(n);
                send.clear();
                counts.clear();
                for l in leaving.iter() {
                    let before = send.len();
                    field.pack(&l[piece(l.len())], send);
                    counts.push(send.len() - before);
                }
                comm.exchange(send, counts, recv, recv_counts);
                let mut at = 0;
                for (&start, &n) in starts.iter().zip(recv_counts.iter()) {
                    // (a sender whose particles are all sent sends nothing more)
                    if n > 0 {
                        field.unpack_at(before + start + round * per, &recv[at..at + n]);
                    }
                    at += n;
                }
            }
            if keep {
                field.keep(staying);
            }
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Vector;

    #[test]
    fn cuts_share_the_particles_and_keep_the_least_width() {
        // particles in layers 10..30 of 50
        let mut counts = vec![0.0; 50];
        for c in &mut counts[10..30] {
            *c = 5.0;
        }
        let cuts = cut(&counts, 4, MIN_WIDTH).unwrap();
        assert_eq!(cuts, vec![0, 15, 20, 25, 50]);
        // all the particles in two layers: each slab still MIN_WIDTH wide
        let mut narrow = vec![0.0; 20];
        narrow[3] = 10.0;
        narrow[4] = 10.0;
        let cuts = cut(&narrow, 3, MIN_WIDTH).unwrap();
        assert!(
            cuts.windows(2).all(|w| w[1] - w[0] >= MIN_WIDTH),
            "{cuts:?}"
        );
        assert!(cut(&narrow, 7, MIN_WIDTH).is_none());
    }

    #[test]
    fn the_owner_of_a_layer_is_the_slab_that_holds_it() {
        let d = Decomposition {
            axis: 0,
            cuts: vec![0, 5, 9, 14],
            window: 0,
            reach: 0,
        };
        let owners: Vec<usize> = (0..14).map(|l| d.owner(l)).collect();
        assert_eq!(owners, [0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 2]);
    }

    #[test]
    fn the_plan_cuts_where_it_shares_best_and_rebalances_only_past_the_drift() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 0.1, [40, 10]);
        let x: Vec<Vector<2>> = (0..400)
            .map(|k| Vector::<2>::new(0.05 + 0.1 * (k % 40) as f64, 0.05 + 0.1 * (k / 40) as f64))
            .collect();
        let mut counts = Counts::default();
        counts.of(&*crate::comm::serial(), &geo, &x);
        let d = Decomposition::plan(&geo, &counts, 4, (0, 0)).unwrap();
        assert_eq!(d.axis, 0);
        assert_eq!(d.largest_share(&counts), 100.0);
        assert!(d.rebalanced(&geo, &counts).is_none());
        // everything moved into the first quarter: cut again
        let x: Vec<Vector<2>> = x
            .iter()
            .map(|x| Vector::<2>::new(x[0] / 4.0, x[1]))
            .collect();
        counts.of(&*crate::comm::serial(), &geo, &x);
        let again = d.rebalanced(&geo, &counts).unwrap();
        assert!(again.largest_share(&counts) < 0.9 * d.largest_share(&counts));
        // shared as well along both axes: the last one, the slowest of the node numbering
        let square = GridGeometry::<2>::new(Vector::<2>::zeros(), 0.1, [20, 20]);
        let x: Vec<Vector<2>> = (0..400)
            .map(|k| Vector::<2>::new(0.05 + 0.1 * (k % 20) as f64, 0.05 + 0.1 * (k / 20) as f64))
            .collect();
        counts.of(&*crate::comm::serial(), &square, &x);
        assert_eq!(
            Decomposition::plan(&square, &counts, 4, (0, 0))
                .unwrap()
                .axis,
            1
        );
    }

    #[test]
    fn every_stencil_node_lies_within_the_reach_of_its_cell() {
        use crate::shape::{ShapeFunction, Stencil};
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [8, 8]);
        for shape in [
            ShapeFunction::Linear,
            ShapeFunction::Gimp,
            ShapeFunction::Bspline2,
            ShapeFunction::Bspline3,
        ] {
            for k in 0..200 {
                let x = Vector::<2>::new(0.01 + k as f64 * 0.0399, 3.3);
                let c = layer_of(&geo, 0, &x);
                let st = Stencil::<2>::new(shape, &geo.to_cells(&x), geo.h, 0.5);
                st.for_each(|nw| {
                    assert!(
                        nw.node[0] + BELOW >= c && nw.node[0] <= c + ABOVE,
                        "{shape:?} at {x:?}"
                    );
                });
            }
        }
    }

    /// Particles of ids `ids` at `x`, every field set from the id.
    fn particles(ids: &[u32], x: &[[f64; 2]]) -> Particles<2> {
        let f = |i: &u32| f64::from(*i);
        let mut ps = Particles::<2> {
            id: ids.to_vec(),
            x: x.iter().map(|x| Vector::<2>::new(x[0], x[1])).collect(),
            v: ids.iter().map(|i| Vector::<2>::new(f(i), -f(i))).collect(),
            mass: ids.iter().map(f).collect(),
            volume0: ids.iter().map(f).collect(),
            jacobian: ids.iter().map(f).collect(),
            pressure: ids.iter().map(f).collect(),
            velocity_gradient: ids
                .iter()
                .map(|i| crate::particles::Matrix::<2>::repeat(f(i)))
                .collect(),
            affine: ids
                .iter()
                .map(|i| crate::particles::Matrix::<2>::repeat(f(i)))
                .collect(),
            material: ids.iter().map(|&i| i as u16).collect(),
            half_width: ids.iter().map(f).collect(),
            ..Particles::default()
        };
        ps.set_stored(crate::particles::Stored {
            deformation: false,
            stress: false,
        });
        ps
    }

    /// Three slabs of x: [0, 5), [5, 9), [9, 14) (padded cell layers, h = 1 from -2).
    fn three_slabs() -> (GridGeometry<2>, Decomposition) {
        let geo = GridGeometry::<2>::new(Vector::<2>::new(-2.0, -2.0), 1.0, [9, 4]);
        let d = Decomposition {
            axis: 0,
            cuts: vec![0, 5, 9, 14],
            window: 0,
            reach: 0,
        };
        (geo, d)
    }

    #[test]
    fn a_rank_takes_in_particles_from_both_neighbours_in_one_step() {
        let (geo, d) = three_slabs();
        // rank 0 and rank 2 each hold a particle that moved into rank 1's slab (x = 4.5)
        let held = [
            (vec![0, 1], vec![[0.5, 0.5], [4.5, 0.5]]),
            (vec![2], vec![[4.5, 1.5]]),
            (vec![3, 4], vec![[4.5, 1.0], [8.5, 1.5]]),
        ];
        let out = crate::comm::threads::run(3, |comm| {
            let (ids, x) = &held[comm.rank()];
            let mut ps = particles(ids, x);
            let mut migration = Migration::default();
            assert!(migration.run(&*comm, &geo, &d, &mut ps).unwrap());
            format!("{:?}", ps)
        });
        let want = |ids: &[u32], x: &[[f64; 2]]| format!("{:?}", particles(ids, x));
        assert_eq!(out[0], want(&[0], &[[0.5, 0.5]]));
        // its own first, then rank 0's, then rank 2's, every field whole
        assert_eq!(
            out[1],
            want(&[2, 1, 3], &[[4.5, 1.5], [4.5, 0.5], [4.5, 1.0]])
        );
        assert_eq!(out[2], want(&[4], &[[8.5, 1.5]]));
    }

    /// A migration of more particles than a piece of the exchange carries (2 MiB of the widest
    /// field, 65,536 particles of 2D matrices) goes in several rounds and keeps each sender's
    /// order: ranks 0 and 2 send rank 1 150,000 and 70,000 particles (3 and 2 pieces), and
    /// rank 1 sends rank 0 one.
    #[test]
    fn a_migration_longer_than_a_piece_keeps_the_senders_order() {
        let (geo, d) = three_slabs();
        let moving = |ids: std::ops::Range<u32>| ids.map(|i| (i, [4.5, 0.5]));
        let held = |rank: usize| -> Vec<(u32, [f64; 2])> {
            match rank {
                0 => std::iter::once((1_000_000, [0.5, 0.5]))
                    .chain(moving(0..150_000))
                    .collect(),
                1 => vec![(2_000_000, [4.5, 1.5]), (2_000_001, [0.5, 1.0])],
                _ => moving(3_000_000..3_070_000)
                    .chain(std::iter::once((4_000_000, [8.5, 1.5])))
                    .collect(),
            }
        };
        let out = crate::comm::threads::run(3, |comm| {
            let (ids, x): (Vec<u32>, Vec<[f64; 2]>) = held(comm.rank()).into_iter().unzip();
            let mut ps = particles(&ids, &x);
            let mut migration = Migration::default();
            assert!(migration.run(&*comm, &geo, &d, &mut ps).unwrap());
            ps
        });
        let ids = |ps: &Particles<2>| ps.id.clone();
        assert_eq!(ids(&out[0]), vec![1_000_000, 2_000_001]);
        let want: Vec<u32> = std::iter::once(2_000_000)
            .chain(0..150_000)
            .chain(3_000_000..3_070_000)
            .collect();
        assert_eq!(ids(&out[1]), want);
        assert_eq!(ids(&out[2]), vec![4_000_000]);
        // every field came with its particle
        for ps in &out {
            let (ids, x): (Vec<u32>, Vec<[f64; 2]>) =
                ps.x.iter()
                    .zip(&ps.id)
                    .map(|(x, &i)| (i, [x[0], x[1]]))
                    .unzip();
            assert_eq!(format!("{:?}", particles(&ids, &x)), format!("{ps:?}"));
        }
    }
}
