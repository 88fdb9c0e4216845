//! Damping zones: layers at the ends of a tank that absorb the waves reaching them.
//!
//! A closed tank keeps every wave it holds: the waves a heaving body radiates, or a paddle
//! makes, come back from the walls and drive it again. A damping zone (a sponge layer, or
//! numerical beach) takes them out. Over the zone the grid's velocities relax towards rest,
//!
//! ```text
//! dv/dt = ... - c(x) v,   c(x) = rate s^2,   s = (x_a - from) / (to - from) clamped to [0, 1],
//! ```
//!
//! x_a the position along the zone's axis, zero on the inner side of `from`. The coefficient
//! rises smoothly from zero, so that the zone's edge reflects little of a wave that enters it
//! (Israeli & Orszag 1981, "Approximation of radiation boundary conditions", J. Comput. Phys.
//! 41; a layer about a wavelength long with a rate of a few times the wave's angular frequency
//! absorbs most of it). The damping acts in the predictor, implicitly (v / (1 + dt c)), so it
//! is stable at any rate. It is not a force a rigid body feels.

use crate::error::DeckError;
use crate::grid::GridGeometry;
use crate::keys::{Check, Frame, AXES};
use serde::{Deserialize, Serialize};

/// `[[damping_zones]]`: a layer where the grid's velocities relax towards rest, to absorb the
/// waves that reach the ends of a tank.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DampingZoneDeck {
    /// "x", "y" or "z": the axis along which the rate grows.
    pub axis: String,
    /// Where the damping starts (rate 0), as a coordinate along `axis` (m).
    pub from: f64,
    /// Where it reaches `rate` (m); the zone lies on this side of `from`.
    pub to: f64,
    /// The rate at `to` and beyond (1/s).
    pub rate: f64,
}

impl DampingZoneDeck {
    /// The zone of a validated entry.
    pub fn zone(&self) -> DampingZone {
        DampingZone {
            axis: AXES.iter().position(|a| *a == self.axis).unwrap_or(0),
            from: self.from,
            to: self.to,
            rate: self.rate,
        }
    }

    /// The `[[damping_zones]]`: each an axis of the run's dimension, `from` and `to` inside
    /// the grid and at least a cell apart, a rate above 0.
    pub(crate) fn check_all(
        zones: &[DampingZoneDeck],
        frame: &Frame,
        c: &Check,
    ) -> Result<(), DeckError> {
        for (i, z) in zones.iter().enumerate() {
            z.check(&format!("damping_zones[{i}]"), frame, c)?;
        }
        Ok(())
    }

    /// One entry, of key `k`.
    fn check(&self, k: &str, frame: &Frame, c: &Check) -> Result<(), DeckError> {
        let (dim, h, lo, hi) = (frame.dim, frame.cell_size, &frame.lo, &frame.hi);
        let tol = 1e-9 * h;
        let Some(axis) = AXES[..dim].iter().position(|a| *a == self.axis) else {
            return Err(c.err(
                format!("{k}.axis"),
                format!(
                    "must be one of {} (dimension = {dim}), got \"{}\"",
                    AXES[..dim]
                        .iter()
                        .map(|a| format!("\"{a}\""))
                        .collect::<Vec<_>>()
                        .join(", "),
                    self.axis
                ),
            ));
        };
        for (name, v) in [("from", self.from), ("to", self.to)] {
            if !v.is_finite() || v < lo[axis] - tol || v > hi[axis] + tol {
                return Err(c.err(
                    format!("{k}.{name}"),
                    format!(
                        "must lie in the grid along {} ([{}, {}]), got {v}",
                        self.axis, lo[axis], hi[axis]
                    ),
                ));
            }
        }
        if (self.to - self.from).abs() < h {
            return Err(c.err(
                format!("{k}.to"),
                format!(
                    "must be at least a cell (grid.cell_size = {}) from `from` = {}, got {}: the rate grows from 0 at `from` to `rate` at `to`, and a sudden rise reflects the waves the zone should absorb",
                    h, self.from, self.to
                ),
            ));
        }
        c.positive(&format!("{k}.rate"), self.rate)?;
        Ok(())
    }
}

/// One zone: the damping rate grows as s^2 from `from` to `to` along `axis`, and stays at
/// `rate` beyond `to`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DampingZone {
    /// The axis along which it grows (0 = x, 1 = y, 2 = z).
    pub axis: usize,
    /// Where the damping starts (m).
    pub from: f64,
    /// Where it reaches `rate` (m).
    pub to: f64,
    /// The rate at `to` and beyond (1/s).
    pub rate: f64,
}

impl DampingZone {
    /// The rate c at a point whose coordinate along the zone's axis is `x` (1/s).
    pub fn rate_at(&self, x: f64) -> f64 {
        let s = ((x - self.from) / (self.to - self.from)).clamp(0.0, 1.0);
        self.rate * s * s
    }
}

/// The zones' summed rate at every node of `geo` (padding included); empty when there are no
/// zones, which the predictor reads as none.
pub fn node_rates<const D: usize>(zones: &[DampingZone], geo: &GridGeometry<D>) -> Vec<f64> {
    if zones.is_empty() {
        return Vec::new();
    }
    (0..geo.node_count())
        .map(|i| {
            let x = geo.node_position(&geo.multi(i));
            zones.iter().map(|z| z.rate_at(x[z.axis])).sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Vector;

    /// Zero on the inner side, rate s^2 across, the full rate beyond; either direction.
    #[test]
    fn the_rate_rises_as_the_square_of_the_depth_into_the_zone() {
        let right = DampingZone {
            axis: 0,
            from: 2.0,
            to: 3.0,
            rate: 8.0,
        };
        assert_eq!(right.rate_at(1.0), 0.0);
        assert_eq!(right.rate_at(2.0), 0.0);
        assert!((right.rate_at(2.5) - 2.0).abs() < 1e-12);
        assert!((right.rate_at(3.0) - 8.0).abs() < 1e-12);
        assert!((right.rate_at(3.5) - 8.0).abs() < 1e-12);
        let left = DampingZone {
            axis: 0,
            from: 1.0,
            to: 0.0,
            rate: 4.0,
        };
        assert_eq!(left.rate_at(1.5), 0.0);
        assert!((left.rate_at(0.5) - 1.0).abs() < 1e-12);
        assert!((left.rate_at(0.0) - 4.0).abs() < 1e-12);
    }

    /// The predictor relaxes each node's velocity by its own rate, implicitly, on top of the
    /// global damping, and leaves the step's force whole: v* = v / (1 + dt (d + c_i)) + dt f / m.
    #[test]
    fn the_predictor_relaxes_each_node_by_its_rate() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 0.5, [4, 2]);
        let zone = DampingZone {
            axis: 0,
            from: 1.0,
            to: 2.0,
            rate: 40.0,
        };
        let mut grid = crate::grid::Grid::new(geo.clone());
        grid.damping = node_rates(&[zone], &geo);
        grid.mass.fill(2.0);
        grid.velocity.fill(Vector::<2>::new(1.0, -0.5));
        grid.force.fill(Vector::<2>::new(0.0, -19.62));
        grid.body.fill(Vector::<2>::new(0.0, -19.62));
        let (dt, global) = (0.01, 3.0);
        grid.predict(dt, global, 1e-12, 0.0);
        for i in 0..geo.node_count() {
            let c = global + zone.rate_at(geo.node_position(&geo.multi(i))[0]);
            let want = Vector::<2>::new(1.0, -0.5) / (1.0 + dt * c)
                + Vector::<2>::new(0.0, -19.62) * (dt / 2.0);
            assert!((grid.velocity_new[i] - want).norm() < 1e-14, "node {i}");
        }
    }

    /// The nodes take the sum of the zones' rates at their positions.
    #[test]
    fn nodes_take_the_zones_rates_where_they_lie() {
        let geo = GridGeometry::<2>::new(Vector::<2>::zeros(), 0.5, [4, 2]);
        assert!(node_rates(&[], &geo).is_empty());
        let zones = [
            DampingZone {
                axis: 0,
                from: 1.0,
                to: 2.0,
                rate: 4.0,
            },
            DampingZone {
                axis: 1,
                from: 0.5,
                to: 0.0,
                rate: 2.0,
            },
        ];
        let rates = node_rates(&zones, &geo);
        assert_eq!(rates.len(), geo.node_count());
        for (i, r) in rates.iter().enumerate() {
            let x = geo.node_position(&geo.multi(i));
            let sx = ((x[0] - 1.0) / 1.0).clamp(0.0, 1.0);
            let sy = ((x[1] - 0.5) / -0.5).clamp(0.0, 1.0);
            assert!((r - (4.0 * sx * sx + 2.0 * sy * sy)).abs() < 1e-12);
        }
    }
}
