//! The room a closed grid leaves for material, and what its inflows bring in over a run: an
//! inflow into a box with no face to leave by fills it, the projection can make no more room,
//! and the particles then pile onto each other (a run ended with 1.7 times the water its box
//! holds). `check` refuses a deck whose inflows bring in more than the room left at t = 0;
//! the run stops (exit status 3) once the material it holds outgrows the room.

use super::{BoundaryKind, Check, Deck, DeckError};

/// Lattice points per axis that measure the room (2D, 3D).
const POINTS: [usize; 2] = [256, 64];

/// Whether no material can leave the grid: no face is open or an outflow, and none moves
/// (a wall's velocity could carry material out).
pub fn closed(deck: &Deck) -> bool {
    deck.grid.boundary.faces().iter().all(|f| {
        f.as_ref().is_none_or(|f| {
            !matches!(f.kind(), BoundaryKind::Open | BoundaryKind::Outflow)
                && f.velocity().is_none()
        })
    })
}

/// The grid's volume (m^3; m^2 in 2D) outside its rigid bodies at t = 0, and outside its
/// `[[bodies]]` too when `bodies`: from a lattice of points over the grid.
pub fn room(deck: &Deck, bodies: bool) -> f64 {
    let dim = deck.simulation.dimension;
    let mut solids: Vec<crate::geometry::Solid> = deck
        .rigid_bodies
        .iter()
        .filter_map(|r| r.shape.solid(dim).ok())
        .collect();
    if bodies {
        solids.extend((0..deck.bodies.len()).filter_map(|b| deck.body_solid(b).ok()));
    }
    let g = &deck.grid;
    let volume: f64 = g.size.iter().product();
    let n = POINTS[usize::from(dim == 3)];
    let total = n.pow(dim as u32);
    let mut x = vec![0.0; dim];
    let free = (0..total)
        .filter(|&k| {
            for (d, c) in x.iter_mut().enumerate() {
                let i = (k / n.pow(d as u32)) % n;
                *c = g.origin[d] + g.size[d] * (i as f64 + 0.5) / n as f64;
            }
            !solids.iter().any(|s| s.contains(&x))
        })
        .count();
    volume * free as f64 / total as f64
}

/// The volume the inflows' patches let in over [0, end_time] at their velocities (the flux
/// into the grid, integrated at the midpoints of 128 intervals of time and of up to 32 pieces
/// of the patch per axis).
pub fn inflow_volume(deck: &Deck) -> f64 {
    const TIMES: usize = 128;
    const PIECES: usize = 32;
    let dim = deck.simulation.dimension;
    let end = deck.simulation.end_time;
    let mut sum = 0.0;
    for q in &deck.inflows {
        let Some(f) = super::FACE_NAMES.iter().position(|n| *n == q.face) else {
            continue;
        };
        let Ok(field) = q.velocity.compile() else {
            continue;
        };
        let axis = f / 2;
        let sign = if f % 2 == 0 { 1.0 } else { -1.0 };
        let pieces: Vec<usize> = (0..dim)
            .map(|d| if d == axis { 1 } else { PIECES })
            .collect();
        let area: f64 = (0..dim)
            .filter(|&d| d != axis)
            .map(|d| q.max[d] - q.min[d])
            .product();
        let count: usize = pieces.iter().product();
        let weight = area / count as f64 * end / TIMES as f64;
        for m in 0..count {
            let mut rem = m;
            let x: Vec<f64> = (0..dim)
                .map(|d| {
                    let i = rem % pieces[d];
                    rem /= pieces[d];
                    q.min[d] + (q.max[d] - q.min[d]) * (i as f64 + 0.5) / pieces[d] as f64
                })
                .collect();
            for k in 0..TIMES {
                let t = end * (k as f64 + 0.5) / TIMES as f64;
                let v = field.eval_at(&x, t);
                sum += (sign * v[axis]).max(0.0) * weight;
            }
        }
    }
    sum
}

impl Deck {
    /// Inflows into a closed grid bring in no more than the room its bodies and rigid bodies
    /// leave at t = 0.
    pub(super) fn check_inflow_room(&self, c: &Check) -> Result<(), DeckError> {
        if self.inflows.is_empty() || !closed(self) {
            return Ok(());
        }
        let brought = inflow_volume(self);
        let left = room(self, true);
        if brought <= left {
            return Ok(());
        }
        let unit = if self.simulation.dimension == 3 {
            "m3"
        } else {
            "m2"
        };
        let short = |x: f64| format!("{x:.3e}");
        Err(c.err(
            "inflows[0].velocity",
            format!(
                "the inflows bring in about {} {unit} of material by simulation.end_time = {} s, and the grid has room for about {} {unit} beside its bodies and rigid bodies, with no open or outflow face for it to leave by: the inflow would fill the domain; make a face \"outflow\", slow the inflow or shorten the run",
                short(brought),
                crate::limits::short(self.simulation.end_time),
                short(left)
            ),
        ))
    }
}

/// A run's guard against an inflow that has filled a closed grid: the room the rigid bodies
/// leave (None when material can leave the grid or nothing enters).
pub fn run_room(deck: &Deck) -> Option<f64> {
    (!deck.inflows.is_empty() && closed(deck)).then(|| room(deck, false))
}
