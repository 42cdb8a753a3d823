//! Where an evaluator is among the run's eval points: both evaluators (the policy's and the
//! planner's) step through them alike and owe a cut every eval point up to its step.

use mbpo_train::Schedule;
use mbpo_wire::{Done, StatsPublisher, Transport};

use crate::barrier::Cut;
use crate::Result;

/// Evaluations done and the next eval point.
#[derive(Debug, Clone, Copy)]
pub struct EvalPoints {
    /// Evaluations done.
    pub evals: u64,
    /// The next eval point (`None`: all evaluated).
    pub next: Option<u64>,
}

impl EvalPoints {
    /// After `evals` evaluations, the last of them at (or the checkpoint after) step `after`.
    pub fn after(schedule: &Schedule, evals: u64, after: u64) -> Self {
        Self {
            evals,
            next: schedule.next_eval_point(after),
        }
    }
    /// Eval point `t` was evaluated.
    pub fn evaluated(&mut self, schedule: &Schedule, t: u64) {
        *self = Self::after(schedule, self.evals + 1, t);
    }
    /// A cut after step T holds every eval point ≤ T evaluated: true while one is missing.
    pub fn behind(&self, cut: Cut) -> bool {
        self.next.is_some_and(|t| t <= cut.env_steps)
    }
    /// The evaluator's `Done`: its evaluations.
    pub fn report_done<S: Transport>(&self, stats: &StatsPublisher<S>) -> Result<()> {
        stats.report(Done {
            work: self.evals,
            ..Default::default()
        })?;
        Ok(())
    }
}
