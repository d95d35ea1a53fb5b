//! Where a training run's wall clock went: learning (replay insertion, batch drawing and the
//! updates), stepping the environment, acting, evaluating, checkpoints and the rest.
//!
//! The learner bench measures updates alone; a run also steps MuJoCo, acts, evaluates and
//! writes checkpoints. Splitting the run's clock lets the two be compared: the updates/s
//! *while learning* is the figure to hold against the bench's row "as trained", and the other
//! shares say what the run spends beside it. The clock is read a few times per environment
//! step (`Instant::now`, tens of nanoseconds against a step of tens of microseconds and an
//! update of milliseconds) and allocates nothing.

use std::time::Instant;

use serde::{Deserialize, Serialize};

/// Seconds spent in each part of a training segment (this process's, not summed over resumed
/// segments).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TimeSplit {
    /// Storing transitions, drawing batches and the learner's updates.
    pub learn_s: f64,
    /// Stepping the environment (and resetting it); with a fleet (`--plants`), waiting for
    /// the plants' blocks.
    pub env_s: f64,
    /// Choosing actions (in-process, through the controller or on the device); with a fleet,
    /// sending the policy to the plants.
    pub act_s: f64,
    /// Evaluation episodes (and evaluation contact sheets).
    pub evaluate_s: f64,
    /// Writing checkpoints and metrics files.
    pub checkpoint_s: f64,
    /// The segment's whole wall clock; what the parts above leave is the loop's own time.
    pub total_s: f64,
    /// Learner updates made in the segment.
    pub updates: u64,
}

impl TimeSplit {
    /// Updates per second of learning time: what to compare with the learner bench.
    pub fn updates_per_learn_s(&self) -> f64 {
        self.updates as f64 / self.learn_s.max(1e-9)
    }

    /// The split as one line for the end of a run.
    pub fn line(&self) -> String {
        let total = self.total_s.max(1e-9);
        let pct = |s: f64| 100.0 * s / total;
        let other = self.total_s
            - (self.learn_s + self.env_s + self.act_s + self.evaluate_s + self.checkpoint_s);
        format!(
            "time: learning {:.1}% ({:.1} updates/s while learning), environment {:.1}%, acting {:.1}%, evaluation {:.1}%, checkpoints and metrics {:.1}%, other {:.1}% of {:.0} s",
            pct(self.learn_s),
            self.updates_per_learn_s(),
            pct(self.env_s),
            pct(self.act_s),
            pct(self.evaluate_s),
            pct(self.checkpoint_s),
            pct(other.max(0.0)),
            self.total_s
        )
    }
}

/// A stopwatch that charges the time since its last lap to one part.
#[derive(Clone, Copy, Debug)]
pub struct Laps {
    last: Instant,
}

impl Laps {
    /// Starts timing now.
    pub fn start() -> Self {
        Self {
            last: Instant::now(),
        }
    }

    /// Adds the seconds since the last lap (or the start) to `into`.
    pub fn lap(&mut self, into: &mut f64) {
        let now = Instant::now();
        *into += now.duration_since(self.last).as_secs_f64();
        self.last = now;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_names_each_share_of_the_total() {
        let s = TimeSplit {
            learn_s: 50.0,
            env_s: 20.0,
            act_s: 5.0,
            evaluate_s: 15.0,
            checkpoint_s: 2.0,
            total_s: 100.0,
            updates: 1000,
        };
        assert_eq!(s.updates_per_learn_s(), 20.0);
        let line = s.line();
        for part in [
            "learning 50.0% (20.0 updates/s while learning)",
            "environment 20.0%",
            "acting 5.0%",
            "evaluation 15.0%",
            "checkpoints and metrics 2.0%",
            "other 8.0% of 100 s",
        ] {
            assert!(line.contains(part), "{part} missing from {line}");
        }
    }

    #[test]
    fn laps_charge_each_interval_once() {
        let mut laps = Laps::start();
        let (mut a, mut b) = (0.0, 0.0);
        std::thread::sleep(std::time::Duration::from_millis(20));
        laps.lap(&mut a);
        laps.lap(&mut b);
        assert!(a >= 0.019, "{a}");
        assert!(
            b < a,
            "the second lap starts where the first ended: {b} vs {a}"
        );
    }
}
