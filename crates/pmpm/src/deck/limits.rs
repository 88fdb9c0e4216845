//! What a deck will cost, estimated from the deck alone before anything is allocated, and the
//! limits past which `check`, `run` and `bench` refuse it (exit status 2) unless the user passes
//! `--allow-large`: a deck that needs more memory than the machine has used to allocate for
//! seconds and abort, and one that needs 1e150 steps used to start without a word.

use super::Deck;
use crate::error::Error;
pub use crate::keys::short;

/// The most steps a deck may need without `--allow-large`.
pub const MAX_STEPS: f64 = 1e9;

/// Peak resident memory per particle and per committed grid node (ghost layers included;
/// [`Estimate::committed_nodes`]) of a run,
/// fitted by `benches/memory_model.sh` (BENCHMARKS.md, "Lean solver state, and the memory model
/// of `check`") and rounded up: the benchmarks' dam break in a tight tank and in a loose one, the same particles
/// in both, so the pair separates what follows the particles from what follows the grid.
/// The scheme sets the solver's buffers; the shape functions' width sets the matrix rows and
/// the transfers' bands; the implicit viscous solve, where a fluid is viscous, adds its own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MemoryModel {
    /// Bytes per particle.
    pub per_particle: f64,
    /// Bytes per grid node the bodies reach ([`Estimate::committed_nodes`]).
    pub per_node: f64,
    /// Bytes per node of the whole grid: the implicit viscous solve's arrays, which are
    /// written over the box.
    pub per_box_node: f64,
}

impl MemoryModel {
    /// The model of a validated deck: its dimension, scheme and shape functions.
    pub fn of(deck: &Deck) -> Self {
        use crate::scheme::Scheme;
        use crate::shape::ShapeFunction;
        // (per particle, per node) in 2D and 3D, for linear shapes, the 3-wide ones (GIMP,
        // quadratic B-splines) and cubic B-splines
        const PROJECTION: [[(f64, f64); 3]; 2] = [
            [(590.0, 390.0), (650.0, 390.0), (730.0, 390.0)],
            [(810.0, 500.0), (1130.0, 470.0), (1650.0, 360.0)],
        ];
        const EXPLICIT: [[(f64, f64); 3]; 2] = [
            [(270.0, 130.0), (270.0, 130.0), (270.0, 130.0)],
            [(500.0, 150.0), (500.0, 150.0), (500.0, 150.0)],
        ];
        let s = &deck.simulation;
        let table = match s.scheme {
            Scheme::Projection => &PROJECTION,
            Scheme::Explicit => &EXPLICIT,
        };
        let width = match s.shape_function {
            ShapeFunction::Linear => 0,
            ShapeFunction::Gimp | ShapeFunction::Bspline2 => 1,
            ShapeFunction::Bspline3 => 2,
        };
        let three = usize::from(s.dimension == 3);
        let (mut per_particle, per_node) = table[three][width];
        // the tables were fitted with F and tau on every particle: take off what the
        // materials leave unstored (a D x D matrix of f64 each, `particles::Stored`)
        let unstored = deck.stored_fields().unstored();
        per_particle -= (unstored * 8 * s.dimension * s.dimension) as f64;
        // the implicit viscous solve's quadrature points, mask, diagonal and work vectors
        let mut per_box_node = 0.0;
        if deck.viscous_solve() {
            per_particle += [100.0, 190.0][three];
            per_box_node = [130.0, 140.0][three];
        }
        Self {
            per_particle,
            per_node,
            per_box_node,
        }
    }

    /// Peak memory in bytes of a run of `particles` particles, `nodes` grid nodes the bodies
    /// reach and `box_nodes` in the whole grid.
    pub fn memory(&self, particles: f64, nodes: f64, box_nodes: f64) -> f64 {
        BYTES_BASE
            + particles * self.per_particle
            + nodes * self.per_node
            + box_nodes * self.per_box_node
    }
}

/// Nodes along axis 0 of a page of a node array: 4 KiB holds 512 `f64` or 256 2D vectors.
const PAGE_NODES: f64 = 256.0;

/// The program itself with its threads, its output buffers and a small grid's fixed costs:
/// the peak of the smallest decks (13.0 MB for the tutorial's 1,600 particles, of which its
/// particles and rows take about 3).
pub const BYTES_BASE: f64 = 10e6;
/// Per triangle of a mesh shape: the file's bytes, the welded vertices, the edge check and
/// parry's triangle mesh with its tree and pseudo-normals while a mesh is read, and the copies
/// a rigid body's shape keeps. Measured: `check` of a deck with a ball of 100k and of 400k
/// triangles peaked 560 B per triangle apart as a body of material, 1250 B as a rigid body.
pub const BYTES_PER_TRIANGLE: f64 = 1300.0;

/// What a deck will cost, from the deck alone.
#[derive(Debug, Clone, Copy)]
pub struct Estimate {
    /// Particles: each body's volume inside the grid over the particle spacing to the power D.
    pub particles: f64,
    /// Grid nodes, with the ghost layers.
    pub nodes: f64,
    /// The nodes whose memory the run holds: in the rows of nodes along axis 0 that the
    /// bodies cross, the run each covers and about a page more (the node arrays commit pages
    /// only where the material writes, [`crate::pages`]).
    pub committed_nodes: f64,
    /// Peak memory in bytes (with the meshes' triangles).
    pub memory: f64,
    /// Steps to the end time that the flow asks for: the fixed step's count, or with `cfl` the
    /// count at the speed of a free fall through the grid's height plus the fastest wave.
    pub flow_steps: f64,
    /// Steps to the end time: [`Self::flow_steps`], and no fewer than the wave and viscous
    /// limits ask for.
    pub steps: f64,
    /// The fastest prescribed rigid body over the run, which bounds the step with `cfl`.
    pub rigid: Option<RigidPace>,
}

/// The fastest a prescribed rigid body moves over the run (its velocity and angular velocity
/// sampled over [0, end_time]): its fastest point's speed, its index, when, and the key that
/// gives the larger part of the speed.
#[derive(Debug, Clone, Copy)]
pub struct RigidPace {
    /// |V| + |omega| R (m/s), R the farthest the body reaches from its centre.
    pub speed: f64,
    /// The body's index in `rigid_bodies`.
    pub body: usize,
    /// When (s).
    pub time: f64,
    /// "velocity" or "angular_velocity".
    pub key: &'static str,
}

/// The prescribed bodies' fastest speed at each of [`crate::rigid::motion_times`] (empty without a
/// moving body), and the [`RigidPace`] of the fastest of all (None without a moving one).
pub fn prescribed_speeds(deck: &Deck) -> (Vec<f64>, Option<RigidPace>) {
    use super::RigidMotion;
    let end = deck.simulation.end_time;
    let mut best: Option<RigidPace> = None;
    let mut speeds: Vec<f64> = Vec::new();
    for (b, r) in deck.rigid_bodies.iter().enumerate() {
        if r.motion != RigidMotion::Prescribed {
            continue;
        }
        let v = r.velocity.as_ref().and_then(|v| v.compile().ok());
        let w = r
            .angular_velocity
            .as_ref()
            .and_then(|w| w.field().compile().ok());
        if v.is_none() && w.is_none() {
            continue;
        }
        let radius = match w {
            Some(_) => deck.rigid_shape(r).map_or(0.0, |s| s.radius()),
            None => 0.0,
        };
        if speeds.is_empty() {
            speeds = vec![0.0; crate::rigid::motion_times(end).count()];
        }
        for (k, t) in crate::rigid::motion_times(end).enumerate() {
            let lin = v.as_ref().map_or(0.0, |v| v.eval_t(t).norm());
            let rot = w.as_ref().map_or(0.0, |w| w.eval_t(t).norm() * radius);
            let speed = lin + rot;
            speeds[k] = speeds[k].max(speed);
            if best.is_none_or(|p| speed > p.speed) {
                let key = if rot > lin {
                    "angular_velocity"
                } else {
                    "velocity"
                };
                best = Some(RigidPace {
                    speed,
                    body: b,
                    time: t,
                    key,
                });
            }
        }
    }
    (speeds, best.filter(|p| p.speed > 0.0))
}

/// Estimates a validated deck's cost without building anything.
pub fn estimate(deck: &Deck) -> Estimate {
    let dim = deck.simulation.dimension;
    let g = &deck.grid;
    let h = g.cell_size;
    let cells: Vec<f64> = g.size.iter().map(|s| (s / h).round()).collect();
    let pad = 2.0 * crate::shape::PAD as f64 + 1.0;
    let nodes: f64 = cells.iter().map(|c| c + pad).product();
    let row = cells[0] + pad;
    let mut crossed = 0.0;
    let particles: f64 = deck
        .bodies
        .iter()
        .enumerate()
        .map(|(i, b)| {
            // the bounding box clipped to the grid, and the part of it inside the shape, from
            // 16 points per axis (a sphere fills pi/4 of its box in 2D, pi/6 in 3D)
            let Ok(solid) = deck.body_solid(i) else {
                return 0.0;
            };
            let (lo, hi) = solid.bounds();
            let a: Vec<f64> = (0..dim).map(|d| lo[d].max(g.origin[d])).collect();
            let z: Vec<f64> = (0..dim)
                .map(|d| hi[d].min(g.origin[d] + g.size[d]))
                .collect();
            let boxed: f64 = (0..dim).map(|d| (z[d] - a[d]).max(0.0)).product();
            if boxed > 0.0 {
                // the node arrays hold pages only where the material writes them
                // (crate::pages), a page a run of nodes along axis 0: the rows of nodes the
                // body's box crosses, with the nodes its particles' stencils reach on either
                // side, each for the run the box covers and about a page more
                let rows: f64 = (1..dim).map(|d| ((z[d] - a[d]) / h).ceil() + pad).product();
                let run = ((z[0] - a[0]) / h).ceil() + pad + PAGE_NODES;
                crossed += rows * run.min(row);
            }
            const N: usize = 16;
            let total = N.pow(dim as u32);
            let inside = (0..total)
                .filter(|&k| {
                    let x: Vec<f64> = (0..dim)
                        .map(|d| {
                            let j = (k / N.pow(d as u32)) % N;
                            a[d] + (z[d] - a[d]) * (j as f64 + 0.5) / N as f64
                        })
                        .collect();
                    solid.contains(&x)
                })
                .count();
            let fill = inside as f64 / total as f64;
            let spacing = h / b.particles_per_cell as f64;
            (boxed * fill / spacing.powi(dim as i32)).round()
        })
        .sum();
    // an inflow's water may go anywhere: with one the whole box counts
    let committed = if deck.inflows.is_empty() {
        crossed.min(nodes)
    } else {
        nodes
    };
    let memory = MemoryModel::of(deck).memory(particles, committed, nodes)
        + deck.mesh_triangles as f64 * BYTES_PER_TRIANGLE;
    let (speeds, rigid) = prescribed_speeds(deck);
    let (flow_steps, steps) = steps(deck, &speeds);
    Estimate {
        particles,
        nodes,
        committed_nodes: committed,
        memory,
        flow_steps,
        steps,
        rigid,
    }
}

/// [`Estimate::flow_steps`] and [`Estimate::steps`], with `rigid` the fastest prescribed
/// rigid body's speed (m/s) at each of [`crate::rigid::motion_times`] (or empty), which the adaptive
/// step follows: the steps are the integral over the run of the faster of it and the flow's
/// speed, over cfl h.
fn steps(deck: &Deck, rigid: &[f64]) -> (f64, f64) {
    let s = &deck.simulation;
    let (_, viscous) = deck.dt_limits();
    let limited = s.end_time / viscous.0;
    match (s.dt, s.cfl) {
        (Some(dt), _) => (s.end_time / dt, s.end_time / dt),
        (None, Some(cfl)) => {
            let h = deck.grid.cell_size;
            // the fastest a gravity-driven flow gets: a free fall through the grid's height
            let g = gravity_at_origin(deck);
            let gnorm = g.iter().map(|a| a * a).sum::<f64>().sqrt();
            let height: f64 = g
                .iter()
                .zip(&deck.grid.size)
                .map(|(a, size)| (a / gnorm.max(1e-300)).abs() * size)
                .sum();
            let speed = (2.0 * gnorm * height).sqrt() + deck.max_wave_speed();
            // the trapezoidal rule over the samples
            let n = rigid.len().saturating_sub(1);
            let mean = match n {
                0 => speed,
                _ => {
                    let at = |k: usize| rigid[k].max(speed);
                    ((1..n).map(at).sum::<f64>() + 0.5 * (at(0) + at(n))) / n as f64
                }
            };
            let flow = s.end_time * mean / (cfl * h);
            // (the wave limit is in the speed already)
            (flow, flow.max(limited))
        }
        (None, None) => (0.0, 0.0),
    }
}

/// The body force at the grid's origin at t = 0, as a list.
fn gravity_at_origin(deck: &Deck) -> Vec<f64> {
    fn at<const D: usize>(deck: &Deck) -> Vec<f64> {
        let origin = crate::grid::Vector::<D>::from_column_slice(&deck.grid.origin);
        deck.simulation
            .gravity
            .compile()
            .map(|f| f.eval(&origin, 0.0).iter().copied().collect())
            .unwrap_or_default()
    }
    if deck.simulation.dimension == 3 {
        at::<3>(deck)
    } else {
        at::<2>(deck)
    }
}

/// The machine's memory in bytes, where the system tells it (Linux: MemTotal).
pub fn machine_memory() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// The process's address-space limit in bytes (`ulimit -v`), where one is set.
pub fn address_space_limit() -> Option<f64> {
    #[cfg(unix)]
    {
        let mut r = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes one rlimit into the struct it is given, which lives here.
        let ok = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut r) } == 0;
        (ok && r.rlim_cur != libc::RLIM_INFINITY).then_some(r.rlim_cur as f64)
    }
    #[cfg(not(unix))]
    None
}

/// Address space a process takes beyond what it uses: each worker thread's stack and the
/// allocator's arena (64 MB reserved per thread by glibc), and the program's own mappings.
/// Only an address-space limit sees it.
fn address_space_overhead() -> f64 {
    let threads = rayon::current_num_threads() as f64 + 1.0;
    threads * 66e6 + 32e6
}

/// Refuses (exit status 2), unless `allow_large`, a deck that cannot run on this machine: more
/// memory than the machine has or its address-space limit allows, or more than [`MAX_STEPS`]
/// steps. (More particles than 32-bit ids is a deck error already.)
pub fn refuse_beyond_limits(deck: &Deck, file: &str, allow_large: bool) -> Result<(), Error> {
    let e = estimate(deck);
    let refuse = |what: String| Err(Error::Usage(format!("{file}: {what}")));
    if allow_large {
        return Ok(());
    }
    if let Some(limit) = address_space_limit().filter(|&l| e.memory + address_space_overhead() > l)
    {
        return refuse(format!(
            "the run needs about {} of memory ({} particles, {} grid nodes) and about {} more \
             of address space for its {} threads, and the address space is limited to {} \
             (ulimit -v): raise the limit, use fewer --threads, coarsen grid.cell_size, or pass \
             --allow-large to try anyway",
            bytes(e.memory),
            short(e.particles),
            short(e.nodes),
            bytes(address_space_overhead()),
            rayon::current_num_threads(),
            bytes(limit)
        ));
    }
    if let Some(have) = machine_memory().filter(|&m| e.memory > m) {
        return refuse(format!(
            "the run needs about {} of memory ({} particles, {} grid nodes) and this machine \
             has {}: coarsen grid.cell_size, shrink grid.size or the bodies, or pass \
             --allow-large to try anyway",
            bytes(e.memory),
            short(e.particles),
            short(e.nodes),
            bytes(have)
        ));
    }
    if let (Some(p), Some(cfl)) = (e.rigid, deck.simulation.cfl) {
        let h = deck.grid.cell_size;
        // the body is what asks for too many steps: without it the run would take fewer
        if e.steps > MAX_STEPS && steps(deck, &[]).1 <= MAX_STEPS {
            return refuse(format!(
                "rigid_bodies[{}].{}: the body's fastest point moves at {} m/s at t = {} s, \
                 and the step follows it (cfl h / speed, simulation.cfl = {cfl}, \
                 grid.cell_size = {h}): about {} steps to simulation.end_time = {} s, more \
                 than {:.0e}; slow the body, or pass --allow-large to run it anyway",
                p.body,
                p.key,
                short(p.speed),
                short(p.time),
                short(e.steps),
                short(deck.simulation.end_time),
                MAX_STEPS
            ));
        }
    }
    if e.steps > MAX_STEPS {
        return refuse(format!(
            "the run needs about {} steps to simulation.end_time = {} s, more than {:.0e}: \
             check simulation.dt, simulation.cfl and the materials' bulk_modulus, viscosity \
             and shear_modulus (which bound the step), or pass --allow-large to run it anyway",
            short(e.steps),
            short(deck.simulation.end_time),
            MAX_STEPS
        ));
    }
    Ok(())
}

/// `text` with every number Rust printed as a long decimal (it writes 1e300 and 1e-300 with
/// 300 digits) in short scientific form, exact (`{:e}`): an integer part of more than 15 digits,
/// or a fraction that starts with more than 15 zeros. Other numbers stay as they are, and so do
/// digits that are part of a word, a path or a file name. The last pass over every message
/// pmpm prints, so that no format site can let a long one through.
pub fn shorten_numbers(text: &str) -> String {
    let bytes = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let mut copied = 0;
    while i < bytes.len() {
        if !bytes[i].is_ascii_digit() {
            i += 1;
            continue;
        }
        // digits glued to a word, a path or a name (run-17, /tmp/123, x1, v2.0) are left alone
        let glued = i > 0 && {
            let c = bytes[i - 1];
            c.is_ascii_alphanumeric()
                || matches!(c, b'_' | b'/' | b'.')
                || (c == b'-' && i > 1 && bytes[i - 2].is_ascii_alphanumeric())
        };
        let start = i;
        let run = |mut j: usize| {
            while j < bytes.len() && bytes[j].is_ascii_digit() {
                j += 1;
            }
            j
        };
        let int_end = run(i);
        let mut end = int_end;
        let mut leading_zeros = 0;
        if end + 1 < bytes.len() && bytes[end] == b'.' && bytes[end + 1].is_ascii_digit() {
            let frac_end = run(end + 1);
            leading_zeros = bytes[end + 1..frac_end]
                .iter()
                .take_while(|&&c| c == b'0')
                .count();
            end = frac_end;
        }
        // an exponent is part of the number: it is short already
        let exponent = end < bytes.len() && matches!(bytes[end], b'e' | b'E');
        if exponent {
            let mut j = end + 1;
            if j < bytes.len() && matches!(bytes[j], b'+' | b'-') {
                j += 1;
            }
            end = run(j);
        }
        let long = int_end - start > 15 || leading_zeros > 15;
        if long && !glued && !exponent {
            if let Ok(x) = text[start..end].parse::<f64>() {
                out += &text[copied..start];
                out += &format!("{x:e}");
                copied = end;
            }
        }
        i = end.max(i + 1);
    }
    out + &text[copied..]
}

/// A byte count for people: kB, MB, GB or TB.
pub fn bytes(b: f64) -> String {
    if b >= 1e12 {
        format!("{} TB", short((b / 1e12 * 10.0).round() / 10.0))
    } else if b >= 1e9 {
        format!("{:.1} GB", b / 1e9)
    } else if b >= 1e6 {
        format!("{:.1} MB", b / 1e6)
    } else {
        format!("{:.0} kB", (b / 1e3).ceil())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_numbers_print_short() {
        assert_eq!(short(0.05), "0.05");
        assert_eq!(short(1e308), "1.000e308");
        assert_eq!(short(2.5e-155), "2.500e-155");
        assert_eq!(short(1.0 / 3.0), "0.333333");
        assert_eq!(short(123456789.0), "123456789");
        assert_eq!(short(1234567890123.0), "1.235e12");
    }

    #[test]
    fn long_numerals_in_messages_are_shortened() {
        let long = format!("x = {}, the grid spans [0, {}]", 1e300, -1.5e-300);
        assert_eq!(
            shorten_numbers(&long),
            "x = 1e300, the grid spans [0, -1.5e-300]"
        );
        for plain in [
            "bodies[0].shape at (0.005000, 0.1): 4294967295 nodes, particles_000012.csv",
            "fixed dt = 3.3333333333333335e-4 s",
            "spans [0, 0.4000000000000001], the grid [0, 0.4]",
            "--resume /tmp/run-1700000000000000000/checkpoint.bin",
            "version 0.1.0",
        ] {
            assert_eq!(shorten_numbers(plain), plain);
        }
    }
}
