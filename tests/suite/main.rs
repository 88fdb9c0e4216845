//! The integration tests, one binary: each module is one area of pmpm, run as a user runs it
//! (the `pmpm` binary, or the library's run and driver). One binary, so that the whole
//! program is linked once (a fat-LTO link a test file took over a minute on 2 cores).

mod bad_decks;
mod bingham;
mod bodies_flows;
mod checkpoint;
mod common;
mod elastic;
mod example_headers;
mod faults;
mod gauges;
mod geometry;
mod limits;
mod locking;
mod open_boundaries;
mod output_dir;
mod periodic;
mod physics;
mod plot;
mod projection;
mod rigid;
mod rigid_shapes;
mod run_decks;
mod seeding;
mod sort;
mod viscosity;
