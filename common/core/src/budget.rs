//! The time budget of an iterative computation (a plan): one rule for every planner.

use std::time::{Duration, Instant};

/// A plan's time budget (`[mpc.planner] budget_ms`, `[tdmpc.planner] budget_ms`): an
/// iterative planner stops before an iteration that would overrun it, predicting the next
/// iteration's time as the mean of those it ran; the first always runs. Without a budget every configured iteration runs (and the
/// plan is the same whatever the machine's speed: a budget makes it depend on timing).
#[derive(Debug, Clone, Copy)]
pub struct Budget {
    limit: Option<Duration>,
    started: Instant,
}

impl Budget {
    /// A plan starting now with `limit`.
    pub fn start(limit: Option<Duration>) -> Self {
        Self {
            limit,
            started: Instant::now(),
        }
    }
    /// Whether another iteration fits after `done` of them.
    pub fn allows(&self, done: usize) -> bool {
        let Some(limit) = self.limit else {
            return true;
        };
        if done == 0 {
            return true;
        }
        let spent = self.started.elapsed();
        spent + spent / done as u32 <= limit
    }
}
