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
    /// Adam steps (one minibatch per member each) over all model trainings.
    pub model_gradient_steps: u64,
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

/// Milliseconds per env step of each phase, and what explains them.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct MsPerStep {
    /// Model training (all of it, holdout included).
    pub model_training: f64,
    /// Of which the holdout MSE after each epoch.
    pub model_holdout: f64,
    /// Epochs per model training.
    pub epochs_per_training: f64,
    /// Seconds per model-training epoch.
    pub seconds_per_epoch: f64,
    /// Milliseconds per model Adam step: a training's seconds without its holdout passes, per
    /// minibatch. An epoch's cost grows with D_env; this one should not, so it is the figure
    /// that shows the kernels' speed across a run.
    pub ms_per_model_step: f64,
    /// Model rollouts.
    pub rollouts: f64,
    /// SAC updates.
    pub sac: f64,
    /// Milliseconds per SAC update.
    pub ms_per_sac_update: f64,
    /// Acting in the env.
    pub acting: f64,
    /// Whatever else the window's wall-clock held (progress, bookkeeping).
    pub other: f64,
    /// The whole window.
    pub total: f64,
}

impl PhaseTimes {
    /// Add one model training.
    pub fn add_training(&mut self, report: &TrainReport) {
        self.model_trainings += 1;
        self.model_epochs += report.epochs as u64;
        self.model_gradient_steps += report.gradient_steps as u64;
        self.model_train_seconds += report.seconds;
        self.model_holdout_seconds += report.holdout_seconds;
    }

    /// What was added since the reading `earlier`.
    pub fn since(&self, earlier: &PhaseTimes) -> PhaseTimes {
        PhaseTimes {
            steps: self.steps - earlier.steps,
            model_trainings: self.model_trainings - earlier.model_trainings,
            model_epochs: self.model_epochs - earlier.model_epochs,
            model_gradient_steps: self.model_gradient_steps - earlier.model_gradient_steps,
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

    /// Milliseconds per env step of each phase over steps that took `wall_seconds` in all
    /// (what no phase holds is `other`).
    pub fn ms_per_step(&self, wall_seconds: f64) -> MsPerStep {
        let per_step = |s: f64| 1e3 * s / self.steps.max(1) as f64;
        let ratio = |a: f64, b: u64| if b == 0 { 0.0 } else { a / b as f64 };
        MsPerStep {
            model_training: per_step(self.model_train_seconds),
            model_holdout: per_step(self.model_holdout_seconds),
            epochs_per_training: ratio(self.model_epochs as f64, self.model_trainings),
            seconds_per_epoch: ratio(self.model_train_seconds, self.model_epochs),
            ms_per_model_step: 1e3
                * ratio(
                    self.model_train_seconds - self.model_holdout_seconds,
                    self.model_gradient_steps,
                ),
            rollouts: per_step(self.rollout_seconds),
            sac: per_step(self.sac_seconds),
            ms_per_sac_update: 1e3 * ratio(self.sac_seconds, self.sac_updates),
            acting: per_step(self.act_seconds),
            other: per_step(wall_seconds - self.total_seconds()).max(0.0),
            total: per_step(wall_seconds),
        }
    }

    /// The model trainings and their epochs in a [`PhaseTimes::per_step_line`] (read back from a
    /// run's `train.log`; the format is written and read only here).
    pub fn trainings_and_epochs_of_line(line: &str) -> Option<(u64, u64)> {
        let rest = line.split("ms per env step over ").nth(1)?;
        let counts = rest.split("model training ").nth(1)?.split('(').nth(1)?;
        let mut words = counts.split(' ');
        let trainings = words.next()?.parse().ok()?;
        (words.next()? == "trainings,").then_some(())?;
        let epochs = words.next()?.parse().ok()?;
        (words.next()? == "epochs,").then_some((trainings, epochs))
    }

    /// One log line: milliseconds per env step of each phase, with the counts that explain them.
    pub fn per_step_line(&self) -> String {
        let m = self.ms_per_step(self.total_seconds());
        format!(
            "ms per env step over {} steps: model training {:.1} ({} trainings, {} epochs, \
             {:.0} ms/epoch, {:.2} ms/minibatch, holdout {:.1}), rollouts {:.1} ({} imagined), \
             SAC {:.1} ({} updates, {:.2} ms each), acting {:.2}; total {:.1}",
            self.steps,
            m.model_training,
            self.model_trainings,
            self.model_epochs,
            1e3 * m.seconds_per_epoch,
            m.ms_per_model_step,
            m.model_holdout,
            m.rollouts,
            self.imagined,
            m.sac,
            self.sac_updates,
            m.ms_per_sac_update,
            m.acting,
            m.total,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trainings_and_epochs_are_read_back_from_the_log_line() {
        let times = PhaseTimes {
            steps: 1000,
            model_trainings: 4,
            model_epochs: 87,
            model_train_seconds: 30.0,
            ..Default::default()
        };
        let line = format!("2026-11-26T06:56:41Z INFO mbpo: {}", times.per_step_line());
        assert_eq!(
            PhaseTimes::trainings_and_epochs_of_line(&line),
            Some((4, 87))
        );
        for other in [
            "seed 0: step 28000 eval 1032.8",
            "ms per env step over 1000 steps: model training 1.0 (x trainings, 3 epochs, ",
            "",
        ] {
            assert_eq!(
                PhaseTimes::trainings_and_epochs_of_line(other),
                None,
                "{other}"
            );
        }
    }

    #[test]
    fn a_minibatch_costs_the_training_time_without_the_holdout_per_adam_step() {
        let run = |epochs, steps, train: f64, holdout: f64| PhaseTimes {
            steps: 1000,
            model_trainings: 4,
            model_epochs: epochs,
            model_gradient_steps: steps,
            model_train_seconds: train,
            model_holdout_seconds: holdout,
            ..Default::default()
        };
        // The same 2000 minibatches at 7 ms each, once in 10 epochs of a large D_env and once in
        // 80 epochs of a small one: the epoch costs differ eightfold, the minibatch does not.
        let large = run(10, 2000, 14.5, 0.5).ms_per_step(20.0);
        let small = run(80, 2000, 15.0, 1.0).ms_per_step(20.0);
        assert!((large.ms_per_model_step - 7.0).abs() < 1e-9);
        assert!((small.ms_per_model_step - 7.0).abs() < 1e-9);
        assert!((large.seconds_per_epoch - 1.45).abs() < 1e-9);
        assert!((small.seconds_per_epoch - 0.1875).abs() < 1e-9);
        let line = run(10, 2000, 14.5, 0.5).per_step_line();
        assert!(
            line.contains(
                "(4 trainings, 10 epochs, 1450 ms/epoch, 7.00 ms/minibatch, holdout 0.5)"
            ),
            "{line}"
        );
        // No training in a window: no division by zero.
        assert_eq!(run(0, 0, 0.0, 0.0).ms_per_step(1.0).ms_per_model_step, 0.0);
    }
}
