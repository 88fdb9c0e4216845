//! Linear algebra for the projection's symmetric positive (semi-)definite systems: the ELL
//! matrix, the conjugate gradient with its preconditioners (Jacobi, incomplete Cholesky, the
//! geometric multigrid of [`multigrid`]) and faer's sparse Cholesky, behind one interface: a
//! [`System`] (matrix, where its rows sit on the grid, whether it is singular), the
//! [`SolveParams`] that stop a solve, and its [`SolveStats`] or [`SolveError`]. Nothing here
//! knows what the unknowns mean.
//!
//! The matrix is stored row by row with a fixed number of slots per row (ELLPACK): a grid node
//! couples with at most (2K - 1)^D nodes for shape functions K nodes wide, so every row has the
//! same capacity, rows are assembled in parallel each into its own slice, and the buffers are
//! reused from step to step (no allocation once the largest system has been seen).
//!
//! The conjugate gradient is written here rather than taken from a crate: it runs on this
//! storage, is parallel with rayon, sums its dot products in fixed chunks (so a run repeats
//! bitwise, whatever the thread count), handles the singular pure-Neumann system of a closed,
//! filled container, and takes any [`Preconditioner`]. The direct solver is faer's sparse
//! Cholesky.

mod cg;
pub mod multigrid;
pub mod spread;

pub use cg::{dot, CgWork, Entry, Operator, Precondition};
pub use multigrid::{GridLayout, Multigrid};
pub use spread::Partition;

use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use rayon::prelude::*;

/// Rows per chunk of the parallel loops and of the fixed-order dot products.
const CHUNK: usize = 2048;

/// A symmetric sparse matrix with `width` slots per row; an unused slot has column = its row
/// and value 0. Over ranks a rank fills only the rows it assembles (its slab's and those
/// beside it, [`spread`]); the others hold what they held (zeros, column 0, where never
/// written): the spread solve computes with its own rows and its halo's only, and the passes
/// over every row (pinning the empty ones, the Jacobi diagonal) read the others to no
/// effect.
#[derive(Debug, Clone, Default)]
pub struct EllMatrix {
    /// Number of rows (and columns).
    pub n: usize,
    /// Slots per row.
    pub width: usize,
    /// Column of each slot, row-major: slot k of row r is at r * width + k.
    pub cols: Slots<u32>,
    /// Value of each slot.
    pub vals: Slots<f64>,
}

/// The slots of a matrix, or a vector of the multigrid's or the spread solve's with a value
/// (or several) per row: `len` values in use at the front of a buffer of zeroed pages
/// ([`crate::pages::zeroed`]), which commit memory only where a row is written. Over ranks these
/// have the whole system's rows on every rank, and each rank writes only its own and those
/// beside them, so its memory follows its share. Reads as the slice of the values in use.
#[derive(Debug, Clone, Default)]
pub struct Slots<T> {
    buf: Vec<T>,
    len: usize,
}

impl<T: bytemuck::Zeroable> Slots<T> {
    /// `len` values in use: those already held are kept, and a buffer too short is replaced by
    /// zeroed pages for a quarter more (the rows' count moves a little from step to step), the
    /// values it held dropped (what reads a row writes it first: the assembly, the levels'
    /// links, the solves).
    pub(crate) fn fit(&mut self, len: usize) {
        if len > self.buf.len() {
            self.buf = crate::pages::zeroed(len + len / 4);
        }
        self.len = len;
    }
}

impl<T> std::ops::Deref for Slots<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        &self.buf[..self.len]
    }
}

impl<T> std::ops::DerefMut for Slots<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        &mut self.buf[..self.len]
    }
}

impl EllMatrix {
    /// Resizes to `n` rows of `width` slots (contents unspecified; the assembly fills every
    /// slot it reads). Keeps the buffers where they are long enough.
    pub fn reshape(&mut self, n: usize, width: usize) {
        self.n = n;
        self.width = width;
        self.cols.fit(n * width);
        self.vals.fit(n * width);
    }

    /// y = A x.
    pub fn matvec(&self, x: &[f64], y: &mut [f64]) {
        self.matvec_rows(x, y, 0);
    }

    /// The rows `first..first + y.len()` of A x, into y.
    pub fn matvec_rows(&self, x: &[f64], y: &mut [f64], first: usize) {
        let w = self.width;
        y.par_chunks_mut(CHUNK).enumerate().for_each(|(c, ys)| {
            for (k, y) in ys.iter_mut().enumerate() {
                let r = first + c * CHUNK + k;
                let cols = &self.cols[r * w..(r + 1) * w];
                let vals = &self.vals[r * w..(r + 1) * w];
                *y = cols
                    .iter()
                    .zip(vals)
                    .map(|(&j, &a)| a * x[j as usize])
                    .sum();
            }
        });
    }

    /// Pins the rows that hold nothing, x_r = 0: a row whose slots are all zero (an unknown
    /// none of whose cells holds a quadrature point: a node beside a sliver that a rigid
    /// body's face leaves of a cell) gets a 1 on its diagonal and b_r = 0, so that the
    /// solvers, which divide by the diagonal, see a definite system. A row pinned before (a
    /// lone diagonal of exactly 1) gets b_r = 0 again. Rows that hold anything are untouched.
    pub fn pin_empty_rows(&mut self, b: &mut [f64]) {
        let w = self.width;
        self.vals
            .par_chunks_mut(w)
            .zip(self.cols.par_chunks(w))
            .zip(b.par_iter_mut())
            .enumerate()
            .for_each(|(r, ((vals, cols), b))| {
                let lone = vals
                    .iter()
                    .zip(cols)
                    .all(|(&v, &c)| v == 0.0 || (c as usize == r && v == 1.0));
                if lone {
                    // the centre slot where it holds the diagonal: rows laid out on the grid
                    // keep each column at its geometric slot (the multigrid relies on it)
                    let centre = (w - 1) / 2;
                    let k = if cols[centre] as usize == r {
                        Some(centre)
                    } else {
                        cols.iter().position(|&c| c as usize == r)
                    };
                    if let Some(k) = k {
                        if vals.iter().all(|&v| v == 0.0) || vals[k] == 1.0 {
                            vals[k] = 1.0;
                            *b = 0.0;
                        }
                    }
                }
            });
    }

    /// The diagonal entries (summed over the row's slots that hold column r).
    pub fn diagonal(&self, d: &mut Vec<f64>) {
        d.resize(self.n, 0.0);
        d.par_iter_mut()
            .enumerate()
            .for_each(|(r, d)| *d = self.diagonal_of(r));
    }

    /// Row r's diagonal entry (summed over its slots that hold column r).
    pub fn diagonal_of(&self, r: usize) -> f64 {
        let w = self.width;
        (0..w)
            .filter(|&k| self.cols[r * w + k] as usize == r)
            .map(|k| self.vals[r * w + k])
            .sum()
    }
}

/// Removes the mean of `x` (the null space of a pure-Neumann Laplacian is the constant).
fn remove_mean(x: &mut [f64], partials: &mut Vec<f64>) {
    let n = x.len();
    remove_mean_of(x, partials, |sum| sum, n);
}

/// Removes from `x`, a part of a vector of `count` entries, the whole vector's mean: the sum
/// of this part's entries (in fixed chunks) made the whole's by `total` (over ranks, the sum
/// over them; every rank calls it, with or without entries).
fn remove_mean_of(
    x: &mut [f64],
    partials: &mut Vec<f64>,
    total: impl FnOnce(f64) -> f64,
    count: usize,
) {
    if count == 0 {
        return;
    }
    x.par_chunks(CHUNK)
        .map(|c| c.iter().sum::<f64>())
        .collect_into_vec(partials);
    let mean = total(partials.iter().sum::<f64>()) / count as f64;
    x.par_iter_mut().for_each(|v| *v -= mean);
}

/// A linear system A x = b as a solver sees it.
#[derive(Debug, Clone, Copy)]
pub struct System<'a> {
    /// A, symmetric positive (semi-)definite.
    pub matrix: &'a EllMatrix,
    /// Where each row's unknown sits on the grid, for a geometric preconditioner (the
    /// multigrid); an empty layout where the rows sit on no grid.
    pub layout: &'a GridLayout,
    /// The constant vector is A's null space (a closed, filled container): b is made
    /// consistent by removing its mean and the solution has zero mean.
    pub singular: bool,
    /// The rows spread over ranks ([`spread`]); `None` on one process.
    pub partition: Option<&'a Partition>,
}

/// When an iterative solve stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveParams {
    /// Relative residual |b - A x| / |b| to reach.
    pub tolerance: f64,
    /// Iterations allowed; reaching them is a [`SolveError::NotConverged`].
    pub max_iterations: usize,
}

/// A preconditioner M^-1 of the conjugate gradient.
pub trait Preconditioner: Send + Sync {
    /// Prepares for a new system.
    fn setup(&mut self, system: &System);
    /// Whether it works on a system spread over ranks ([`spread`]): given the rows of this
    /// rank's slab, it gives back those rows, as on one process.
    fn spreads(&self) -> bool {
        false
    }
    /// z = M^-1 r, for the matrix `a` of the system last given to `setup`.
    fn apply(&mut self, a: &EllMatrix, r: &[f64], z: &mut [f64]);
}

/// Diagonal (Jacobi) preconditioner.
#[derive(Debug, Default)]
pub struct Jacobi {
    inverse_diagonal: Vec<f64>,
}

impl Preconditioner for Jacobi {
    fn spreads(&self) -> bool {
        true
    }

    fn setup(&mut self, system: &System) {
        system.matrix.diagonal(&mut self.inverse_diagonal);
        self.inverse_diagonal
            .par_iter_mut()
            .for_each(|d| *d = if *d > 0.0 { 1.0 / *d } else { 1.0 });
    }

    fn apply(&mut self, _a: &EllMatrix, r: &[f64], z: &mut [f64]) {
        z.par_iter_mut()
            .zip(r.par_iter())
            .zip(self.inverse_diagonal.par_iter())
            .for_each(|((z, r), d)| *z = r * d);
    }
}

/// Incomplete Cholesky factorisation with zero fill-in, IC(0): A ~ L L^T with L on the lower
/// triangle of A's own pattern (Meijerink & van der Vorst 1977). About half Jacobi's iterations
/// on the nodal Laplacian, but its triangular solves are sequential, so it runs on one thread.
///
/// Written here because it runs on [`EllMatrix`] rows and has to survive what a pressure matrix
/// gives it: the B-spline Laplacians are not M-matrices and the closed-container system is
/// singular, so a pivot can come out zero or negative. Such a pivot is replaced by the row's
/// own diagonal entry, which keeps M = L L^T symmetric positive definite (a weaker
/// preconditioner on that row, never a breakdown).
#[derive(Debug, Default)]
pub struct IncompleteCholesky {
    /// Start of each row's strictly-lower entries in `cols`/`vals` (CSR, `n + 1` entries).
    start: Vec<usize>,
    /// Columns of the strictly-lower entries, ascending within a row.
    cols: Vec<u32>,
    /// L's strictly-lower entries.
    vals: Vec<f64>,
    /// L's diagonal.
    diag: Vec<f64>,
    /// Forward-solve work vector.
    y: Vec<f64>,
}

impl Preconditioner for IncompleteCholesky {
    fn setup(&mut self, system: &System) {
        let a = system.matrix;
        let (n, w) = (a.n, a.width);
        self.start.clear();
        self.cols.clear();
        self.vals.clear();
        self.diag.clear();
        self.start.push(0);
        for r in 0..n {
            // the row's lower part of A, columns sorted and repeated slots summed
            let row = self.cols.len();
            let mut d = 0.0;
            for k in 0..w {
                let (j, v) = (a.cols[r * w + k] as usize, a.vals[r * w + k]);
                if j == r {
                    d += v;
                } else if j < r && v != 0.0 {
                    match self.cols[row..].iter().position(|&c| c as usize == j) {
                        Some(q) => self.vals[row + q] += v,
                        None => {
                            self.cols.push(j as u32);
                            self.vals.push(v);
                        }
                    }
                }
            }
            // insertion sort by column: a row holds at most (2K - 1)^D / 2 entries
            for i in row + 1..self.cols.len() {
                let mut q = i;
                while q > row && self.cols[q - 1] > self.cols[q] {
                    self.cols.swap(q - 1, q);
                    self.vals.swap(q - 1, q);
                    q -= 1;
                }
            }
            // L[r][k] = (A[r][k] - sum_{j<k} L[r][j] L[k][j]) / L[k][k], in column order
            for q in row..self.cols.len() {
                let k = self.cols[q] as usize;
                let (ks, ke) = (self.start[k], self.start[k + 1]);
                let mut s = self.vals[q];
                let (mut i, mut m) = (row, ks);
                while i < q && m < ke {
                    match self.cols[i].cmp(&self.cols[m]) {
                        std::cmp::Ordering::Less => i += 1,
                        std::cmp::Ordering::Greater => m += 1,
                        std::cmp::Ordering::Equal => {
                            s -= self.vals[i] * self.vals[m];
                            i += 1;
                            m += 1;
                        }
                    }
                }
                self.vals[q] = s / self.diag[k];
            }
            let pivot = d - self.vals[row..].iter().map(|l| l * l).sum::<f64>();
            let fallback = if d > 0.0 { d } else { 1.0 };
            self.diag.push(if pivot > 1e-12 * fallback {
                pivot.sqrt()
            } else {
                fallback.sqrt()
            });
            self.start.push(self.cols.len());
        }
        self.y.resize(n, 0.0);
    }

    fn apply(&mut self, _a: &EllMatrix, r: &[f64], z: &mut [f64]) {
        // L y = r
        for i in 0..r.len() {
            let mut s = r[i];
            for q in self.start[i]..self.start[i + 1] {
                s -= self.vals[q] * self.y[self.cols[q] as usize];
            }
            self.y[i] = s / self.diag[i];
        }
        // L^T z = y, by columns of L^T (rows of L) from the last
        z.copy_from_slice(&self.y);
        for i in (0..r.len()).rev() {
            z[i] /= self.diag[i];
            let zi = z[i];
            for q in self.start[i]..self.start[i + 1] {
                z[self.cols[q] as usize] -= self.vals[q] * zi;
            }
        }
    }
}

/// Outcome of a solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveStats {
    /// Iterations (0 for the direct solver).
    pub iterations: usize,
    /// Final relative residual |b - A x| / |b|.
    pub relative_residual: f64,
}

/// Why a solve failed.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum SolveError {
    /// The iteration limit was reached.
    #[error("the pressure solve did not converge: relative residual {residual:.3e} after {iterations} iterations (pressure.tolerance = {tolerance:.1e}, pressure.max_iterations = {iterations})")]
    NotConverged {
        /// Iterations done.
        iterations: usize,
        /// Relative residual reached.
        residual: f64,
        /// Relative residual asked for.
        tolerance: f64,
    },
    /// The matrix is not positive definite, or the right-hand side is not finite.
    #[error("the pressure solve broke down: {0}")]
    Breakdown(String),
}

/// Preconditioned conjugate gradient on an [`EllMatrix`] ([`CgWork`]), with its preconditioner
/// and work vectors (kept between solves).
pub struct Pcg {
    preconditioner: Box<dyn Preconditioner>,
    work: CgWork<f64>,
    /// Its work over ranks ([`spread`]), boxed: a one-process solve leaves it empty.
    spread: Box<spread::SpreadWork>,
}

/// A system's matrix as the conjugate gradient's operator, the constant removed where the
/// system is singular.
struct MatrixOperator<'a> {
    matrix: &'a EllMatrix,
    singular: bool,
}

impl Operator<f64> for MatrixOperator<'_> {
    fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        self.matrix.matvec(x, y);
    }
    fn project(&self, v: &mut [f64], partials: &mut Vec<f64>) {
        if self.singular {
            remove_mean(v, partials);
        }
    }
}

/// A [`Preconditioner`] set up for `matrix`, as the conjugate gradient applies it.
struct SetUp<'a> {
    preconditioner: &'a mut dyn Preconditioner,
    matrix: &'a EllMatrix,
}

impl Precondition<f64> for SetUp<'_> {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        self.preconditioner.apply(self.matrix, r, z);
    }
}

impl Pcg {
    /// A conjugate gradient with the given preconditioner.
    pub fn new(preconditioner: Box<dyn Preconditioner>) -> Self {
        Self {
            preconditioner,
            work: CgWork::default(),
            spread: Default::default(),
        }
    }

    /// With `setup` false the preconditioner is the one set up for the last system, which
    /// must have the same matrix.
    fn solve(
        &mut self,
        system: &System,
        b: &[f64],
        x: &mut [f64],
        params: SolveParams,
        setup: bool,
    ) -> Result<SolveStats, SolveError> {
        if let Some(partition) = system.partition.filter(|p| p.is_spread()) {
            return spread::solve(self, system, partition, (b, x), params, setup);
        }
        let a = system.matrix;
        self.work.resize(a.n);
        if setup {
            self.preconditioner.setup(system);
        }
        let b_norm = dot(b, b, &mut self.work.partials).sqrt();
        if let Some(done) = nothing_to_solve(b_norm, x) {
            return done;
        }
        // r = b - A x (x holds the initial guess)
        let r = &mut self.work.r;
        a.matvec(x, r);
        r.par_iter_mut()
            .zip(b.par_iter())
            .for_each(|(r, b)| *r = b - *r);
        let mut op = MatrixOperator {
            matrix: a,
            singular: system.singular,
        };
        let mut pre = SetUp {
            preconditioner: self.preconditioner.as_mut(),
            matrix: a,
        };
        self.work.solve(&mut op, &mut pre, x, b_norm, params)
    }
}

/// A solve that ends before it starts, from |b|: refused where b is not finite, x = 0 where
/// b = 0; `None` where there is something to solve.
fn nothing_to_solve(b_norm: f64, x: &mut [f64]) -> Option<Result<SolveStats, SolveError>> {
    if !b_norm.is_finite() {
        return Some(Err(SolveError::Breakdown(
            "the right-hand side is not finite".into(),
        )));
    }
    (b_norm == 0.0).then(|| {
        x.fill(0.0);
        Ok(SolveStats {
            iterations: 0,
            relative_residual: 0.0,
        })
    })
}

/// Sparse Cholesky (faer), the factorisation redone for every matrix.
#[derive(Default)]
pub struct Direct {
    triplets: Vec<Triplet<usize, usize, f64>>,
    partials: Vec<f64>,
    residual: Vec<f64>,
}

impl Direct {
    fn solve(
        &mut self,
        a: &EllMatrix,
        b: &[f64],
        x: &mut [f64],
        singular: bool,
    ) -> Result<SolveStats, SolveError> {
        let n = a.n;
        if n == 0 {
            return Ok(SolveStats {
                iterations: 0,
                relative_residual: 0.0,
            });
        }
        // A singular (pure Neumann) system: pin the last unknown to 0 (drop its row and
        // column), solve, then remove the mean as the conjugate gradient does.
        let m = if singular { n - 1 } else { n };
        self.triplets.clear();
        for r in 0..m {
            for k in 0..a.width {
                let c = a.cols[r * a.width + k] as usize;
                let v = a.vals[r * a.width + k];
                // lower triangle only: the factorisation reads that side
                if c <= r && v != 0.0 {
                    self.triplets.push(Triplet::new(r, c, v));
                }
            }
        }
        let mat = SparseColMat::<usize, f64>::try_new_from_triplets(m, m, &self.triplets)
            .map_err(|e| SolveError::Breakdown(format!("assembling the sparse matrix: {e:?}")))?;
        let llt = mat
            .sp_cholesky(faer::Side::Lower)
            .map_err(|e| SolveError::Breakdown(format!("Cholesky factorisation: {e:?}")))?;
        x[..m].copy_from_slice(&b[..m]);
        if singular {
            // consistent right-hand side: the constant is in A's null space
            let mean = b.iter().sum::<f64>() / n as f64;
            x[..m].iter_mut().for_each(|v| *v -= mean);
            x[m] = 0.0;
        }
        llt.solve_in_place(faer::MatMut::from_column_major_slice_mut(&mut x[..m], m, 1));
        if singular {
            remove_mean(x, &mut self.partials);
        }
        // report the true residual of the full system
        let r = &mut self.residual;
        r.resize(n, 0.0);
        a.matvec(x, r);
        let (mut num, mut den) = (0.0, 0.0);
        let mean_b = if singular {
            b.iter().sum::<f64>() / n as f64
        } else {
            0.0
        };
        for (ri, bi) in r.iter().zip(b) {
            num += (bi - mean_b - ri).powi(2);
            den += bi * bi;
        }
        let res = if den > 0.0 { (num / den).sqrt() } else { 0.0 };
        if !res.is_finite() {
            return Err(SolveError::Breakdown(
                "the direct solve gave a non-finite pressure".into(),
            ));
        }
        Ok(SolveStats {
            iterations: 0,
            relative_residual: res,
        })
    }
}

/// The pressure solver chosen in the deck.
pub enum LinearSolver {
    /// Preconditioned conjugate gradient.
    Pcg(Pcg),
    /// Sparse Cholesky.
    Direct(Direct),
}

impl LinearSolver {
    /// Whether it solves a system spread over ranks ([`spread`]): the conjugate gradient
    /// with Jacobi or the multigrid.
    pub fn spreads(&self) -> bool {
        match self {
            LinearSolver::Pcg(pcg) => pcg.preconditioner.spreads(),
            LinearSolver::Direct(_) => false,
        }
    }

    /// Solves A x = b to the relative residual `params.tolerance`; x holds the initial guess of
    /// the iterative solver.
    pub fn solve(
        &mut self,
        system: &System,
        b: &[f64],
        x: &mut [f64],
        params: SolveParams,
    ) -> Result<SolveStats, SolveError> {
        self.solve_with(system, b, x, params, true)
    }

    /// [`LinearSolver::solve`] for the matrix of the last solve, with a new right-hand side:
    /// the preconditioner is not set up again (the direct solver factorises again).
    pub fn solve_again(
        &mut self,
        system: &System,
        b: &[f64],
        x: &mut [f64],
        params: SolveParams,
    ) -> Result<SolveStats, SolveError> {
        self.solve_with(system, b, x, params, false)
    }

    /// Both solves: `setup` false keeps the preconditioner of the last matrix.
    fn solve_with(
        &mut self,
        system: &System,
        b: &[f64],
        x: &mut [f64],
        params: SolveParams,
        setup: bool,
    ) -> Result<SolveStats, SolveError> {
        match self {
            LinearSolver::Pcg(s) => s.solve(system, b, x, params, setup),
            LinearSolver::Direct(_) if system.partition.is_some_and(|p| p.is_spread()) => {
                Err(SolveError::Breakdown(
                    "the direct solver cannot be spread over ranks (the conjugate gradient \
                     can)"
                        .into(),
                ))
            }
            LinearSolver::Direct(s) => s.solve(system.matrix, b, x, system.singular),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `a` as a system on no grid.
    fn system(a: &EllMatrix, singular: bool) -> System<'_> {
        static NO_GRID: GridLayout = GridLayout::EMPTY;
        System {
            matrix: a,
            layout: &NO_GRID,
            singular,
            partition: None,
        }
    }

    fn params(tolerance: f64, max_iterations: usize) -> SolveParams {
        SolveParams {
            tolerance,
            max_iterations,
        }
    }

    /// 1D Laplacian with `n` unknowns; Dirichlet at both ends unless `neumann`.
    fn laplacian(n: usize, neumann: bool) -> EllMatrix {
        let mut a = EllMatrix::default();
        a.reshape(n, 3);
        for r in 0..n {
            let mut diag = 2.0;
            if neumann && (r == 0 || r == n - 1) {
                diag = 1.0;
            }
            let slots = [(r.wrapping_sub(1), -1.0), (r, diag), (r + 1, -1.0)];
            for (k, (c, v)) in slots.into_iter().enumerate() {
                let ok = c < n;
                a.cols[r * 3 + k] = if ok { c as u32 } else { r as u32 };
                a.vals[r * 3 + k] = if ok { v } else { 0.0 };
            }
        }
        a
    }

    fn residual(a: &EllMatrix, b: &[f64], x: &[f64]) -> f64 {
        let mut ax = vec![0.0; a.n];
        a.matvec(x, &mut ax);
        let num: f64 = ax.iter().zip(b).map(|(p, q)| (p - q).powi(2)).sum();
        let den: f64 = b.iter().map(|q| q * q).sum();
        (num / den).sqrt()
    }

    #[test]
    fn pcg_and_direct_agree_on_a_dirichlet_laplacian() {
        let n = 200;
        let a = laplacian(n, false);
        let b: Vec<f64> = (0..n).map(|i| ((i * 7) % 13) as f64 - 6.0).collect();
        let mut x1 = vec![0.0; n];
        let mut pcg = LinearSolver::Pcg(Pcg::new(Box::new(Jacobi::default())));
        let s = pcg
            .solve(&system(&a, false), &b, &mut x1, params(1e-12, 1000))
            .unwrap();
        assert!(s.iterations > 0 && s.relative_residual <= 1e-12);
        assert!(residual(&a, &b, &x1) <= 1e-11);
        let mut x2 = vec![0.0; n];
        let mut direct = LinearSolver::Direct(Direct::default());
        direct
            .solve(&system(&a, false), &b, &mut x2, params(1e-12, 0))
            .unwrap();
        assert!(residual(&a, &b, &x2) <= 1e-12);
        let scale = x2.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (p, q) in x1.iter().zip(&x2) {
            assert!((p - q).abs() <= 1e-9 * scale, "{p} {q}");
        }
    }

    #[test]
    fn singular_neumann_system_is_solved_up_to_the_constant() {
        let n = 100;
        let a = laplacian(n, true);
        // an inconsistent right-hand side: its mean is removed
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).sin() + 0.3).collect();
        let mean_b = b.iter().sum::<f64>() / n as f64;
        let consistent: Vec<f64> = b.iter().map(|v| v - mean_b).collect();
        for mut solver in [
            LinearSolver::Pcg(Pcg::new(Box::new(Jacobi::default()))),
            LinearSolver::Pcg(Pcg::new(Box::<IncompleteCholesky>::default())),
            LinearSolver::Direct(Direct::default()),
        ] {
            let mut x = vec![1.0; n];
            solver
                .solve(&system(&a, true), &b, &mut x, params(1e-12, 1000))
                .unwrap();
            assert!(residual(&a, &consistent, &x) <= 1e-10);
            let mean = x.iter().sum::<f64>() / n as f64;
            assert!(mean.abs() <= 1e-12 * x.iter().fold(0.0f64, |m, v| m.max(v.abs())));
        }
    }

    /// 2D five-point Laplacian on an m x m grid, Dirichlet outside, rows numbered in
    /// row-major order; each row's slots in a scrambled order with a repeated diagonal slot, as
    /// the assembly may leave them.
    fn laplacian_2d(m: usize) -> EllMatrix {
        let mut a = EllMatrix::default();
        a.reshape(m * m, 6);
        for r in 0..m * m {
            let (i, j) = (r % m, r / m);
            let mut slots = vec![(r, 3.0), (r, 1.0)];
            if i > 0 {
                slots.push((r - 1, -1.0));
            }
            if i + 1 < m {
                slots.push((r + 1, -1.0));
            }
            if j > 0 {
                slots.push((r - m, -1.0));
            }
            if j + 1 < m {
                slots.push((r + m, -1.0));
            }
            let len = slots.len();
            slots.rotate_left(r % len);
            slots.resize(6, (r, 0.0));
            for (k, (c, v)) in slots.into_iter().enumerate() {
                a.cols[r * 6 + k] = c as u32;
                a.vals[r * 6 + k] = v;
            }
        }
        a
    }

    #[test]
    fn incomplete_cholesky_is_exact_on_a_tridiagonal_matrix() {
        // no fill-in: IC(0) is the full Cholesky factor, so one application solves the system
        let n = 50;
        let a = laplacian(n, false);
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).cos()).collect();
        let mut ic = IncompleteCholesky::default();
        ic.setup(&system(&a, false));
        let mut x = vec![0.0; n];
        ic.apply(&a, &b, &mut x);
        assert!(residual(&a, &b, &x) <= 1e-13, "{}", residual(&a, &b, &x));
    }

    #[test]
    fn incomplete_cholesky_halves_the_iterations_on_a_2d_laplacian() {
        let a = laplacian_2d(40);
        let b: Vec<f64> = (0..a.n).map(|i| ((i * 7) % 13) as f64 - 6.0).collect();
        let mut iterations = [0; 2];
        for (k, pre) in [
            Box::new(Jacobi::default()) as Box<dyn Preconditioner>,
            Box::<IncompleteCholesky>::default(),
        ]
        .into_iter()
        .enumerate()
        {
            let mut x = vec![0.0; a.n];
            let s = LinearSolver::Pcg(Pcg::new(pre))
                .solve(&system(&a, false), &b, &mut x, params(1e-10, 1000))
                .unwrap();
            assert!(residual(&a, &b, &x) <= 1e-9);
            iterations[k] = s.iterations;
        }
        // IC(0) on the five-point Laplacian: about half the condition number's square root
        assert!(
            2 * iterations[1] <= iterations[0] + 2,
            "jacobi {} ic0 {}",
            iterations[0],
            iterations[1]
        );
    }

    #[test]
    fn iteration_limit_is_an_error() {
        let a = laplacian(500, false);
        let b = vec![1.0; 500];
        let mut x = vec![0.0; 500];
        let mut pcg = LinearSolver::Pcg(Pcg::new(Box::new(Jacobi::default())));
        let e = pcg
            .solve(&system(&a, false), &b, &mut x, params(1e-12, 10))
            .unwrap_err();
        assert!(matches!(e, SolveError::NotConverged { iterations: 10, .. }));
    }
}
