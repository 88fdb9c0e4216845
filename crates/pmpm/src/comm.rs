//! The processes a run is spread over, and the collective operations its step needs.
//!
//! A run on one process has [`Serial`], whose operations do nothing. A run started under
//! `mpirun` (the `mpi` feature) has `Mpi`: each rank holds a share of the particles, so every
//! sum of particles onto the grid ends with [`Comm::add_nodes`] before it is read (over the
//! whole grid, or, with the grid cut into slabs, over the layers neighbours share), and every
//! decision taken from the particles (the time step, a blow-up) with a reduction, so that the
//! ranks take the same steps and stop together (docs/distributed.md).
//!
//! The reductions give every rank the same bits (reduced onto rank 0, then broadcast): the
//! grid's work, done by every rank on its own nodes, then stays the same where ranks share
//! nodes without being exchanged again.

use std::sync::Arc;

/// The collective operations over the ranks of a run; every rank calls each one in the same
/// order (MPI's rule for collectives).
pub trait Comm: Send + Sync {
    /// This process's rank, from 0.
    fn rank(&self) -> usize;
    /// How many ranks the run has.
    fn size(&self) -> usize;
    /// Element-wise sums over the ranks, the same bits on every rank for a given rank count.
    fn sum(&self, values: &mut [f64]);
    /// [`Comm::sum`] of several arrays in one exchange.
    fn sum_all(&self, arrays: &mut [&mut [f64]]) {
        for a in arrays {
            self.sum(a);
        }
    }
    /// Element-wise maxima over the ranks.
    fn max(&self, values: &mut [f64]);
    /// Element-wise minima over the ranks.
    fn min(&self, values: &mut [f64]);
    /// Every rank's bytes on rank 0, in rank order; an empty list on the other ranks.
    fn gather(&self, bytes: &[u8]) -> Vec<Vec<u8>>;
    /// Rank 0's bytes on every rank (what the others passed in is replaced).
    fn broadcast(&self, bytes: &mut Vec<u8>);
    /// Every rank's bytes on every rank, in rank order, into `all` (whose allocation is kept
    /// from call to call): an all-gather of pieces of any length.
    fn all_gather(&self, bytes: &[u8], all: &mut Vec<u8>) {
        let pieces = self.gather(bytes);
        all.clear();
        for piece in &pieces {
            all.extend_from_slice(piece);
        }
        self.broadcast(all);
    }
    /// Sums of particles onto the grid's node arrays (each the grid's whole length, a node's
    /// components together) over the ranks: after it every node this rank's particles reach
    /// holds every rank's sum. Where each rank holds the whole grid that is [`Comm::sum_all`]
    /// of the whole arrays; a grid cut into slabs (the `slabs` module) exchanges only the
    /// layers of nodes that two ranks' particles share.
    fn add_nodes(&self, arrays: &mut [&mut [f64]]) {
        self.sum_all(arrays);
    }
    /// [`Comm::add_nodes`] for the one sum that is read deeper past a slab than the others
    /// (the cells' raw volume fractions, which the bubble closing reads `bubble_cells` layers
    /// deep): copied onto the slabs' whole window, where the others stop short of it.
    fn add_nodes_wide(&self, arrays: &mut [&mut [f64]]) {
        self.add_nodes(arrays);
    }
    /// Sends `send` to rank `peer` and receives as many values from it into `recv` (both
    /// ranks call it with each other as `peer`).
    fn swap(&self, peer: usize, send: &[f64], recv: &mut [f64]);
    /// Sends `bytes` to rank `to`, which takes them with [`Comm::receive_bytes`].
    fn send_bytes(&self, to: usize, bytes: &[u8]);
    /// The bytes rank `from` sends this one with [`Comm::send_bytes`].
    fn receive_bytes(&self, from: usize) -> Vec<u8>;
    /// Sends `send[at..at + counts[r]]` to each rank r (its pieces in rank order) and
    /// receives what each rank sends this one into `recv`, in rank order, with their lengths
    /// in `recv_counts`: an all-to-all of bytes.
    fn exchange(
        &self,
        send: &[u8],
        counts: &[usize],
        recv: &mut Vec<u8>,
        recv_counts: &mut Vec<usize>,
    );
}

impl<'a> dyn Comm + 'a {
    /// Whether this is rank 0, the rank that writes the run's shared files (the others write
    /// only their pieces of frames and checkpoints).
    pub fn is_root(&self) -> bool {
        self.rank() == 0
    }

    /// Whether the run has more than one rank.
    pub fn is_distributed(&self) -> bool {
        self.size() > 1
    }

    /// Whether `flag` holds on any rank.
    pub fn any(&self, flag: bool) -> bool {
        let mut v = [f64::from(u8::from(flag))];
        self.max(&mut v);
        v[0] > 0.0
    }

    /// The sum of `x` over the ranks.
    pub fn sum_scalar(&self, x: f64) -> f64 {
        let mut v = [x];
        self.sum(&mut v);
        v[0]
    }

    /// The largest `x` over the ranks.
    pub fn max_scalar(&self, x: f64) -> f64 {
        let mut v = [x];
        self.max(&mut v);
        v[0]
    }

    /// The first rank's `Some` (a fault one rank found in its particles, say) on every rank;
    /// `None` where no rank has one.
    pub fn agree(&self, found: Option<String>) -> Option<String> {
        if !self.is_distributed() {
            return found;
        }
        if !self.any(found.is_some()) {
            return None;
        }
        let pieces = self.gather(found.unwrap_or_default().as_bytes());
        let mut first = pieces
            .into_iter()
            .find(|p| !p.is_empty())
            .unwrap_or_default();
        self.broadcast(&mut first);
        Some(String::from_utf8_lossy(&first).into_owned())
    }

    /// Element-wise sums of D-vectors over the ranks.
    pub fn sum_vectors<const D: usize>(&self, values: &mut [crate::grid::Vector<D>]) {
        self.sum(bytemuck::cast_slice_mut(values));
    }
}

/// One process: every collective is the identity.
#[derive(Debug, Clone, Copy, Default)]
pub struct Serial;

impl Comm for Serial {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn sum(&self, _: &mut [f64]) {}
    fn max(&self, _: &mut [f64]) {}
    fn min(&self, _: &mut [f64]) {}
    fn gather(&self, bytes: &[u8]) -> Vec<Vec<u8>> {
        vec![bytes.to_vec()]
    }
    fn broadcast(&self, _: &mut Vec<u8>) {}
    fn all_gather(&self, bytes: &[u8], all: &mut Vec<u8>) {
        all.clear();
        all.extend_from_slice(bytes);
    }
    fn swap(&self, _: usize, send: &[f64], recv: &mut [f64]) {
        recv.copy_from_slice(send);
    }
    // (one process has no other rank to send to or receive from)
    fn send_bytes(&self, _: usize, _: &[u8]) {}
    fn receive_bytes(&self, _: usize) -> Vec<u8> {
        Vec::new()
    }
    fn exchange(&self, send: &[u8], _: &[usize], recv: &mut Vec<u8>, recv_counts: &mut Vec<usize>) {
        recv.clear();
        recv.extend_from_slice(send);
        recv_counts.clear();
        recv_counts.push(send.len());
    }
}

/// The two rounds in which rank `rank` of `size` swaps with its neighbours along a line of
/// slabs, as (whether with the upper one, its rank): the upper neighbour in the even ranks'
/// first round and the odd ranks' second, so that the pairs (0, 1), (2, 3), ... swap at once,
/// then (1, 2), (3, 4), ..., and no rank waits on a chain.
pub fn neighbour_rounds(rank: usize, size: usize) -> impl Iterator<Item = (bool, usize)> {
    (0..2).filter_map(move |round| {
        let upper = (rank % 2 == 0) == (round == 0);
        let peer = if upper {
            rank.checked_add(1).filter(|&p| p < size)
        } else {
            rank.checked_sub(1)
        };
        peer.map(|p| (upper, p))
    })
}

/// The most values one [`Comm::swap`] of a long exchange carries: a longer one goes in pieces
/// ([`pieces`]), so that its buffers stay at 2 MiB each way however large the face between
/// two slabs grows.
pub const PIECE: usize = 1 << 18;

/// The pieces of a swap of `send` items out and `recv` items in, `width` values an item, as
/// the ranges of the items each piece sends and receives: at most [`PIECE`] values each way,
/// and as many pieces on both ranks (each one's `send` is the other's `recv`).
pub fn pieces(
    send: usize,
    recv: usize,
    width: usize,
) -> impl Iterator<Item = (std::ops::Range<usize>, std::ops::Range<usize>)> {
    let per = (PIECE / width.max(1)).max(1);
    let count = send.div_ceil(per).max(recv.div_ceil(per));
    (0..count).map(move |k| {
        let part = |n: usize| (k * per).min(n)..((k + 1) * per).min(n);
        (part(send), part(recv))
    })
}

/// The ranks a run is spread over, as the run's options carry them (shared, and one process by
/// default).
#[derive(Clone)]
pub struct Ranks(pub Arc<dyn Comm>);

impl Default for Ranks {
    /// One process.
    fn default() -> Self {
        Self(serial())
    }
}

impl std::ops::Deref for Ranks {
    type Target = dyn Comm;
    fn deref(&self) -> &Self::Target {
        &*self.0
    }
}

impl std::fmt::Debug for Ranks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "rank {} of {}", self.0.rank(), self.0.size())
    }
}

/// The one-process communicator, shared.
pub fn serial() -> Arc<dyn Comm> {
    Arc::new(Serial)
}

/// The range of `n` items that rank `rank` of `size` holds: an equal contiguous share, the
/// first `n mod size` ranks one more.
pub fn share(n: usize, rank: usize, size: usize) -> std::ops::Range<usize> {
    let (base, extra) = (n / size, n % size);
    let start = rank * base + rank.min(extra);
    start..start + base + usize::from(rank < extra)
}

#[cfg(feature = "mpi")]
pub use self::mpi_comm::Mpi;

#[cfg(feature = "mpi")]
mod mpi_comm {
    use super::Comm;
    use mpi::collective::SystemOperation;
    use mpi::topology::SimpleCommunicator;
    use mpi::traits::*;
    use std::sync::{Mutex, MutexGuard};

    /// The ranks of `MPI_COMM_WORLD` (MPICH through the `mpi` crate). MPI is started with
    /// `MPI_THREAD_SERIALIZED`: only the thread that drives the step calls it (a worker of the
    /// thread pool the run is installed on), never two threads at once, which is what makes
    /// the `Send` and `Sync` below sound.
    pub struct Mpi {
        world: SimpleCommunicator,
        /// The reductions' buffers (the values packed, the sums), kept from step to step: no
        /// allocation in the step loop.
        buffers: Mutex<(Vec<f64>, Vec<f64>)>,
        /// [`Comm::all_gather`]'s every rank's length, and its pieces' lengths and offsets as
        /// MPI counts them, kept likewise.
        pieces: Mutex<(Vec<u64>, Vec<i32>, Vec<i32>)>,
        // dropped last: finalises MPI
        _universe: mpi::environment::Universe,
    }

    // SAFETY: MPI_THREAD_SERIALIZED; the communicator is only used by the one thread that runs
    // the step loop, never concurrently (the step's parallel loops do not call it).
    unsafe impl Send for Mpi {}
    unsafe impl Sync for Mpi {}

    impl Mpi {
        /// Starts MPI; `None` where it was already started or cannot be, an error where the
        /// library cannot take calls from the thread the run is installed on.
        ///
        /// Over several ranks a panic on one rank ends every rank (`MPI_Abort`, through the
        /// panic hook), where the others would wait in their next collective for ever.
        pub fn init() -> Option<Result<Self, String>> {
            let (universe, provided) = mpi::initialize_with_threading(mpi::Threading::Serialized)?;
            if provided < mpi::Threading::Serialized {
                return Some(Err(format!(
                    "this MPI library gives thread level {provided:?}; pmpm needs Serialized \
                     (MPICH gives it)"
                )));
            }
            let world = universe.world();
            if world.size() > 1 {
                let hook = std::panic::take_hook();
                std::panic::set_hook(Box::new(move |info| {
                    hook(info);
                    SimpleCommunicator::world().abort(101);
                }));
            }
            Some(Ok(Self {
                world,
                buffers: Mutex::new((Vec::new(), Vec::new())),
                pieces: Mutex::new((Vec::new(), Vec::new(), Vec::new())),
                _universe: universe,
            }))
        }

        /// Ends every rank of the run at once with exit status `code` (`MPI_Abort`): for a
        /// rank that stops alone, which the others would otherwise wait for.
        pub fn abort(&self, code: i32) -> ! {
            self.world.abort(code)
        }

        fn buffers(&self) -> MutexGuard<'_, (Vec<f64>, Vec<f64>)> {
            self.buffers.lock().unwrap_or_else(|e| e.into_inner())
        }

        /// The arrays' element-wise `op` reduced onto rank 0 and broadcast from there, so that
        /// every rank holds the same bits (an all-reduce may round differently on different
        /// ranks); packed into one buffer, so that several arrays take one exchange.
        fn reduce(&self, arrays: &mut [&mut [f64]], op: SystemOperation) {
            let n: usize = arrays.iter().map(|a| a.len()).sum();
            if self.size() == 1 || n == 0 {
                return;
            }
            let mut guard = self.buffers();
            let (packed, sums) = &mut *guard;
            packed.clear();
            for a in arrays.iter() {
                packed.extend_from_slice(a);
            }
            let root = self.world.process_at_rank(0);
            if self.rank() == 0 {
                sums.resize(n, 0.0);
                root.reduce_into_root(&packed[..], &mut sums[..], op);
                std::mem::swap(packed, sums);
            } else {
                root.reduce_into(&packed[..], op);
            }
            root.broadcast_into(&mut packed[..]);
            let mut at = 0;
            for a in arrays.iter_mut() {
                a.copy_from_slice(&packed[at..at + a.len()]);
                at += a.len();
            }
        }
    }

    impl Comm for Mpi {
        fn rank(&self) -> usize {
            self.world.rank() as usize
        }
        fn size(&self) -> usize {
            self.world.size() as usize
        }
        fn sum(&self, values: &mut [f64]) {
            self.reduce(&mut [values], SystemOperation::sum());
        }
        fn sum_all(&self, arrays: &mut [&mut [f64]]) {
            self.reduce(arrays, SystemOperation::sum());
        }
        fn max(&self, values: &mut [f64]) {
            self.reduce(&mut [values], SystemOperation::max());
        }
        fn min(&self, values: &mut [f64]) {
            self.reduce(&mut [values], SystemOperation::min());
        }
        fn gather(&self, bytes: &[u8]) -> Vec<Vec<u8>> {
            let root = self.world.process_at_rank(0);
            let n = bytes.len() as u64;
            if self.rank() != 0 {
                root.gather_into(&n);
                root.gather_varcount_into(bytes);
                return Vec::new();
            }
            let mut counts = vec![0u64; self.size()];
            root.gather_into_root(&n, &mut counts[..]);
            let counts: Vec<i32> = counts.iter().map(|&c| c as i32).collect();
            let displs: Vec<i32> = counts
                .iter()
                .scan(0, |at, &c| {
                    let d = *at;
                    *at += c;
                    Some(d)
                })
                .collect();
            let mut all = vec![0u8; counts.iter().map(|&c| c as usize).sum()];
            {
                let mut partition =
                    mpi::datatype::PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
                root.gather_varcount_into_root(bytes, &mut partition);
            }
            let mut out = Vec::with_capacity(self.size());
            let mut at = 0;
            for &c in &counts {
                out.push(all[at..at + c as usize].to_vec());
                at += c as usize;
            }
            out
        }
        fn all_gather(&self, bytes: &[u8], all: &mut Vec<u8>) {
            let mut guard = self.pieces.lock().unwrap_or_else(|e| e.into_inner());
            let (lengths, counts, displs) = &mut *guard;
            lengths.resize(self.size(), 0);
            self.world
                .all_gather_into(&(bytes.len() as u64), &mut lengths[..]);
            counts.clear();
            displs.clear();
            let mut at = 0;
            for &n in lengths.iter() {
                counts.push(n as i32);
                displs.push(at);
                at += n as i32;
            }
            all.resize(at as usize, 0);
            let mut partition =
                mpi::datatype::PartitionMut::new(&mut all[..], &counts[..], &displs[..]);
            self.world.all_gather_varcount_into(bytes, &mut partition);
        }
        fn broadcast(&self, bytes: &mut Vec<u8>) {
            let root = self.world.process_at_rank(0);
            let mut n = bytes.len() as u64;
            root.broadcast_into(&mut n);
            bytes.resize(n as usize, 0);
            root.broadcast_into(&mut bytes[..]);
        }
        fn send_bytes(&self, to: usize, bytes: &[u8]) {
            self.world.process_at_rank(to as i32).send(bytes);
        }
        fn receive_bytes(&self, from: usize) -> Vec<u8> {
            self.world
                .process_at_rank(from as i32)
                .receive_vec::<u8>()
                .0
        }
        fn swap(&self, peer: usize, send: &[f64], recv: &mut [f64]) {
            let peer = self.world.process_at_rank(peer as i32);
            mpi::point_to_point::send_receive_into(send, &peer, recv, &peer);
        }
        fn exchange(
            &self,
            send: &[u8],
            counts: &[usize],
            recv: &mut Vec<u8>,
            recv_counts: &mut Vec<usize>,
        ) {
            let size = self.size();
            let sizes: Vec<i32> = counts.iter().map(|&c| c as i32).collect();
            let mut theirs = vec![0i32; size];
            self.world.all_to_all_into(&sizes[..], &mut theirs[..]);
            let displs = |c: &[i32]| -> Vec<i32> {
                c.iter()
                    .scan(0, |at, &c| {
                        let d = *at;
                        *at += c;
                        Some(d)
                    })
                    .collect()
            };
            let (send_at, recv_at) = (displs(&sizes), displs(&theirs));
            recv.resize(theirs.iter().map(|&c| c as usize).sum(), 0);
            let out = mpi::datatype::Partition::new(send, &sizes[..], &send_at[..]);
            let mut into =
                mpi::datatype::PartitionMut::new(&mut recv[..], &theirs[..], &recv_at[..]);
            self.world.all_to_all_varcount_into(&out, &mut into);
            recv_counts.clear();
            recv_counts.extend(theirs.iter().map(|&c| c as usize));
        }
    }
}

/// Ranks as threads of one process, for the tests of what runs over ranks without MPI: every
/// operation is built on one mailbox of byte messages, first in first out per pair of ranks,
/// and the reductions add up on rank 0 in rank order (the same bits on every rank, as MPI's).
#[cfg(test)]
pub(crate) mod threads {
    use super::Comm;
    use std::collections::{HashMap, VecDeque};
    use std::sync::{Arc, Condvar, Mutex};

    /// The messages from one rank to another, oldest first.
    type Queues = HashMap<(usize, usize), VecDeque<Vec<u8>>>;

    #[derive(Default)]
    struct Post {
        boxes: Mutex<Queues>,
        arrived: Condvar,
        /// A rank panicked: the others stop waiting for it, and panic too.
        poisoned: std::sync::atomic::AtomicBool,
    }

    /// One rank of a run over threads.
    pub(crate) struct Threads {
        rank: usize,
        size: usize,
        post: Arc<Post>,
    }

    /// Runs `f` on `size` ranks, each a thread with its own [`Threads`], and returns what each
    /// rank returned, in rank order.
    pub(crate) fn run<T: Send>(size: usize, f: impl Fn(Arc<dyn Comm>) -> T + Sync) -> Vec<T> {
        let post = Arc::new(Post::default());
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..size)
                .map(|rank| {
                    let (post, f) = (post.clone(), &f);
                    s.spawn(move || {
                        let comm = Arc::new(Threads {
                            rank,
                            size,
                            post: post.clone(),
                        });
                        let run = std::panic::AssertUnwindSafe(|| f(comm));
                        std::panic::catch_unwind(run).unwrap_or_else(|why| {
                            let _guard = post.boxes.lock();
                            post.poisoned
                                .store(true, std::sync::atomic::Ordering::SeqCst);
                            post.arrived.notify_all();
                            std::panic::resume_unwind(why)
                        })
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        })
    }

    impl Threads {
        fn reduce(&self, values: &mut [f64], op: fn(f64, f64) -> f64) {
            if self.rank == 0 {
                for from in 1..self.size {
                    let theirs: Vec<f64> = bytemuck::pod_collect_to_vec(&self.receive_bytes(from));
                    assert_eq!(
                        theirs.len(),
                        values.len(),
                        "rank {from} reduced another length"
                    );
                    for (v, t) in values.iter_mut().zip(theirs) {
                        *v = op(*v, t);
                    }
                }
            } else {
                self.send_bytes(0, bytemuck::cast_slice(values));
            }
            let mut bytes = bytemuck::cast_slice(values).to_vec();
            self.broadcast(&mut bytes);
            values.copy_from_slice(&bytemuck::pod_collect_to_vec::<u8, f64>(&bytes));
        }
    }

    impl Comm for Threads {
        fn rank(&self) -> usize {
            self.rank
        }
        fn size(&self) -> usize {
            self.size
        }
        fn sum(&self, values: &mut [f64]) {
            self.reduce(values, |a, b| a + b)
        }
        fn max(&self, values: &mut [f64]) {
            self.reduce(values, f64::max)
        }
        fn min(&self, values: &mut [f64]) {
            self.reduce(values, f64::min)
        }
        fn gather(&self, bytes: &[u8]) -> Vec<Vec<u8>> {
            if self.rank != 0 {
                self.send_bytes(0, bytes);
                return Vec::new();
            }
            let mut all = vec![bytes.to_vec()];
            all.extend((1..self.size).map(|from| self.receive_bytes(from)));
            all
        }
        fn broadcast(&self, bytes: &mut Vec<u8>) {
            if self.rank == 0 {
                for to in 1..self.size {
                    self.send_bytes(to, bytes);
                }
            } else {
                *bytes = self.receive_bytes(0);
            }
        }
        fn swap(&self, peer: usize, send: &[f64], recv: &mut [f64]) {
            self.send_bytes(peer, bytemuck::cast_slice(send));
            let theirs: Vec<f64> = bytemuck::pod_collect_to_vec(&self.receive_bytes(peer));
            recv.copy_from_slice(&theirs);
        }
        fn send_bytes(&self, to: usize, bytes: &[u8]) {
            let mut boxes = self.post.boxes.lock().unwrap();
            boxes
                .entry((self.rank, to))
                .or_default()
                .push_back(bytes.to_vec());
            self.post.arrived.notify_all();
        }
        fn receive_bytes(&self, from: usize) -> Vec<u8> {
            let mut boxes = self.post.boxes.lock().unwrap();
            loop {
                if let Some(m) = boxes
                    .get_mut(&(from, self.rank))
                    .and_then(|q| q.pop_front())
                {
                    return m;
                }
                if self.post.poisoned.load(std::sync::atomic::Ordering::SeqCst) {
                    panic!("rank {}: another rank panicked", self.rank);
                }
                boxes = self.post.arrived.wait(boxes).unwrap();
            }
        }
        fn exchange(
            &self,
            send: &[u8],
            counts: &[usize],
            recv: &mut Vec<u8>,
            recv_counts: &mut Vec<usize>,
        ) {
            let mut at = 0;
            for (to, &c) in counts.iter().enumerate() {
                self.send_bytes(to, &send[at..at + c]);
                at += c;
            }
            recv.clear();
            recv_counts.clear();
            for from in 0..self.size {
                let m = self.receive_bytes(from);
                recv_counts.push(m.len());
                recv.extend_from_slice(&m);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pieces_of_a_swap_cover_both_ways_and_agree_on_both_ranks() {
        for (send, recv, width) in [(0, 0, 9), (0, 3, 9), (10_000, 5_000, 54), (1, 1, PIECE * 2)] {
            let mine: Vec<_> = pieces(send, recv, width).collect();
            let theirs: Vec<_> = pieces(recv, send, width).collect();
            assert_eq!(mine.len(), theirs.len());
            for ((s, r), (their_s, their_r)) in mine.iter().zip(&theirs) {
                // what one rank sends in a piece, the other receives in the same piece
                assert_eq!((s.clone(), r.clone()), (their_r.clone(), their_s.clone()));
                assert!(s.len().max(r.len()) * width <= PIECE.max(width));
            }
            type Piece = (std::ops::Range<usize>, std::ops::Range<usize>);
            let ends = |way: fn(&Piece) -> &std::ops::Range<usize>| {
                mine.iter().map(way).fold(0, |at, piece| {
                    assert_eq!(piece.start, at);
                    piece.end
                })
            };
            assert_eq!(ends(|p| &p.0), send);
            assert_eq!(ends(|p| &p.1), recv);
        }
        assert_eq!(pieces(10_000, 5_000, 54).count(), 3);
    }

    #[test]
    fn the_shares_cover_every_item_once_and_differ_by_at_most_one() {
        for n in [0, 1, 5, 17, 100] {
            for size in 1..6 {
                let ranges: Vec<_> = (0..size).map(|r| share(n, r, size)).collect();
                assert_eq!(ranges[0].start, 0);
                assert_eq!(ranges[size - 1].end, n);
                for w in ranges.windows(2) {
                    assert_eq!(w[0].end, w[1].start);
                }
                let lens: Vec<_> = ranges.iter().map(|r| r.len()).collect();
                let (lo, hi) = (lens.iter().min().unwrap(), lens.iter().max().unwrap());
                assert!(hi - lo <= 1, "n {n} size {size}: {lens:?}");
            }
        }
    }

    #[test]
    fn one_process_reduces_to_itself() {
        let c = serial();
        let mut v = [1.0, -2.0];
        c.sum(&mut v);
        c.max(&mut v);
        assert_eq!(v, [1.0, -2.0]);
        assert!(c.any(true) && !c.any(false));
        assert_eq!(c.gather(b"ab"), vec![b"ab".to_vec()]);
        let mut all = b"old".to_vec();
        c.all_gather(b"ab", &mut all);
        assert_eq!(all, b"ab");
        assert!(c.is_root() && !c.is_distributed());
    }
}
