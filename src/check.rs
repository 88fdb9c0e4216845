//! What `pmpm check` and `pmpm bench` print: a deck's summary, cost and warnings, and the
//! time per phase of a run.

use pmpm::deck::{Deck, Scheme};
use pmpm::error::Error;
use pmpm::limits::bytes;
use pmpm::run::RunSummary;
use pmpm::scheme::Simulation;
use pmpm::timing::Phase;

/// Warnings about a valid deck that is likely to go wrong.
pub fn warnings(deck: &Deck) -> Vec<String> {
    let mut w = Vec::new();
    rounded_grid(deck, &mut w);
    unstable_transfers(deck, &mut w);
    creeping_or_locking_solids(deck, &mut w);
    long_output_interval(deck, &mut w);
    thin_rigid_bodies(deck, &mut w);
    // an inflow patch whose edge lies on a no-slip wall with a velocity there: the wall
    // holds the flow at rest, and the buffer's particles at the edge run ahead of it
    inflow_at_no_slip(deck, &mut w);
    bodies_in_rigid_bodies(deck, &mut w);
    w
}

/// Warns of a transfer that turns unstable or noisy with the deck's scheme and shape functions.
fn unstable_transfers(deck: &Deck, w: &mut Vec<String>) {
    use pmpm::deck::{ShapeFunction, Transfer};
    let s = &deck.simulation;
    if s.transfer == Some(Transfer::Apic)
        && s.scheme == pmpm::deck::Scheme::Explicit
        && matches!(
            s.shape_function,
            ShapeFunction::Linear | ShapeFunction::Gimp
        )
    {
        w.push(format!(
            "simulation.transfer: \"apic\" with shape_function = \"{}\" grows an unstable mode at free surfaces with the explicit scheme (seen in the dam break); use \"bspline2\" or transfer = \"flip\"",
            format!("{:?}", s.shape_function).to_lowercase()
        ));
    }
    // FLIP under the projection for a fluid: its particle noise goes into the particles'
    // volumes (a closed tank's splash and the two-fluid column stopped on a particle's volume
    // with FLIP where APIC ran)
    if s.transfer == Some(Transfer::Flip)
        && s.scheme == pmpm::deck::Scheme::Projection
        && !deck
            .materials
            .iter()
            .any(pmpm::deck::MaterialDeck::is_solid)
    {
        w.push(
            "simulation.transfer: \"flip\" with the projection scheme: FLIP's particle noise enters the particles' volumes, and after splashes single particles can be crushed or blown up until the run stops; the projection's default for fluids, \"apic\", keeps them (docs/deck.md)".to_string(),
        );
    }
    // an elastic solid with APIC under MUSL and linear or GIMP shapes: the remap takes the last
    // step's affine matrix (`transfer::grid_to_particles`), the strain rate lags a step, and
    // the solid's waves grow (a von Mises block on a floor blew up in 390 explicit steps)
    if s.transfer == Some(Transfer::Apic)
        && s.stress_update == pmpm::deck::StressUpdate::Musl
        && matches!(
            s.shape_function,
            ShapeFunction::Linear | ShapeFunction::Gimp
        )
    {
        if let Some(m) = deck.materials.iter().find(|m| m.shear_modulus.is_some()) {
            w.push(format!(
                "simulation.stress_update: \"musl\" with transfer = \"apic\" can let the elastic waves of \"{}\" ({}) grow: the remap takes the last step's affine matrix (a von Mises block at cfl 0.5 blew up within 400 steps); use shape_function = \"bspline2\", transfer = \"flip\", or a step well below the wave limit",
                m.name,
                m.model.name()
            ));
        }
    }
}

/// Warns of a solid that locks under the explicit scheme or creeps under the nodal pressure.
fn creeping_or_locking_solids(deck: &Deck, w: &mut Vec<String>) {
    let s = &deck.simulation;
    // a nearly incompressible solid under the explicit scheme without the nodal averaging:
    // one volume constraint per particle locks the grid (the strip footing's load 38% high at
    // K = 100 G, and a thin layer on a no-slip floor held still)
    if s.scheme == pmpm::deck::Scheme::Explicit
        && s.volumetric_averaging == pmpm::deck::VolumetricAveraging::None
    {
        let stiff = deck
            .materials
            .iter()
            .find_map(|m| match (m.shear_modulus, m.bulk_modulus) {
                (Some(g), Some(k)) if g > 0.0 && k >= 10.0 * g => Some((m, k / g)),
                _ => None,
            });
        if let Some((m, ratio)) = stiff {
            w.push(format!(
                "materials \"{}\": bulk_modulus / shear_modulus = {:.0} with the explicit scheme: such a nearly incompressible solid can lock (respond too stiffly); set simulation.volumetric_averaging = \"nodal\" (docs/materials.md), or use the projection scheme",
                m.name, ratio
            ));
        }
    }
    // solids only, under the projection with the nodal pressure: its stabilisation residual
    // lets a loaded solid creep (the elastic column 75% past its settlement and sinking)
    if s.scheme == pmpm::deck::Scheme::Projection
        && deck.pressure.unknowns == pmpm::deck::PressureUnknowns::Nodes
        && deck
            .materials
            .iter()
            .all(pmpm::deck::MaterialDeck::is_solid)
    {
        w.push("every material is a solid and the projection's pressure sits on the nodes: a solid under a steady load creeps with it (docs/method.md, \"One pressure per cell\"); set pressure.unknowns = \"cells\" with simulation.stress_update = \"usl\"".into());
    }
}

/// Warns of an output interval longer than the run: only its first and last frame are written.
fn long_output_interval(deck: &Deck, w: &mut Vec<String>) {
    let s = &deck.simulation;
    if let Some(interval) = deck.output.interval {
        if interval > s.end_time {
            w.push(format!(
                "output.interval = {interval} s is longer than simulation.end_time = {} s: only the first and the last frame are written",
                s.end_time
            ));
        }
    }
}

/// Warns of a rigid body too thin for the grid to hold water back.
fn thin_rigid_bodies(deck: &Deck, w: &mut Vec<String>) {
    // a rigid body thinner than two cells between two faces inside the grid: no node row or
    // one lies inside it, and water passes it or is squeezed next to it (a plate 0.4 cells
    // thick let water through at the floor, or lost 3.5 % of the volume passing over it)
    let g = &deck.grid;
    for (r, rigid) in deck.rigid_bodies.iter().enumerate() {
        let (Some(lo), Some(hi)) = (&rigid.shape.min, &rigid.shape.max) else {
            continue;
        };
        for d in 0..lo.len().min(g.size.len()) {
            let inside = lo[d] > g.origin[d] && hi[d] < g.origin[d] + g.size[d];
            let cells = (hi[d] - lo[d]) / g.cell_size;
            if inside && cells < 2.0 {
                w.push(format!(
                    "rigid_bodies[{r}] (\"{}\") is {cells:.2} cells thick along {}: a body thinner than two cells holds water back poorly at this resolution (water passes it or is lost next to it); make it at least two cells thick, or refine grid.cell_size",
                    rigid.name,
                    ["x", "y", "z"][d]
                ));
            }
        }
    }
}

/// Warns of a body that reaches into a rigid body, where none of its particles is placed.
fn bodies_in_rigid_bodies(deck: &Deck, w: &mut Vec<String>) {
    // material that starts inside a rigid body: the body's nodes take its velocity, and the
    // particles inside are squeezed out (or held) in the first steps
    let (glo, ghi) = deck.domain();
    for b in 0..deck.bodies.len() {
        let Ok(body) = deck.body_solid(b) else {
            continue;
        };
        for (r, rigid) in deck.rigid_bodies.iter().enumerate() {
            if let Some(x) = overlap_point(&body, &rigid.shape, (&glo, &ghi)) {
                let at: Vec<String> = x.iter().map(|c| format!("{c}")).collect();
                w.push(format!(
                    "bodies[{b}] reaches into rigid_bodies[{r}] (for example at ({})): no particle is placed inside a rigid body, so that part of the body is left out (its particle count and volume above are what remains)",
                    at.join(", ")
                ));
            }
        }
    }
}

/// A tank that is not a whole number of cells: what the grid took instead.
fn rounded_grid(deck: &Deck, w: &mut Vec<String>) {
    for &(d, given) in &deck.grid.rounded {
        let g = &deck.grid;
        let axis = ["x", "y", "z"][d];
        w.push(format!(
            "grid.size[{d}] = {given} m is {:.4} cells of {} m: the grid takes {} cells, {} m, and its {axis}_max face stands {:.4e} m beyond the deck's {} m; for that face where the deck says, give a cell_size that divides every size",
            given / g.cell_size,
            g.cell_size,
            (g.size[d] / g.cell_size).round(),
            g.origin[d] + g.size[d],
            g.size[d] - given,
            g.origin[d] + given,
        ));
    }
}

/// A velocity as the deck gives it: numbers as `[0, -0.1]`, expressions quoted.
fn describe_field(f: &pmpm::field::VectorField) -> String {
    match f.numbers() {
        Some(v) => format!("{v:?}"),
        None => {
            let parts: Vec<String> =
                f.0.iter()
                    .map(|c| match c {
                        pmpm::field::Component::Number(x) => format!("{x:?}"),
                        pmpm::field::Component::Expression(e) => format!("\"{e}\""),
                    })
                    .collect();
            format!("[{}]", parts.join(", "))
        }
    }
}

/// Warns of an inflow patch that reaches a no-slip wall with a velocity that does not vanish
/// there at t = 0.
fn inflow_at_no_slip(deck: &Deck, w: &mut Vec<String>) {
    let dim = deck.simulation.dimension;
    let g = &deck.grid;
    let faces = g.boundary.faces();
    for (i, q) in deck.inflows.iter().enumerate() {
        let Ok(field) = q.velocity.compile() else {
            continue;
        };
        let axis = pmpm::deck::FACE_NAMES
            .iter()
            .position(|n| *n == q.face)
            .unwrap_or(0)
            / 2;
        for d in (0..dim).filter(|&d| d != axis) {
            for (f, at) in [(2 * d, q.min[d]), (2 * d + 1, q.max[d])] {
                let wall = if f % 2 == 0 {
                    g.origin[d]
                } else {
                    g.origin[d] + g.size[d]
                };
                let no_slip =
                    faces[f].as_ref().map(|s| s.kind()) == Some(pmpm::deck::BoundaryKind::NoSlip);
                if !no_slip || (at - wall).abs() > 1e-9 * g.cell_size {
                    continue;
                }
                let mut x: Vec<f64> = (0..dim).map(|e| 0.5 * (q.min[e] + q.max[e])).collect();
                x[d] = at;
                let speed = field
                    .eval_at(&x, 0.0)
                    .iter()
                    .map(|c| c * c)
                    .sum::<f64>()
                    .sqrt();
                if speed > 1e-9 {
                    w.push(format!(
                        "inflows[{i}] meets the no-slip wall {} with a velocity of {speed:.3} m/s there: the wall holds the flow at rest, and the entering particles pack into the corner (volume is lost there); give a velocity that vanishes on the wall (a parabolic profile, docs/deck.md)",
                        pmpm::deck::FACE_NAMES[f]
                    ));
                }
            }
        }
    }
}

/// A point inside both a body's shape and a rigid body's, if the two overlap within the grid.
fn overlap_point(
    body: &pmpm::geometry::Solid,
    rigid: &pmpm::deck::ShapeDeck,
    grid: (&[f64], &[f64]),
) -> Option<Vec<f64>> {
    let (lo, _) = body.bounds();
    let rigid = rigid.solid(lo.len()).ok()?;
    body.common_point(&rigid, grid)
}

/// The summary `pmpm check` prints: what the deck sets up and what a run will cost.
pub fn check_summary(deck: &Deck, file: &str) -> Result<String, Error> {
    match deck.simulation.dimension {
        2 => summary_dim::<2>(deck, file),
        3 => summary_dim::<3>(deck, file),
        d => unreachable!("validated: dimension is 2 or 3, got {d}"),
    }
}

/// The viscosity the PIC share of the transfer adds at the first step, against the fluids'
/// own: a flow held to a small step (a viscous or sound-speed limit) is damped more by PIC's
/// per-step smoothing than by its material (`Transfer::pic_viscosity`).
fn pic_damping<const D: usize>(deck: &Deck, sim: &Simulation<D>, dt: f64) -> Option<String> {
    let s = &deck.simulation;
    let transfer = s.transfer.unwrap_or_default();
    let nu = transfer.pic_viscosity(s.flip_ratio, s.shape_function, sim.grid.geo.h, dt);
    if !(nu > 0.0 && nu.is_finite()) {
        return None;
    }
    let share = match transfer {
        pmpm::deck::Transfer::Flip => {
            format!(
                "its PIC share (1 - flip_ratio = {:.1e})",
                1.0 - s.flip_ratio
            )
        }
        _ => "PIC".to_string(),
    };
    let fluids = deck
        .materials
        .iter()
        .filter(|m| !m.is_solid() && m.viscosity > 0.0)
        .map(|m| format!("\"{}\" mu / rho = {:.1e}", m.name, m.viscosity / m.density))
        .collect::<Vec<_>>();
    let own = if fluids.is_empty() {
        String::new()
    } else {
        format!(" (the fluid's own: {} m2/s)", fluids.join(", "))
    };
    Some(format!(
        "                   {share} damps like a kinematic viscosity of about {nu:.1e} m2/s at the first step{own}; it grows as the step shrinks, APIC does not add it\n"
    ))
}

fn summary_dim<const D: usize>(deck: &Deck, file: &str) -> Result<String, Error> {
    let sim = Simulation::<D>::new(deck).map_err(|e| e.with_file(file))?;
    let s = &deck.simulation;
    let geo = &sim.grid.geo;
    let mut out = format!("{file}: deck is valid\n");
    if let Some(a) = &deck.about {
        out += &format!("  about            {}\n", a.describe());
    }
    for w in warnings(deck) {
        out += &format!("warning: {w}\n");
    }
    out += &format!(
        "  dimension        {D}\n  scheme           {:?}\n",
        s.scheme
    );
    out += &format!(
        "  grid             {} cells of h = {} m, {} nodes (with ghosts)\n",
        geo.cells
            .iter()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(" x "),
        geo.h,
        geo.node_count()
    );
    out += &walls(deck, D);
    let mut warn = Vec::new();
    bodies(deck, &sim, &mut out, &mut warn);
    for m in &deck.materials {
        out += &format!("  material         {}\n", m.describe());
    }
    rigid_bodies(deck, D, &mut out);
    inflows::<D>(deck, &mut out);
    for (i, z) in deck.damping_zones.iter().enumerate() {
        out += &format!(
            "  damping zone {i}   {} from {} m (rate 0) to {} m ({} 1/s) and beyond, as s^2\n",
            z.axis, z.from, z.to, z.rate
        );
    }
    out += &format!("  particles        {}\n", sim.particles.len());
    out += &format!(
        "  transfer         {:?}, shape functions {:?}\n",
        s.transfer.unwrap_or_default(),
        s.shape_function
    );
    // the first step: the fixed one, or the one cfl gives the initial state
    let first_dt =
        s.dt.unwrap_or_else(|| sim.stable_dt(s.cfl.expect("validated: dt or cfl")));
    if let Some(line) = pic_damping(deck, &sim, first_dt) {
        out += &line;
    }
    time_step(deck, &sim, first_dt, &mut out, &mut warn);
    gravity_towards_open_faces(deck, sim.settings.gravity.as_slice(), &mut warn);
    step_limits(deck, first_dt, &mut out);
    pressure(deck, &mut out);
    output_and_memory(deck, sim.particles.len() as f64, geo, &mut out);
    for w in warn {
        out += &format!("warning: {w}\n");
    }
    Ok(out)
}

/// The particles of each body, and the warnings about them: too few per cell, and a later
/// body's particles inside an earlier body.
fn bodies<const D: usize>(
    deck: &Deck,
    sim: &Simulation<D>,
    out: &mut String,
    warn: &mut Vec<String>,
) {
    let geo = &sim.grid.geo;
    // particles per body (the bodies are filled in deck order, so body b's particles are a
    // range of ids), and those of a later body that lie inside an earlier one
    let seeding = pmpm::build::seeded::<D>(deck, geo).map_or(Vec::new(), |(_, s)| s);
    let per_body: Vec<usize> = (0..deck.bodies.len())
        .map(|b| seeding.get(b).map_or(0, |s| s.particles))
        .collect();
    let solids: Vec<Option<pmpm::geometry::Solid>> = (0..deck.bodies.len())
        .map(|b| deck.body_solid(b).ok())
        .collect();
    let mut overlaps: Vec<(usize, usize, usize)> = Vec::new();
    let mut first = 0;
    for (b, &n) in per_body.iter().enumerate() {
        let xs = &sim.particles.x[first..first + n];
        for a in 0..b {
            let Some(solid) = &solids[a] else {
                continue;
            };
            let inside = xs.iter().filter(|x| solid.contains(x.as_slice())).count();
            if inside > 0 {
                overlaps.push((a, b, inside));
            }
        }
        first += n;
    }
    let unit = if D == 2 {
        "m2 (per metre of depth)"
    } else {
        "m3"
    };
    for (b, body) in deck.bodies.iter().enumerate() {
        let Some(seed) = seeding.get(b) else {
            continue;
        };
        *out += &format!(
            "  bodies[{b}]        {} particles of \"{}\" ({} per cell per direction), volume {:.6e} {unit}\n",
            per_body[b],
            body.material,
            body.particles_per_cell,
            seed.seeded
        );
        // the lattice rounds each face to a row of lattice points: the particles' volumes
        // are scaled back to the shape's, which a user should know where it is not small
        if seed.excess().abs() > 0.005 {
            let spacing = geo.h / body.particles_per_cell as f64;
            warn.push(format!(
                "bodies[{b}]: its lattice (spacing {spacing} m) covers {:.6e} m{D}, {:+.2} % of its shape's {:.6e} m{D} in the grid: each particle's volume and mass are scaled by {:.5} so that the body holds density times its shape's volume; faces on the lattice's rows (the grid's origin plus whole multiples of the spacing) seed it evenly",
                seed.lattice_volume,
                100.0 * seed.excess(),
                seed.volume,
                seed.volume / seed.lattice_volume,
            ));
        }
        if let Some(solid) = &solids[b] {
            let (lo, hi) = solid.bounds();
            let (glo, ghi) = (geo.origin, geo.upper());
            if let Some(d) = (0..D).find(|&d| {
                (lo[d].is_finite() && lo[d] < glo[d]) || (hi[d].is_finite() && hi[d] > ghi[d])
            }) {
                warn.push(format!(
                    "bodies[{b}].shape reaches past the grid along {} (it spans [{}, {}], the grid [{}, {}]): only the part inside the grid is filled",
                    ["x", "y", "z"][d], lo[d], hi[d], glo[d], ghi[d]
                ));
            }
        }
        if body.particles_per_cell < 2 {
            warn.push(format!(
                "bodies[{b}].particles_per_cell = {}: fewer than 2 particles per cell per \
                 direction leave cells empty as the material deforms (the pressure then \
                 checkerboards and the free surface is found inside the water); use 2 or more",
                body.particles_per_cell
            ));
        }
    }
    for (a, b, n) in overlaps {
        warn.push(format!(
            "bodies[{a}] and bodies[{b}] overlap: {n} particles of bodies[{b}] lie inside \
             bodies[{a}], which has its own there (more mass than the material's density)"
        ));
    }
}

/// One line per inflow: its patch and the mass it lets in at t = 0, rho sum over its lanes of
/// u . n s^(D-1).
fn inflows<const D: usize>(deck: &Deck, out: &mut String) {
    for (i, q) in deck.inflows.iter().enumerate() {
        let Ok(field) = q.velocity.compile() else {
            continue;
        };
        let Some(f) = pmpm::deck::FACE_NAMES.iter().position(|n| *n == q.face) else {
            continue;
        };
        let axis = f / 2;
        let s = deck.grid.cell_size / q.particles_per_cell as f64;
        let lanes: Vec<usize> = (0..D)
            .map(|d| {
                if d == axis {
                    1
                } else {
                    ((q.max[d] - q.min[d]) / s).round().max(1.0) as usize
                }
            })
            .collect();
        let mut flux = 0.0;
        for k in 0..lanes.iter().product::<usize>() {
            let mut rem = k;
            let x = pmpm::grid::Vector::<D>::from_fn(|d, _| {
                let j = rem % lanes[d];
                rem /= lanes[d];
                if d == axis {
                    q.min[d]
                } else {
                    q.min[d] + (j as f64 + 0.5) * s
                }
            });
            let un = field.eval(&x, 0.0)[axis] * if f % 2 == 0 { 1.0 } else { -1.0 };
            flux += un * s.powi(D as i32 - 1);
        }
        let rho = deck
            .materials
            .iter()
            .find(|m| m.name == q.material)
            .map_or(0.0, |m| m.density);
        let unit = if D == 2 { "kg/s per metre" } else { "kg/s" };
        *out += &format!(
            "  inflows[{i}]       \"{}\" through {} from {:?} to {:?}: {:.4e} {unit} at t = 0; what enters and leaves is in series.csv\n",
            q.material,
            q.face,
            q.min,
            q.max,
            rho * flux
        );
    }
}

/// One line per rigid body: its box, velocity, sides and how its faces act; for a body of
/// another shape, or one that turns or moves freely, its volume, centroid and motion.
fn rigid_bodies(deck: &Deck, dim: usize, out: &mut String) {
    let s = &deck.simulation;
    for r in &deck.rigid_bodies {
        if let Some(line) = shaped_rigid_line(deck, r, dim) {
            *out += &line;
            continue;
        }
        let (lo, hi) = (
            r.shape.min.clone().unwrap_or_default(),
            r.shape.max.clone().unwrap_or_default(),
        );
        let v = r
            .velocity
            .as_ref()
            .map_or_else(|| format!("{:?}", vec![0.0; dim]), describe_field);
        let sides = match r.sides {
            pmpm::deck::RigidSides::Rough => "rough",
            pmpm::deck::RigidSides::Smooth => "smooth sides",
        };
        // how the faces act: where they lie (cut cells), or at the nodes inside
        let faces = if deck.simulation.scheme == pmpm::deck::Scheme::Projection
            && deck.pressure.cuts_cells(s.shape_function)
        {
            "faces cut the cells where they lie"
        } else {
            "faces act at node resolution (put them midway between node rows)"
        };
        *out += &format!(
            "  rigid body       \"{}\": box {lo:?} to {hi:?} m, velocity {v} m/s, {sides}, {faces}; its force in rigid_bodies.csv every step\n",
            r.name
        );
    }
}
/// The line of a rigid body of the general path (or a free box): its shape's volume and
/// centroid, its motion, a free body's mass and the added mass its coupling assumes.
fn shaped_rigid_line(deck: &Deck, r: &pmpm::deck::RigidBodyDeck, dim: usize) -> Option<String> {
    use pmpm::deck::RigidMotion;
    if !r.is_shaped() && r.motion != RigidMotion::Free {
        return None;
    }
    let shape = deck.rigid_shape(r)?;
    let unit = if dim == 2 { "m2 (per metre)" } else { "m3" };
    let c: Vec<f64> = shape.centroid.as_slice()[..dim].to_vec();
    let motion = match r.motion {
        RigidMotion::Free => {
            let rho = r.density.unwrap_or(0.0);
            let mass_unit = if dim == 2 { "kg/m" } else { "kg" };
            let held = if r.fixed.is_empty() {
                String::new()
            } else {
                format!(", holding {}", r.fixed.join(", "))
            };
            format!(
                "free, density {rho} kg/m3, mass {:.4e} {mass_unit}{held}",
                rho * shape.volume
            )
        }
        RigidMotion::Prescribed => {
            let v = r
                .velocity
                .as_ref()
                .map_or_else(|| format!("{:?}", vec![0.0; dim]), describe_field);
            match &r.angular_velocity {
                Some(w) => format!(
                    "velocity {v} m/s, angular velocity {} rad/s about {:?}",
                    describe_field(&w.field()),
                    &shape.reference().as_slice()[..dim]
                ),
                None => format!("velocity {v} m/s"),
            }
        }
    };
    let path = if r.is_shaped() {
        "its nodes hold it where it is (node resolution)"
    } else {
        "a box whose faces cut the cells where they lie (with the projection's cut cells)"
    };
    Some(format!(
        "  rigid body       \"{}\": {} of volume {:.4e} {unit}, centroid {c:.4?}, {motion}; {path}; its force in rigid_bodies.csv every step\n",
        r.name,
        spelling_kind(&r.shape),
        shape.volume,
    ))
}

/// The shape's type as the deck spells it.
fn spelling_kind(s: &pmpm::deck::ShapeDeck) -> String {
    toml::Value::try_from(s.kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_else(|| "shape".into())
}

/// The time step at t = 0 (`dt0`: the fixed one, or the one cfl gives the initial state) and
/// the steps to the end; a fixed step too large for a fall.
fn time_step<const D: usize>(
    deck: &Deck,
    sim: &Simulation<D>,
    dt0: f64,
    out: &mut String,
    warn: &mut Vec<String>,
) {
    let s = &deck.simulation;
    let geo = &sim.grid.geo;
    let dt = match (s.dt, s.cfl) {
        (Some(dt), _) => format!("fixed dt = {dt:e} s"),
        (None, Some(cfl)) => {
            if dt0.is_finite() {
                format!("adaptive, cfl = {cfl}; at t = 0 dt = {dt0:.3e} s")
            } else {
                format!("adaptive, cfl = {cfl}; at rest at t = 0 (set by the flow)")
            }
        }
        (None, None) => unreachable!("validated: dt or cfl"),
    };
    *out += &format!("  time step        {dt}\n");
    let g = sim.settings.gravity;
    let gnorm = g.norm();
    let estimate = pmpm::limits::estimate(deck);
    // with cfl: the free fall's estimate (an upper bound on the flow's steps), or, where a
    // limit of the step sets more, that many at least; without gravity, the speed at t = 0
    let at_start = if s.dt.is_none() && dt0.is_finite() && dt0 > 0.0 {
        s.end_time / dt0
    } else {
        0.0
    };
    let (n, why) = if s.dt.is_some() {
        (estimate.steps, "")
    } else if estimate.steps > estimate.flow_steps {
        (
            estimate.steps.max(at_start),
            " (at least: the viscous limit sets the step)",
        )
    } else if estimate.flow_steps > 0.0 {
        (
            estimate.steps,
            " (at most: with cfl the step follows the flow)",
        )
    } else {
        (
            at_start,
            " (at the speeds of t = 0: with cfl the step follows the flow)",
        )
    };
    if n > 0.0 && n.is_finite() {
        *out += &format!(
            "  steps            about {} to t = {} s{why}\n",
            pmpm::limits::short(n.ceil()),
            s.end_time,
        );
    }
    if let (Some(dt), Scheme::Projection) = (s.dt, s.scheme) {
        if gnorm > 0.0 && dt > (geo.h / gnorm).sqrt() {
            warn.push(format!(
                "simulation.dt = {dt} s is above sqrt(h / |g|) = {:.3e} s: a particle falling \
                 from rest crosses more than a cell in a step; lower dt or use cfl",
                (geo.h / gnorm).sqrt()
            ));
        }
    }
}

/// A warning for each open face that gravity pulls the material towards.
fn gravity_towards_open_faces(deck: &Deck, g: &[f64], warn: &mut Vec<String>) {
    // gravity pulling the material out of the grid through an open face
    let faces = deck.grid.boundary.faces();
    for d in 0..g.len() {
        if g[d] == 0.0 {
            continue;
        }
        let face = 2 * d + usize::from(g[d] > 0.0);
        let open = faces[face]
            .as_ref()
            .is_none_or(|f| f.kind() == pmpm::deck::BoundaryKind::Open);
        if open {
            warn.push(format!(
                "grid.boundary.{} is open and gravity pulls the material towards it: particles \
                 that fall out of the grid stop the run (exit status 3); make it a wall \
                 (\"slip\" or \"no_slip\") unless the bodies rest on something",
                pmpm::deck::FACE_NAMES[face]
            ));
        }
    }
}

/// The wave limit, and the viscous limit where it binds.
fn step_limits(deck: &Deck, dt0: f64, out: &mut String) {
    let s = &deck.simulation;
    // the flow's steps: the free fall's estimate, or those of the speeds at t = 0 (a lid,
    // an inflow, an initial velocity), whichever is more
    let at_start = if dt0.is_finite() && dt0 > 0.0 {
        s.end_time / dt0
    } else {
        0.0
    };
    let fall = pmpm::limits::estimate(deck).flow_steps;
    let flow = fall.max(at_start);
    let (wave, viscous) = deck.dt_limits();
    if wave.is_finite() {
        *out += &format!(
            "  wave limit       h / c = {wave:.3e} s ({}): about {:.0} steps or more to t = {}\n",
            if s.scheme == Scheme::Explicit {
                "c the sound speed"
            } else {
                "c the shear wave speed"
            },
            s.end_time / (wave * s.cfl.unwrap_or(1.0)),
            s.end_time
        );
    }
    // the viscous limit, where it binds: below the wave limit and asking for more steps than
    // the flow does (a yield-stress fluid's regularisation sets it; plain water never does)
    if viscous.0 < wave && s.end_time / viscous.0 > fall {
        *out += &format!(
            "  viscous limit    h^2 rho / (2 D mu) = {:.3e} s (material \"{}\"): about {:.0} steps or more to t = {}\n",
            viscous.0,
            deck.materials[viscous.1].name,
            (s.end_time / viscous.0).ceil(),
            s.end_time
        );
    }
    // the limit the implicit viscous solve lifts, where it would have bound
    let lifted = deck.lifted_viscous_limit();
    if lifted.0 < wave && s.end_time / lifted.0 > flow {
        *out += &format!(
            "  viscous limit    h^2 rho / (2 D mu) = {:.3e} s (material \"{}\"), lifted: \
             simulation.viscosity = \"implicit\" solves the viscous stress with the pressure's \
             step (about {:.0} steps to t = {} with it explicit)\n",
            lifted.0,
            deck.materials[lifted.1].name,
            (s.end_time / lifted.0).ceil(),
            s.end_time
        );
    }
}

/// The faces of the grid and how its walls hold the material (`grid.boundary.contact`).
fn walls(deck: &Deck, dim: usize) -> String {
    use pmpm::deck::{BoundaryKind, WallContact, FACE_NAMES};
    let faces = deck.grid.boundary.faces();
    let list: Vec<String> = (0..2 * dim)
        .map(|f| {
            let spec = faces[f].as_ref();
            let kind = spec.map_or(BoundaryKind::Slip, |s| s.kind()).name();
            let moving = spec.is_some_and(|s| s.velocity().is_some());
            let moving = if moving { " (moving)" } else { "" };
            format!("{} {kind}{moving}", FACE_NAMES[f])
        })
        .collect();
    let contact = match deck.grid.boundary.contact {
        Some(WallContact::Bonded) => {
            "they hold the material both ways (contact = \"bonded\": water under a lid hangs in tension)"
        }
        _ => "they only push (contact = \"separating\": water leaves a lid as free water; a symmetry face holds both ways)",
    };
    format!("  walls            {}; {contact}\n", list.join(", "))
}

/// The pressure solve's settings, under the projection; the explicit scheme's packing.
fn pressure(deck: &Deck, out: &mut String) {
    let cells = deck.grid.cells().iter().product();
    let s = &deck.simulation;
    if s.scheme == Scheme::Projection {
        let p = &deck.pressure;
        let lower = |x: String| x.to_lowercase();
        if p.unknowns == pmpm::deck::PressureUnknowns::Cells {
            *out += &format!(
                "  pressure         one per cell (unknowns = \"cells\"): {} ({}), tolerance {:e}, at most {} iterations; each cell's weak divergence held at zero, no free-surface detection\n",
                lower(format!("{:?}", p.solver)),
                lower(format!("{:?}", p.preconditioner(cells))),
                p.tolerance,
                p.max_iterations,
            );
        } else {
            let surface = match p.free_surface.unwrap_or_default() {
                pmpm::deck::FreeSurface::LevelSet => {
                    "free surface from the level set (ghost fluid)".to_string()
                }
                pmpm::deck::FreeSurface::VolumeFraction => format!(
                    "free surface (the paper's rule) where a cell is below {} full",
                    p.volume_fraction_tolerance
                ),
                pmpm::deck::FreeSurface::None => "no free surface".to_string(),
            };
            let density = match p.density_correction.unwrap_or_default() {
                pmpm::deck::DensityCorrection::Positions => {
                    "particle volumes restored by a position correction"
                }
                pmpm::deck::DensityCorrection::Particles => {
                    "particles spread to rest density by a position correction"
                }
                pmpm::deck::DensityCorrection::None => "no density correction",
            };
            *out += &format!(
                "  pressure         {} ({}), tolerance {:e}, at most {} iterations; rhs {}, beta = {}; {surface}; {density}\n",
                lower(format!("{:?}", p.solver)),
                lower(format!("{:?}", p.preconditioner(cells))),
                p.tolerance,
                p.max_iterations,
                lower(format!("{:?}", p.rhs)),
                p.beta,
            );
        }
    } else if deck.pressure.density_correction == Some(pmpm::deck::DensityCorrection::Particles) {
        let p = &deck.pressure;
        *out += &format!(
            "  packing          particles spread to rest density by a position correction (density_correction = \"particles\"), J and its pressure untouched, twelve times per cell crossing at the flow's speed; {} ({})\n",
            format!("{:?}", p.solver).to_lowercase(),
            format!("{:?}", p.preconditioner(cells)).to_lowercase(),
        );
    }
}

/// Frames, their size on disk, the checkpoint's, and the memory the run needs.
fn output_and_memory<const D: usize>(
    deck: &Deck,
    n: f64,
    geo: &pmpm::grid::GridGeometry<D>,
    out: &mut String,
) {
    let s = &deck.simulation;
    let frames = (s.end_time / deck.output.interval.unwrap_or(s.end_time)).round() as usize + 1;
    // bytes per particle: a CSV row (about 17 characters per number), the .vtu's raw arrays,
    // the checkpoint's particle state
    let csv = 17.0 * (2 * D + 5) as f64;
    // (position, velocity, id, pressure, mass, volume, J, shear rate, yielded, material,
    // stress and strain rate, cells)
    let vtu = 8.0 * 3.0 * 2.0 + 8.0 * 7.0 + 4.0 + 8.0 * 18.0 + 17.0;
    // the grid's .vti: 27 numbers a node (mass, velocity, pressure, volume fraction, density,
    // strain rate, shear rate, stress, yielded)
    let nodes: f64 = geo.cells.iter().map(|&c| (c + 1) as f64).product();
    let vti = 8.0 * 27.0 * nodes;
    // four D x D matrices (F, tau, L, C), less F and tau where no material reads them
    let matrices = 4 - deck.stored_fields().unstored();
    let checkpoint = 8.0 * (2 * D + 5 + matrices * D * D) as f64 + 6.0;
    let formats = &deck.output.formats;
    let has = |f: pmpm::deck::Format| formats.contains(&f);
    let per_frame =
        n * (if has(pmpm::deck::Format::Csv) {
            csv
        } else {
            0.0
        } + if has(pmpm::deck::Format::Vtk) {
            vtu
        } else {
            0.0
        }) + if has(pmpm::deck::Format::Grid) {
            vti
        } else {
            0.0
        };
    *out += &format!(
        "  output           {} every {} s into {}: {frames} frames of about {}, {} in all, \
         and a checkpoint of {}\n",
        formats
            .iter()
            .map(|f| format!("{f:?}").to_lowercase())
            .collect::<Vec<_>>()
            .join(", "),
        deck.output.interval.unwrap_or(0.0),
        deck.output.directory,
        bytes(per_frame),
        bytes(per_frame * frames as f64),
        bytes(n * checkpoint + 8.0 * geo.node_count() as f64)
    );
    let triangles = deck.mesh_triangles as f64;
    let meshes = if triangles > 0.0 {
        format!(
            ", {} B per mesh triangle ({triangles} triangles)",
            pmpm::limits::BYTES_PER_TRIANGLE
        )
    } else {
        String::new()
    };
    let model = pmpm::limits::MemoryModel::of(deck);
    let committed = pmpm::limits::estimate(deck).committed_nodes;
    let box_nodes = geo.node_count() as f64;
    let viscous = if model.per_box_node > 0.0 {
        format!(
            ", {} B per node of the grid (the viscous solve)",
            model.per_box_node
        )
    } else {
        String::new()
    };
    *out += &format!(
        "  memory           about {} ({} MB, {} B per particle and {} B per node for the {} \
         nodes the bodies reach{viscous}{meshes}, from the benchmarks)\n",
        bytes(model.memory(n, committed, box_nodes) + triangles * pmpm::limits::BYTES_PER_TRIANGLE),
        pmpm::limits::BYTES_BASE / 1e6,
        model.per_particle,
        model.per_node,
        pmpm::limits::short(committed),
    );
}

/// The table `pmpm bench` prints: per phase seconds, ms per step, ns per particle and step
/// (what compares across problem sizes and with a floor set by memory traffic) and share of the
/// wall time; particle updates per second; pressure iterations; peak memory per particle. The last line,
/// `BENCH key=value ...`, is for scripts.
pub fn bench_report(deck: &Deck, file: &str, r: &RunSummary, threads: usize) -> String {
    use std::fmt::Write;
    let steps = r.steps.max(1) as f64;
    let total = r.timers.total();
    let ns_per_update = |sec: f64| 1e9 * sec / (steps * r.particles.max(1) as f64);
    let mut t = String::new();
    let _ = writeln!(
        t,
        "pmpm bench {file}: {}D {:?}, {} particles, {} steps to t = {:.6} s, {threads} thread(s)\n",
        deck.simulation.dimension, deck.simulation.scheme, r.particles, r.steps, r.time
    );
    let _ = writeln!(
        t,
        "| phase | seconds | ms/step | ns/particle/step | share |"
    );
    let _ = writeln!(t, "|---|---:|---:|---:|---:|");
    for p in Phase::ALL {
        let sec = r.timers.seconds(p);
        if sec == 0.0 {
            continue;
        }
        let _ = writeln!(
            t,
            "| {} | {:.3} | {:.3} | {:.1} | {:.1}% |",
            p.name(),
            sec,
            1e3 * sec / steps,
            ns_per_update(sec),
            100.0 * sec / total.max(1e-300)
        );
    }
    let _ = writeln!(
        t,
        "| **step loop** | **{total:.3}** | **{:.3}** | **{:.1}** | 100% |\n",
        1e3 * total / steps,
        ns_per_update(total)
    );
    let updates = r.particles as f64 * r.steps as f64 / total.max(1e-300);
    let _ = writeln!(t, "particle updates per second: {updates:.3e}");
    let (iters, max_iters) = r.pressure_iterations;
    if deck.simulation.scheme == Scheme::Projection {
        let _ = writeln!(
            t,
            "pressure iterations: {:.1} per step, at most {max_iters}",
            iters as f64 / steps
        );
    }
    let mem = r
        .peak_memory
        .map(|b| (b, b as f64 / r.particles.max(1) as f64));
    match mem {
        Some((b, per)) => {
            let _ = writeln!(
                t,
                "peak memory: {:.1} MB, {per:.0} bytes per particle (whole process: grid, solver and buffers included)",
                b as f64 / 1e6
            );
        }
        None => {
            let _ = writeln!(t, "peak memory: not available on this system");
        }
    }
    let _ = write!(
        t,
        "BENCH dim={} scheme={:?} particles={} steps={} sim_time={:.6} threads={threads} wall_s={total:.4} ms_per_step={:.4} ns_per_particle_step={:.1} updates_per_s={updates:.4e} pressure_iterations={iters} max_iterations={max_iters} peak_bytes={} bytes_per_particle={}",
        deck.simulation.dimension,
        deck.simulation.scheme,
        r.particles,
        r.steps,
        r.time,
        1e3 * total / steps,
        ns_per_update(total),
        mem.map_or(0, |m| m.0),
        mem.map_or(0.0, |m| m.1).round()
    );
    for p in Phase::ALL {
        let _ = write!(t, " {}={:.4}", p.key(), r.timers.seconds(p));
    }
    t.push('\n');
    t
}
