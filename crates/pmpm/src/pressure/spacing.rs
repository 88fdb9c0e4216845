//! Sub-cell spacing: particles closer than their rest spacing push each other apart
//! (`density_correction = "particles"`, with the packing of [`super::density`]).
//!
//! The packing's solve measures the density on the grid's nodes, so it cannot see how the
//! particles sit inside a cell. A flow that stretches one way and squeezes the other (a
//! collapsing column) deforms the particles' lattice with it: at J = 1 they end up in lines a
//! cell or two apart along x, a quarter of their rest spacing apart along y, and a hat a cell
//! wide reads full and empty columns by turns. Every particle of such a line sits in the same
//! place of the same cells, so any displacement the nodes give (a gradient, an average)
//! moves the line whole and never opens it. Particle shifting in SPH acts between the
//! particles themselves (Xu, Stansby & Laurence 2009; Lind et al. 2012): here, each pair
//! closer than their mean rest spacing s = (s_p + s_q) / 2, s_p = (J_p V0_p)^(1/D), pushes
//! both apart,
//!
//! ```text
//! dx_p = (a / 2) sum_q s (1 - r_pq / s)^2 (x_p - x_q) / r_pq,   r_pq < s,
//! ```
//!
//! a the strength (the correction's rate: the pace of the flow). A regular lattice, whose
//! nearest neighbours are exactly s apart, is not moved (a pool at rest stays as it is), and
//! the push ends at s, so it never draws particles together or spreads a free surface. A line
//! is unstable under it: a particle slightly off the line is pushed further off by its close
//! neighbours along it, and the line opens into the gaps beside it. Pairs are summed both
//! ways with the same weight, so before the bounds on a move they add no net displacement. The neighbours are found
//! through the cell bins (the particles of the 3^D cells around a particle's own), which
//! reach every neighbour closer than s wherever s <= h (a particle per cell or more). The
//! packing pushes with the linear hat only ([`super::density`]). Written
//! by hand: a neighbour sum over the grid's own bins, the heart of the correction.

use crate::grid::{CellBins, GridGeometry, Vector};
use rayon::prelude::*;

/// Largest push of a particle in one correction, as a share of its rest spacing.
const MAX_PUSH: f64 = 0.25;

/// The pushes and the particles' rest spacings they come from, reused from step to step.
#[derive(Default)]
pub struct Spacing<const D: usize> {
    /// Per particle, s_p = (J_p V0_p)^(1/D).
    spacing: Vec<f64>,
    /// Per particle, its push dx_p.
    pub push: Vec<Vector<D>>,
}

impl<const D: usize> Spacing<D> {
    /// No push for any of `n` particles.
    pub fn clear(&mut self, n: usize) {
        self.push.clear();
        self.push.resize(n, Vector::<D>::zeros());
    }

    /// The push of every particle from the pairs closer than their rest spacing, at strength
    /// `a`: `x` the positions (sorted into `bins` where they are now), `v0` and `jac` each
    /// particle's V0 and J.
    pub fn pushes(
        &mut self,
        geo: &GridGeometry<D>,
        bins: &CellBins,
        (x, v0, jac): (&[Vector<D>], &[f64], &[f64]),
        a: f64,
    ) {
        let n = x.len();
        self.spacing.resize(n, 0.0);
        self.push.resize(n, Vector::<D>::zeros());
        (self.spacing.par_iter_mut(), v0.par_iter(), jac.par_iter())
            .into_par_iter()
            .for_each(|(s, &v0, &j)| {
                let v = v0 * j;
                *s = match D {
                    1 => v,
                    2 => v.sqrt(),
                    _ => v.cbrt(),
                };
            });
        let spacing = &self.spacing;
        // the reach: no pair is farther apart than the largest spacing
        let reach = spacing.par_iter().copied().reduce(|| 0.0, f64::max);
        let period: [f64; D] = std::array::from_fn(|d| geo.cells[d] as f64 * geo.h);
        self.push.par_iter_mut().enumerate().for_each(|(p, push)| {
            let sp = spacing[p];
            let mut sum = Vector::<D>::zeros();
            let cell = bins.cell_of[p] as usize;
            for_each_neighbour_cell(geo, cell, &x[p], reach, |c| {
                for &q in bins.particles(c) {
                    let q = q as usize;
                    if q == p {
                        continue;
                    }
                    let mut dx = x[p] - x[q];
                    for d in (0..D).filter(|&d| geo.periodic[d]) {
                        dx[d] -= period[d] * (dx[d] / period[d]).round();
                    }
                    let s = 0.5 * (sp + spacing[q]);
                    let r2 = dx.norm_squared();
                    if r2 < s * s && r2 > 0.0 {
                        let r = r2.sqrt();
                        let w = 1.0 - r / s;
                        sum += dx * (s * w * w / r);
                    }
                }
            });
            sum *= 0.5 * a;
            let limit = MAX_PUSH * sp;
            let norm = sum.norm();
            if norm > limit {
                sum *= limit / norm;
            }
            *push = sum;
        });
    }
}

/// Calls `f` with each distinct flat cell around flat cell `c` (the cell of the point `x`)
/// that a point within `reach` of `x` can lie in: the cell itself and, along each direction,
/// the neighbour on each side whose face is closer than `reach` (at most the 3^D block),
/// wrapped across the periodic directions.
fn for_each_neighbour_cell<const D: usize>(
    geo: &GridGeometry<D>,
    c: usize,
    x: &Vector<D>,
    reach: f64,
    mut f: impl FnMut(usize),
) {
    let pad = crate::shape::PAD;
    let at = geo.multi(c);
    let xc = geo.to_cells(x);
    let reach = reach / geo.h;
    // per direction the distinct cell indices to visit (a periodic direction of fewer than
    // three cells repeats one)
    let mut axis = [[0usize; 3]; D];
    let mut count = [0usize; D];
    for d in 0..D {
        let frac = xc[d] - (at[d] as f64 - pad as f64);
        for o in 0..3 {
            let near = match o {
                0 => frac < reach,
                1 => true,
                _ => 1.0 - frac < reach,
            };
            let Some(i) = (at[d] + o).checked_sub(1).filter(|_| near) else {
                continue;
            };
            let i = if geo.periodic[d] {
                let n = geo.cells[d] as isize;
                pad + (i as isize - pad as isize).rem_euclid(n) as usize
            } else if i + 1 < geo.nodes[d] {
                i
            } else {
                continue;
            };
            if !axis[d][..count[d]].contains(&i) {
                axis[d][count[d]] = i;
                count[d] += 1;
            }
        }
    }
    let mut k = [0usize; D];
    loop {
        let mut flat = 0;
        for d in 0..D {
            flat += axis[d][k[d]] * geo.strides[d];
        }
        f(flat);
        let mut d = 0;
        loop {
            if d == D {
                return;
            }
            k[d] += 1;
            if k[d] < count[d] {
                break;
            }
            k[d] = 0;
            d += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridGeometry;

    /// The pushes of particles at `x` (rest volume 0.25 h^2 each, J = 1) on a 10 x 10 grid of
    /// h = 1, periodic along x if asked.
    fn pushes(x: &[Vector<2>], periodic: bool) -> Vec<Vector<2>> {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 1.0, [10, 10])
            .with_periodic([periodic, false]);
        let mut bins = CellBins::default();
        bins.sort(&geo, x);
        let v0 = vec![0.25; x.len()];
        let jac = vec![1.0; x.len()];
        let mut s = Spacing::<2>::default();
        s.pushes(&geo, &bins, (x, &v0, &jac), 1.0);
        s.push
    }

    /// A regular lattice at its rest spacing (0.5) is not moved.
    #[test]
    fn a_lattice_at_rest_spacing_is_left_alone() {
        let x: Vec<Vector<2>> = (0..16)
            .flat_map(|i| {
                (0..16).map(move |j| Vector::<2>::new(1.25 + 0.5 * i as f64, 1.25 + 0.5 * j as f64))
            })
            .collect();
        assert!(pushes(&x, false).iter().all(|p| p.norm() == 0.0));
    }

    /// Two particles 0.3 apart (rest spacing 0.5) are pushed apart along their line, equally
    /// and oppositely, by (1/2) s (1 - r/s)^2 each; across a periodic face as inside.
    #[test]
    fn a_close_pair_is_pushed_apart_along_its_line() {
        let expected = 0.5 * 0.5 * (1.0 - 0.3 / 0.5_f64).powi(2);
        for (a, b, periodic) in [(4.35, 4.65, false), (0.1, 9.8, true)] {
            let x = [Vector::<2>::new(a, 5.0), Vector::<2>::new(b, 5.0)];
            let p = pushes(&x, periodic);
            // the first is pushed towards -x inside, towards +x across the periodic face
            let sign = if periodic { 1.0 } else { -1.0 };
            assert!((p[0][0] - sign * expected).abs() < 1e-14, "{p:?}");
            assert!((p[0] + p[1]).norm() < 1e-14 && p[0][1] == 0.0, "{p:?}");
        }
    }
}
