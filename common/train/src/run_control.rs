//! How a single-process run starts (fresh, or from its newest checkpoint) and when it
//! checkpoints and stops: the scaffolding the SAC, MBPO and MPC trainers share, so all three
//! resume, checkpoint and stop by the same rules.

use crate::checkpoint;
use crate::config::ExperimentConfig;
use crate::error::TrainError;
use crate::run_dir::RunDir;
use mbpo_config::SolvedRule;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// How a single-process run starts and when it stops early.
#[derive(Debug, Default, Clone, Copy)]
pub struct RunOptions<'a> {
    /// Continue from the newest complete checkpoint in the run directory.
    pub resume: bool,
    /// Checked after every env step and every epoch of a model training (which is then
    /// undone): when set, checkpoint and return (status `stopped`).
    pub stop: Option<&'a AtomicBool>,
}

impl RunOptions<'_> {
    /// Whether the run stops after env step `t` of `steps`: a stop was requested and steps
    /// are left (after the last step the run ends as `completed` anyway).
    /// (Also checked inside the model training of step `t`.)
    pub(crate) fn stopping_at(&self, t: u64, steps: u64) -> bool {
        t < steps && self.stop.is_some_and(|s| s.load(Ordering::Relaxed))
    }
}

/// The newest complete checkpoint of `out`, or an error saying there is none.
pub fn latest_checkpoint(out: &Path) -> Result<(PathBuf, checkpoint::Manifest), TrainError> {
    checkpoint::latest(out)?.ok_or_else(|| {
        TrainError::Config(format!(
            "{} has no complete checkpoint to resume from (looked in {})",
            out.display(),
            checkpoint::root(out).display()
        ))
    })
}

/// Open the run directory `out` of a run of `cfg`, returning it and the env steps already
/// done: a fresh directory, or (with `opts.resume`) the newest checkpoint handed to `restore`
/// (its directory and env steps) and the directory reopened after the checkpoint's step.
///
/// A checkpoint after more steps than the run has is refused before anything is read: the
/// run would end at once with a summary that claims `steps` it never stopped at.
pub(crate) fn open_run(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
    restore: impl FnOnce(&Path, u64) -> Result<(), TrainError>,
) -> Result<(RunDir, u64), TrainError> {
    if !opts.resume {
        return Ok((RunDir::create(out, cfg)?, 0));
    }
    let (dir, manifest) = latest_checkpoint(out)?;
    let done = manifest.env_steps;
    if done > cfg.steps {
        return Err(TrainError::Config(format!(
            "the checkpoint is after step {done}, past the run's {} steps; \
             give --steps N with N >= {done}",
            cfg.steps
        )));
    }
    restore(&dir, done)?;
    tracing::info!(
        "resuming {} from its checkpoint after {done} env steps",
        out.display()
    );
    Ok((RunDir::reopen_with_config(out, cfg, done)?, done))
}

/// The solved rule (`eval.stop_when_solved`) of a run of `cfg` in `out`. Off when the run
/// resumes after it was solved: extending a solved run (`--resume RUN --steps N`) asks for
/// the steps, not for the same stop again.
pub fn solved_rule(cfg: &ExperimentConfig, out: &Path, resume: bool) -> Option<SolvedRule> {
    let summary = std::fs::read_to_string(out.join("summary.json")).unwrap_or_default();
    let status = serde_json::from_str::<serde_json::Value>(&summary)
        .ok()
        .and_then(|s| s.get("status")?.as_str().map(str::to_string));
    let was_solved = resume && status.as_deref() == Some(SOLVED);
    SolvedRule::of(cfg).filter(|_| !was_solved)
}

/// A run's status when `eval.stop_when_solved` ended it: checkpointed, as after a stop, and as
/// good as complete (rerunning its command does nothing).
pub const SOLVED: &str = "solved";

/// Log a run ended by its solved rule at eval point `t`, and how to run it on.
pub(crate) fn log_solved(rule: &SolvedRule, t: u64, out: &Path) {
    tracing::info!(
        "solved at env step {t} ({}): stopped with a checkpoint; run on with --resume {} --steps N",
        rule.describe(),
        out.display()
    );
}

/// Whether env step `t` ends with a checkpoint: every `checkpoint.every` steps, after the last
/// step, and when the run is stopping.
pub(crate) fn checkpoint_due(cfg: &ExperimentConfig, t: u64, stopping: bool) -> bool {
    let every = cfg.checkpoint.every;
    t == cfg.steps || stopping || (every > 0 && t.is_multiple_of(every))
}

/// Stop a run whose step `t` was abandoned part-way (its model training undone): checkpoint
/// the state after step t − 1 with `save` and log the stop. (When t − 1 is the checkpoint the
/// run resumed from, the same files are written again.)
pub(crate) fn stop_before(
    t: u64,
    save: impl FnOnce(u64) -> Result<(), TrainError>,
    out: &Path,
) -> Result<(), TrainError> {
    let done = t - 1;
    if done > 0 {
        save(done)?;
    }
    log_stopped(done, out);
    Ok(())
}

/// Log a clean stop after env step `t` and how to continue.
pub(crate) fn log_stopped(t: u64, out: &Path) {
    tracing::info!(
        "stopped after {t} env steps; continue with --resume {}",
        out.display()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_request_stops_every_step_but_the_last() {
        let flag = AtomicBool::new(false);
        let opts = RunOptions {
            stop: Some(&flag),
            ..Default::default()
        };
        assert!(!opts.stopping_at(5, 10));
        flag.store(true, Ordering::Relaxed);
        assert!(opts.stopping_at(5, 10));
        assert!(!opts.stopping_at(10, 10));
        assert!(!RunOptions::default().stopping_at(5, 10));
    }

    #[test]
    fn checkpoints_fall_every_n_steps_at_the_end_and_on_stop() {
        let mut cfg = ExperimentConfig {
            steps: 25,
            ..Default::default()
        };
        cfg.checkpoint.every = 10;
        let due: Vec<u64> = (1..=25)
            .filter(|&t| checkpoint_due(&cfg, t, false))
            .collect();
        assert_eq!(due, [10, 20, 25]);
        assert!(checkpoint_due(&cfg, 7, true));
        cfg.checkpoint.every = 0;
        let due: Vec<u64> = (1..=25)
            .filter(|&t| checkpoint_due(&cfg, t, false))
            .collect();
        assert_eq!(due, [25]);
    }

    #[test]
    fn resuming_past_the_runs_steps_is_refused_before_restoring() {
        let out = std::env::temp_dir().join(format!("run-control-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let dir = checkpoint::dir_for(&out, 300);
        std::fs::create_dir_all(&dir).unwrap();
        checkpoint::mark_complete(&dir, 300, &[]).unwrap();
        let cfg = ExperimentConfig {
            steps: 200,
            ..Default::default()
        };
        let resume = RunOptions {
            resume: true,
            ..Default::default()
        };
        let err = open_run(&cfg, &out, resume, |_, _| panic!("restored"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("after step 300, past the run's 200 steps"),
            "{err}"
        );
        assert!(err.contains("--steps N with N >= 300"), "{err}");
        std::fs::remove_dir_all(&out).unwrap();
    }
}
