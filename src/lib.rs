//! The `pmpm` application: what the command line adds to the solver crate (`pmpm`): deck
//! summaries and warnings (`check`), the progress display and clean interrupts (`run`),
//! pictures (`plot`) and the validation report (`validate`).
#![warn(missing_docs)]
// Loops over the D axes index several arrays at once and read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod check;
pub mod plot;
pub mod progress;
pub mod table;
pub mod validation;
