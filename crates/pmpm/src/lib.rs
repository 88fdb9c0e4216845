//! pmpm: a material point method (MPM) solver for incompressible materials.
//!
//! Water, mud, undrained clay and rubber-like solids are simulated with material points that
//! carry mass, velocity and stress across a fixed background grid. Two schemes share all the
//! code but the pressure:
//!
//! * `explicit`: weakly compressible, p = K (1 - J), the baseline every claim is measured against;
//! * `projection`: Chorin's projection (Kularathna & Soga 2017), pressure from a Poisson solve.
//!
//! One time step ([`scheme::Simulation::step`]):
//!
//! ```text
//! particles -> grid (mass, momentum, forces)     transfer
//! predictor v* = v + dt f / m                    scheme (Grid::predict)
//! boundary conditions on v*                      boundary
//! [projection: free surface, Poisson, corrector] pressure
//! grid -> particles (PIC/FLIP/APIC), move        transfer
//! [explicit: nodal averaging of tr L]            averaging
//! strain rate, stress, F, J                      material
//! ```
//!
//! The deck (`deck`) is read and checked in one module and turned into a simulation in one
//! other (`build`): each physics module defines the settings it takes (`PressureSettings`,
//! `BoundaryKind`, `Model`, `RigidBox`, ...), and none of them reads the deck.
//! `python3 scripts/module_cycles.py` lists the modules' imports and fails on a cycle.
//!
//! A dam break from Rust: a deck (the TOML of `docs/deck.md`, here inline), validated, a
//! simulation built from it, and the driver's time loop ([`driver::Driver`]: the deck's step
//! size, landing on frame times). [`run::run`] drives the same loop and writes frames,
//! checkpoints and time series, as `pmpm run` does.
//!
//! ```
//! use pmpm::{build, driver::Driver, scheme::Simulation, Deck};
//! let mut deck = Deck::parse(
//!     r#"
//!     [simulation]
//!     dimension = 2
//!     scheme = "projection"
//!     end_time = 0.1
//!     cfl = 0.5
//!     [grid]
//!     size = [0.4, 0.2]
//!     cell_size = 0.01
//!     [[materials]]
//!     name = "water"
//!     model = "newtonian"
//!     density = 1000.0
//!     viscosity = 1.0e-3
//!     [[bodies]]
//!     material = "water"
//!     shape = { type = "box", min = [0.0, 0.0], max = [0.1, 0.15] }
//!     "#,
//!     "dam_break.toml",
//! )?;
//! deck.validate("dam_break.toml")?; // checks every key and fills in the defaults
//! let mut sim = Simulation::<2>::new(&deck)?;
//! Driver::new(build::clock(&deck)).run(&mut sim, |_sim, _step| true)?; // to end_time
//! let p = &sim.particles;
//! let volume = |j: &[f64]| j.iter().zip(&p.volume0).map(|(j, v)| j * v).sum::<f64>();
//! assert!((volume(&p.jacobian) / p.volume0.iter().sum::<f64>() - 1.0).abs() < 0.01);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![warn(missing_docs)]
// Loops over the D axes index several arrays at once and read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod about;
pub mod atomic;
pub(crate) mod averaging;
pub mod boundary;
pub mod build;
pub mod checkpoint;
pub mod comm;
pub(crate) mod damping;
pub mod deck;
pub mod distributed;
pub mod driver;
pub mod error;
pub mod field;
pub mod fill;
pub mod flow;
pub mod gauges;
pub mod geometry;
pub mod grid;
pub mod grid_fields;
mod keys;
pub mod linalg;
pub mod material;
pub mod output;
pub mod pages;
pub mod particles;
pub mod pressure;
pub mod rigid;
pub mod run;
pub mod scheme;
pub mod seed;
pub mod shape;
pub mod slabs;
pub mod timing;
pub(crate) mod transfer;
pub(crate) mod viscosity;
pub mod wall_law;

pub use deck::{limits, Deck};
pub use error::Error;

/// A deterministic pseudo-random source for unit tests: uniform in [0, 1), from a 64-bit
/// linear congruential generator (Knuth's MMIX constants) seeded with `seed`.
#[cfg(test)]
pub(crate) fn test_random(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}
