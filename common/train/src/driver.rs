//! The one loop of a single-process run (`mbpo train`), which SAC, MBPO and MPC share: open
//! the run directory (fresh or from its newest checkpoint), then per env step t take the step,
//! write the metrics row of an eval point, show progress, checkpoint when due, stop when asked
//! or when solved (`eval.stop_when_solved`);
//! at the end, the summary. What differs between the algorithms -- the step, the row, the
//! checkpoint files, the summary's fields -- is a [`SequentialRun`].
//!
//! Order matters: every algorithm draws its random numbers in the order of its steps, evals
//! and checkpoints (a checkpoint draws none, but it must hold the state after exactly step t),
//! and the pipeline in lockstep equals this order bit for bit.

use std::path::Path;

use crate::config::ExperimentConfig;
use crate::error::TrainError;
use crate::progress::{training_note, Display, Progress};
use crate::run_control::{
    checkpoint_due, log_solved, log_stopped, open_run, solved_rule, stop_before, RunOptions, SOLVED,
};
use crate::run_dir::{MetricsRow, RunDir, Summary};
use crate::schedule::Schedule;
use mbpo_model::EpochProgress;

/// One algorithm's run in one process, as [`drive`] calls it.
pub(crate) trait SequentialRun {
    /// What the progress line counts besides env steps, when not SAC updates.
    const COUNTING: Option<&'static str> = None;

    /// Continue from the checkpoint in `dir` after `t` env steps.
    fn restore(&mut self, dir: &Path, t: u64) -> Result<(), TrainError>;
    /// Once the run directory is open (fresh or resumed): start the clock.
    fn begin(&mut self) {}
    /// Env step `t` and the learning that goes with it. A model training shows `stop` where
    /// it stands after each epoch; `Ok(false)`: `stop` said stop, and the step was undone (the
    /// state is that after step t − 1).
    fn step(
        &mut self,
        t: u64,
        stop: &mut dyn FnMut(&EpochProgress) -> bool,
    ) -> Result<bool, TrainError>;
    /// The metrics row of eval point `t` (evaluating the current policy or planner).
    fn evaluate(&mut self, t: u64) -> Result<MetricsRow, TrainError>;
    /// The progress line's counter (SAC updates, plans) and the model version it shows.
    fn progress(&self) -> (u64, Option<u64>);
    /// Write the checkpoint after env step `t`; `wait`: return only once it is on disk.
    fn save(&mut self, t: u64, wait: bool) -> Result<(), TrainError>;
    /// The summary with `status`, and (completed) the final policy file.
    fn finish(&mut self, status: &str, run: &mut RunDir) -> Result<Summary, TrainError>;
}

/// Run `algo` per `cfg` into the run directory `out`, from its start or (`opts.resume`) its
/// newest checkpoint; returns the summary (also written to `summary.json`).
pub(crate) fn drive<R: SequentialRun>(
    algo: &mut R,
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    let (mut run, done) = open_run(cfg, out, opts, |dir, t| algo.restore(dir, t))?;
    algo.begin();
    let schedule = Schedule::of(cfg);
    // A Python env's own name where its config gives one (`gym:dmc_env:make` makes many tasks).
    let env = cfg.gym.name.as_deref().unwrap_or(&cfg.env);
    let label = format!("{} {env} s{}", cfg.algo.name(), cfg.seed);
    let mut progress = Progress::new(label, cfg.steps, Display::auto());
    if let Some(what) = R::COUNTING {
        progress = progress.counting(what);
    }
    let mut status = "completed";
    let mut solved = solved_rule(cfg, out, opts.resume);
    for t in done + 1..=cfg.steps {
        let (_, model_version) = algo.progress();
        let training = model_version.unwrap_or(0) + 1;
        let mut watch = |e: &EpochProgress| {
            progress.hold_up(training_note(training, e.epoch, e.holdout_mse, e.seconds));
            opts.stopping_at(t, cfg.steps)
        };
        let stepped = algo.step(t, &mut watch)?;
        progress.set_activity(None);
        if !stepped {
            stop_before(t, |at| algo.save(at, true), out)?;
            status = "stopped";
            break;
        }
        let mut solved_now = false;
        if schedule.is_eval_point(t) {
            let row = algo.evaluate(t)?;
            run.write_metrics(&row)?;
            progress.set_eval(row.eval_return);
            solved_now = solved.as_mut().is_some_and(|s| s.see(row.eval_return));
        }
        let (counter, model_version) = algo.progress();
        if let Some(v) = model_version {
            progress.set_model_version(v);
        }
        progress.update(t, counter);
        let solved_now = solved_now && t < cfg.steps;
        let stopping = opts.stopping_at(t, cfg.steps) || solved_now;
        if checkpoint_due(cfg, t, stopping) {
            algo.save(t, stopping || t == cfg.steps)?;
        }
        if let (true, Some(rule)) = (solved_now, &solved) {
            log_solved(rule, t, out);
            status = SOLVED;
            break;
        }
        if stopping {
            log_stopped(t, out);
            status = "stopped";
            break;
        }
    }
    progress.finish();
    let summary = algo.finish(status, &mut run)?;
    run.write_summary(&summary)?;
    Ok(summary)
}
