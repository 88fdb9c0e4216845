//! The time loop every run goes through: the size of each step, landing on frame times, and
//! the end. `pmpm run` (the `run` module, a layer above) adds frames, checkpoints and progress
//! to it; the validation suite and the tests step through it as it is, so that they test the
//! steps a user's run takes.
//!
//! ```text
//! while not finished:
//!     dt = fixed dt, or stable_dt(cfl), split to land on the next frame time, <= end - t
//!     step(dt)
//!     frame due if t >= next frame time (or at the end); next frame time moves on
//! ```

use crate::error::Error;
use crate::scheme::Simulation;

/// How large the steps are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepSize {
    /// The same step throughout (s).
    Fixed(f64),
    /// The stable step at a Courant number ([`Simulation::stable_dt`]).
    Adaptive {
        /// Courant number.
        cfl: f64,
        /// Shorten the steps before each frame into equal parts, so that a step ends on the
        /// frame's time; without it a frame is written at the first step end past its time.
        land_on_frames: bool,
    },
}

/// The time-step policy of a run: its end, its frame interval and its step size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clock {
    /// End time (s).
    pub end: f64,
    /// Time between frames (s).
    pub interval: f64,
    /// Step size.
    pub step: StepSize,
}

impl Clock {
    /// The tolerance of time comparisons: far below any step, so that frame k lands at
    /// k interval and the run ends at its end time, without a sliver of a step.
    pub fn eps(&self) -> f64 {
        1e-9 * self.interval.min(self.end)
    }

    /// Whether time `t` is at the end.
    pub fn finished(&self, t: f64) -> bool {
        t >= self.end - self.eps()
    }

    /// The next step's size from `sim`'s state, with the next frame due at `next_frame`:
    /// never past the end time. An error when the stable step has fallen below a trillionth
    /// of the output interval (or of the run): something has blown up.
    pub fn next_dt<const D: usize>(
        &self,
        sim: &Simulation<D>,
        next_frame: f64,
    ) -> Result<f64, Error> {
        let mut dt = match self.step {
            StepSize::Fixed(dt) => dt,
            StepSize::Adaptive {
                cfl,
                land_on_frames,
            } => {
                let dt = sim.stable_dt(cfl);
                if dt < 1e-3 * self.eps() {
                    // a trillion steps to the next frame: a speed has run away (a free body
                    // fed by its coupling, a particle flung out), and the run would crawl
                    return Err(Error::BlowUp(format!(
                        "run stopped at t = {:.6} s: the stable step fell to {dt:.3e} s, below \
                         a trillionth of the output interval, at a speed of {:.3e} m/s (the \
                         fastest particle, wall or rigid body). Likely cause: a flow or body \
                         that blew up; lower simulation.cfl",
                        sim.time,
                        sim.max_speed().max(sim.boundary.max_wall_speed())
                    )));
                }
                let left = next_frame.min(self.end) - sim.time;
                if !land_on_frames {
                    // at most one frame interval, so that no frame is skipped
                    dt.min(self.interval)
                } else if dt.is_finite() && dt > 0.0 && left > 0.0 {
                    // the time left to the frame in equal steps: with the projection a tiny
                    // last step would turn the leftover divergence into a pressure spike
                    left / (left / dt).ceil()
                } else {
                    dt
                }
            }
        };
        dt = dt.min(self.end - sim.time);
        if !(dt > 0.0 && dt.is_finite()) {
            // at rest with nothing to bound the step: step to the next frame
            dt = (next_frame.min(self.end) - sim.time).max(self.eps());
        }
        Ok(dt)
    }
}

/// One step the driver took.
#[derive(Debug, Clone, Copy)]
pub struct Step {
    /// Time at the step's start (s): when the probes sampled.
    pub t0: f64,
    /// The step's size (s).
    pub dt: f64,
    /// A frame is due after this step (its time is reached, or the end is).
    pub frame: bool,
}

/// A run's place on its clock: the time of the next frame.
#[derive(Debug, Clone, Copy)]
pub struct Driver {
    /// The time-step policy.
    pub clock: Clock,
    /// Time of the next frame (s).
    pub next_frame: f64,
}

impl Driver {
    /// A run from its initial state, whose frame at t = 0 is written (or not wanted): the
    /// next frame is one interval on.
    pub fn new(clock: Clock) -> Self {
        Self {
            clock,
            next_frame: clock.interval,
        }
    }

    /// A run resumed with its next frame at `next_frame`.
    pub fn resume(clock: Clock, next_frame: f64) -> Self {
        Self { clock, next_frame }
    }

    /// Whether `sim` has reached the end time.
    pub fn finished<const D: usize>(&self, sim: &Simulation<D>) -> bool {
        self.clock.finished(sim.time)
    }

    /// Takes one step of the policy's size and says whether a frame is due after it.
    pub fn step<const D: usize>(&mut self, sim: &mut Simulation<D>) -> Result<Step, Error> {
        let dt = self.clock.next_dt(sim, self.next_frame)?;
        self.step_by(sim, dt)
    }

    /// Takes one step of size `dt` (a caller's own choice, within the policy's) and says
    /// whether a frame is due after it.
    pub fn step_by<const D: usize>(
        &mut self,
        sim: &mut Simulation<D>,
        dt: f64,
    ) -> Result<Step, Error> {
        let t0 = sim.time;
        sim.step(dt)?;
        let eps = self.clock.eps();
        let frame = sim.time >= self.next_frame - eps || self.finished(sim);
        if frame {
            self.next_frame = next_after(self.next_frame, sim.time + eps, self.clock.interval);
        }
        Ok(Step { t0, dt, frame })
    }

    /// Steps `sim` to the end time. After every step `each` sees the state and the step; it
    /// returns `false` to stop early.
    pub fn run<const D: usize>(
        &mut self,
        sim: &mut Simulation<D>,
        mut each: impl FnMut(&Simulation<D>, &Step) -> bool,
    ) -> Result<(), Error> {
        while !self.finished(sim) {
            let step = self.step(sim)?;
            if !each(sim, &step) {
                break;
            }
        }
        Ok(())
    }
}

/// The first of `next`, `next + interval`, `next + 2 interval`, ... past `t`, found without a
/// loop: an interval below the spacing of floating-point numbers near `t` would never get
/// there by adding.
pub fn next_after(next: f64, t: f64, interval: f64) -> f64 {
    if next > t {
        return next;
    }
    let k = ((t - next) / interval).floor() + 1.0;
    let mut n = next + k * interval;
    if n <= t {
        // (t - next) / interval rounded down across a whole number
        n += interval;
    }
    if n > t {
        n
    } else {
        // interval below the floating-point spacing at t: the next number above t
        f64::from_bits(t.to_bits() + 1).max(n)
    }
}

#[cfg(test)]
mod tests {
    use super::next_after;

    #[test]
    fn the_next_output_time_is_found_without_a_loop() {
        assert_eq!(next_after(0.5, 0.2, 0.1), 0.5);
        let n = next_after(0.1, 0.35, 0.1);
        assert!((n - 0.4).abs() < 1e-15, "{n}");
        // an interval far below the spacing of numbers near t: the next number above t, at once
        let n = next_after(1e-300, 0.01, 1e-300);
        assert!(n > 0.01 && n - 0.01 < 1e-17, "{n}");
    }
}
