//! Open boundaries: material that enters the run through an inflow patch and leaves it through
//! an outflow face, and the ledger that accounts for it.
//!
//! An **outflow** face (`"outflow"` in `[grid.boundary]`) is an open face (nothing held on the
//! velocity, p = 0 beyond it: the projection reads the cells past it as empty) whose
//! particles, once the step has carried them past it, are taken out of the run.
//!
//! An **inflow** (`[[inflows]]`) is a patch of a wall face through which material enters at a
//! given velocity: the face's nodes on the patch, and the ghost nodes behind them, hold that
//! velocity (the projection sees a wall moving into the domain: a given normal flux), and
//! particles are emitted where there is room for them. The patch is divided into lanes, one
//! per lattice point of spacing s = h / particles_per_cell across it; in each lane, when the
//! particle nearest the face has moved 3 s / 2 from it, a new one is placed s behind it (the
//! first row of a lattice lies at s / 2). The particles then enter at the rate the flow
//! carries them away from the face, lane by lane: emitting at the prescribed rate instead
//! piled particles three deep in the corner of a no-slip floor, where the flow is slower than
//! the patch's velocity.
//!
//! The [`Ledger`] counts what entered and left, so that series.csv closes the mass balance:
//! m(0) + m_in - m_out - m(t) = 0 to round-off.

use crate::field::CompiledField;
use crate::grid::{GridGeometry, Vector};
use crate::particles::Matrix;
use crate::particles::Particles;
use serde::{Deserialize, Serialize};

/// What entered and left the run through its open boundaries, and the next particle id.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Ledger {
    /// The particles' mass at t = 0 (kg; kg/m in 2D).
    pub mass0: f64,
    /// Mass emitted by the inflows.
    pub mass_in: f64,
    /// Mass taken out at the outflow faces.
    pub mass_out: f64,
    /// Volume emitted (the particles' volume at emission, m3; m2 in 2D).
    pub volume_in: f64,
    /// Volume taken out (the particles' volume J V0 when they left).
    pub volume_out: f64,
    /// Id of the next particle an inflow emits.
    pub next_id: u32,
}

impl Ledger {
    /// The mass balance (m(0) + m_in - m_out - m(t)) / (m(0) + m_in), round-off when no
    /// particle is lost or made uncounted.
    pub fn balance<const D: usize>(&self, ps: &Particles<D>) -> f64 {
        let held: f64 = ps.mass.iter().sum();
        (self.mass0 + self.mass_in - self.mass_out - held) / (self.mass0 + self.mass_in)
    }
}

/// One inflow patch.
#[derive(Debug, Clone)]
pub struct Inflow<const D: usize> {
    /// The face, in the order x_min, x_max, y_min, ...
    pub face: usize,
    /// The patch's corners (their normal components are the face's coordinate).
    pub lo: Vector<D>,
    /// See `lo`.
    pub hi: Vector<D>,
    /// Velocity of the entering material, in x, y, z and t.
    pub velocity: CompiledField,
    /// Material index and density.
    pub material: u16,
    /// Density (kg/m3).
    pub density: f64,
    /// Lattice spacing s = h / particles_per_cell.
    pub spacing: f64,
    /// Half the particle's width in cells, 0.5 / particles_per_cell (GIMP).
    pub half_width: f64,
    /// Lanes per axis (1 along the normal).
    counts: [usize; D],
    /// The lattice points of a layer, on the face, lane by lane.
    layer: Vec<Vector<D>>,
    /// Scratch: per lane, the distance from the face of the nearest particle.
    nearest: Vec<f64>,
    /// The particles in the buffer at the step's start, and their positions then.
    buffer: Vec<(u32, Vector<D>)>,
}

impl<const D: usize> Inflow<D> {
    /// An inflow on `face` over the patch lo..hi, its layer's lattice laid out.
    pub fn new(
        face: usize,
        (lo, hi): (Vector<D>, Vector<D>),
        velocity: CompiledField,
        material: u16,
        density: f64,
        particles_per_cell: usize,
        h: f64,
    ) -> Self {
        let spacing = h / particles_per_cell as f64;
        let axis = face / 2;
        // the tangential lattice: points at the centres of the sub-cells of spacing s
        let counts: [usize; D] = std::array::from_fn(|d| {
            if d == axis {
                1
            } else {
                ((hi[d] - lo[d]) / spacing).round().max(1.0) as usize
            }
        });
        let total: usize = counts.iter().product();
        let layer = (0..total)
            .map(|k| {
                let mut rem = k;
                Vector::<D>::from_fn(|d, _| {
                    let i = rem % counts[d];
                    rem /= counts[d];
                    if d == axis {
                        lo[d]
                    } else {
                        lo[d] + (hi[d] - lo[d]) * (i as f64 + 0.5) / counts[d] as f64
                    }
                })
            })
            .collect();
        Self {
            face,
            lo,
            hi,
            velocity,
            material,
            density,
            spacing,
            half_width: 0.5 / particles_per_cell as f64,
            counts,
            layer,
            nearest: Vec::new(),
            buffer: Vec::new(),
        }
    }

    /// The unit normal into the domain.
    pub fn inward(&self) -> Vector<D> {
        let mut n = Vector::<D>::zeros();
        n[self.face / 2] = if self.face % 2 == 0 { 1.0 } else { -1.0 };
        n
    }

    /// The velocity the patch's nodes hold at `x` and `t`.
    pub fn velocity_at(&self, x: &Vector<D>, t: f64) -> Vector<D> {
        self.velocity.eval(x, t)
    }

    /// Whether the node at `x` lies on the patch (within a millionth of a cell of it).
    pub fn covers(&self, x: &Vector<D>, h: f64) -> bool {
        let axis = self.face / 2;
        (0..D)
            .all(|d| d == axis || (x[d] >= self.lo[d] - 1e-6 * h && x[d] <= self.hi[d] + 1e-6 * h))
    }

    /// Emits, lane by lane, the particles for which there is room: in each lane (a row of
    /// the patch's lattice along the face's normal) the particle nearest the face, at a
    /// distance d, makes room for a new one at d - s once d >= 3 s / 2 (the first row of a
    /// lattice lies at s / 2). Appends them to `out` at time `t`, with the ledger's count.
    pub fn emit(&mut self, ps: &Particles<D>, t: f64, ledger: &mut Ledger, out: &mut Particles<D>) {
        let s = self.spacing;
        let axis = self.face / 2;
        let n = self.inward();
        let plane = self.lo[axis];
        // lanes with no particle nearer than this are filled from it
        let band = 2.5 * s;
        self.nearest.clear();
        self.nearest.resize(self.layer.len(), band);
        for x in &ps.x {
            let dn = (x - self.lo).dot(&n);
            if !(0.0..band).contains(&dn) {
                continue;
            }
            if let Some(lane) = self.lane(x) {
                self.nearest[lane] = self.nearest[lane].min(dn);
            }
        }
        let volume = s.powi(D as i32);
        let mass = self.density * volume;
        for (lane, x0) in self.layer.iter().enumerate() {
            let mut d = self.nearest[lane];
            while d >= 1.5 * s && ledger.next_id < u32::MAX {
                d -= s;
                let mut x = x0 + n * d;
                x[axis] = plane + n[axis] * d;
                out.id.push(ledger.next_id);
                ledger.next_id += 1;
                out.x.push(x);
                out.v.push(self.velocity.eval(&x, t));
                out.mass.push(mass);
                out.volume0.push(volume);
                out.jacobian.push(1.0);
                out.deformation.push(Matrix::<D>::identity());
                out.pressure.push(0.0);
                out.tau.push(Matrix::<D>::zeros());
                out.velocity_gradient.push(Matrix::<D>::zeros());
                out.affine.push(Matrix::<D>::zeros());
                out.material.push(self.material);
                out.half_width.push(self.half_width);
                ledger.mass_in += mass;
                ledger.volume_in += volume;
            }
        }
    }

    /// Notes the particles in the buffer, less than a cell in front of the patch, and where
    /// they are, before the step moves them ([`Inflow::hold_buffer`]).
    pub fn mark_buffer(&mut self, ps: &Particles<D>, h: f64) {
        let n = self.inward();
        self.buffer.clear();
        for (p, x) in ps.x.iter().enumerate() {
            if (0.0..h).contains(&(x - self.lo).dot(&n)) && self.lane(x).is_some() {
                self.buffer.push((p as u32, *x));
            }
        }
    }

    /// Moves the particles [`Inflow::mark_buffer`] noted at the patch's velocity over the
    /// step `dt` ending at `t`, instead of the grid's: they leave the buffer at the rate the
    /// patch gives, whatever the flow beyond it (a no-slip floor that slows the water at the
    /// patch's foot), and the lanes open at that rate. Emitting at that rate without the
    /// buffer piled particles three deep in the floor's corner; emitting as the grid moved
    /// them fell a third short, the flow fanning out of the lanes in the first cell.
    pub fn hold_buffer(&self, ps: &mut Particles<D>, t: f64, dt: f64) {
        for &(p, x0) in &self.buffer {
            let p = p as usize;
            let u = self.velocity.eval(&x0, t);
            ps.x[p] = x0 + u * dt;
            ps.v[p] = u;
            ps.affine[p] = Matrix::<D>::zeros();
        }
    }

    /// The lane of the patch's lattice a point lies in, if it lies within the patch.
    fn lane(&self, x: &Vector<D>) -> Option<usize> {
        let axis = self.face / 2;
        let (mut lane, mut stride) = (0, 1);
        for d in (0..D).filter(|&d| d != axis) {
            let u = (x[d] - self.lo[d]) / (self.hi[d] - self.lo[d]);
            if !(0.0..1.0).contains(&u) {
                return None;
            }
            let c = self.counts[d];
            lane += ((u * c as f64) as usize).min(c - 1) * stride;
            stride *= c;
        }
        Some(lane)
    }
}

/// Whether a particle at `x` has crossed an outflow face (`outflow[f]`, faces in the order
/// x_min, x_max, y_min, ...).
pub fn has_left<const D: usize>(geo: &GridGeometry<D>, outflow: &[bool], x: &Vector<D>) -> bool {
    let (lo, hi) = (geo.origin, geo.upper());
    (0..D).any(|d| (outflow[2 * d] && x[d] < lo[d]) || (outflow[2 * d + 1] && x[d] > hi[d]))
}
