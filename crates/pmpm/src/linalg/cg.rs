//! The preconditioned conjugate gradient, once for every symmetric positive definite solve of
//! pmpm: the pressure and the density correction (scalars at nodes or cells, an [`EllMatrix`]
//! and its preconditioner) and the implicit viscosity (a vector per node, a matrix-free
//! operator and a diagonal preconditioner).
//!
//! Written here rather than taken from a crate: the solves need their reductions in fixed
//! chunks summed in order (the same bits for any thread count), their work vectors kept
//! between steps (no allocation in the step loop), an operator that is not a stored matrix,
//! and the null space of a closed container's Laplacian removed at each iteration.
//!
//! Algorithm: Saad, "Iterative Methods for Sparse Linear Systems" (2003), algorithm 9.1.
//!
//! [`EllMatrix`]: super::EllMatrix

use super::{SolveError, SolveParams, SolveStats};
use crate::pages::store;
use rayon::prelude::*;

/// An entry of the vectors the conjugate gradient works on: a number, or a small vector of
/// them (a node's velocity).
pub trait Entry: Copy + Send + Sync + bytemuck::NoUninit {
    /// The zero entry.
    const ZERO: Self;
    /// Entries per chunk of the reductions, summed in order.
    const CHUNK: usize;
    /// The inner product of two entries.
    fn dot(&self, other: &Self) -> f64;
    /// self + a x.
    fn add_scaled(self, a: f64, x: Self) -> Self;
}

impl Entry for f64 {
    const ZERO: f64 = 0.0;
    const CHUNK: usize = super::CHUNK;
    fn dot(&self, other: &f64) -> f64 {
        self * other
    }
    fn add_scaled(self, a: f64, x: f64) -> f64 {
        self + a * x
    }
}

impl<const D: usize> Entry for nalgebra::SVector<f64, D> {
    const ZERO: Self = Self::from_array_storage(nalgebra::ArrayStorage([[0.0; D]; 1]));
    const CHUNK: usize = 4096;
    fn dot(&self, other: &Self) -> f64 {
        nalgebra::Matrix::dot(self, other)
    }
    fn add_scaled(self, a: f64, x: Self) -> Self {
        self + x * a
    }
}

/// A symmetric positive (semi-)definite operator A.
pub trait Operator<T> {
    /// y = A x.
    fn apply(&mut self, x: &[T], y: &mut [T]);
    /// Removes A's null space from `v` (the constant of a closed container's Laplacian);
    /// nothing where A is definite.
    fn project(&self, _v: &mut [T], _partials: &mut Vec<f64>) {}
    /// The inner product of two vectors of the solve (over ranks, of their own rows summed
    /// over the ranks).
    fn dot(&self, a: &[T], b: &[T], partials: &mut Vec<f64>) -> f64
    where
        T: Entry,
    {
        dot(a, b, partials)
    }
}

/// A preconditioner M^-1 of the conjugate gradient.
pub trait Precondition<T> {
    /// z = M^-1 r.
    fn apply(&mut self, r: &[T], z: &mut [T]);
}

/// The conjugate gradient's work vectors, kept between solves.
#[derive(Debug)]
pub struct CgWork<T> {
    /// The residual b - A x.
    pub r: Vec<T>,
    z: Vec<T>,
    p: Vec<T>,
    q: Vec<T>,
    /// The reductions' partial sums.
    pub partials: Vec<f64>,
}

impl<T> Default for CgWork<T> {
    fn default() -> Self {
        Self {
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            q: Vec::new(),
            partials: Vec::new(),
        }
    }
}

impl<T: Entry> CgWork<T> {
    /// Work vectors of `n` entries (what they held is overwritten by the next solve).
    pub fn resize(&mut self, n: usize) {
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            v.resize(n, T::ZERO);
        }
    }

    /// Work vectors of `n` entries, one a node ([`crate::pages::fit`]): a vector the length of
    /// the grid commits memory only where its entries leave zero, and the loops below write
    /// an entry only where it changes, so the nodes no material reaches (the box's air, the
    /// other ranks' slabs) stay uncommitted.
    pub fn fit_nodes(&mut self, n: usize)
    where
        T: bytemuck::Zeroable,
    {
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            crate::pages::fit(v, n);
        }
    }

    /// Solves A x = b to |r| <= tolerance * `b_norm`, `self.r` holding b - A x for the
    /// initial x on entry. Stops with [`SolveError::NotConverged`] after
    /// `params.max_iterations`, and with [`SolveError::Breakdown`] on a residual that is not
    /// finite or a direction of non-positive curvature.
    pub fn solve(
        &mut self,
        a: &mut impl Operator<T>,
        m: &mut impl Precondition<T>,
        x: &mut [T],
        b_norm: f64,
        params: SolveParams,
    ) -> Result<SolveStats, SolveError> {
        let Self {
            r,
            z,
            p,
            q,
            partials,
        } = self;
        let (tol, max_iterations) = (params.tolerance, params.max_iterations);
        a.project(r, partials);
        let mut r_norm = a.dot(r, r, partials).sqrt();
        if !r_norm.is_finite() {
            return Err(SolveError::Breakdown(
                "the right-hand side is not finite".into(),
            ));
        }
        let mut res = if r_norm == 0.0 { 0.0 } else { r_norm / b_norm };
        if res <= tol {
            a.project(x, partials);
            return Ok(SolveStats {
                iterations: 0,
                relative_residual: res,
            });
        }
        m.apply(r, z);
        a.project(z, partials);
        p.par_iter_mut()
            .zip(z.par_iter())
            .for_each(|(p, z)| store(p, *z));
        let mut rz = a.dot(r, z, partials);
        for it in 1..=max_iterations {
            a.apply(p, q);
            let pq = a.dot(p, q, partials);
            if pq <= 0.0 || !pq.is_finite() {
                return Err(SolveError::Breakdown(format!(
                    "p.Ap = {pq:.3e} at iteration {it}: the operator is not positive definite"
                )));
            }
            let alpha = rz / pq;
            x.par_iter_mut()
                .zip(r.par_iter_mut())
                .zip(p.par_iter().zip(q.par_iter()))
                .for_each(|((x, r), (p, q))| {
                    store(x, x.add_scaled(alpha, *p));
                    store(r, r.add_scaled(-alpha, *q));
                });
            a.project(r, partials);
            r_norm = a.dot(r, r, partials).sqrt();
            if !r_norm.is_finite() {
                return Err(SolveError::Breakdown(format!(
                    "the residual is not finite at iteration {it}"
                )));
            }
            res = r_norm / b_norm;
            if res <= tol {
                a.project(x, partials);
                return Ok(SolveStats {
                    iterations: it,
                    relative_residual: res,
                });
            }
            m.apply(r, z);
            a.project(z, partials);
            let rz_new = a.dot(r, z, partials);
            let beta = rz_new / rz;
            rz = rz_new;
            p.par_iter_mut()
                .zip(z.par_iter())
                .for_each(|(p, z)| store(p, z.add_scaled(beta, *p)));
        }
        Err(SolveError::NotConverged {
            iterations: max_iterations,
            residual: res,
            tolerance: tol,
        })
    }
}

/// sum_i a_i . b_i in fixed chunks summed in order: the same bits for any thread count.
pub fn dot<T: Entry>(a: &[T], b: &[T], partials: &mut Vec<f64>) -> f64 {
    a.par_chunks(T::CHUNK)
        .zip(b.par_chunks(T::CHUNK))
        .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x.dot(y)).sum::<f64>())
        .collect_into_vec(partials);
    partials.iter().sum()
}
