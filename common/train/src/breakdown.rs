//! `mbpo bench breakdown`: where an MBPO run's time goes at a given size of D_env.
//!
//! A run's cost per env step grows with its data: each model training is more epochs over
//! more transitions, and rollouts grow longer with the epoch. So the breakdown is measured
//! where it applies: from a run's kept checkpoint at N real transitions (`checkpoint.keep_every`),
//! the sequential trainer continues for a window of steps (whole model-training periods, as
//! the run would: same data, same model, same policy) and its [`PhaseTimes`] are reported per
//! env step. A projection integrates those per-step costs over a whole run, piecewise linear in
//! N between the measured points (each phase's cost per step is close to linear in N or
//! constant), so a run too long for one session still gets a figure.

use crate::config::ExperimentConfig;
use crate::phase_times::{MsPerStep, PhaseTimes};
use crate::sac_trainer::TrainError;
use crate::schedule::Schedule;
use crate::Mbpo;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The cost of `window` env steps after `at` real transitions.
#[derive(Debug, Clone, Serialize)]
pub struct BreakdownPoint {
    /// Real transitions in D_env when the window starts (the checkpoint's env steps).
    pub at: u64,
    /// Env steps measured.
    pub window: u64,
    /// Rollout length k in force during the window.
    pub rollout_length: usize,
    /// Wall seconds of the whole window.
    pub wall_seconds: f64,
    /// The phases' totals over the window.
    pub phases: PhaseTimes,
    /// Milliseconds per env step, by phase (the table's row).
    pub ms_per_step: MsPerStep,
}

impl BreakdownPoint {
    fn new(at: u64, rollout_length: usize, wall_seconds: f64, phases: PhaseTimes) -> Self {
        let ms_per_step = phases.ms_per_step(wall_seconds);
        Self {
            at,
            window: phases.steps,
            rollout_length,
            wall_seconds,
            phases,
            ms_per_step,
        }
    }
}

/// Continue `run` (its config `cfg`, which may differ from the run's in thread counts only)
/// from its complete checkpoint at `at` env steps for `window` steps, and time each phase.
/// Nothing is written to the run.
pub fn breakdown_at(
    cfg: &ExperimentConfig,
    run: &Path,
    at: u64,
    window: u64,
) -> Result<BreakdownPoint, TrainError> {
    let (mut mbpo, _) = Mbpo::from_kept_checkpoint(cfg, run, at)?;
    let schedule = Schedule::of(cfg);
    let epoch = (at + 1..=at + window).find_map(|t| schedule.train_point(t));
    let k = mbpo_model::rollout_length(epoch.unwrap_or(0), cfg.mbpo.rollout_schedule);
    let started = Instant::now();
    for t in at + 1..=at + window {
        if schedule.is_warm_up(t) {
            return Err(TrainError::Config(format!(
                "breakdown at {at}: step {t} is a warm-up step; measure after \
                 mbpo.init_random_steps ({})",
                cfg.mbpo.init_random_steps
            )));
        }
        mbpo.step_unless(t, || false)?;
    }
    let wall = started.elapsed().as_secs_f64();
    Ok(BreakdownPoint::new(at, k, wall, mbpo.phases))
}

/// Seconds a run of `steps` env steps would take, from per-step costs measured at `points`:
/// piecewise linear in N between the points, held at the first point's value before it and
/// extended along the last segment after the last point. `None` with fewer than two points at
/// distinct steps: the cost grows with N, so one point says nothing about a run. Warm-up steps
/// (uniform random, no training) are left out.
pub fn projected_seconds(
    points: &[BreakdownPoint],
    init_random_steps: u64,
    steps: u64,
) -> Option<f64> {
    let mut pts: Vec<(f64, f64)> = points
        .iter()
        .map(|p| (p.at as f64, p.ms_per_step.total / 1e3))
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.dedup_by(|a, b| a.0 == b.0);
    if pts.len() < 2 {
        return None;
    }
    let first = pts[0];
    let cost = |n: f64| -> f64 {
        if n <= first.0 {
            return first.1;
        }
        let i = pts
            .windows(2)
            .position(|w| n <= w[1].0)
            .unwrap_or(pts.len() - 2);
        let (a, b) = (pts[i], pts[i + 1]);
        (a.1 + (b.1 - a.1) * (n - a.0) / (b.0 - a.0)).max(0.0)
    };
    // Midpoint rule over blocks of 100 steps: smooth enough for a piecewise-linear cost.
    let block = 100u64;
    let mut total = 0.0;
    let mut n = init_random_steps;
    while n < steps {
        let len = block.min(steps - n);
        total += cost(n as f64 + len as f64 / 2.0) * len as f64;
        n += len;
    }
    Some(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(at: u64, ms_total: f64) -> BreakdownPoint {
        let phases = PhaseTimes {
            steps: 1000,
            ..Default::default()
        };
        BreakdownPoint::new(at, 1, ms_total, phases)
    }

    #[test]
    fn projection_integrates_the_piecewise_linear_cost() {
        // 1 ms/step at 10k, 3 ms/step at 30k: linear, 2e-4 ms per transition.
        let pts = [point(10_000, 1.0), point(30_000, 3.0)];
        // From 10k to 30k the mean cost is 2 ms: 40 s.
        let s = projected_seconds(&pts, 10_000, 30_000).unwrap();
        assert!((s - 40.0).abs() < 1e-9, "{s}");
        // Before the first point the first cost holds: 5k..10k at 1 ms.
        let s = projected_seconds(&pts, 5_000, 10_000).unwrap();
        assert!((s - 5.0).abs() < 1e-9, "{s}");
        // After the last point the last segment goes on: 30k..40k, 3 -> 4 ms, mean 3.5 ms.
        let s = projected_seconds(&pts, 30_000, 40_000).unwrap();
        assert!((s - 35.0).abs() < 1e-9, "{s}");
        // One point, or two at the same step: no projection.
        assert_eq!(projected_seconds(&pts[..1], 0, 2_000), None);
        let same = [point(10_000, 1.0), point(10_000, 2.0)];
        assert_eq!(projected_seconds(&same, 0, 2_000), None);
    }

    #[test]
    fn per_step_figures_divide_by_steps_trainings_and_updates() {
        let phases = PhaseTimes {
            steps: 500,
            model_trainings: 2,
            model_epochs: 30,
            model_train_seconds: 15.0,
            model_holdout_seconds: 1.0,
            rollout_seconds: 2.0,
            imagined: 100,
            sac_seconds: 20.0,
            sac_updates: 10_000,
            act_seconds: 0.5,
        };
        let p = BreakdownPoint::new(10_000, 3, 40.0, phases);
        let m = p.ms_per_step;
        assert_eq!(m.model_training, 30.0);
        assert_eq!(m.model_holdout, 2.0);
        assert_eq!(m.epochs_per_training, 15.0);
        assert_eq!(m.seconds_per_epoch, 0.5);
        assert_eq!(m.rollouts, 4.0);
        assert_eq!(m.sac, 40.0);
        assert_eq!(m.ms_per_sac_update, 2.0);
        assert_eq!(m.acting, 1.0);
        assert_eq!(m.total, 80.0);
        assert!((m.other - 5.0).abs() < 1e-9);
    }
}
