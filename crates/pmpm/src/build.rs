//! The one place a checked deck becomes a simulation: each part (particles, materials,
//! transfers, walls, rigid bodies, the projection) is built from the settings its module
//! defines, and the step never sees the deck.

use crate::averaging::{NodalAveraging, VolumetricAveraging};
use crate::boundary::{Boundary, BoundaryKind};
use crate::deck::RigidMotion;
use crate::deck::{Deck, DeckError, MaterialDeck, ProbeSample};
use crate::driver::{Clock, StepSize};
use crate::error::Error;
use crate::grid::{GridGeometry, Vector};
use crate::material::MaterialParams;
use crate::particles::Particles;
use crate::pressure::{DensityCorrection, Packing, PressureUnknowns, Projection};
use crate::rigid::{Free, Motion, Pose, RigidBodies, RigidBox, ShapedBody};
use crate::scheme::{least_density, Parts, Scheme, Simulation, StepPolicy, Stepper, LIGHT_NODE};
use crate::seed::Seeding;
use crate::transfer::TransferSettings;
use crate::wall_law::{WallFriction, WallLaw};

impl<const D: usize> Simulation<D> {
    /// Sets up particles, grid and every part of the step from a validated deck.
    pub fn new(deck: &Deck) -> Result<Self, Error> {
        Self::new_part(deck, &crate::comm::Serial, &mut |_, _| true)
    }

    /// [`Simulation::new`] for one rank of `comm`'s: only the particles `keep` takes (given
    /// each one's id and place) are built, and what the setup reads of the particles (a body
    /// left empty, a value that is not finite, the lightest particle) is found over every
    /// rank's. Every rank calls it, with the same deck.
    pub fn new_part(
        deck: &Deck,
        comm: &dyn crate::comm::Comm,
        keep: &mut dyn FnMut(u32, &Vector<D>) -> bool,
    ) -> Result<Self, Error> {
        let geo = grid_geometry::<D>(deck);
        let h = geo.h;
        let particles = part(deck, &geo, keep)?;
        let solids = (0..deck.bodies.len())
            .map(|b| deck.body_solid(b))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some(b) = (0..deck.bodies.len())
            .find(|&b| !comm.any(particles.x.iter().any(|x| solids[b].contains(x.as_slice()))))
        {
            let spacing = h / deck.bodies[b].particles_per_cell as f64;
            return Err(DeckError {
                file: String::new(),
                key: format!("bodies[{b}].shape"),
                line_col: None,
                message: format!(
                    "holds no particle: it is smaller than the particle spacing h / particles_per_cell = {spacing}"
                ),
            }
            .into());
        }
        let gravity = deck
            .simulation
            .gravity
            .compile()
            .expect("validated expressions");
        let why = not_finite(&particles, deck, &solids, |x| gravity.eval(x, 0.0));
        if let Some(why) = agree_on_first(comm, why) {
            return Err(why.into());
        }
        let materials: Vec<MaterialParams> =
            deck.materials.iter().map(MaterialDeck::params).collect();
        let min_mass = least(
            comm,
            particles.mass.iter().copied().fold(f64::INFINITY, f64::min),
        );
        let implicit_viscosity =
            deck.simulation.viscosity == Some(crate::viscosity::ViscosityTreatment::Implicit);
        let settings = TransferSettings {
            shape: deck.simulation.shape_function,
            transfer: deck.simulation.transfer.unwrap_or_default(),
            flip_ratio: deck.simulation.flip_ratio,
            gravity: gravity.eval(&geo.origin, 0.0),
            pressure_weight: match deck.simulation.scheme {
                Scheme::Explicit => 1.0,
                // the projection applies its pressure on the grid
                Scheme::Projection => 0.0,
            },
            // below a millionth of a particle's smallest weight a node is empty
            mass_epsilon: 1e-12 * min_mass,
            // with one pressure per cell (solids) the cells' constraint is built on v* as it is,
            // and a solid's stress is real up to its edge
            mass_floor: match (deck.simulation.scheme, deck.pressure.unknowns) {
                (Scheme::Projection, PressureUnknowns::Nodes) => {
                    LIGHT_NODE * least(comm, least_density(&particles)) * geo.h.powi(D as i32)
                }
                _ => 0.0,
            },
            isochoric_affine: deck.simulation.scheme == Scheme::Projection,
            implicit_stress: if implicit_viscosity {
                crate::viscosity::implicit_mask(&materials)
            } else {
                0
            },
        };
        let boundary = boundary(deck, &geo, settings.mass_epsilon);
        let probes = probes(deck, &geo);
        let stepper = stepper(deck, &particles, &boundary, &geo, &settings);
        // the projection with nodal pressures reads J with the nodally averaged dilatation (the
        // F-bar idea): its velocity is divergence free node by node, in the weak sense, not at
        // each particle, and the density correction restores volumes node by node
        // (docs/method.md). A particle's own divergence lets single particles of a stretching
        // flow (the lid-driven cavity) swell to several cells
        let averaged = deck.simulation.scheme == Scheme::Projection
            && deck.pressure.unknowns == PressureUnknowns::Nodes;
        let averaging = (deck.simulation.volumetric_averaging == VolumetricAveraging::Nodal
            || averaged)
            .then(|| NodalAveraging::new(rayon::current_num_threads(), geo.node_count()));
        let zones: Vec<crate::damping::DampingZone> = deck
            .damping_zones
            .iter()
            .map(crate::deck::DampingZoneDeck::zone)
            .collect();
        let damping = crate::damping::node_rates(&zones, &geo);
        let parts = Parts {
            damping,
            policy: step_policy(deck),
            particles,
            geo,
            materials,
            settings,
            boundary,
            probes,
            stepper,
            averaging,
            body_force: (!gravity.is_constant()).then_some(gravity),
            viscosity: deck.viscous_solve().then(|| {
                crate::viscosity::ImplicitViscosity::new(
                    deck.simulation.viscosity_tolerance,
                    deck.simulation.viscosity_max_iterations,
                    settings.implicit_stress,
                    settings.shape,
                    settings.mass_epsilon,
                )
            }),
        };
        let mut sim = Self::from_parts(parts);
        sim.seeded = comm.sum_scalar(sim.particles.len() as f64) as usize;
        sim.ledger.mass0 = comm.sum_scalar(sim.ledger.mass0);
        sim.ledger.next_id = sim.seeded as u32;
        Ok(sim)
    }
}

/// The scheme's state: the projection with its solves, or the explicit scheme with its
/// packing where `density_correction = "particles"`; the free surface's ceilings from the body
/// force at the origin.
fn stepper<const D: usize>(
    deck: &Deck,
    particles: &Particles<D>,
    boundary: &Boundary<D>,
    geo: &GridGeometry<D>,
    settings: &TransferSettings<D>,
) -> Stepper<D> {
    let (pd, shape) = (&deck.pressure, deck.simulation.shape_function);
    let cells = geo.cells.iter().product();
    let gravity = settings.gravity.as_slice();
    match deck.simulation.scheme {
        Scheme::Explicit => Stepper::Explicit(
            (pd.density_correction == Some(DensityCorrection::Particles))
                .then(|| Box::new(Packing::new(pd, shape, boundary, cells, gravity))),
        ),
        Scheme::Projection => {
            let solids = deck.materials.iter().any(MaterialDeck::is_solid);
            let epsilon = settings.mass_epsilon;
            let mut p = Projection::new(pd, shape, solids, particles, boundary, cells, epsilon);
            p.shared.surface.set_ceilings(gravity);
            Stepper::Projection(Box::new(p))
        }
    }
}

/// Each probe's place, and the radius of its particles' mean (None: it reads the nodes).
fn probes<const D: usize>(deck: &Deck, geo: &GridGeometry<D>) -> Vec<(Vector<D>, Option<f64>)> {
    deck.output
        .probes
        .iter()
        .map(|p| {
            let radius = (p.sample == ProbeSample::Particles).then(|| p.radius.unwrap_or(geo.h));
            (Vector::<D>::from_column_slice(&p.position), radius)
        })
        .collect()
}

/// The grid of a validated deck: its origin, cells and periodic axes.
pub fn grid_geometry<const D: usize>(deck: &Deck) -> GridGeometry<D> {
    let g = &deck.grid;
    let counts = g.cells();
    let cells: [usize; D] = std::array::from_fn(|d| counts[d]);
    let faces = g.boundary.faces();
    let periodic: [bool; D] = std::array::from_fn(|d| {
        faces[2 * d].as_ref().map(|f| f.kind()) == Some(BoundaryKind::Periodic)
    });
    GridGeometry::new(
        Vector::<D>::from_column_slice(&g.origin),
        g.cell_size,
        cells,
    )
    .with_periodic(periodic)
}

/// The step's own settings of a validated deck.
pub fn step_policy(deck: &Deck) -> StepPolicy {
    let s = &deck.simulation;
    StepPolicy {
        sort_interval: s.sort_interval,
        damping: s.damping,
        stress_update: s.stress_update,
        volume_limits: s.volume_limits,
        max_dt: s.max_dt,
        dt: s.dt,
    }
}

/// The time-step policy of a validated deck: its end, frame interval and step size.
pub fn clock(deck: &Deck) -> Clock {
    let s = &deck.simulation;
    let step = match (s.dt, s.cfl) {
        (Some(dt), _) => StepSize::Fixed(dt),
        (None, cfl) => StepSize::Adaptive {
            cfl: cfl.unwrap_or(0.5),
            land_on_frames: s.land_on_frames.unwrap_or(s.scheme == Scheme::Explicit),
        },
    };
    Clock {
        end: s.end_time,
        interval: deck.output.interval.unwrap_or(s.end_time),
        step,
    }
}

/// The walls and rigid bodies of a validated deck on a grid; below `mass_epsilon` a node is
/// empty (the walls' friction passes it by).
pub fn boundary<const D: usize>(
    deck: &Deck,
    geo: &GridGeometry<D>,
    mass_epsilon: f64,
) -> Boundary<D> {
    let faces: Vec<(BoundaryKind, Vector<D>)> = deck.grid.boundary.faces()[..2 * D]
        .iter()
        .map(|f| {
            let f = f.as_ref().expect("validated: every face filled in");
            let v = f
                .velocity()
                .map(|v| {
                    let c = v.compile().expect("validated expressions");
                    c.eval(&geo.origin, 0.0)
                })
                .unwrap_or_else(Vector::<D>::zeros);
            (f.kind(), v)
        })
        .collect();
    let fields: Vec<Option<crate::field::CompiledField>> = deck.grid.boundary.faces()[..2 * D]
        .iter()
        .map(|f| {
            let c = f.as_ref()?.velocity()?.compile().ok()?;
            (!c.is_constant()).then_some(c)
        })
        .collect();
    // under the nodal projection a ghost node behind a face mirrors the node as far inside it
    let mirrors = deck.simulation.scheme == Scheme::Projection
        && deck.pressure.unknowns == PressureUnknowns::Nodes;
    let separating = deck.grid.boundary.contact == Some(crate::deck::WallContact::Separating);
    let friction = (deck.grid.boundary.friction == Some(WallFriction::WallLaw)).then(|| {
        // the checks let the law on with one Newtonian fluid only
        let m = &deck.materials[0];
        let ppc = deck.bodies.first().map_or(2, |b| b.particles_per_cell);
        WallLaw::new(
            m.density,
            m.viscosity,
            geo.h,
            D,
            deck.simulation.shape_function,
            0.5 / ppc as f64,
        )
    });
    Boundary::new(faces, fields, mirrors, rigid_bodies(deck), geo)
        .with_separation(separating)
        .with_friction(friction, geo, mass_epsilon)
        .with_inflows(
            crate::flow::InflowDeck::build(
                &deck.inflows,
                &deck
                    .materials
                    .iter()
                    .map(|m| (m.name.as_str(), m.density))
                    .collect::<Vec<_>>(),
                geo,
            ),
            // the rows of nodes a particle less than a cell from the face reads from
            match deck.simulation.shape_function {
                crate::shape::ShapeFunction::Linear => 1,
                _ => 2,
            },
            geo,
        )
}

/// The rigid bodies of a validated deck.
pub fn rigid_bodies<const D: usize>(deck: &Deck) -> RigidBodies<D> {
    let v = |x: &[f64]| Vector::<D>::from_column_slice(x);
    let dim = deck.simulation.dimension;
    let bodies: Vec<RigidBox<D>> = deck
        .rigid_bodies
        .iter()
        .map(|b| {
            let shaped = b.is_shaped().then(|| shaped_body::<D>(deck, b));
            let (lo, hi) = match &shaped {
                // a shaped body's box is its bounds (for the reach of its nodes)
                Some(_) => {
                    let (lo, hi) = b.shape.solid(dim).expect("validated shape").bounds();
                    (v(&lo), v(&hi))
                }
                None => (
                    v(b.shape
                        .min
                        .as_deref()
                        .expect("validated: a rigid box has min")),
                    v(b.shape
                        .max
                        .as_deref()
                        .expect("validated: a rigid box has max")),
                ),
            };
            let free = (shaped.is_none() && b.motion == RigidMotion::Free).then(|| {
                let volume: f64 = (0..D).map(|d| hi[d] - lo[d]).product();
                let r = 0.5 * (hi - lo).norm();
                free_motion(deck, b, volume, nalgebra::Matrix3::zeros(), r)
            });
            RigidBox {
                lo,
                hi,
                velocity: b.velocity.as_ref().map_or_else(Vector::<D>::zeros, |f| {
                    f.compile()
                        .expect("validated expressions")
                        .eval(&Vector::<D>::zeros(), 0.0)
                }),
                motion: b
                    .velocity
                    .as_ref()
                    .map(|f| f.compile().expect("validated expressions"))
                    .filter(|f| !f.is_constant() && free.is_none()),
                sides: b.sides,
                shaped,
                free,
            }
        })
        .collect();
    let cut = deck.simulation.scheme == Scheme::Projection
        && deck.pressure.cuts_cells(deck.simulation.shape_function);
    RigidBodies::new(&bodies, cut)
}

/// A rigid body of the general path ([`crate::rigid`]): its shape (cut to the grid, grown by a
/// cell, where it is unbounded), its motion, and its pose at t = 0.
fn shaped_body<const D: usize>(deck: &Deck, b: &crate::deck::RigidBodyDeck) -> ShapedBody {
    use nalgebra::Vector3;
    let dim = deck.simulation.dimension;
    let shape = deck
        .rigid_shape(b)
        .expect("validated: the shape holds a volume");
    let compile = |f: &crate::field::VectorField| f.compile().expect("validated expressions");
    let velocity = b.velocity.as_ref().map(compile);
    let spin = b.angular_velocity.as_ref().map(|w| compile(&w.field()));
    let mut start = Pose::at(shape.reference());
    if let Some(f) = &velocity {
        start.velocity = f.eval_t(0.0);
    }
    if let Some(f) = &spin {
        let w = f.eval_t(0.0);
        start.omega = if dim == 2 {
            Vector3::new(0.0, 0.0, w[0])
        } else {
            w
        };
    }
    let motion = match b.motion {
        RigidMotion::Prescribed => Motion::Prescribed { velocity, spin },
        RigidMotion::Free => Motion::Free(free_motion(
            deck,
            b,
            shape.volume,
            shape.inertia,
            shape.radius(),
        )),
    };
    ShapedBody {
        shape: std::sync::Arc::new(shape),
        motion,
        start,
    }
}

/// A free body's mass and inertia (from its `volume` and its second moments `moments` about
/// its centroid per unit density), gravity, the motions it keeps still, and the added mass
/// the coupling assumes ([`crate::rigid::Free::advance`]): the densest material's mass in the
/// disc (2D) or ball of radius `r` about the centroid that holds the body, above the added
/// mass of any body it holds (a plate's across the disc, rho pi a^2, is the most), so that
/// the coupling is stable at any density; for the rotation that ball's polar moment less the
/// body's least moment, at least 0.
fn free_motion(
    deck: &Deck,
    b: &crate::deck::RigidBodyDeck,
    volume: f64,
    moments: nalgebra::Matrix3<f64>,
    r: f64,
) -> Free {
    let dim = deck.simulation.dimension;
    let density = b.density.expect("validated: a free body has a density");
    let gravity = deck
        .simulation
        .gravity
        .compile()
        .expect("validated expressions")
        .eval_t(0.0);
    let fluid = deck.materials.iter().map(|m| m.density).fold(0.0, f64::max);
    let ball = if dim == 2 {
        std::f64::consts::PI * r * r
    } else {
        4.0 / 3.0 * std::f64::consts::PI * r * r * r
    };
    let held = |n: &str| b.fixed.iter().any(|f| f == n);
    // the rotation's assumed added inertia: the ball's (disc's) of water, less the body's own
    // least moment. The coupling is stable for any assumed value above half the true added
    // inertia less the body's (at most the ball's, less the body's); the part above the true
    // one feeds the spin through the lagged term (docs/method.md, "Free rigid bodies")
    let inertia = moments * density;
    let least_moment = if dim == 2 {
        inertia[(2, 2)]
    } else {
        inertia.symmetric_eigenvalues().min()
    };
    Free {
        mass: density * volume,
        inertia,
        gravity,
        held_axes: [held("x"), held("y"), held("z")],
        held_rotation: held("rotation"),
        dim,
        added_mass: fluid * ball,
        added_inertia: (0.5 * fluid * ball * r * r - least_moment).max(0.0),
    }
}

/// Fills every body of the deck with particles ([`crate::seed`]), none inside a rigid body.
pub fn particles<const D: usize>(
    deck: &Deck,
    geo: &GridGeometry<D>,
) -> Result<Particles<D>, DeckError> {
    seeded(deck, geo).map(|(ps, _)| ps)
}

/// [`particles`], only those `keep` takes (given each one's id and place).
pub fn part<const D: usize>(
    deck: &Deck,
    geo: &GridGeometry<D>,
    keep: &mut dyn FnMut(u32, &Vector<D>) -> bool,
) -> Result<Particles<D>, DeckError> {
    seeded_part(deck, geo, keep).map(|(ps, _)| ps)
}

/// The least `x` over `comm`'s ranks.
fn least(comm: &dyn crate::comm::Comm, x: f64) -> f64 {
    -comm.max_scalar(-x)
}

/// The first rank's deck error on every rank (its key and message); `None` where no rank
/// has one.
fn agree_on_first(comm: &dyn crate::comm::Comm, found: Option<DeckError>) -> Option<DeckError> {
    if !comm.is_distributed() {
        return found;
    }
    let said = comm.agree(found.map(|e| format!("{}\n{}", e.key, e.message)))?;
    let (key, message) = said.split_once('\n').unwrap_or(("", &said));
    Some(DeckError {
        file: String::new(),
        key: key.to_string(),
        line_col: None,
        message: message.to_string(),
    })
}

/// The particles, and what each body's lattice holds against its shape (`check` reports it).
pub fn seeded<const D: usize>(
    deck: &Deck,
    geo: &GridGeometry<D>,
) -> Result<(Particles<D>, Vec<Seeding>), DeckError> {
    seeded_part(deck, geo, &mut |_, _| true)
}

/// [`seeded`], only the particles `keep` takes.
fn seeded_part<const D: usize>(
    deck: &Deck,
    geo: &GridGeometry<D>,
    keep: &mut dyn FnMut(u32, &Vector<D>) -> bool,
) -> Result<(Particles<D>, Vec<Seeding>), DeckError> {
    // no material starts inside a rigid body: a body of water drawn around an obstacle, or
    // under a floating box, fills only the room the rigid bodies leave (`check` counts what
    // they take)
    let mut rigid = rigid_bodies::<D>(deck);
    rigid.set_time(0.0, geo);
    crate::seed::fill(deck, geo, &rigid, keep)
}

/// The first expression field that is not a finite number where the run reads it at t = 0: a
/// body's initial velocity at one of its particles, or the body force at the grid's origin
/// (the hydrostatic initial stress) or at a particle. `check` calls the deck valid only when
/// the run can start.
fn not_finite<const D: usize>(
    ps: &Particles<D>,
    deck: &Deck,
    solids: &[crate::geometry::Solid],
    gravity: impl Fn(&Vector<D>) -> Vector<D>,
) -> Option<DeckError> {
    let error = |key: String, x: &Vector<D>, value: &Vector<D>| DeckError {
        file: String::new(),
        key,
        line_col: None,
        message: format!(
            "is not a finite number at ({}) at t = 0: ({}); change the expression there",
            x.iter()
                .map(|a| format!("{a:.6}"))
                .collect::<Vec<_>>()
                .join(", "),
            value
                .iter()
                .map(|a| format!("{a}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let origin = Vector::<D>::from_column_slice(&deck.grid.origin);
    let g = gravity(&origin);
    if !g.iter().all(|a| a.is_finite()) {
        return Some(error("simulation.gravity".into(), &origin, &g));
    }
    for (x, v) in ps.x.iter().zip(&ps.v) {
        let g = gravity(x);
        if !g.iter().all(|a| a.is_finite()) {
            return Some(error("simulation.gravity".into(), x, &g));
        }
        if !v.iter().all(|a| a.is_finite()) {
            let b = (0..deck.bodies.len())
                .find(|&b| solids[b].contains(x.as_slice()))
                .unwrap_or(0);
            return Some(error(format!("bodies[{b}].velocity"), x, v));
        }
    }
    None
}
