//! Where an MBPO run's time goes: wall seconds per phase of Algorithm 2, summed over steps.
//!
//! The sequential trainer ([`crate::Mbpo`]) adds to one [`PhaseTimes`] as it goes; the
//! difference of two readings ([`PhaseTimes::since`]) is the cost of the steps between them.
//! `train.log` gets one line per evaluation point ([`PhaseTimes::per_step_line`]), and `mbpo
//! bench breakdown` reports it per env step at chosen sizes of D_env.

use mbpo_model::TrainReport;
use serde::Serialize;

/// Seconds and counts per phase; every field is a running total.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct PhaseTimes {
    /// Env steps (warm-up steps excluded).
    pub steps: u64,
    /// Model trainings.
    pub model_trainings: u64,
    /// Training epochs over all model trainings.
    pub model_epochs: u64,
    /// Seconds of whole model trainings (epochs, holdout, split, termination rule).
    pub model_train_seconds: f64,
    /// Of those, seconds computing the holdout MSE after each epoch.
    pub model_holdout_seconds: f64,
    /// Model rollouts: seconds of branching (model and policy forward passes, D_model pushes).
    pub rollout_seconds: f64,
    /// Imagined transitions added to D_model.
    pub imagined: u64,
    /// SAC updates: seconds.
    pub sac_seconds: f64,
    /// SAC updates.
    pub sac_updates: u64,
    /// Acting: the policy's action, the env step and handing the transition to every D_env.
    pub act_seconds: f64,
}

impl PhaseTimes {
    /// Add one model training.
    pub fn add_training(&mut self, report: &TrainReport) {
        self.model_trainings += 1;
        self.model_epochs += report.epochs as u64;
        self.model_train_seconds += report.seconds;
        self.model_holdout_seconds += report.holdout_seconds;
    }

    /// What was added since the reading `earlier`.
    pub fn since(&self, earlier: &PhaseTimes) -> PhaseTimes {
        PhaseTimes {
            steps: self.steps - earlier.steps,
            model_trainings: self.model_trainings - earlier.model_trainings,
            model_epochs: self.model_epochs - earlier.model_epochs,
            model_train_seconds: self.model_train_seconds - earlier.model_train_seconds,
            model_holdout_seconds: self.model_holdout_seconds - earlier.model_holdout_seconds,
            rollout_seconds: self.rollout_seconds - earlier.rollout_seconds,
            imagined: self.imagined - earlier.imagined,
            sac_seconds: self.sac_seconds - earlier.sac_seconds,
            sac_updates: self.sac_updates - earlier.sac_updates,
            act_seconds: self.act_seconds - earlier.act_seconds,
        }
    }

    /// Seconds of every phase together.
    pub fn total_seconds(&self) -> f64 {
        self.model_train_seconds + self.rollout_seconds + self.sac_seconds + self.act_seconds
    }

    /// One log line: milliseconds per env step of each phase, with the counts that explain them.
    pub fn per_step_line(&self) -> String {
        let per_step = |s: f64| 1e3 * s / self.steps.max(1) as f64;
        let per = |s: f64, n: u64| if n == 0 { 0.0 } else { 1e3 * s / n as f64 };
        format!(
            "ms per env step over {} steps: model training {:.1} ({} trainings, {} epochs, \
             {:.0} ms/epoch, holdout {:.1}), rollouts {:.1} ({} imagined), SAC {:.1} ({} updates, \
             {:.2} ms each), acting {:.2}; total {:.1}",
            self.steps,
            per_step(self.model_train_seconds),
            self.model_trainings,
            self.model_epochs,
            per(self.model_train_seconds, self.model_epochs),
            per_step(self.model_holdout_seconds),
            per_step(self.rollout_seconds),
            self.imagined,
            per_step(self.sac_seconds),
            self.sac_updates,
            per(self.sac_seconds, self.sac_updates),
            per_step(self.act_seconds),
            per_step(self.total_seconds()),
        )
    }
}
