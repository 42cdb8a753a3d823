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
//!
//! Model training dominates at MuJoCo scale, and its one lever that changes results is an epoch
//! cap (`model.max_epochs`). Each point therefore also reports, for a few caps, what the
//! window's trainings would have saved in epochs and lost in elite holdout MSE, replayed
//! exactly from the epochs they ran ([`mbpo_model::elite_holdout_mse_if_capped`]).

use mbpo_model::TrainReport;
use mbpo_train::config::ExperimentConfig;
use mbpo_train::error::TrainError;
use mbpo_train::phase_times::{MsPerStep, PhaseTimes};
use mbpo_train::schedule::Schedule;
use mbpo_train::Mbpo;
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
    /// Epochs each model training of the window ran (the paper's early-stopping rule).
    pub training_epochs: Vec<usize>,
    /// What capping those trainings' epochs would have saved and cost, for [`EPOCH_CAPS`].
    pub epoch_caps: Vec<EpochCap>,
}

/// The epoch caps each breakdown point reports on.
pub const EPOCH_CAPS: [usize; 5] = [5, 10, 15, 20, 30];

/// One epoch cap (`model.max_epochs`) applied to a window's model trainings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EpochCap {
    /// The cap.
    pub cap: usize,
    /// Epochs the trainings would have run under the cap, over the epochs they ran: the share
    /// of model-training time left (every epoch costs the same within a training).
    pub epochs_fraction: f64,
    /// Mean over the trainings of (capped elite holdout MSE) / (elite holdout MSE they ended
    /// with): 1.0 costs nothing, 1.10 is a model 10 % worse on held-out transitions.
    pub holdout_ratio: f64,
}

impl EpochCap {
    /// The cap applied to `reports` (a model with `elites` elites and improvement threshold
    /// `threshold`).
    pub fn of(cap: usize, reports: &[TrainReport], elites: usize, threshold: f32) -> Self {
        let ran: usize = reports.iter().map(|r| r.epochs).sum();
        let capped: usize = reports.iter().map(|r| r.epochs.min(cap)).sum();
        let ratio = |r: &TrainReport| {
            mbpo_model::elite_holdout_mse_if_capped(r, cap, elites, threshold)
                / r.elite_holdout_mse()
        };
        // A window without trainings has nothing to cut and nothing to lose.
        if reports.is_empty() {
            return Self {
                cap,
                epochs_fraction: 1.0,
                holdout_ratio: 1.0,
            };
        }
        Self {
            cap,
            epochs_fraction: capped as f64 / ran.max(1) as f64,
            holdout_ratio: reports.iter().map(ratio).sum::<f64>() / reports.len() as f64,
        }
    }
}

impl BreakdownPoint {
    fn new(
        at: u64,
        rollout_length: usize,
        wall_seconds: f64,
        phases: PhaseTimes,
        trainings: (&[TrainReport], usize, f32),
    ) -> Self {
        let ms_per_step = phases.ms_per_step(wall_seconds);
        let (reports, elites, threshold) = trainings;
        Self {
            at,
            window: phases.steps,
            rollout_length,
            wall_seconds,
            phases,
            ms_per_step,
            training_epochs: reports.iter().map(|r| r.epochs).collect(),
            epoch_caps: EPOCH_CAPS
                .iter()
                .map(|&cap| EpochCap::of(cap, reports, elites, threshold))
                .collect(),
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
    let mut reports = Vec::new();
    let started = Instant::now();
    for t in at + 1..=at + window {
        if schedule.is_warm_up(t) {
            return Err(TrainError::Config(format!(
                "breakdown at {at}: step {t} is a warm-up step; measure after \
                 mbpo.init_random_steps ({})",
                cfg.mbpo.init_random_steps
            )));
        }
        let trainings = mbpo.phases.model_trainings;
        mbpo.step_unless(t, |_| false)?;
        if mbpo.phases.model_trainings > trainings {
            reports.extend(mbpo.last_model_report.clone());
        }
    }
    let wall = started.elapsed().as_secs_f64();
    let model = (cfg.model.elites, cfg.model.improvement_threshold);
    Ok(BreakdownPoint::new(
        at,
        k,
        wall,
        mbpo.phases,
        (&reports, model.0, model.1),
    ))
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
    let per_step = points.iter().map(|p| (p.at, p.ms_per_step.total / 1e3));
    project(per_step.collect(), init_random_steps, steps)
}

/// [`projected_seconds`] with every model training capped at `cap` epochs: each point's
/// model-training time scaled by its [`EpochCap::epochs_fraction`] for that cap. The same
/// trainings, shortened; a capped run's later data would differ. `None` as there, or when
/// `cap` is not one of [`EPOCH_CAPS`].
pub fn projected_seconds_capped(
    points: &[BreakdownPoint],
    init_random_steps: u64,
    steps: u64,
    cap: usize,
) -> Option<f64> {
    projected_with_model_scaled(points, init_random_steps, steps, |p| {
        Some(p.epoch_caps.iter().find(|c| c.cap == cap)?.epochs_fraction)
    })
}

/// [`projected_seconds`] at `epochs` epochs per model training instead of each window's own:
/// each point's model-training time scaled by `epochs` / its epochs per training. The early-
/// stopping rule's epoch count varies a lot from one training to the next (4 trainings of one
/// window ran 15 to 50 epochs), so a window of a few trainings says little about it, while
/// the seconds per epoch are steady; a run's whole log gives the epochs
/// ([`logged_epochs_per_training`]).
pub fn projected_seconds_at_epochs(
    points: &[BreakdownPoint],
    init_random_steps: u64,
    steps: u64,
    epochs: f64,
) -> Option<f64> {
    projected_with_model_scaled(points, init_random_steps, steps, |p| {
        let own = p.ms_per_step.epochs_per_training;
        (own > 0.0).then(|| epochs / own)
    })
}

/// Epochs per model training over everything a run logged (`logs/train.log`: the per-window
/// lines of [`PhaseTimes::per_step_line`]), with the number of trainings; `None` without
/// any.
pub fn logged_epochs_per_training(run: &Path) -> Option<(f64, u64)> {
    let log = std::fs::read_to_string(run.join("logs").join("train.log")).ok()?;
    let (trainings, epochs) = log
        .lines()
        .filter_map(PhaseTimes::trainings_and_epochs_of_line)
        .fold((0, 0), |(t, e), (dt, de)| (t + dt, e + de));
    (trainings > 0).then(|| (epochs as f64 / trainings as f64, trainings))
}

/// A whole run's projected hours from breakdown points: at the windows' own epochs per
/// training, at the run's mean over its log, and with each epoch cap (the JSON `projection`).
#[derive(Debug, Clone, Serialize)]
pub struct Projection {
    /// Env steps of the projected run.
    pub env_steps: u64,
    /// Hours at each window's own costs ([`projected_seconds`]).
    pub hours: Option<f64>,
    /// How `hours` is computed (for a reader of the JSON).
    pub note: &'static str,
    /// Hours at the run's mean epochs per training ([`projected_seconds_at_epochs`]).
    pub at_logged_epochs: Option<LoggedEpochs>,
    /// Hours with every training capped, for each of [`EPOCH_CAPS`]
    /// ([`projected_seconds_capped`]).
    pub capped: Vec<CappedProjection>,
    /// How `capped` is computed.
    pub capped_note: &'static str,
}

/// [`Projection::at_logged_epochs`].
#[derive(Debug, Clone, Serialize)]
pub struct LoggedEpochs {
    /// Mean epochs per training over the run's log.
    pub epochs_per_training: f64,
    /// Trainings in the run's log.
    pub trainings: u64,
    /// Projected hours at `epochs_per_training`.
    pub hours: Option<f64>,
    /// How `hours` is computed.
    pub note: &'static str,
}

/// One entry of [`Projection::capped`].
#[derive(Debug, Clone, Serialize)]
pub struct CappedProjection {
    /// The cap.
    pub max_epochs: usize,
    /// Projected hours with every training capped at it.
    pub hours: Option<f64>,
}

impl Projection {
    /// The projections of a run of `steps` env steps (warm-up `init_random_steps` left out)
    /// from `points` measured on `run`.
    pub fn of(points: &[BreakdownPoint], run: &Path, init_random_steps: u64, steps: u64) -> Self {
        let hours = |s: Option<f64>| s.map(|s| s / 3600.0);
        // The windows' few trainings say little about the early-stopping rule's epoch count;
        // the run's whole log says more.
        let at_logged_epochs =
            logged_epochs_per_training(run).map(|(epochs, trainings)| LoggedEpochs {
                epochs_per_training: epochs,
                trainings,
                hours: hours(projected_seconds_at_epochs(
                    points,
                    init_random_steps,
                    steps,
                    epochs,
                )),
                note: "each point's model training scaled to the run's mean epochs per training \
                       over its logs/train.log",
            });
        Self {
            env_steps: steps,
            hours: hours(projected_seconds(points, init_random_steps, steps)),
            note: "per-step cost piecewise linear in env steps between the points (null with \
                   fewer than two), warm-up left out",
            at_logged_epochs,
            capped: EPOCH_CAPS
                .iter()
                .map(|&cap| CappedProjection {
                    max_epochs: cap,
                    hours: hours(projected_seconds_capped(
                        points,
                        init_random_steps,
                        steps,
                        cap,
                    )),
                })
                .collect(),
            capped_note: "the same trainings cut at model.max_epochs (a result-changing \
                          option): model-training time scaled by the epochs left; the holdout \
                          cost is in each point's epoch_caps",
        }
    }

    /// Terminal lines: the projection, at the run's own epochs, with each cap.
    pub fn lines(&self) -> Vec<String> {
        let mut lines = vec![match self.hours {
            Some(h) => format!("projected: {h:.2} h for {} env steps", self.env_steps),
            None => "no projection: it needs points at two or more steps".into(),
        }];
        if let Some(LoggedEpochs {
            epochs_per_training,
            trainings,
            hours: Some(h),
            ..
        }) = &self.at_logged_epochs
        {
            lines.push(format!(
                "  at the run's own {epochs_per_training:.1} epochs per training ({trainings} \
                 trainings in its logs/train.log): {h:.2} h"
            ));
        }
        for c in &self.capped {
            if let Some(h) = c.hours {
                lines.push(format!(
                    "  the same trainings capped at model.max_epochs = {}: {h:.2} h",
                    c.max_epochs
                ));
            }
        }
        lines
    }
}

impl BreakdownPoint {
    /// One terminal line of the point's milliseconds per env step by phase.
    pub fn summary_line(&self) -> String {
        let m = &self.ms_per_step;
        format!(
            "at {:>6}: {:7.1} ms/step = model training {:6.1} ({:4.1} epochs x {:.2} s, {:.2} \
             ms/minibatch, holdout {:4.1}) + rollouts {:5.1} (k = {}) + SAC {:5.1} ({:.2} \
             ms/update) + acting {:4.2} + other {:4.2}",
            self.at,
            m.total,
            m.model_training,
            m.epochs_per_training,
            m.seconds_per_epoch,
            m.ms_per_model_step,
            m.model_holdout,
            m.rollouts,
            self.rollout_length,
            m.sac,
            m.ms_per_sac_update,
            m.acting,
            m.other
        )
    }

    /// One terminal line of the window's trainings and what each epoch cap would do to them.
    pub fn epoch_caps_line(&self) -> String {
        let caps: Vec<String> = self
            .epoch_caps
            .iter()
            .map(|c| {
                format!(
                    "{}: {:.2} of the epochs, holdout x{:.3}",
                    c.cap, c.epochs_fraction, c.holdout_ratio
                )
            })
            .collect();
        format!(
            "at {:>6}: trainings ran {:?} epochs; model.max_epochs = {}",
            self.at,
            self.training_epochs,
            caps.join("; ")
        )
    }
}

/// [`projected_seconds`] with each point's model-training time multiplied by `scale(point)`
/// (`None` from any point: no projection).
fn projected_with_model_scaled(
    points: &[BreakdownPoint],
    init_random_steps: u64,
    steps: u64,
    scale: impl Fn(&BreakdownPoint) -> Option<f64>,
) -> Option<f64> {
    let mut per_step = Vec::new();
    for p in points {
        let m = &p.ms_per_step;
        let model = m.model_training * scale(p)?;
        per_step.push((p.at, (m.total - m.model_training + model) / 1e3));
    }
    project(per_step, init_random_steps, steps)
}

/// Seconds over `init_random_steps..steps` of a per-step cost given at points `(N, s/step)`.
fn project(points: Vec<(u64, f64)>, init_random_steps: u64, steps: u64) -> Option<f64> {
    let mut pts: Vec<(f64, f64)> = points.iter().map(|&(n, s)| (n as f64, s)).collect();
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
        BreakdownPoint::new(at, 1, ms_total, phases, (&[], 5, 0.01))
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
    fn a_capped_projection_scales_model_training_by_the_epochs_left() {
        // 1 and 3 ms/step at 10k and 30k, of which model training 0.5 and 2 ms; capped at 10
        // epochs the trainings would run half their epochs: 0.75 and 2 ms/step, 27.5 s.
        let capped = |at, total, model, fraction| {
            let mut p = point(at, total);
            p.ms_per_step.model_training = model;
            p.epoch_caps = vec![EpochCap {
                cap: 10,
                epochs_fraction: fraction,
                holdout_ratio: 1.1,
            }];
            p
        };
        let pts = [capped(10_000, 1.0, 0.5, 0.5), capped(30_000, 3.0, 2.0, 0.5)];
        let s = projected_seconds_capped(&pts, 10_000, 30_000, 10).unwrap();
        assert!((s - 27.5).abs() < 1e-9, "{s}");
        assert_eq!(projected_seconds_capped(&pts, 10_000, 30_000, 20), None);
    }

    #[test]
    fn a_runs_epochs_per_training_are_summed_over_its_log() {
        let run = std::env::temp_dir().join(format!("mbpo-logged-epochs-{}", std::process::id()));
        std::fs::create_dir_all(run.join("logs")).unwrap();
        assert_eq!(logged_epochs_per_training(&run), None, "no log");
        let window = |trainings, epochs| PhaseTimes {
            steps: 1000,
            model_trainings: trainings,
            model_epochs: epochs,
            ..Default::default()
        };
        let log = format!(
            "INFO a: {}\nINFO seed 0: step 2000 eval 10.0\nINFO b: {}\n",
            window(1, 160).per_step_line(),
            window(4, 80).per_step_line()
        );
        std::fs::write(run.join("logs").join("train.log"), log).unwrap();
        assert_eq!(logged_epochs_per_training(&run), Some((48.0, 5)));
        std::fs::remove_dir_all(&run).unwrap();
    }

    #[test]
    fn a_projection_at_other_epochs_scales_model_training_by_their_ratio() {
        // The same points at 20 epochs per training where the windows ran 10: model training
        // doubles, 2 and 5 ms/step at 10k and 30k, 70 s.
        let at = |n, total, model| {
            let mut p = point(n, total);
            p.ms_per_step.model_training = model;
            p.ms_per_step.epochs_per_training = 10.0;
            p
        };
        let pts = [at(10_000, 1.0, 1.0), at(30_000, 3.0, 2.0)];
        let s = projected_seconds_at_epochs(&pts, 10_000, 30_000, 20.0).unwrap();
        assert!((s - 70.0).abs() < 1e-9, "{s}");
        let mut none = pts.clone();
        none[0].ms_per_step.epochs_per_training = 0.0;
        assert_eq!(
            projected_seconds_at_epochs(&none, 10_000, 30_000, 20.0),
            None
        );
    }

    #[test]
    fn a_projection_serialises_and_prints_each_way_it_was_computed() {
        let pts = [point(10_000, 1.0), point(30_000, 3.0)];
        let none = Projection::of(&pts, Path::new("/nonexistent-run"), 10_000, 30_000);
        assert_eq!(
            none.hours,
            projected_seconds(&pts, 10_000, 30_000).map(|s| s / 3600.0)
        );
        assert!(none.at_logged_epochs.is_none(), "no log, no figure");
        // The windows held no trainings: a cap cuts nothing.
        assert_eq!(none.capped.len(), EPOCH_CAPS.len());
        assert!(
            none.capped.iter().all(|c| c.hours == none.hours),
            "{none:?}"
        );
        let lines = none.lines();
        assert_eq!(lines[0], "projected: 0.01 h for 30000 env steps");
        assert_eq!(lines.len(), 1 + EPOCH_CAPS.len());
        assert!(
            lines[1].contains("capped at model.max_epochs = 5: 0.01 h"),
            "{lines:?}"
        );
        let json = serde_json::to_value(&none).unwrap();
        for key in [
            "env_steps",
            "hours",
            "note",
            "at_logged_epochs",
            "capped",
            "capped_note",
        ] {
            assert!(json.get(key).is_some(), "{key} in {json}");
        }
    }

    fn report(
        holdout_mse: Vec<Vec<f32>>,
        final_holdout_mse: Vec<f32>,
        elite: usize,
    ) -> TrainReport {
        TrainReport {
            n_train: 100,
            n_holdout: 20,
            epochs: holdout_mse.len(),
            gradient_steps: 0,
            train_loss: vec![],
            holdout_mse,
            best_epoch: vec![],
            final_holdout_mse,
            elites: vec![elite],
            stop: mbpo_model::StopReason::NoImprovement,
            seconds: 0.0,
            holdout_seconds: 0.0,
            termination: None,
        }
    }

    #[test]
    fn epoch_caps_count_the_epochs_saved_and_the_holdout_lost() {
        // Member 0 improves 50 %, 10 %, then 0.2 % (under the 1 % threshold: restored at
        // epoch 2, 0.45); member 1 ends at 0.9. One elite: member 0, 0.45. Capped after two
        // epochs member 0 has 0.5 and is still the elite.
        let four = report(
            vec![
                vec![1.0, 2.0],
                vec![0.5, 2.0],
                vec![0.45, 1.0],
                vec![0.449, 0.9],
            ],
            vec![0.45, 0.9],
            0,
        );
        // A one-epoch training no cap shortens.
        let one = report(vec![vec![0.3, 0.2]], vec![0.3, 0.2], 1);
        let two = EpochCap::of(2, &[four.clone(), one.clone()], 1, 0.01);
        assert_eq!(two.epochs_fraction, 3.0 / 5.0);
        let lost = (0.5f32 as f64 / 0.45f32 as f64 + 1.0) / 2.0;
        assert!((two.holdout_ratio - lost).abs() < 1e-12, "{two:?}");
        let none = EpochCap::of(5, &[four, one], 1, 0.01);
        assert_eq!((none.epochs_fraction, none.holdout_ratio), (1.0, 1.0));
    }

    #[test]
    fn per_step_figures_divide_by_steps_trainings_and_updates() {
        let phases = PhaseTimes {
            steps: 500,
            model_trainings: 2,
            model_epochs: 30,
            model_gradient_steps: 2800,
            model_train_seconds: 15.0,
            model_holdout_seconds: 1.0,
            rollout_seconds: 2.0,
            imagined: 100,
            sac_seconds: 20.0,
            sac_updates: 10_000,
            act_seconds: 0.5,
        };
        let p = BreakdownPoint::new(10_000, 3, 40.0, phases, (&[], 5, 0.01));
        let m = p.ms_per_step;
        assert_eq!(m.model_training, 30.0);
        assert_eq!(m.model_holdout, 2.0);
        assert_eq!(m.epochs_per_training, 15.0);
        assert_eq!(m.seconds_per_epoch, 0.5);
        // 14 s of minibatches (15 less the holdout's 1) over 2800 Adam steps.
        assert!((m.ms_per_model_step - 5.0).abs() < 1e-12);
        assert_eq!(m.rollouts, 4.0);
        assert_eq!(m.sac, 40.0);
        assert_eq!(m.ms_per_sac_update, 2.0);
        assert_eq!(m.acting, 1.0);
        assert_eq!(m.total, 80.0);
        assert!((m.other - 5.0).abs() < 1e-9);
    }
}
