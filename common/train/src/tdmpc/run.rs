//! A TD-MPC2 run under the shared single-process driver: each env step acts and learns, eval
//! points evaluate the planner, checkpoints hold every part's state so a resumed run plans and
//! learns exactly as an uninterrupted one.

use std::path::Path;
use std::time::Instant;

use mbpo_core::TransitionSink;
use mbpo_model::EpochProgress;

use super::roles::{TdmpcActor, TdmpcEvaluator, WorldModelLearner};
use crate::actor::Behaviour;
use crate::checkpoint::{self, CheckpointError};
use crate::config::ExperimentConfig;
use crate::driver::{drive, SequentialRun};
use crate::error::TrainError;
use crate::run_control::RunOptions;
use crate::run_dir::{MetricsRow, RunDir, Summary};
use crate::run_files::{
    actor_file, check_one_actor_cut, file, kind, LatentActorCheckpoint, LatentEvaluatorCheckpoint,
    RunBook, WorldModelLearnerCheckpoint,
};
use crate::schedule::Schedule;

/// Run TD-MPC2 per `cfg` into the run directory `out`; returns the summary.
pub fn train_tdmpc(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    train_tdmpc_with(cfg, out, RunOptions::default())
}

/// [`train_tdmpc`] with resume and stop control: checkpoints every `checkpoint.every` env
/// steps, at the end and when stopped. `summary.json`'s `policy_sha256` is the SHA-256 of the
/// final parameters, `sac_updates` the world model's updates and `median_seconds_per_env_step`
/// the median wall time of a step after the seed steps (plan and update).
pub fn train_tdmpc_with(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    let env = cfg.make_env()?;
    let mut run = TdmpcRun {
        cfg,
        out,
        schedule: Schedule::of(cfg),
        learner: WorldModelLearner::new(cfg, env.as_ref()),
        actor: TdmpcActor::new(cfg, 0)?,
        evaluator: TdmpcEvaluator::new(cfg)?,
        book: RunBook::start(),
        started: Instant::now(),
    };
    run.hand_out_params(0);
    drive(&mut run, cfg, out, opts)
}

/// Every part of one run, its book and its clock.
struct TdmpcRun<'a> {
    cfg: &'a ExperimentConfig,
    out: &'a Path,
    schedule: Schedule,
    learner: WorldModelLearner,
    actor: TdmpcActor,
    evaluator: TdmpcEvaluator,
    book: RunBook,
    started: Instant,
}

impl TdmpcRun<'_> {
    /// Give the planners the learner's parameters after env step `version`.
    fn hand_out_params(&mut self, version: u64) {
        let params = self.learner.params();
        self.actor.planner().set_params(params, version);
        self.evaluator.planner().set_params(params, version);
    }

    /// Write the checkpoint after env step `t` into `dir`: the files of a one-actor TD-MPC
    /// pipeline ([`crate::run_files`]), so `mbpo run --resume` continues it too.
    fn write_checkpoint(&self, dir: &Path, t: u64) -> Result<(), CheckpointError> {
        std::fs::create_dir_all(dir).map_err(|source| CheckpointError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let learner = WorldModelLearnerCheckpoint::of(&self.learner, t);
        let actor = LatentActorCheckpoint {
            role: self.actor.checkpoint(),
            steps: t,
        };
        let evaluator = LatentEvaluatorCheckpoint {
            role: self.evaluator.checkpoint(),
            version: t,
            evals: self.schedule.eval_points_upto(t),
            env_steps: t,
        };
        checkpoint::write(
            &dir.join(file::LEARNER),
            kind::WORLD_MODEL_LEARNER,
            &learner,
        )?;
        checkpoint::write(&dir.join(actor_file(0)), kind::LATENT_ACTOR, &actor)?;
        checkpoint::write(
            &dir.join(file::EVALUATOR),
            kind::LATENT_EVALUATOR,
            &evaluator,
        )?;
        checkpoint::write(&dir.join(file::RUN_BOOK), kind::RUN_BOOK, &self.book)?;
        let files = [
            file::LEARNER.to_string(),
            file::EVALUATOR.into(),
            actor_file(0),
            file::RUN_BOOK.into(),
        ];
        let names: Vec<&str> = files.iter().map(String::as_str).collect();
        checkpoint::mark_complete(dir, t, &names)
    }
}

impl SequentialRun for TdmpcRun<'_> {
    const COUNTING: Option<&'static str> = Some("updates");

    /// Continue from the checkpoint in `dir` (after `t` env steps), written by this trainer or
    /// by a one-actor `mbpo run`; the planners get the learner's parameters.
    fn restore(&mut self, dir: &Path, t: u64) -> Result<(), TrainError> {
        let learner: WorldModelLearnerCheckpoint =
            checkpoint::read(&dir.join(file::LEARNER), kind::WORLD_MODEL_LEARNER)?;
        let actor: LatentActorCheckpoint =
            checkpoint::read(&dir.join(actor_file(0)), kind::LATENT_ACTOR)?;
        let evaluator: LatentEvaluatorCheckpoint =
            checkpoint::read(&dir.join(file::EVALUATOR), kind::LATENT_EVALUATOR)?;
        let k = self.schedule.train_points_upto(t);
        let steps = [("learner", learner.consumed), ("actor", actor.steps)];
        check_one_actor_cut(dir, &self.schedule, t, k, &steps, &[])?;
        self.book = checkpoint::read(&dir.join(file::RUN_BOOK), kind::RUN_BOOK)?;
        learner.restore_into(&mut self.learner)?;
        self.actor.restore(actor.role)?;
        self.evaluator.restore(evaluator.role);
        self.hand_out_params(t);
        Ok(())
    }

    /// The clock continues from the checkpoint's.
    fn begin(&mut self) {
        self.started = self.book.clock();
    }

    fn step(
        &mut self,
        t: u64,
        _stop: &mut dyn FnMut(&EpochProgress) -> bool,
    ) -> Result<bool, TrainError> {
        let start = Instant::now();
        let behaviour = match self.schedule.is_warm_up(t) {
            true => Behaviour::Uniform,
            false => Behaviour::Policy,
        };
        let episodes = self.actor.env_actor().episodes;
        let row = self.actor.act(behaviour)?;
        let (obs, act, next) = (&row.obs, &row.act, &row.next_obs);
        let terminated = row.terminated[0] > 0.5;
        self.learner.push(obs, act, row.reward[0], next, terminated);
        let updates = self.schedule.updates_at(t);
        if updates > 0 {
            self.learner.update(updates)?;
            self.hand_out_params(t);
        }
        self.book.note_episode_end(self.actor.env_actor(), episodes);
        if t > self.schedule.init_random_steps {
            self.book.step_seconds.push(start.elapsed().as_secs_f64());
        }
        Ok(true)
    }

    fn evaluate(&mut self, t: u64) -> Result<MetricsRow, TrainError> {
        let ret = self.evaluator.evaluate(self.cfg.eval.episodes)?;
        let now = self.started.elapsed().as_secs_f64();
        let (last_time, last_steps) = self.book.last_row;
        let updates = self.learner.updates();
        let span = (now - last_time).max(1e-9);
        let actor = self.actor.env_actor();
        let losses = self.learner.reported_losses();
        let cell = |v: f32| v.is_finite().then_some(v as f64);
        let row = MetricsRow {
            env_steps: t,
            episodes: actor.episodes,
            eval_return: ret,
            train_return: actor.last_return,
            sac_updates: updates,
            critic_loss: cell(losses.value),
            actor_loss: cell(losses.policy),
            consistency_loss: cell(losses.consistency),
            reward_loss: cell(losses.reward),
            wall_seconds: now,
            env_steps_per_sec: (t - last_steps) as f64 / span,
            updates_per_sec: (updates - self.book.last_row_updates) as f64 / span,
            ..Default::default()
        };
        self.book.wrote_row(t, ret, now, updates);
        tracing::info!(
            "tdmpc {} seed {}: step {t} eval {ret:.1} best {:.1} train episode {:.1} \
             updates {updates} losses {losses:?}",
            self.cfg.env,
            self.cfg.seed,
            self.book.best_return,
            row.train_return.unwrap_or(f64::NAN),
        );
        Ok(row)
    }

    fn progress(&self) -> (u64, Option<u64>) {
        (self.learner.updates(), None)
    }

    fn save(&mut self, t: u64, _wait: bool) -> Result<(), TrainError> {
        self.book.elapsed_seconds = self.started.elapsed().as_secs_f64();
        self.book.progress = (t, self.learner.updates(), 0);
        self.write_checkpoint(&checkpoint::dir_for(self.out, t), t)?;
        let keep = &self.cfg.checkpoint;
        Ok(checkpoint::prune(self.out, keep.keep, keep.keep_every)?)
    }

    fn finish(&mut self, status: &str, run: &mut RunDir) -> Result<Summary, TrainError> {
        if let Some((plans, fewest, mean, most)) = self.actor.planner().iterations_per_plan() {
            tracing::info!(
                "the actor planned {plans} times: iterations per plan {fewest}..{most} (mean {mean:.2})"
            );
        }
        let actor = self.actor.env_actor();
        let learned = (self.learner.updates(), self.learner.params());
        self.book
            .one_actor_summary(self.cfg, actor, learned, self.started, status, run)
    }
}
