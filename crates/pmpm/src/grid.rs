//! The uniform background grid: node numbering, node positions and node fields.
//!
//! Nodes are numbered row-major (axis 0 fastest) over the cells' corners plus [`PAD`] ghost
//! layers beyond every face, so that every shape function's stencil of a particle inside the
//! domain lies on the grid. Node fields are stored as separate arrays (struct of arrays).

use crate::pages::zeroed;
use crate::shape::PAD;
use nalgebra::SVector;

/// D-vector of f64.
pub type Vector<const D: usize> = SVector<f64, D>;

/// Grid geometry: origin, cell size, cell and node counts.
#[derive(Debug, Clone)]
pub struct GridGeometry<const D: usize> {
    /// Lower corner of the domain.
    pub origin: Vector<D>,
    /// Cell size h.
    pub h: f64,
    /// Cells per direction.
    pub cells: [usize; D],
    /// Nodes per direction, ghosts included.
    pub nodes: [usize; D],
    /// Flat-index stride of each direction.
    pub strides: [usize; D],
    /// Periodic directions: node x_min + k L and x_min are the same node.
    pub periodic: [bool; D],
    /// (image, canonical) flat pairs of the nodes that repeat another across a periodic
    /// direction (the ghosts and the upper boundary layer), for [`GridGeometry::fold`].
    images: Vec<(u32, u32)>,
}

impl<const D: usize> GridGeometry<D> {
    /// Geometry of a grid of `cells` cells of size `h` from `origin`.
    pub fn new(origin: Vector<D>, h: f64, cells: [usize; D]) -> Self {
        let nodes: [usize; D] = std::array::from_fn(|d| cells[d] + 1 + 2 * PAD);
        let mut strides = [1usize; D];
        for d in 1..D {
            strides[d] = strides[d - 1] * nodes[d - 1];
        }
        Self {
            origin,
            h,
            cells,
            nodes,
            strides,
            periodic: [false; D],
            images: Vec::new(),
        }
    }

    /// The same grid with the given directions periodic.
    pub fn with_periodic(mut self, periodic: [bool; D]) -> Self {
        self.periodic = periodic;
        self.images = (0..self.node_count())
            .filter_map(|f| {
                let c = self.canonical(f);
                (c != f).then_some((f as u32, c as u32))
            })
            .collect();
        self
    }

    /// Whether any direction is periodic.
    #[inline]
    pub fn has_periodic(&self) -> bool {
        !self.images.is_empty()
    }

    /// The node a periodic image stands for (itself where no direction is periodic): padded
    /// index PAD + ((i - PAD) mod cells) in each periodic direction.
    #[inline]
    pub fn canonical(&self, flat: usize) -> usize {
        if !self.periodic.iter().any(|&p| p) {
            return flat;
        }
        let mut idx = self.multi(flat);
        for d in 0..D {
            if self.periodic[d] {
                let n = self.cells[d] as isize;
                let r = (idx[d] as isize - PAD as isize).rem_euclid(n);
                idx[d] = PAD + r as usize;
            }
        }
        self.flat(&idx)
    }

    /// Makes a node field periodic after a scatter: each image's sum is added to the node it
    /// stands for, and the total is copied back to every image.
    pub fn fold<T: Copy + std::ops::AddAssign>(&self, field: &mut [T]) {
        for &(i, c) in &self.images {
            let v = field[i as usize];
            field[c as usize] += v;
        }
        self.copy_to_images(field);
    }

    /// Copies every node's value to its periodic images.
    pub fn copy_to_images<T: Copy>(&self, field: &mut [T]) {
        for &(i, c) in &self.images {
            field[i as usize] = field[c as usize];
        }
    }

    /// Calls `f` with every padded node index that stands for the same node as `idx`
    /// (`idx` itself included).
    #[inline]
    pub fn for_each_image(&self, idx: &[usize; D], mut f: impl FnMut([usize; D])) {
        if !self.has_periodic() {
            // the common case: no images, and no 3^D odometer per gathered node
            f(*idx);
            return;
        }
        // per direction up to three candidates: idx, idx - cells, idx + cells
        let mut cand = [[usize::MAX; 3]; D];
        for d in 0..D {
            cand[d][0] = idx[d];
            if self.periodic[d] {
                let n = self.cells[d];
                if idx[d] >= n {
                    cand[d][1] = idx[d] - n;
                }
                if idx[d] + n < self.nodes[d] {
                    cand[d][2] = idx[d] + n;
                }
            }
        }
        let mut k = [0usize; D];
        loop {
            if (0..D).all(|d| cand[d][k[d]] != usize::MAX) {
                f(std::array::from_fn(|d| cand[d][k[d]]));
            }
            let mut d = 0;
            loop {
                if d == D {
                    return;
                }
                k[d] += 1;
                if k[d] < 3 {
                    break;
                }
                k[d] = 0;
                d += 1;
            }
        }
    }

    /// Wraps a position into the domain along the periodic directions.
    #[inline]
    pub fn wrap(&self, x: &mut Vector<D>) {
        for d in 0..D {
            if self.periodic[d] {
                let l = self.cells[d] as f64 * self.h;
                let mut r = (x[d] - self.origin[d]).rem_euclid(l);
                if r >= l {
                    r = 0.0;
                }
                x[d] = self.origin[d] + r;
            }
        }
    }

    /// Number of nodes, ghosts included.
    pub fn node_count(&self) -> usize {
        self.nodes.iter().product()
    }

    /// Flat index of a padded multi-index.
    #[inline]
    pub fn flat(&self, idx: &[usize; D]) -> usize {
        (0..D).map(|d| idx[d] * self.strides[d]).sum()
    }

    /// The nodes (flat) of node layer `layer` along `axis`, in node order.
    pub fn layer_nodes(&self, axis: usize, layer: usize) -> impl Iterator<Item = usize> + '_ {
        let count = self.node_count() / self.nodes[axis];
        (0..count).map(move |mut k| {
            let mut i = layer * self.strides[axis];
            for d in (0..D).filter(|&d| d != axis) {
                i += (k % self.nodes[d]) * self.strides[d];
                k /= self.nodes[d];
            }
            i
        })
    }

    /// The layer along `axis` of node (or cell) `flat`: `multi(flat)[axis]` with one
    /// division and one remainder, not D of each.
    #[inline]
    pub fn layer(&self, flat: usize, axis: usize) -> usize {
        (flat / self.strides[axis]) % self.nodes[axis]
    }

    /// `idx` moved on to the next node in flat order (the multi-index of flat + 1): a loop
    /// over every node in order keeps its multi-index without a division a node.
    #[inline]
    pub fn advance(&self, idx: &mut [usize; D]) {
        for d in 0..D {
            idx[d] += 1;
            if idx[d] < self.nodes[d] || d == D - 1 {
                return;
            }
            idx[d] = 0;
        }
    }

    /// Padded multi-index of a flat index.
    #[inline]
    pub fn multi(&self, mut flat: usize) -> [usize; D] {
        std::array::from_fn(|d| {
            let i = flat % self.nodes[d];
            flat /= self.nodes[d];
            i
        })
    }

    /// Position of a node from its padded multi-index.
    #[inline]
    pub fn node_position(&self, idx: &[usize; D]) -> Vector<D> {
        Vector::<D>::from_fn(|d, _| self.origin[d] + (idx[d] as f64 - PAD as f64) * self.h)
    }

    /// Position in cells from the origin.
    #[inline]
    pub fn to_cells(&self, x: &Vector<D>) -> Vector<D> {
        (x - self.origin) / self.h
    }

    /// Upper corner of the domain.
    pub fn upper(&self) -> Vector<D> {
        Vector::<D>::from_fn(|d, _| self.origin[d] + self.cells[d] as f64 * self.h)
    }

    /// Flat (padded) index of the cell holding `x`, clamped to the padded grid; a cell is
    /// numbered like its lower-corner node.
    #[inline]
    pub fn cell_of(&self, x: &Vector<D>) -> usize {
        let xc = self.to_cells(x);
        let idx: [usize; D] = std::array::from_fn(|d| {
            let c = xc[d].floor() + PAD as f64;
            (c.max(0.0) as usize).min(self.nodes[d] - 2)
        });
        self.flat(&idx)
    }

    /// Whether a point lies in the closed domain.
    #[inline]
    pub fn contains(&self, x: &Vector<D>) -> bool {
        let up = self.upper();
        (0..D).all(|d| x[d] >= self.origin[d] && x[d] <= up[d])
    }
}

/// Gauss point `k` (0 to 2^D - 1, bit d for axis d) of the 2-point Gauss rule on a cell, as a
/// fraction of the cell from its lower corner: 1/2 -+ 1/(2 sqrt 3) along each axis. The
/// pressure's cell quadrature and the viscous solve's deep cells both use it.
pub fn gauss_point<const D: usize>(k: usize) -> Vector<D> {
    let a = 0.5 / 3f64.sqrt();
    Vector::<D>::from_fn(|d, _| if (k >> d) & 1 == 1 { 0.5 + a } else { 0.5 - a })
}

/// Particles sorted by the cell they are in (a counting sort, redone every step with reused
/// buffers), so that a node can gather from the particles of the cells around it: the
/// projection's assembly and corrector are gathers, deterministic for any thread count.
///
/// Cells are numbered like their lower-corner node, so the arrays have one slot per node. A
/// cell's count and start are written only where it holds particles (a running sum of the
/// counts would be non-zero over the whole box), so the arrays hold memory only where the
/// particles are ([`crate::pages`]).
#[derive(Debug, Clone, Default)]
pub struct CellBins {
    /// Cell (flat, padded) of each particle.
    pub cell_of: Vec<u32>,
    /// Particles in each cell.
    count: Vec<u32>,
    /// Where a cell's particles start in `order` (meaningful where `count` is not zero).
    start: Vec<u32>,
    /// Particle ids sorted by cell, in increasing id within a cell.
    pub order: Vec<u32>,
}

impl CellBins {
    /// Sorts the particles at `x` into the cells of `geo`.
    pub fn sort<const D: usize>(&mut self, geo: &GridGeometry<D>, x: &[Vector<D>]) {
        use crate::pages;
        use rayon::prelude::*;
        let n_cells = geo.node_count();
        self.cell_of.resize(x.len(), 0);
        self.cell_of
            .par_iter_mut()
            .zip(x.par_iter())
            .for_each(|(c, x)| *c = geo.cell_of(x) as u32);
        pages::fit(&mut self.count, n_cells);
        pages::fit(&mut self.start, n_cells);
        pages::reset(&mut self.count);
        for &c in &self.cell_of {
            self.count[c as usize] += 1;
        }
        let mut running = 0u32;
        for (start, &count) in self.start.iter_mut().zip(&self.count) {
            if count > 0 {
                pages::store(start, running);
                running += count;
            }
        }
        self.order.resize(x.len(), 0);
        // fill with a running cursor per cell, kept in `count` counted up again from zero
        pages::reset(&mut self.count);
        for (p, &c) in self.cell_of.iter().enumerate() {
            let c = c as usize;
            self.order[(self.start[c] + self.count[c]) as usize] = p as u32;
            self.count[c] += 1;
        }
    }

    /// The particles of flat cell `c`.
    #[inline]
    pub fn particles(&self, c: usize) -> &[u32] {
        match self.count[c] {
            0 => &[],
            n => &self.order[self.start[c] as usize..(self.start[c] + n) as usize],
        }
    }
}

/// Node fields of the background grid.
#[derive(Debug, Clone)]
pub struct Grid<const D: usize> {
    /// Geometry.
    pub geo: GridGeometry<D>,
    /// m_i
    pub mass: Vec<f64>,
    /// (m v)_i, then reused for nothing else.
    pub momentum: Vec<Vector<D>>,
    /// v_i^n = (m v)_i / m_i
    pub velocity: Vec<Vector<D>>,
    /// v_i^{n+1} (v* during the projection's predictor)
    pub velocity_new: Vec<Vector<D>>,
    /// f_i: internal and body forces.
    pub force: Vec<Vector<D>>,
    /// The body force's part of f_i, sum_p N_ip m_p b_p.
    pub body: Vec<Vector<D>>,
    /// Mass-weighted particle pressure, sum N m p; divided by m_i after P2G.
    pub pressure: Vec<f64>,
    /// The damping zones' rate at each node (1/s; set from the deck's zones at the start),
    /// fixed for the run;
    /// empty where the deck has none.
    pub damping: Vec<f64>,
    /// The nodes P2G's gather visits ([`Live`]); `None`: every node.
    pub live: Option<Live>,
}

/// The run of nodes (flat indices) that P2G's gather visits, where it need not visit the whole
/// box: the nodes the particles' bands reach now and reached at the last gather, and over
/// ranks the slab's (the layers a neighbour's sums can reach). Outside them every P2G field
/// (mass, momentum, forces, pressure, v^n) is zero, and stays so: a node the particles leave
/// is visited, and zeroed, once more. So the gather's cost follows the material, not the box
/// (a tall tank, a rank's slab of a wide one), and its bits are the whole loop's.
#[derive(Debug, Clone, Default)]
pub struct Live {
    /// Over ranks, this rank's slab's nodes with three layers either side (the window's,
    /// where the explicit packing's is wider); empty on one process.
    pub slab: std::ops::Range<usize>,
    /// What the last gather reached (its bands, and the slab).
    pub previous: std::ops::Range<usize>,
}

impl Live {
    /// The nodes to visit now, the particles' bands reaching `now`, and `now` with the slab
    /// kept for the next gather.
    pub fn visit(&mut self, now: std::ops::Range<usize>) -> std::ops::Range<usize> {
        let now = hull(now, self.slab.clone());
        let visit = hull(now.clone(), self.previous.clone());
        self.previous = now;
        visit
    }
}

/// The smallest run holding both (an empty run holds nothing).
fn hull(a: std::ops::Range<usize>, b: std::ops::Range<usize>) -> std::ops::Range<usize> {
    match (a.is_empty(), b.is_empty()) {
        (true, _) => b,
        (_, true) => a,
        _ => a.start.min(b.start)..a.end.max(b.end),
    }
}

impl<const D: usize> Grid<D> {
    /// A zeroed grid.
    pub fn new(geo: GridGeometry<D>) -> Self {
        let n = geo.node_count();
        Self {
            geo,
            mass: zeroed(n),
            momentum: zeroed(n),
            velocity: zeroed(n),
            velocity_new: zeroed(n),
            force: zeroed(n),
            body: zeroed(n),
            pressure: zeroed(n),
            damping: Vec::new(),
            live: None,
        }
    }
}

/// The role of a node in the pressure solve (one byte, `Empty` all zero bits, so that an
/// array of kinds keeps the pages of empty nodes uncommitted: [`crate::pages`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum NodeKind {
    /// No mass: not part of the fluid.
    #[default]
    Empty = 0,
    /// On the free surface: p = 0 (a Dirichlet node).
    FreeSurface,
    /// Inside the fluid: an unknown of the Poisson equation.
    Interior,
    /// Inside a rigid body (every cell around it covered), under the level-set free surface:
    /// no unknown, and no Dirichlet value either. The wider shape functions couple the nodes
    /// near a face to it; there its pressure reads as the coupled node's own, a Neumann
    /// condition on the face (taken as 0, it pulled the face's pressure down by a tenth).
    Solid,
}

// SAFETY: NodeKind is a fieldless repr(u8) enum: one initialised byte and no padding, and
// the all-zero byte is its variant `Empty`.
unsafe impl bytemuck::NoUninit for NodeKind {}
// SAFETY: as above; zero is `Empty`.
unsafe impl bytemuck::Zeroable for NodeKind {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn periodic_images_fold_onto_their_node() {
        let g =
            GridGeometry::<2>::new(Vector::<2>::zeros(), 0.1, [6, 4]).with_periodic([true, false]);
        // node x = 0 and x = L are one node; ghosts wrap
        assert_eq!(g.canonical(g.flat(&[PAD + 6, 3])), g.flat(&[PAD, 3]));
        assert_eq!(g.canonical(g.flat(&[PAD - 1, 3])), g.flat(&[PAD + 5, 3]));
        assert_eq!(g.canonical(g.flat(&[PAD + 2, 0])), g.flat(&[PAD + 2, 0]));
        let mut f = vec![1.0; g.node_count()];
        g.fold(&mut f);
        // a node with images: itself plus each image
        let mut n = 0;
        g.for_each_image(&[PAD, 3], |_| n += 1);
        assert_eq!(n, 2);
        assert_eq!(f[g.flat(&[PAD, 3])], 2.0);
        assert_eq!(f[g.flat(&[PAD + 6, 3])], 2.0);
        assert_eq!(f[g.flat(&[PAD + 3, 3])], 1.0);
        let mut x = Vector::<2>::new(-0.05, 0.2);
        g.wrap(&mut x);
        assert!((x[0] - 0.55).abs() < 1e-12 && x[1] == 0.2);
    }

    #[test]
    fn flat_and_multi_are_inverse() {
        let g = GridGeometry::<3>::new(Vector::<3>::zeros(), 0.1, [3, 4, 5]);
        for f in 0..g.node_count() {
            assert_eq!(g.flat(&g.multi(f)), f);
        }
        let x = g.node_position(&[PAD, PAD, PAD]);
        assert!(x.norm() < 1e-15);
    }

    #[test]
    fn advance_and_layer_follow_multi() {
        let g = GridGeometry::<3>::new(Vector::<3>::zeros(), 0.1, [3, 4, 5]);
        let mut idx = [0; 3];
        for f in 0..g.node_count() {
            assert_eq!(idx, g.multi(f), "node {f}");
            for d in 0..3 {
                assert_eq!(g.layer(f, d), idx[d], "node {f}, axis {d}");
            }
            g.advance(&mut idx);
        }
    }
}
