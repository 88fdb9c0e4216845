//! Interior fill: how evenly the particles pack, measured from their positions alone.
//!
//! J integrates the velocity divergence along each particle's path and says nothing about
//! where the particles are: they can bunch on the floor under a collapsing column while every
//! J stays at 1. This figure sees them. Each particle's rest volume V0_p is spread with a
//! linear hat onto nodes x_i spaced c, twice the particles' initial spacing:
//!
//! ```text
//! fill_i = sum_p V0_p N_i(x_p) / c^D,   N_i(x) = prod_d max(0, 1 - |x_d - x_i,d| / c)
//! ```
//!
//! Inside a regular lattice of spacing c / 2 (V0 = (c/2)^D) fill_i = 1 exactly, at any offset of
//! the lattice: the hat spans a whole number of spacings, so its samples sum to its integral.
//! A node is interior when it and its 3^D neighbours all have fill >= 1/2 (away from the free
//! surface and the walls, where the hat is only partly covered). Per frame the run writes the
//! 1st and 99th percentiles of the interior nodes' fill and the share within 5 % of 1
//! (series.csv). The measure is the one docs/method.md ("Particles at rest density") quotes
//! for pmpm's schemes and for SPlisHSPlasH's DFSPH.

use crate::deck::Deck;
use crate::grid::Vector;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// The band around 1 a node's fill counts as right in: 5 %.
pub const WITHIN: f64 = 0.05;

/// Fill below which a node is at the material's edge: half its hat is empty.
const EDGE: f64 = 0.5;

/// Particles per chunk of the parallel spread: each chunk sums into its own map, and the maps
/// are added in chunk order, so the sums do not depend on the thread count.
const CHUNK: usize = 1 << 15;

/// The figures of one frame: percentiles and share over the interior nodes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FillFigures {
    /// 1st percentile of the interior nodes' fill (NaN without interior nodes).
    pub p1: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Share of interior nodes with |fill - 1| <= [`WITHIN`], in [0, 1].
    pub within: f64,
    /// Interior nodes.
    pub nodes: usize,
}

/// The nodes of the measure: spacing c and an origin (the run takes the grid's; a regular
/// lattice gives 1 from any).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FillLattice<const D: usize> {
    /// Lower corner the nodes are counted from.
    pub origin: Vector<D>,
    /// Node spacing c.
    pub spacing: f64,
}

/// c for a deck: twice the largest initial particle spacing h / particles_per_cell among its
/// bodies and inflows (a finer lattice then still covers each hat with a whole number of its
/// spacings).
pub fn spacing(deck: &Deck) -> f64 {
    let h = deck.grid.cell_size;
    let widest = deck
        .bodies
        .iter()
        .map(|b| b.particles_per_cell)
        .chain(deck.inflows.iter().map(|f| f.particles_per_cell))
        .min()
        .unwrap_or(2)
        .max(1);
    2.0 * h / widest as f64
}

impl<const D: usize> FillLattice<D> {
    /// The fill figures of particles at `x` with rest volumes `volume0`.
    pub fn measure(&self, x: &[Vector<D>], volume0: &[f64]) -> FillFigures {
        self.figures_of(&self.spread(x, volume0))
    }

    /// The figures of the nodes' `fill`.
    fn figures_of(&self, fill: &FxHashMap<[i64; D], f64>) -> FillFigures {
        let mut interior: Vec<f64> = fill
            .iter()
            .filter(|(node, f)| **f >= EDGE && self.inner(fill, node))
            .map(|(_, f)| *f)
            .collect();
        figures(&mut interior)
    }

    /// [`FillLattice::measure`] of the particles of every rank of `comm` (every rank calls
    /// it; the figures are rank 0's): each rank spreads its own, and rank 0 adds up the
    /// nodes' fill, one rank's nodes at a time (a node near a cut has fill from both sides).
    pub fn measure_over(
        &self,
        comm: &dyn crate::comm::Comm,
        x: &[Vector<D>],
        volume0: &[f64],
    ) -> FillFigures {
        if !comm.is_distributed() {
            return self.measure(x, volume0);
        }
        let mut fill = self.spread(x, volume0);
        if !comm.is_root() {
            // in node order, so that rank 0 adds them up the same way each time
            let mut nodes: Vec<([i64; D], f64)> = fill.into_iter().collect();
            nodes.sort_unstable_by_key(|e| e.0);
            let bytes: Vec<u8> = nodes
                .iter()
                .flat_map(|(node, f)| {
                    node.iter()
                        .map(|i| i.to_le_bytes())
                        .chain([f.to_le_bytes()])
                })
                .flatten()
                .collect();
            comm.send_bytes(0, &bytes);
            return FillFigures {
                p1: f64::NAN,
                p99: f64::NAN,
                within: f64::NAN,
                nodes: 0,
            };
        }
        for rank in 1..comm.size() {
            let bytes = comm.receive_bytes(rank);
            for entry in bytes.chunks_exact(8 * (D + 1)) {
                let word =
                    |k: usize| <[u8; 8]>::try_from(&entry[8 * k..8 * k + 8]).expect("8 bytes");
                let node: [i64; D] = std::array::from_fn(|d| i64::from_le_bytes(word(d)));
                *fill.entry(node).or_insert(0.0) += f64::from_le_bytes(word(D));
            }
        }
        self.figures_of(&fill)
    }

    /// fill_i at every node some particle's hat reaches.
    fn spread(&self, x: &[Vector<D>], volume0: &[f64]) -> FxHashMap<[i64; D], f64> {
        let inv = 1.0 / self.spacing;
        let norm = inv.powi(D as i32);
        let parts: Vec<FxHashMap<[i64; D], f64>> = x
            .par_chunks(CHUNK)
            .zip(volume0.par_chunks(CHUNK))
            .map(|(xs, vs)| {
                let mut map = FxHashMap::default();
                for (xp, v) in xs.iter().zip(vs) {
                    let mut base = [0i64; D];
                    let mut frac = [0.0; D];
                    for d in 0..D {
                        let s = (xp[d] - self.origin[d]) * inv;
                        let b = s.floor();
                        base[d] = b as i64;
                        frac[d] = s - b;
                    }
                    // the 2^D nodes of the particle's cell, corner k's bit d choosing base or
                    // base + 1 along d
                    for k in 0..1usize << D {
                        let mut node = base;
                        let mut w = v * norm;
                        for d in 0..D {
                            if k >> d & 1 == 1 {
                                node[d] += 1;
                                w *= frac[d];
                            } else {
                                w *= 1.0 - frac[d];
                            }
                        }
                        *map.entry(node).or_insert(0.0) += w;
                    }
                }
                map
            })
            .collect();
        let mut parts = parts.into_iter();
        let mut fill = parts.next().unwrap_or_default();
        for part in parts {
            for (node, w) in part {
                *fill.entry(node).or_insert(0.0) += w;
            }
        }
        fill
    }

    /// Whether each of the 3^D neighbours of `node` (itself included) has fill >= 1/2.
    fn inner(&self, fill: &FxHashMap<[i64; D], f64>, node: &[i64; D]) -> bool {
        (0..3usize.pow(D as u32)).all(|k| {
            let mut at = *node;
            let mut rest = k;
            for a in at.iter_mut() {
                *a += (rest % 3) as i64 - 1;
                rest /= 3;
            }
            fill.get(&at).is_some_and(|f| *f >= EDGE)
        })
    }
}

/// Percentiles (linear between order statistics, as numpy's default) and the share within
/// [`WITHIN`] of 1 of `values`, which it sorts.
fn figures(values: &mut [f64]) -> FillFigures {
    let n = values.len();
    if n == 0 {
        return FillFigures {
            p1: f64::NAN,
            p99: f64::NAN,
            within: f64::NAN,
            nodes: 0,
        };
    }
    values.par_sort_unstable_by(f64::total_cmp);
    let quantile = |q: f64| {
        let rank = q * (n - 1) as f64;
        let lo = rank.floor() as usize;
        let hi = (lo + 1).min(n - 1);
        values[lo] + (values[hi] - values[lo]) * (rank - lo as f64)
    };
    let within = values.iter().filter(|f| (*f - 1.0).abs() <= WITHIN).count();
    FillFigures {
        p1: quantile(0.01),
        p99: quantile(0.99),
        within: within as f64 / n as f64,
        nodes: n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block of `n`^D particles of spacing `s` from `start`, each of volume s^D.
    fn lattice<const D: usize>(n: usize, s: f64, start: f64) -> (Vec<Vector<D>>, Vec<f64>) {
        let mut x = Vec::new();
        for k in 0..n.pow(D as u32) {
            let mut p = Vector::<D>::zeros();
            let mut rest = k;
            for d in 0..D {
                p[d] = start + s * ((rest % n) as f64 + 0.5);
                rest /= n;
            }
            x.push(p);
        }
        let v = vec![s.powi(D as i32); x.len()];
        (x, v)
    }

    #[test]
    fn a_regular_lattice_fills_its_interior_exactly_at_any_offset() {
        for offset in [0.0, 0.013, 0.05, 0.0731] {
            let (x, v) = lattice::<2>(40, 0.1, offset);
            let lat = FillLattice {
                origin: Vector::<2>::zeros(),
                spacing: 0.2,
            };
            let f = lat.measure(&x, &v);
            assert!(f.nodes > 200, "{f:?}");
            assert!(
                (f.p1 - 1.0).abs() < 1e-12 && (f.p99 - 1.0).abs() < 1e-12,
                "{f:?}"
            );
            assert_eq!(f.within, 1.0);
        }
        let (x, v) = lattice::<3>(12, 0.1, 0.037);
        let lat = FillLattice {
            origin: Vector::<3>::zeros(),
            spacing: 0.2,
        };
        let f = lat.measure(&x, &v);
        assert!(f.nodes > 27 && (f.p99 - 1.0).abs() < 1e-12, "{f:?}");
    }

    #[test]
    fn a_bunched_patch_shows_in_the_upper_percentile_and_the_share() {
        // squeeze the middle third of the columns together: 1.5 times the particles per
        // length there
        let (mut x, v) = lattice::<2>(60, 0.1, 0.0);
        for p in &mut x {
            if (2.0..4.0).contains(&p[0]) {
                p[0] = 2.0 + (p[0] - 2.0) / 1.5;
            } else if p[0] >= 4.0 {
                p[0] -= 2.0 / 3.0 * 1.0;
            }
        }
        let lat = FillLattice {
            origin: Vector::<2>::zeros(),
            spacing: 0.2,
        };
        let f = lat.measure(&x, &v);
        assert!((f.p99 - 1.5).abs() < 0.05, "{f:?}");
        assert!((f.p1 - 1.0).abs() < 1e-9, "{f:?}");
        assert!(f.within < 0.9 && f.within > 0.5, "{f:?}");
    }

    #[test]
    fn the_percentiles_interpolate_between_order_statistics() {
        let mut v: Vec<f64> = (0..101).map(|k| k as f64 / 100.0).rev().collect();
        let f = figures(&mut v);
        assert!((f.p1 - 0.01).abs() < 1e-12 && (f.p99 - 0.99).abs() < 1e-12);
        assert_eq!(f.nodes, 101);
        let f = figures(&mut [1.1, 0.96, 1.0, 0.9, 1.04]);
        assert!((f.within - 0.6).abs() < 1e-12);
        assert!(figures(&mut []).p99.is_nan());
    }

    #[test]
    fn the_sums_do_not_depend_on_the_thread_count() {
        let (mut x, v) = lattice::<2>(300, 0.01, 0.0);
        for (k, p) in x.iter_mut().enumerate() {
            p[0] += 0.003 * ((k as f64 * 0.7).sin());
        }
        let lat = FillLattice {
            origin: Vector::<2>::zeros(),
            spacing: 0.02,
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let a = one.install(|| lat.measure(&x, &v));
        let b = two.install(|| lat.measure(&x, &v));
        assert_eq!(a, b);
    }
}
