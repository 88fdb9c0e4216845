//! The particles at t = 0: each `[[bodies]]` entry filled with a regular lattice of spacing
//! s = h / particles_per_cell, lattice points at the centres of the sub-cells, and the
//! particles' volumes (and masses) scaled so that the body holds rho times its shape's volume.
//!
//! A lattice point stands for the cube of side s about it, so a face that falls between
//! lattice rows is rounded to the nearest row: a body 0.55 m high at s = 2 cm is seeded as
//! 0.56 m of lattice. Each particle's volume is therefore V0 = s^D V / (N s^D), with V the
//! volume of the body's shape inside the grid and N the lattice points in it: the mass is
//! right, and the lattice (which the transfers need regular) is kept. The grid's faces lie on
//! lattice rows, so they round nothing. The rigid bodies are left out of both V and N: the
//! points inside one get no particle, and the cut cells take the part of a cell a body's face
//! leaves open as the cell beyond it (docs/deck.md), which keeps water at rest against a face
//! between rows exact; scaling for that sliver would move the whole body's free surface.
//! V is in closed form where the shape has one and lies wholly in the grid
//! ([`crate::geometry::Solid::volume`]); elsewhere it is integrated on the lattice, each cell
//! whose centre's side differs from a neighbour's sampled by M^D points (M = 32 in 2D, 8 in
//! 3D: a face placed to s / (2M)). Written by hand: it is the seeding loop's own inside test,
//! counted.

use crate::deck::{Deck, DeckError, Transfer};
use crate::geometry::Solid;
use crate::grid::{GridGeometry, Vector};
use crate::particles::{InitialStress, Matrix, Particles};
use crate::rigid::RigidBodies;
use crate::scheme::Scheme;
use rayon::prelude::*;

/// What one body's lattice holds against the shape it fills.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seeding {
    /// Particles placed.
    pub particles: usize,
    /// The lattice's volume in the shape and the grid, its points there times s^D (m3; m2
    /// in 2D), the rigid bodies' included.
    pub lattice_volume: f64,
    /// The shape's volume inside the grid.
    pub volume: f64,
    /// The particles' volume: the particles times s^D, scaled by volume / lattice_volume.
    pub seeded: f64,
}

impl Seeding {
    /// The lattice's volume over the shape's, less 1 (0 where the body is empty).
    pub fn excess(&self) -> f64 {
        if self.volume > 0.0 {
            self.lattice_volume / self.volume - 1.0
        } else {
            0.0
        }
    }
}

/// Sub-points per lattice spacing along each axis where a cell is cut by the body's surface.
fn samples(dim: usize) -> usize {
    if dim == 2 {
        32
    } else {
        8
    }
}

/// The lattice points over a body's bounding box: index `first..=last` along each axis.
struct Lattice<const D: usize> {
    origin: Vector<D>,
    spacing: f64,
    first: [i64; D],
    last: [i64; D],
}

impl<const D: usize> Lattice<D> {
    fn point(&self, idx: &[i64; D]) -> Vector<D> {
        Vector::<D>::from_fn(|d, _| self.origin[d] + (idx[d] as f64 + 0.5) * self.spacing)
    }
    fn extent(&self, d: usize) -> usize {
        (self.last[d] - self.first[d] + 1).max(0) as usize
    }
    fn len(&self) -> usize {
        (0..D).map(|d| self.extent(d)).product()
    }
    /// The index of flat position `k` (axis 0 fastest).
    fn index(&self, mut k: usize) -> [i64; D] {
        std::array::from_fn(|d| {
            let n = self.extent(d);
            let i = self.first[d] + (k % n) as i64;
            k /= n;
            i
        })
    }
}

/// Fills every body of the deck, in deck order, leaving out what lies in `rigid` (at t = 0),
/// and keeping only the particles that `keep` takes (given each particle's id and place): a
/// rank of a distributed run builds its own part, never the whole. Ids, volumes, masses, the
/// hydrostatic pressure and the report are those of the whole seeding.
pub fn fill<const D: usize>(
    deck: &Deck,
    geo: &GridGeometry<D>,
    rigid: &RigidBodies<D>,
    keep: &mut dyn FnMut(u32, &Vector<D>) -> bool,
) -> Result<(Particles<D>, Vec<Seeding>), DeckError> {
    let mut ps = Particles::default();
    let mut report = Vec::with_capacity(deck.bodies.len());
    let mut next_id = 0;
    for b in 0..deck.bodies.len() {
        report.push(fill_body(deck, b, geo, rigid, keep, &mut next_id, &mut ps)?);
    }
    let n = ps.len();
    // the lattice loop grew the arrays by doubling: give back the unused half
    ps.shrink_to_fit();
    ps.set_stored(deck.stored_fields());
    ps.velocity_gradient = vec![Matrix::<D>::zeros(); n];
    if deck.simulation.transfer != Some(Transfer::Apic) {
        ps.affine = vec![Matrix::<D>::zeros(); n];
    }
    Ok((ps, report))
}

/// Body `b`'s particles appended to `ps`: the lattice points inside its shape, the grid and
/// no rigid body, at its initial velocity and stress, with volumes scaled to the shape's;
/// numbered from `next_id` on, and only those `keep` takes.
fn fill_body<const D: usize>(
    deck: &Deck,
    b: usize,
    geo: &GridGeometry<D>,
    rigid: &RigidBodies<D>,
    keep: &mut dyn FnMut(u32, &Vector<D>) -> bool,
    next_id: &mut u32,
    ps: &mut Particles<D>,
) -> Result<Seeding, DeckError> {
    let body = &deck.bodies[b];
    let solid = deck.body_solid(b)?;
    let mat = deck
        .materials
        .iter()
        .position(|m| m.name == body.material)
        .expect("validated: body material exists");
    let rho = deck.materials[mat].density;
    let ppc = body.particles_per_cell;
    let lattice = lattice_over(&solid, geo, geo.h / ppc as f64);
    let vol = lattice.spacing.powi(D as i32);
    let apic = deck.simulation.transfer == Some(Transfer::Apic);
    let isochoric = deck.simulation.scheme == Scheme::Projection;
    let inside = |x: &Vector<D>| geo.contains(x) && solid.contains(x.as_slice());
    let start = ps.len();
    let velocity = body.velocity.compile().expect("validated expressions");
    let down = (body.stress == Some(InitialStress::Hydrostatic))
        .then(|| downward(deck, geo))
        .flatten();
    // the highest particle along -g, of the whole seeding (not only of those kept)
    let mut top = f64::NEG_INFINITY;
    let mut placed = 0;
    // each lattice point's side, kept for the volume's integration
    let mut status = vec![false; lattice.len()];
    for (k, s) in status.iter_mut().enumerate() {
        let x = lattice.point(&lattice.index(k));
        *s = inside(&x);
        if !*s || rigid.contains(&x) {
            continue;
        }
        let id = *next_id;
        *next_id += 1;
        placed += 1;
        if let Some((down, _)) = &down {
            top = top.max(-x.dot(down));
        }
        if !keep(id, &x) {
            continue;
        }
        ps.id.push(id);
        ps.x.push(x);
        ps.v.push(velocity.eval(&x, 0.0));
        if apic {
            ps.affine.push(initial_affine(
                &velocity,
                &x,
                1e-3 * lattice.spacing,
                isochoric,
            ));
        }
        ps.mass.push(rho * vol);
        ps.volume0.push(vol);
        ps.material.push(mat as u16);
        ps.half_width.push(0.5 / ppc as f64);
    }
    let n = ps.len();
    ps.jacobian.resize(n, 1.0);
    ps.pressure.resize(n, 0.0);
    if let Some((down, gnorm)) = down {
        let top = top + 0.5 * lattice.spacing;
        hydrostatic(deck, mat, down, gnorm, top, start, ps);
    }
    let count = placed;
    let points = status.iter().filter(|s| **s).count();
    let mut seeding = Seeding {
        particles: count,
        lattice_volume: points as f64 * vol,
        volume: shape_volume(&solid, geo, &lattice, &status, &inside),
        seeded: count as f64 * vol,
    };
    // a lattice that fits its shape (to round-off) is left as it is, bit for bit
    if points > 0 && seeding.volume > 0.0 && seeding.excess().abs() > 1e-12 {
        let scale = seeding.volume / seeding.lattice_volume;
        for p in start..n {
            ps.volume0[p] *= scale;
            ps.mass[p] *= scale;
        }
        seeding.seeded *= scale;
    }
    Ok(seeding)
}

/// The lattice of `spacing` over the solid's bounding box, cut off at the grid (a half-space
/// has no bound of its own).
fn lattice_over<const D: usize>(solid: &Solid, geo: &GridGeometry<D>, spacing: f64) -> Lattice<D> {
    let (lo, hi) = solid.bounds();
    let up = geo.upper();
    let first = std::array::from_fn(|d| {
        ((lo[d].max(geo.origin[d]) - geo.origin[d]) / spacing - 0.5).floor() as i64
    });
    let last =
        std::array::from_fn(|d| ((hi[d].min(up[d]) - geo.origin[d]) / spacing - 0.5).ceil() as i64);
    Lattice {
        origin: geo.origin,
        spacing,
        first,
        last,
    }
}

/// The direction of the body force at the grid's origin at t = 0, and its magnitude; `None`
/// without one.
fn downward<const D: usize>(deck: &Deck, geo: &GridGeometry<D>) -> Option<(Vector<D>, f64)> {
    let g = deck
        .simulation
        .gravity
        .compile()
        .expect("validated expressions")
        .eval(&geo.origin, 0.0);
    let gnorm = g.norm();
    (gnorm != 0.0).then(|| (g / gnorm, gnorm))
}

/// The initial pressure p = rho |g| (H - y) of particles `start..`, H = `top`, the body's top
/// along -g (`down`, the body force at the grid's origin at t = 0, of magnitude `gnorm`).
/// With an equation of state p = K (1 - J) the particle is compressed: it fills its lattice
/// volume now, so its reference volume and mass are larger.
fn hydrostatic<const D: usize>(
    deck: &Deck,
    mat: usize,
    down: Vector<D>,
    gnorm: f64,
    top: f64,
    start: usize,
    ps: &mut Particles<D>,
) {
    let rho = deck.materials[mat].density;
    for p in start..ps.len() {
        ps.pressure[p] = rho * gnorm * (top + ps.x[p].dot(&down));
        if let Some(k) = deck.materials[mat].bulk_modulus {
            let j = 1.0 - ps.pressure[p] / k;
            ps.jacobian[p] = j;
            ps.volume0[p] /= j;
            ps.mass[p] /= j;
        }
    }
}

/// The volume of the part of `solid` that `inside` admits (the grid's): in closed form where
/// the solid has one and lies in the grid; else the lattice's cells counted, those on the
/// surface (a neighbour along an axis on the other side) by sub-points.
fn shape_volume<const D: usize>(
    solid: &Solid,
    geo: &GridGeometry<D>,
    lattice: &Lattice<D>,
    status: &[bool],
    inside: &(impl Fn(&Vector<D>) -> bool + Sync),
) -> f64 {
    let (lo, hi) = solid.bounds();
    let (glo, ghi) = (geo.origin, geo.upper());
    if let (Some(v), true) = (
        solid.volume(),
        (0..D).all(|d| lo[d] >= glo[d] && hi[d] <= ghi[d]),
    ) {
        return v;
    }
    let m = samples(D);
    let sub = lattice.spacing / m as f64;
    let cell = lattice.spacing.powi(D as i32);
    let on_surface = |k: usize| {
        let idx = lattice.index(k);
        (0..D).any(|d| {
            [-1, 1].into_iter().any(|step| {
                let mut j = idx;
                j[d] += step;
                let other = (j[d] >= lattice.first[d] && j[d] <= lattice.last[d]) && {
                    // flat position of j
                    let mut flat = 0;
                    for e in (0..D).rev() {
                        flat = flat * lattice.extent(e) + (j[e] - lattice.first[e]) as usize;
                    }
                    status[flat]
                };
                other != status[k]
            })
        })
    };
    // each cell's share, in lattice order (the sum is then the same for any thread count)
    let shares: Vec<f64> = (0..status.len())
        .into_par_iter()
        .map(|k| {
            if !on_surface(k) {
                return if status[k] { cell } else { 0.0 };
            }
            let centre = lattice.point(&lattice.index(k));
            let mut hits = 0usize;
            for q in 0..m.pow(D as u32) {
                let mut r = q;
                let x = Vector::<D>::from_fn(|d, _| {
                    let i = r % m;
                    r /= m;
                    centre[d] - 0.5 * lattice.spacing + (i as f64 + 0.5) * sub
                });
                hits += inside(&x) as usize;
            }
            cell * hits as f64 / m.pow(D as u32) as f64
        })
        .collect();
    shares.iter().sum()
}

/// APIC's affine matrix C_p at t = 0: the gradient of the body's initial velocity field at `x`
/// (central differences over `eps`; exact for the linear field of a rigid rotation or a shear,
/// zero for a uniform velocity), less its trace under the projection as after every transfer.
/// Left at zero, the first transfer drops the velocity's variation around each particle, and
/// a spinning block loses angular momentum in its first step.
fn initial_affine<const D: usize>(
    velocity: &crate::field::CompiledField,
    x: &Vector<D>,
    eps: f64,
    isochoric: bool,
) -> Matrix<D> {
    let mut c = Matrix::<D>::zeros();
    for d in 0..D {
        let mut e = Vector::<D>::zeros();
        e[d] = eps;
        let dv = (velocity.eval(&(x + e), 0.0) - velocity.eval(&(x - e), 0.0)) / (2.0 * eps);
        c.set_column(d, &dv);
    }
    crate::transfer::affine(c, isochoric)
}
