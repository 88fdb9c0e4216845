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

use crate::error::DeckError;
use crate::field::CompiledField;
use crate::field::VectorField;
use crate::geometry::Solid;
use crate::grid::{GridGeometry, Vector};
use crate::keys::{point, Check, Frame, AXES, FACE_NAMES};
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
                if out.stored.deformation {
                    out.deformation.push(Matrix::<D>::identity());
                }
                out.pressure.push(0.0);
                if out.stored.stress {
                    out.tau.push(Matrix::<D>::zeros());
                }
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

/// `[[inflows]]`: a patch of a wall face through which material enters at a given velocity
/// (this module).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InflowDeck {
    /// Name of a `[[materials]]` entry.
    pub material: String,
    /// The face: "x_min", "x_max", "y_min", ... (a slip or no-slip face).
    pub face: String,
    /// The patch's lower corner on the face (its component along the face's normal is the
    /// face's coordinate).
    pub min: Vec<f64>,
    /// The patch's upper corner.
    pub max: Vec<f64>,
    /// Velocity of the entering material (numbers or expressions in x, y, z, t), into the
    /// domain.
    pub velocity: VectorField,
    /// Particles per cell per direction of the emitted lattice (default 2).
    #[serde(default = "default_particles_per_cell")]
    pub particles_per_cell: usize,
}

fn default_particles_per_cell() -> usize {
    2
}

impl InflowDeck {
    /// The inflows of a validated deck: each its face's index, its material's (by the
    /// deck's `[[materials]]` names and densities) and the lattice of its patch.
    pub fn build<const D: usize>(
        inflows: &[InflowDeck],
        materials: &[(&str, f64)],
        geo: &GridGeometry<D>,
    ) -> Vec<Inflow<D>> {
        inflows
            .iter()
            .map(|q| {
                let face = FACE_NAMES
                    .iter()
                    .position(|n| *n == q.face)
                    .expect("validated face");
                let mat = materials
                    .iter()
                    .position(|m| m.0 == q.material)
                    .expect("validated: inflow material exists");
                Inflow::new(
                    face,
                    (
                        Vector::<D>::from_column_slice(&q.min),
                        Vector::<D>::from_column_slice(&q.max),
                    ),
                    q.velocity.compile().expect("validated expressions"),
                    mat as u16,
                    materials[mat].1,
                    q.particles_per_cell,
                    geo.h,
                )
            })
            .collect()
    }

    /// The `[[inflows]]`: each a patch of a wall face inside the grid, a whole number of
    /// lanes wide, apart from the others, not covered by a rigid body (`rigid`: each body's
    /// name and region), with a velocity that enters.
    pub(crate) fn check_all(
        inflows: &[InflowDeck],
        frame: &Frame,
        rigid: &[(&str, Solid)],
        c: &Check,
    ) -> Result<(), DeckError> {
        for (i, q) in inflows.iter().enumerate() {
            let k = format!("inflows[{i}]");
            let f = q.check(&k, frame, c)?;
            if let Some((j, _)) = inflows[..i].iter().enumerate().find(|(_, o)| {
                o.face == q.face
                    && (0..frame.dim)
                        .filter(|&d| d != f / 2)
                        .all(|d| o.min[d] < q.max[d] && q.min[d] < o.max[d])
            }) {
                return Err(c.err(
                    format!("{k}.min"),
                    format!("the patch overlaps inflows[{j}]'s on the face {}", q.face),
                ));
            }
            c.field(&format!("{k}.velocity"), &q.velocity, frame.dim)?;
            q.check_enters(&k, f, frame, c)?;
        }
        for (i, q) in inflows.iter().enumerate() {
            let axis = FACE_NAMES.iter().position(|n| *n == q.face).unwrap_or(0) / 2;
            q.check_uncovered(&format!("inflows[{i}]"), axis, frame, rigid, c)?;
        }
        Ok(())
    }

    /// One inflow's keys (`k` its key): material, face, corners on the face and inside the
    /// grid, particles per cell, width. Gives the face's index.
    fn check(&self, k: &str, frame: &Frame, c: &Check) -> Result<usize, DeckError> {
        let q = self;
        let (dim, h) = (frame.dim, frame.cell_size);
        let (lo, hi) = (&frame.lo, &frame.hi);
        frame.material(&format!("{k}.material"), &q.material, c)?;
        let f = frame.face(&format!("{k}.face"), &q.face, c)?;
        if !frame.is_wall(f) {
            return Err(c.err(
                format!("{k}.face"),
                format!(
                    "grid.boundary.{} is \"{}\": an inflow is a patch of a slip or no-slip face",
                    q.face, frame.faces[f]
                ),
            ));
        }
        c.vector(&format!("{k}.min"), &q.min, dim)?;
        c.vector(&format!("{k}.max"), &q.max, dim)?;
        let axis = f / 2;
        let plane = if f % 2 == 0 { lo[axis] } else { hi[axis] };
        for (name, v) in [("min", &q.min), ("max", &q.max)] {
            if (v[axis] - plane).abs() > 1e-9 * h {
                return Err(c.err(
                    format!("{k}.{name}"),
                    format!(
                        "must lie on the face {}: its {} component must be {plane}, got {}",
                        q.face, AXES[axis], v[axis]
                    ),
                ));
            }
        }
        for d in (0..dim).filter(|&d| d != axis) {
            if q.max[d] <= q.min[d] {
                return Err(c.err(
                    format!("{k}.max"),
                    format!(
                        "must exceed min along {}: {} <= {}",
                        AXES[d], q.max[d], q.min[d]
                    ),
                ));
            }
            if q.min[d] < lo[d] - 1e-9 * h || q.max[d] > hi[d] + 1e-9 * h {
                return Err(c.err(
                    format!("{k}.min"),
                    format!(
                        "the patch spans [{}, {}] along {}, past the grid's [{}, {}]",
                        q.min[d], q.max[d], AXES[d], lo[d], hi[d]
                    ),
                ));
            }
        }
        if !(1..=8).contains(&q.particles_per_cell) {
            return Err(c.err(
                format!("{k}.particles_per_cell"),
                format!("must be between 1 and 8, got {}", q.particles_per_cell),
            ));
        }
        // each lane of the lattice carries s^(D-1) of the patch: its width must be a whole
        // number of spacings, and at least a cell so that the face's nodes hold its flux
        let s = h / q.particles_per_cell as f64;
        for d in (0..dim).filter(|&d| d != axis) {
            let w = q.max[d] - q.min[d];
            let lanes = w / s;
            if w < h * (1.0 - 1e-9) || (lanes - lanes.round()).abs() > 1e-6 * lanes {
                return Err(c.err(
                    format!("{k}.max"),
                    format!(
                        "the patch is {w} m wide along {}: it must be at least a cell (grid.cell_size = {h}) and a whole number of particle spacings (cell_size / particles_per_cell = {s})",
                        AXES[d]
                    ),
                ));
            }
        }
        Ok(f)
    }
    /// The material of this inflow (key `k`, on face `f`) enters: its velocity at t = 0 on a
    /// lattice over the patch (its corners, its edges, the face's nodes on it) is finite and
    /// points inwards.
    fn check_enters(&self, k: &str, f: usize, frame: &Frame, c: &Check) -> Result<(), DeckError> {
        let q = self;
        let (dim, h, axis) = (frame.dim, frame.cell_size, f / 2);
        let field = q.velocity.compile().expect("checked before");
        let steps: Vec<usize> = (0..dim)
            .map(|d| {
                if d == axis {
                    0
                } else {
                    ((q.max[d] - q.min[d]) / h).round() as usize
                }
            })
            .collect();
        let total: usize = steps.iter().map(|n| n + 1).product();
        for m in 0..total {
            let mut rem = m;
            let x: Vec<f64> = (0..dim)
                .map(|d| {
                    let i = rem % (steps[d] + 1);
                    rem /= steps[d] + 1;
                    if steps[d] == 0 {
                        q.min[d]
                    } else {
                        q.min[d] + (q.max[d] - q.min[d]) * i as f64 / steps[d] as f64
                    }
                })
                .collect();
            let v = field.eval_at(&x, 0.0);
            let at = x
                .iter()
                .map(|c| format!("{c}"))
                .collect::<Vec<_>>()
                .join(", ");
            if v.iter().any(|c| !c.is_finite()) {
                return Err(c.err(
                    format!("{k}.velocity"),
                    format!("is not a finite number at ({at}) at t = 0: {v:?}"),
                ));
            }
            let inward = if f % 2 == 0 { v[axis] } else { -v[axis] };
            if inward < 0.0 {
                return Err(c.err(
                    format!("{k}.velocity"),
                    format!(
                        "points out of the domain at ({at}) at t = 0 (its {} component is {} on the face {}): an inflow's velocity points into the grid",
                        AXES[axis], v[axis], q.face
                    ),
                ));
            }
        }
        Ok(())
    }

    /// No rigid body covers this inflow's patch (key `k`, on a face normal to `axis`) at
    /// t = 0: the patch's nodes would hold the inflow's velocity inside the solid, and the
    /// particles it emits would enter the solid. Tested at the first row of the particles it
    /// emits (half a spacing in front of the patch), at each lane's centre.
    fn check_uncovered(
        &self,
        k: &str,
        axis: usize,
        frame: &Frame,
        rigid: &[(&str, Solid)],
        c: &Check,
    ) -> Result<(), DeckError> {
        let q = self;
        let dim = frame.dim;
        let s = frame.cell_size / q.particles_per_cell as f64;
        let inward = if q.min[axis] <= frame.lo[axis] {
            1.0
        } else {
            -1.0
        };
        let lanes: Vec<usize> = (0..dim)
            .map(|d| {
                if d == axis {
                    1
                } else {
                    ((q.max[d] - q.min[d]) / s).round().max(1.0) as usize
                }
            })
            .collect();
        let total: usize = lanes.iter().product();
        for (r, (name, solid)) in rigid.iter().enumerate() {
            for m in 0..total {
                let mut rem = m;
                let x: Vec<f64> = (0..dim)
                    .map(|d| {
                        let i = rem % lanes[d];
                        rem /= lanes[d];
                        if d == axis {
                            q.min[d] + inward * 0.5 * s
                        } else {
                            q.min[d] + (q.max[d] - q.min[d]) * (i as f64 + 0.5) / lanes[d] as f64
                        }
                    })
                    .collect();
                if solid.contains(&x) {
                    return Err(c.err(
                        format!("{k}.min"),
                        format!(
                            "the patch on the face {} is covered by rigid_bodies[{r}] (\"{}\") at t = 0 (for example at ({})): material would enter through the solid; move the patch or the body",
                            q.face,
                            name,
                            point(&x)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}
