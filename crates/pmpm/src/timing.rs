//! Wall-clock time per phase of the step, for `pmpm bench` and the end-of-run summary.
//!
//! A lap clock: [`PhaseTimers::lap`] charges the time since the previous lap to one phase, so
//! the phases add up to the wall time of the loop with nothing counted twice. It reads the
//! clock about a dozen times per step (tens of nanoseconds each), always on, so the figures a
//! user sees come from the code that ran, not from a special build.

use std::time::Instant;

/// A phase of the time step (docs/method.md's order), plus the driver's own work.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Sorting the particles by cell (every `simulation.sort_interval` steps).
    Sort,
    /// Particles to grid: mass, momentum, forces.
    P2g,
    /// Grid update: predictor v* and the wall conditions.
    Predictor,
    /// The implicit viscous solve (projection, `simulation.viscosity = "implicit"`).
    Viscosity,
    /// Volume fractions, bubble closing and node classification (projection).
    FreeSurface,
    /// Poisson matrix and right-hand side (projection).
    Assembly,
    /// Pressure solve, preconditioner set-up included (projection).
    Solve,
    /// Velocity correction and pressure to particles (projection).
    Corrector,
    /// The particles moved back towards their rest volumes, a second Poisson solve
    /// (projection, `pressure.density_correction`).
    Density,
    /// Grid to particles, the MUSL remap and the move.
    G2p,
    /// Strain rate, stress, F and J.
    Constitutive,
    /// Frames, series and probes.
    Output,
    /// Time-step choice and checks.
    Other,
}

impl Phase {
    /// Every phase, in step order.
    pub const ALL: [Phase; 13] = [
        Phase::Sort,
        Phase::P2g,
        Phase::Predictor,
        Phase::Viscosity,
        Phase::FreeSurface,
        Phase::Assembly,
        Phase::Solve,
        Phase::Corrector,
        Phase::Density,
        Phase::G2p,
        Phase::Constitutive,
        Phase::Output,
        Phase::Other,
    ];

    /// One-word key for the `BENCH` line of `pmpm bench`.
    pub fn key(self) -> &'static str {
        match self {
            Phase::Sort => "sort",
            Phase::P2g => "p2g",
            Phase::Predictor => "grid",
            Phase::Viscosity => "viscosity",
            Phase::FreeSurface => "free-surface",
            Phase::Assembly => "assembly",
            Phase::Solve => "pressure",
            Phase::Corrector => "corrector",
            Phase::Density => "density",
            Phase::G2p => "g2p",
            Phase::Constitutive => "constitutive",
            Phase::Output => "output",
            Phase::Other => "other",
        }
    }

    /// Name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Sort => "particle sort by cell",
            Phase::P2g => "P2G",
            Phase::Predictor => "grid update / predictor",
            Phase::Viscosity => "viscous solve",
            Phase::FreeSurface => "free-surface detection",
            Phase::Assembly => "assembly",
            Phase::Solve => "pressure solve",
            Phase::Corrector => "corrector",
            Phase::Density => "density correction",
            Phase::G2p => "G2P and move",
            Phase::Constitutive => "constitutive update",
            Phase::Output => "output",
            Phase::Other => "other (dt, checks)",
        }
    }
}

/// Accumulated seconds per phase.
#[derive(Debug, Clone)]
pub struct PhaseTimers {
    seconds: [f64; Phase::ALL.len()],
    last: Instant,
}

impl Default for PhaseTimers {
    fn default() -> Self {
        Self {
            seconds: [0.0; Phase::ALL.len()],
            last: Instant::now(),
        }
    }
}

impl PhaseTimers {
    /// Charges the time since the last lap to `phase`.
    #[inline]
    pub fn lap(&mut self, phase: Phase) {
        let now = Instant::now();
        self.seconds[phase as usize] += (now - self.last).as_secs_f64();
        self.last = now;
    }

    /// Seconds charged to `phase` so far.
    pub fn seconds(&self, phase: Phase) -> f64 {
        self.seconds[phase as usize]
    }

    /// Seconds of all phases.
    pub fn total(&self) -> f64 {
        self.seconds.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laps_add_up_and_go_to_their_phase() {
        let mut t = PhaseTimers::default();
        t.lap(Phase::Other);
        std::thread::sleep(std::time::Duration::from_millis(20));
        t.lap(Phase::Solve);
        assert!(t.seconds(Phase::Solve) >= 0.02);
        assert_eq!(t.seconds(Phase::P2g), 0.0);
        let sum: f64 = Phase::ALL.iter().map(|&p| t.seconds(p)).sum();
        assert_eq!(sum, t.total());
    }
}
