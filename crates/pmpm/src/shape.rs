//! Shape functions N_i(x) of the background grid and their gradients (docs/method.md).
//!
//! Every kind here is a tensor product of a 1D kernel, so a particle's stencil is K nodes per
//! direction (K = 2 linear, 3 GIMP and quadratic B-spline, 4 cubic B-spline) and the weights of
//! its K^D nodes are products of 1D weights. The grid carries two ghost layers of nodes beyond
//! each face ([`PAD`]), so the wider kernels keep their partition of unity up to the walls.
use nalgebra::SVector;

use serde::{Deserialize, Serialize};

/// Shape functions of the background grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ShapeFunction {
    /// Multilinear (the paper's).
    #[default]
    Linear,
    /// Generalised interpolation material point (uGIMP), particle domain fixed at its start size.
    Gimp,
    /// Quadratic B-spline.
    Bspline2,
    /// Cubic B-spline.
    Bspline3,
}

/// Ghost node layers beyond each face of the grid.
pub const PAD: usize = 2;
/// Largest stencil width per direction.
pub const MAX_K: usize = 4;

/// floor() without the libm call (x86-64 has no rounding instruction before SSE4.1), exact for
/// |x| < 2^52; the stencils call it D times per particle per transfer.
#[inline]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// uGIMP kernel value and derivative d/dr at r = x_p - x_i (in cells), half-width `lp`.
#[inline]
fn gimp(r: f64, lp: f64) -> (f64, f64) {
    let (a, s) = (r.abs(), r.signum());
    if a < lp {
        (1.0 - (r * r + lp * lp) / (2.0 * lp), -r / lp)
    } else if a < 1.0 - lp {
        (1.0 - a, -s)
    } else if a < 1.0 + lp {
        let t = 1.0 + lp - a;
        (t * t / (4.0 * lp), -s * t / (2.0 * lp))
    } else {
        (0.0, 0.0)
    }
}

/// Cubic B-spline value and derivative d/dr at r = x_p - x_i (in cells).
#[inline]
fn cubic_bspline(r: f64) -> (f64, f64) {
    let (a, s) = (r.abs(), r.signum());
    if a < 1.0 {
        (0.5 * a * a * a - a * a + 2.0 / 3.0, 1.5 * r * a - 2.0 * r)
    } else if a < 2.0 {
        let t = 2.0 - a;
        (t * t * t / 6.0, -0.5 * s * t * t)
    } else {
        (0.0, 0.0)
    }
}

/// Runs `$body` with `$S` a `const u8` that names the shape function `$shape` (see
/// [`ShapeFunction::from_code`]). A transfer written generic over `const S: u8` and dispatched
/// this way once per call, rather than once per particle and axis, gets its kernel's `match`
/// folded away and its stencil loops unrolled for the width: the per-particle kernels are the
/// hot path of every transfer.
#[macro_export]
macro_rules! with_shape {
    ($shape:expr, $S:ident => $body:expr) => {
        match $shape {
            $crate::shape::ShapeFunction::Linear => {
                const $S: u8 = 0;
                $body
            }
            $crate::shape::ShapeFunction::Gimp => {
                const $S: u8 = 1;
                $body
            }
            $crate::shape::ShapeFunction::Bspline2 => {
                const $S: u8 = 2;
                $body
            }
            $crate::shape::ShapeFunction::Bspline3 => {
                const $S: u8 = 3;
                $body
            }
        }
    };
}

/// One direction of a particle's stencil.
#[derive(Debug, Clone, Copy, Default)]
pub struct Kernel1 {
    /// Index (in padded node numbering) of the first node.
    pub base: usize,
    /// Weights of the K nodes.
    pub w: [f64; MAX_K],
    /// Derivatives dN/dx_p of the K nodes (1/m).
    pub dw: [f64; MAX_K],
    /// APIC coefficients w (x_i - x_p) / D_p (1/m); D_p = sum w (x_i - x_p)^2.
    pub aw: [f64; MAX_K],
}

impl ShapeFunction {
    /// The kind numbered `code` by [`with_shape!`](crate::with_shape).
    #[inline(always)]
    pub const fn from_code(code: u8) -> Self {
        match code {
            0 => ShapeFunction::Linear,
            1 => ShapeFunction::Gimp,
            2 => ShapeFunction::Bspline2,
            _ => ShapeFunction::Bspline3,
        }
    }

    /// Nodes per direction in a stencil.
    #[inline(always)]
    pub fn width(self) -> usize {
        match self {
            ShapeFunction::Linear => 2,
            ShapeFunction::Gimp | ShapeFunction::Bspline2 => 3,
            ShapeFunction::Bspline3 => 4,
        }
    }

    /// The weight N of padded node `node` alone, for a particle at `xi` (in cells from the grid
    /// origin) with GIMP half-width `lp`: what `kernel_1d` gives for that node (0 outside the
    /// stencil), without the other nodes, derivatives and APIC terms. For gathers that need one
    /// node's weight per particle.
    #[inline]
    pub fn weight_1d(self, xi: f64, lp: f64, node: usize) -> f64 {
        let first: f64 = match self {
            ShapeFunction::Linear => floor(xi),
            ShapeFunction::Gimp => floor(xi - 1.0 - lp) + 1.0,
            ShapeFunction::Bspline2 => floor(xi - 0.5),
            ShapeFunction::Bspline3 => floor(xi) - 1.0,
        };
        let padded = (first + PAD as f64).max(0.0);
        let base = padded as i64 as usize;
        let o = node.wrapping_sub(base);
        if o >= self.width() {
            return 0.0;
        }
        let first = padded - PAD as f64;
        // the same arithmetic as kernel_1d, so that both give the same bits
        match self {
            ShapeFunction::Linear => {
                let f = xi - first;
                if o == 0 {
                    1.0 - f
                } else {
                    f
                }
            }
            ShapeFunction::Bspline2 => {
                let f = xi - first;
                match o {
                    0 => {
                        let a = 1.5 - f;
                        0.5 * a * a
                    }
                    1 => 0.75 - (f - 1.0) * (f - 1.0),
                    _ => {
                        let b = f - 0.5;
                        0.5 * b * b
                    }
                }
            }
            ShapeFunction::Gimp => gimp(xi - (first + o as f64), lp).0,
            ShapeFunction::Bspline3 => cubic_bspline(xi - (first + o as f64)).0,
        }
    }

    /// 1D kernel of a particle at `xi` (in cells from the grid origin), cell size `h`, GIMP
    /// half-width `lp` (in cells; ignored by the other kinds).
    #[inline(always)]
    pub fn kernel_1d(self, xi: f64, h: f64, lp: f64) -> Kernel1 {
        let mut k = Kernel1::default();
        let first: f64 = match self {
            ShapeFunction::Linear => floor(xi),
            ShapeFunction::Gimp => floor(xi - 1.0 - lp) + 1.0,
            ShapeFunction::Bspline2 => floor(xi - 0.5),
            ShapeFunction::Bspline3 => floor(xi) - 1.0,
        };
        // first >= -PAD for any xi >= 0 (validated positions), so the cast is exact; the
        // signed cast and the float kept for `first` spare the unsigned round trip
        // (usize -> f64 takes several instructions on x86-64), with the same bits.
        let padded = (first + PAD as f64).max(0.0);
        k.base = padded as i64 as usize;
        let first = padded - PAD as f64;
        let inv_h = 1.0 / h;
        match self {
            ShapeFunction::Linear => {
                // The one kernel with a kink at the nodes: take the derivative of the cell the
                // particle is in, so that the gradients sum to zero on a node too. For
                // multilinear kernels w (x_i - x_p) / D is exactly dN/dx.
                let f = xi - first;
                k.w[0] = 1.0 - f;
                k.w[1] = f;
                k.dw[0] = -inv_h;
                k.dw[1] = inv_h;
                k.aw = k.dw;
            }
            ShapeFunction::Bspline2 => {
                let f = xi - first; // in [0.5, 1.5)
                let (a, b) = (1.5 - f, f - 0.5);
                k.w[0] = 0.5 * a * a;
                k.w[1] = 0.75 - (f - 1.0) * (f - 1.0);
                k.w[2] = 0.5 * b * b;
                k.dw[0] = -a * inv_h;
                k.dw[1] = -2.0 * (f - 1.0) * inv_h;
                k.dw[2] = b * inv_h;
                // D = h^2 / 4 for the quadratic B-spline
                for o in 0..3 {
                    k.aw[o] = -4.0 * k.w[o] * (f - o as f64) * inv_h;
                }
            }
            ShapeFunction::Gimp | ShapeFunction::Bspline3 => {
                let mut second_moment = 0.0;
                for o in 0..self.width() {
                    // r = x_p - x_i in cells
                    let r = xi - (first + o as f64);
                    let (w, dwdr) = if self == ShapeFunction::Gimp {
                        gimp(r, lp)
                    } else {
                        cubic_bspline(r)
                    };
                    k.w[o] = w;
                    k.dw[o] = dwdr * inv_h;
                    second_moment += w * r * r;
                }
                for o in 0..self.width() {
                    let r = xi - (first + o as f64);
                    // where D vanishes (cannot happen for these kernels) fall back to dN/dx
                    k.aw[o] = if second_moment > 1e-10 {
                        -k.w[o] * r * inv_h / second_moment
                    } else {
                        k.dw[o]
                    };
                }
            }
        }
        k
    }
}

/// A particle's full stencil: K^D nodes, built from D 1D kernels.
#[derive(Debug, Clone, Copy)]
pub struct Stencil<const D: usize> {
    /// Per-direction kernels.
    pub k: [Kernel1; D],
    /// Nodes per direction.
    pub width: usize,
}

/// One node of a stencil as seen by a particle.
#[derive(Debug, Clone, Copy)]
pub struct NodeWeight<const D: usize> {
    /// Padded multi-index of the node.
    pub node: [usize; D],
    /// N_ip
    pub n: f64,
    /// G_ip = grad N_i(x_p)
    pub grad: SVector<f64, D>,
    /// APIC coefficient vector: C_p = sum_i v_i (x) a_ip.
    pub apic: SVector<f64, D>,
}

impl<const D: usize> Stencil<D> {
    /// Stencil of a particle at `x_cells` (position in cells from the grid origin).
    #[inline(always)]
    pub fn new(kind: ShapeFunction, x_cells: &SVector<f64, D>, h: f64, lp: f64) -> Self {
        Self {
            k: std::array::from_fn(|d| kind.kernel_1d(x_cells[d], h, lp)),
            width: kind.width(),
        }
    }

    /// N_ip and G_ip of the node at offset `o` (per direction, 0..K) from the stencil's base.
    #[inline]
    pub fn at(&self, o: &[usize; D]) -> (f64, SVector<f64, D>) {
        let mut n = 1.0;
        let mut grad = SVector::<f64, D>::zeros();
        for d in 0..D {
            n *= self.k[d].w[o[d]];
            let mut g = self.k[d].dw[o[d]];
            for e in 0..D {
                if e != d {
                    g *= self.k[e].w[o[e]];
                }
            }
            grad[d] = g;
        }
        (n, grad)
    }

    /// Offset of padded node `node` from the stencil's base, if the stencil holds it.
    #[inline]
    pub fn offset_of(&self, node: &[usize; D]) -> Option<[usize; D]> {
        let mut o = [0usize; D];
        for d in 0..D {
            let r = node[d].wrapping_sub(self.k[d].base);
            if r >= self.width {
                return None;
            }
            o[d] = r;
        }
        Some(o)
    }

    /// Calls `f` for each of the K^D nodes of the stencil, in a fixed order.
    #[inline(always)]
    pub fn for_each(&self, mut f: impl FnMut(NodeWeight<D>)) {
        let kw = self.width;
        let total = kw.pow(D as u32);
        let mut o = [0usize; D];
        for _ in 0..total {
            let mut n = 1.0;
            let mut node = [0usize; D];
            for d in 0..D {
                n *= self.k[d].w[o[d]];
                node[d] = self.k[d].base + o[d];
            }
            let mut grad = SVector::<f64, D>::zeros();
            let mut apic = SVector::<f64, D>::zeros();
            for d in 0..D {
                let mut g = self.k[d].dw[o[d]];
                let mut a = self.k[d].aw[o[d]];
                for e in 0..D {
                    if e != d {
                        g *= self.k[e].w[o[e]];
                        a *= self.k[e].w[o[e]];
                    }
                }
                grad[d] = g;
                apic[d] = a;
            }
            f(NodeWeight {
                node,
                n,
                grad,
                apic,
            });
            // odometer
            for d in 0..D {
                o[d] += 1;
                if o[d] < kw {
                    break;
                }
                o[d] = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KINDS: [ShapeFunction; 4] = [
        ShapeFunction::Linear,
        ShapeFunction::Gimp,
        ShapeFunction::Bspline2,
        ShapeFunction::Bspline3,
    ];

    /// Partition of unity and zero gradient sum at many points in [0, n] cells, incl. the faces.
    fn check_partition<const D: usize>(kind: ShapeFunction) {
        let h = 0.1;
        let n = 5.0;
        let steps = 23;
        let total = (steps + 1usize).pow(D as u32);
        for idx in 0..total {
            let mut x = SVector::<f64, D>::zeros();
            let mut r = idx;
            for d in 0..D {
                x[d] = n * (r % (steps + 1)) as f64 / steps as f64;
                r /= steps + 1;
            }
            let s = Stencil::<D>::new(kind, &x, h, 0.25);
            let mut sum = 0.0;
            let mut gsum = SVector::<f64, D>::zeros();
            let mut first_moment = SVector::<f64, D>::zeros();
            s.for_each(|nw| {
                sum += nw.n;
                gsum += nw.grad;
                for d in 0..D {
                    first_moment[d] += nw.n * (nw.node[d] as f64 - PAD as f64 - x[d]);
                }
                assert!(nw.n >= -1e-15, "{kind:?} negative weight at {x:?}");
            });
            assert!((sum - 1.0).abs() < 1e-13, "{kind:?} sum {sum} at {x:?}");
            assert!(
                gsum.norm() * h < 1e-12,
                "{kind:?} grad sum {gsum:?} at {x:?}"
            );
            assert!(
                first_moment.norm() < 1e-12,
                "{kind:?} linear completeness at {x:?}"
            );
        }
    }

    #[test]
    fn partition_of_unity_2d_and_3d() {
        for kind in KINDS {
            check_partition::<2>(kind);
            check_partition::<3>(kind);
        }
    }

    /// Gradients agree with central finite differences of the weights.
    #[test]
    fn gradients_match_finite_differences() {
        let h = 0.2;
        for kind in KINDS {
            for i in 0..200 {
                let xi = 0.013 + 3.0 * i as f64 / 200.0;
                let eps = 1e-6;
                let k = kind.kernel_1d(xi, h, 0.25);
                let kp = kind.kernel_1d(xi + eps, h, 0.25);
                let km = kind.kernel_1d(xi - eps, h, 0.25);
                if kp.base != k.base || km.base != k.base {
                    continue;
                }
                for o in 0..kind.width() {
                    let fd = (kp.w[o] - km.w[o]) / (2.0 * eps * h);
                    assert!(
                        (fd - k.dw[o]).abs() < 1e-5,
                        "{kind:?} xi {xi} node {o}: fd {fd} vs {}",
                        k.dw[o]
                    );
                }
            }
        }
    }

    #[test]
    fn linear_apic_coefficient_is_the_gradient() {
        let k = ShapeFunction::Linear.kernel_1d(2.3, 0.5, 0.0);
        for o in 0..2 {
            assert!((k.aw[o] - k.dw[o]).abs() < 1e-12);
        }
    }
}
