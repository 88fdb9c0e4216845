//! Gauges (`[[output.gauges]]`, docs/deck.md): the free surface's height at a place (a wave
//! gauge), the pressure and velocity at a point, and the force of the material on a wall
//! face, read from the particles at the end of each step into gauges.csv.
//!
//! Each reads the particles through the linear hat weights N(x) = prod_d (1 - |x_d - a_d| / h)
//! about its place, as the grid's frames do ([`crate::grid_fields`]), whatever shape
//! function the run steps with. Written by hand: each is a few lines over the particles near
//! it, and the wall force is the grid's own momentum balance at the face's nodes.
//!
//! The section's settings are here too: `[[output.gauges]]`, and the probes
//! (`[[output.probes]]`, sampled every step into probes.csv by the scheme).

use crate::error::DeckError;
use crate::grid::Vector;
use crate::keys::{Check, Frame, AXES, FACE_NAMES};
use crate::scheme::ProbeSample;
use crate::scheme::Simulation;
use serde::{Deserialize, Serialize};

/// One gauge, as the run reads it.
#[derive(Debug, Clone)]
pub enum Gauge {
    /// The surface's height on a vertical line.
    Surface {
        /// A point of the line (its `up` component unused).
        at: [f64; 3],
        /// The vertical axis.
        up: usize,
    },
    /// Pressure at a point.
    Pressure {
        /// The point.
        at: [f64; 3],
    },
    /// Velocity at a point.
    Velocity {
        /// The point.
        at: [f64; 3],
    },
    /// The force on a wall face.
    WallForce {
        /// The face, in [`FACE_NAMES`] order.
        face: usize,
        /// Whether the face holds every component (no-slip), else only its normal.
        all: bool,
    },
}

impl Gauge {
    /// The gauges of a validated deck.
    pub(crate) fn build(gauges: &[GaugeDeck], frame: &Frame) -> Vec<Self> {
        let (dim, up) = (frame.dim, frame.up);
        gauges
            .iter()
            .map(|q| {
                let point = |horizontal: bool| {
                    let p = q.position.as_deref().expect("validated: a position");
                    let mut at = [0.0; 3];
                    let mut k = 0;
                    for d in 0..dim {
                        if horizontal && d == up {
                            continue;
                        }
                        at[d] = p[k];
                        k += 1;
                    }
                    at
                };
                match q.kind {
                    GaugeKind::Surface => Gauge::Surface {
                        at: point(true),
                        up,
                    },
                    GaugeKind::Pressure => Gauge::Pressure { at: point(false) },
                    GaugeKind::Velocity => Gauge::Velocity { at: point(false) },
                    GaugeKind::WallForce => {
                        let name = q.face.as_deref().expect("validated: a face");
                        let face = FACE_NAMES
                            .iter()
                            .position(|n| *n == name)
                            .expect("validated");
                        let all = frame.faces[face] == "no_slip";
                        Gauge::WallForce { face, all }
                    }
                }
            })
            .collect()
    }

    /// The names of its columns in gauges.csv, after its name and an underscore.
    pub fn columns(&self, dim: usize) -> Vec<&'static str> {
        match self {
            Gauge::Surface { .. } => vec!["height"],
            Gauge::Pressure { .. } => vec!["pressure"],
            Gauge::Velocity { .. } => ["vx", "vy", "vz"][..dim].to_vec(),
            Gauge::WallForce { .. } => ["fx", "fy", "fz"][..dim].to_vec(),
        }
    }

    /// The gauge's reading now, of the particles of every rank of `sim`'s run (every rank
    /// calls it, and reads the same), appended to `out`.
    pub fn read<const D: usize>(&self, sim: &Simulation<D>, out: &mut Vec<f64>) {
        let point = |at: &[f64; 3]| Vector::<D>::from_fn(|d, _| at[d]);
        match self {
            Gauge::Surface { at, up } => {
                let y = surface(sim, &point(at), *up, out);
                out.push(y);
            }
            Gauge::Pressure { at } => {
                let (m, q) = point_mean(sim, &point(at), |p| {
                    Vector::<D>::repeat(sim.particles.pressure[p])
                });
                out.push(if m > 0.0 { q[0] } else { 0.0 });
            }
            Gauge::Velocity { at } => {
                let (m, q) = point_mean(sim, &point(at), |p| sim.particles.v[p]);
                for d in 0..D {
                    out.push(if m > 0.0 { q[d] } else { 0.0 });
                }
            }
            Gauge::WallForce { face, all } => {
                let mut f = wall_force(sim, *face);
                sim.comm.sum_vectors(std::slice::from_mut(&mut f));
                let axis = face / 2;
                for d in 0..D {
                    out.push(if *all || d == axis { f[d] } else { 0.0 });
                }
            }
        }
    }
}

/// The part of the hat of half-width h about `a` that lies in [lo, hi] (its integral over it).
fn hat_inside(a: f64, lo: f64, hi: f64, h: f64) -> f64 {
    let cut = |gap: f64| {
        let s = (1.0 - gap / h).clamp(0.0, 1.0);
        0.5 * h * s * s
    };
    h - cut(a - lo) - cut(hi - a)
}

/// The mass-weighted mean of `q` over the particles within a cell of `at` (hat weights), and
/// their weighted mass (0: no material there), over every rank.
fn point_mean<const D: usize>(
    sim: &Simulation<D>,
    at: &Vector<D>,
    q: impl Fn(usize) -> Vector<D>,
) -> (f64, Vector<D>) {
    let comm = &sim.comm;
    if !comm.is_distributed() {
        return sim.particles.hat_mean(at, sim.grid.geo.h, q);
    }
    let (m, sum) = sim.particles.hat_sums(at, sim.grid.geo.h, q);
    let mut sums = [Vector::<D>::repeat(m), sum];
    comm.sum_vectors(&mut sums);
    let (m, sum) = (sums[0][0], sums[1]);
    (m, if m > 0.0 { sum / m } else { sum })
}

/// The surface's height on the vertical line through `at`: the volume fraction phi (the
/// particles' volume under the hat weights over the hat's volume inside the grid) at points
/// a cell apart up the line, and from the top down the first place it reaches 1/2, between
/// the two points about it by linear interpolation. Water at rest reads its level to a small
/// part of a cell. The floor's height where the line is dry.
///
/// `scratch` lends room for the line's samples past its end, and is given back as it was (the
/// row's own buffer: no allocation once it has grown).
fn surface<const D: usize>(
    sim: &Simulation<D>,
    at: &Vector<D>,
    up: usize,
    scratch: &mut Vec<f64>,
) -> f64 {
    let geo = &sim.grid.geo;
    let h = geo.h;
    let (lo, hi) = (geo.origin, geo.upper());
    let n = geo.cells[up] + 1;
    let ps = &sim.particles;
    // the hat's volume inside the grid across the line
    let mut across = 1.0;
    for d in 0..D {
        if d != up {
            across *= hat_inside(at[d], lo[d], hi[d], h);
        }
    }
    // phi at the points of the line
    let base = scratch.len();
    scratch.resize(base + n, 0.0);
    let phi = &mut scratch[base..];
    for p in 0..ps.len() {
        let mut w = 1.0;
        for d in 0..D {
            if d != up {
                w *= (1.0 - (ps.x[p][d] - at[d]).abs() / h).max(0.0);
            }
        }
        if w == 0.0 {
            continue;
        }
        let s = (ps.x[p][up] - lo[up]) / h;
        let j = (s.floor().max(0.0) as usize).min(n - 2);
        let f = s - j as f64;
        let v = w * ps.volume(p);
        phi[j] += v * (1.0 - f).max(0.0);
        phi[j + 1] += v * f.clamp(0.0, 1.0);
    }
    sim.comm.sum(phi);
    for (j, value) in phi.iter_mut().enumerate() {
        let y = lo[up] + j as f64 * h;
        *value /= across * hat_inside(y, lo[up], hi[up], h);
    }
    let height = match (0..n).rev().find(|&j| phi[j] >= 0.5) {
        Some(j) if j + 1 == n => lo[up] + j as f64 * h,
        Some(j) => lo[up] + j as f64 * h + h * (phi[j] - 0.5) / (phi[j] - phi[j + 1]),
        None => lo[up],
    };
    scratch.truncate(base);
    height
}

/// The force of the material on face `face` (N; N per metre in 2D): what the face's nodes
/// must hold, the sum over them of the internal and gravity forces, -sum_p V_p sigma_p
/// grad N_ip + m_i g. Over a face's nodes the hat weights sum to the weight of the node
/// layer, 1 - |x_a - face| / h along the face's axis a (and 1 across it), so the sum is
///
/// ```text
/// F = sum_{p within h of the face} (-+ V_p sigma_p e_a / h + m_p (1 - |x_a - face| / h) g)
/// ```
///
/// (+ on a lower face, - on an upper one). For water at rest it is the integral of the
/// hydrostatic pressure over the face (the particles' quadrature of it), and on the floor the
/// water's weight.
fn wall_force<const D: usize>(sim: &Simulation<D>, face: usize) -> Vector<D> {
    let geo = &sim.grid.geo;
    let h = geo.h;
    let (a, upper) = (face / 2, face % 2 == 1);
    let at = if upper { geo.upper()[a] } else { geo.origin[a] };
    let sign = if upper { -1.0 } else { 1.0 };
    let g = sim.settings.gravity;
    let ps = &sim.particles;
    let mut f = Vector::<D>::zeros();
    for p in 0..ps.len() {
        let gap = (ps.x[p][a] - at).abs();
        if gap >= h {
            continue;
        }
        // sigma e_a = -p e_a + tau e_a
        let tau = crate::material::deviatoric_stress(ps, &sim.materials, p);
        let mut sigma_a = tau.column(a).into_owned();
        sigma_a[a] -= ps.pressure[p];
        f += sigma_a * (sign * ps.volume(p) / h) + g * (ps.mass[p] * (1.0 - gap / h));
    }
    f
}

/// `[[output.probes]]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeDeck {
    /// Column prefix in probes.csv.
    pub name: String,
    /// Where the grid fields are sampled.
    pub position: Vec<f64>,
    /// What is read there.
    #[serde(default)]
    pub sample: ProbeSample,
    /// With `sample = "particles"`: the half-width of the hat weights (m); the cell size
    /// where absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
}

/// What a gauge reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GaugeKind {
    /// The free surface's height on a vertical line (a wave gauge).
    Surface,
    /// Pressure at a point.
    Pressure,
    /// Velocity at a point.
    Velocity,
    /// The material's force on a wall face.
    WallForce,
}

/// `[[output.gauges]]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GaugeDeck {
    /// Column prefix in gauges.csv.
    pub name: String,
    /// What it reads.
    #[serde(rename = "type")]
    pub kind: GaugeKind,
    /// Where: a point (pressure, velocity), or the horizontal coordinates of a vertical line
    /// (surface).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<Vec<f64>>,
    /// The face of a wall force: "x_min", "x_max", ...
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub face: Option<String>,
}

impl GaugeDeck {
    /// The `[[output.gauges]]` and `output.gauge_interval`: names that head CSV columns,
    /// once each; a wall force on a wall face; a point or a vertical line inside the grid.
    pub(crate) fn check_all(
        gauges: &[GaugeDeck],
        interval: Option<f64>,
        frame: &Frame,
        c: &Check,
    ) -> Result<(), DeckError> {
        let (dim, up) = (frame.dim, frame.up);
        let (lo, hi) = (&frame.lo, &frame.hi);
        if let Some(i) = interval {
            c.positive("output.gauge_interval", i)?;
        }
        for (i, q) in gauges.iter().enumerate() {
            let k = format!("output.gauges[{i}]");
            c.column_name(
                &format!("{k}.name"),
                i,
                gauges.iter().map(|e| e.name.as_str()),
            )?;
            if q.kind == GaugeKind::WallForce {
                if q.position.is_some() {
                    return Err(c.err(
                        format!("{k}.position"),
                        "is not for a wall force, which reads a whole face: give face",
                    ));
                }
                let Some(name) = &q.face else {
                    return Err(c.err(
                        format!("{k}.face"),
                        "a wall force needs the face it reads: \"x_min\", \"x_max\", ...",
                    ));
                };
                let f = frame.face(&format!("{k}.face"), name, c)?;
                if !frame.is_wall(f) {
                    return Err(c.err(
                        format!("{k}.face"),
                        format!("grid.boundary.{name} is not a wall (slip or no_slip): nothing holds the material there"),
                    ));
                }
                continue;
            }
            if q.face.is_some() {
                return Err(c.err(format!("{k}.face"), "is only for type = \"wall_force\""));
            }
            let key = format!("{k}.position");
            let Some(p) = &q.position else {
                return Err(c.err(key, "a gauge needs its position"));
            };
            let (want, axes): (usize, Vec<usize>) = if q.kind == GaugeKind::Surface {
                (dim - 1, (0..dim).filter(|&d| d != up).collect())
            } else {
                (dim, (0..dim).collect())
            };
            if p.len() != want {
                return Err(c.err(
                    key,
                    if q.kind == GaugeKind::Surface {
                        format!(
                            "of a surface gauge is the place of its vertical line, its {} coordinate{} ({} is up, along gravity): {want} number{}, got {}",
                            axes.iter().map(|&d| AXES[d]).collect::<Vec<_>>().join(" and "),
                            if want > 1 { "s" } else { "" },
                            AXES[up],
                            if want > 1 { "s" } else { "" },
                            p.len()
                        )
                    } else {
                        format!("must have {dim} components (dimension = {dim}), got {}", p.len())
                    },
                ));
            }
            for (&d, &x) in axes.iter().zip(p) {
                if !x.is_finite() || x < lo[d] || x > hi[d] {
                    return Err(c.err(
                        key,
                        format!(
                            "lies outside the grid along {}: {} = {x}, the grid spans [{}, {}]",
                            AXES[d], AXES[d], lo[d], hi[d]
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

impl ProbeDeck {
    /// The `[[output.probes]]`: names that head CSV columns, once each; points inside the
    /// grid; a radius only for a particles' reading, and at most the grid's extent.
    pub(crate) fn check_all(
        probes: &[ProbeDeck],
        frame: &Frame,
        c: &Check,
    ) -> Result<(), DeckError> {
        let dim = frame.dim;
        let (lo, hi) = (&frame.lo, &frame.hi);
        for (i, pr) in probes.iter().enumerate() {
            let k = format!("output.probes[{i}]");
            c.column_name(
                &format!("{k}.name"),
                i,
                probes.iter().map(|e| e.name.as_str()),
            )?;
            c.vector(&format!("{k}.position"), &pr.position, dim)?;
            if let Some(r) = pr.radius {
                if pr.sample != ProbeSample::Particles {
                    return Err(c.err(
                            format!("{k}.radius"),
                            "applies to sample = \"particles\" only (the nodes' reading has the shape functions' reach)",
                        ));
                }
                c.positive(&format!("{k}.radius"), r)?;
                let span = (0..dim).map(|d| hi[d] - lo[d]).fold(0.0, f64::max);
                if r > span {
                    return Err(c.err(
                        format!("{k}.radius"),
                        format!("must be at most the grid's extent ({span} m), got {r}"),
                    ));
                }
            }
            if let Some(d) = (0..dim).find(|&d| pr.position[d] < lo[d] || pr.position[d] > hi[d]) {
                return Err(c.err(
                    format!("{k}.position"),
                    format!(
                        "lies outside the grid along {}: {} = {}, the grid spans [{}, {}]",
                        AXES[d], AXES[d], pr.position[d], lo[d], hi[d]
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tank(depth: f64) -> Simulation<2> {
        let text = format!(
            r#"
[simulation]
dimension = 2
scheme = "projection"
end_time = 0.01
dt = 0.001
gravity = [0.0, -9.81]

[grid]
origin = [0.0, 0.0]
size = [0.4, 0.3]
cell_size = 0.01

[grid.boundary]
x_min = "slip"
x_max = "no_slip"
y_min = "slip"
y_max = "slip"

[[materials]]
name = "water"
model = "newtonian"
density = 1000.0
viscosity = 1.0e-3

[[bodies]]
material = "water"
shape = {{ type = "box", min = [0.0, 0.0], max = [0.4, {depth}] }}
"#
        );
        let mut deck = crate::deck::Deck::parse(&text, "t.toml").unwrap();
        deck.validate("t.toml").unwrap();
        let mut sim = Simulation::<2>::new(&deck).unwrap();
        for p in 0..sim.particles.len() {
            sim.particles.pressure[p] = 1000.0 * 9.81 * (depth - sim.particles.x[p][1]);
        }
        sim
    }

    /// Water at rest: a wave gauge reads the particles' surface (the top of the highest
    /// particles' own squares, half a particle spacing above them) within a tenth of a cell,
    /// anywhere across the tank (at a wall too), with the surface on a node row or between.
    #[test]
    fn a_wave_gauge_reads_the_level_of_water_at_rest() {
        for depth in [0.2, 0.2037, 0.2151] {
            let sim = tank(depth);
            let top = sim.particles.x.iter().map(|x| x[1]).fold(0.0, f64::max) + 0.0025;
            for x in [0.0, 0.013, 0.2, 0.4] {
                let at = Vector::<2>::new(x, 0.0);
                let y = surface(&sim, &at, 1, &mut Vec::new());
                assert!((y - top).abs() < 0.1 * 0.01, "{x}: {y} against {top}");
            }
        }
    }

    /// Water at rest, H = 0.2 m, 0.4 m wide: the side walls take rho g H^2 / 2 = 196.2 N/m,
    /// outward, the floor the water's weight, rho g H L = 784.8 N/m, downward, both to
    /// round-off (the particles' quadrature of a linear pressure is exact).
    #[test]
    fn walls_of_a_tank_at_rest_take_the_hydrostatic_force() {
        let sim = tank(0.2);
        let side = 1000.0 * 9.81 * 0.2 * 0.2 / 2.0;
        let left = wall_force(&sim, 0);
        let right = wall_force(&sim, 1);
        let floor = wall_force(&sim, 2);
        assert!((left[0] + side).abs() < 1e-9 * side, "{left}");
        assert!((right[0] - side).abs() < 1e-9 * side, "{right}");
        let weight = 1000.0 * 9.81 * 0.2 * 0.4;
        assert!((floor[1] + weight).abs() < 1e-9 * weight, "{floor}");
    }
}
