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
#![warn(missing_docs)]
// Loops over the D axes index several arrays at once and read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod averaging;
pub mod boundary;
pub mod checkpoint;
pub mod deck;
pub mod error;
pub mod field;
pub mod grid;
pub mod limits;
pub mod material;
pub mod output;
pub mod particles;
pub mod plot;
pub mod pressure;
pub mod rigid;
pub mod run;
pub mod scheme;
pub mod shape;
pub mod timing;
pub mod transfer;
pub mod validation;

pub use deck::Deck;
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
