//! Deterministic evaluation episodes.

use crate::actor::EnvActor;
use crate::config::ExperimentConfig;
use crate::run_dir::{policy_sha256, MetricsRow, Summary};
use crate::run_files::RunBook;
use mbpo_core::rng::stream;
use mbpo_core::{BatchPolicy, Rng};
use mbpo_envs::{Env, EnvError};
use mbpo_sac::{ActorPolicy, Sac, SacStats};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Mean undiscounted return of `episodes` episodes with `policy` (deterministic: tanh μ(s));
/// start states come from `rng` (the evaluation stream, separate from training's).
///
/// An episode whose environment process exits (a Python env) is played again once in a new
/// process; a second exit in a row fails the evaluation.
pub fn evaluate(
    policy: &mut dyn BatchPolicy,
    env: &mut dyn Env,
    episodes: usize,
    rng: &mut Rng,
) -> Result<f64, EnvError> {
    crate::episodes::mean_return(
        env,
        episodes,
        rng,
        policy,
        |_| {},
        |policy, rng, obs, action| {
            policy.act_batch(obs, 1, action, rng);
            Ok::<(), EnvError>(())
        },
    )
}

/// Periodic evaluation and the bookkeeping around it (best return, rates).
pub struct Evaluator {
    env: Box<dyn Env>,
    rng: Rng,
    episodes: usize,
    env_id: String,
    seed: u64,
    start: Instant,
    last_time: f64,
    last_steps: u64,
    last_updates: u64,
    env_steps: u64,
    final_return: f64,
    best_return: f64,
}

/// What a checkpoint keeps of an [`Evaluator`]: its stream and the run's bookkeeping.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvaluatorState {
    /// The `eval.env` stream.
    pub rng: Rng,
    /// Wall seconds of the run so far (the clock continues from here).
    pub elapsed_seconds: f64,
    /// Wall seconds at the last evaluation.
    pub last_time: f64,
    /// Env steps at the last evaluation.
    pub last_steps: u64,
    /// Last evaluation return.
    pub final_return: f64,
    /// Best evaluation return.
    pub best_return: f64,
}

impl Evaluator {
    /// The evaluator's state (for checkpoints).
    pub fn checkpoint(&self) -> EvaluatorState {
        EvaluatorState {
            rng: self.rng.clone(),
            elapsed_seconds: self.start.elapsed().as_secs_f64(),
            last_time: self.last_time,
            last_steps: self.last_steps,
            final_return: self.final_return,
            best_return: self.best_return,
        }
    }

    /// Continue from [`Evaluator::checkpoint`]; the wall clock continues from its time.
    pub fn restore(&mut self, s: EvaluatorState) {
        self.rng = s.rng;
        self.start = crate::run_files::started_ago(s.elapsed_seconds);
        self.last_time = s.last_time;
        self.last_steps = s.last_steps;
        self.env_steps = s.last_steps;
        self.final_return = s.final_return;
        self.best_return = s.best_return;
    }

    /// The `eval.env` stream (the evaluator's checkpoint file keeps it).
    pub fn rng(&self) -> &Rng {
        &self.rng
    }

    /// Copy the bookkeeping the run book keeps of evaluations into `book`: the returns, where
    /// the next row's rates start, the clock.
    pub fn write_book(&self, book: &mut RunBook) {
        book.last_row = (self.last_time, self.last_steps);
        book.last_row_updates = self.last_updates;
        book.final_return = self.final_return;
        book.best_return = self.best_return;
        book.last_eval = (!self.final_return.is_nan()).then_some(self.final_return);
        book.elapsed_seconds = self.start.elapsed().as_secs_f64();
    }

    /// Continue from a checkpoint: its `eval.env` stream and run book (the wall clock
    /// continues from the book's time).
    pub fn restore_book(&mut self, rng: Rng, book: &RunBook) {
        self.rng = rng;
        self.start = book.clock();
        (self.last_time, self.last_steps) = book.last_row;
        self.env_steps = book.last_row.1;
        self.last_updates = book.last_row_updates;
        self.final_return = book.final_return;
        self.best_return = book.best_return;
    }

    /// An evaluator with its own environment and stream (`eval.env`).
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, EnvError> {
        Ok(Self {
            env: cfg.make_env()?,
            rng: stream(cfg.seed, "eval.env", 0),
            episodes: cfg.eval.episodes,
            env_id: cfg.env.clone(),
            seed: cfg.seed,
            start: Instant::now(),
            last_time: 0.0,
            last_steps: 0,
            last_updates: 0,
            env_steps: 0,
            final_return: f64::NAN,
            best_return: f64::NEG_INFINITY,
        })
    }

    /// Evaluate at `env_steps` and build the metrics row (SAC columns filled).
    pub fn evaluate(
        &mut self,
        env_steps: u64,
        sac: &Sac,
        stats: &SacStats,
        actor: &EnvActor,
    ) -> Result<MetricsRow, EnvError> {
        // Evaluation acts with a copy of the parameters, as the pipeline's evaluation actor does.
        let mut policy = ActorPolicy::new(sac.actor.clone(), sac.actor_params.clone(), true);
        let ret = evaluate(&mut policy, self.env.as_mut(), self.episodes, &mut self.rng)?;
        self.final_return = ret;
        self.best_return = self.best_return.max(ret);
        let now = self.start.elapsed().as_secs_f64();
        let dt = (now - self.last_time).max(1e-9);
        let sps = (env_steps - self.last_steps) as f64 / dt;
        let ups = (sac.updates() - self.last_updates) as f64 / dt;
        (self.last_time, self.last_steps, self.env_steps) = (now, env_steps, env_steps);
        self.last_updates = sac.updates();
        let updated = sac.updates() > 0;
        let some = |v: f32| updated.then_some(v as f64);
        Ok(MetricsRow {
            env_steps,
            episodes: actor.episodes,
            eval_return: ret,
            train_return: actor.last_return,
            sac_updates: sac.updates(),
            critic_loss: some(stats.critic_loss),
            actor_loss: some(stats.actor_loss),
            alpha: Some(sac.alpha() as f64),
            entropy: some(stats.entropy),
            q_mean: some(stats.q_mean),
            wall_seconds: now,
            env_steps_per_sec: sps,
            updates_per_sec: ups,
            ..Default::default()
        })
    }

    /// One progress line for a metrics row.
    pub fn log(&self, algo: &str, row: &MetricsRow) {
        tracing::info!(
            "{algo} {} seed {}: step {} eval {:.1} best {:.1} alpha {:.3} ({:.1} steps/s)",
            self.env_id,
            self.seed,
            row.env_steps,
            row.eval_return,
            self.best_return,
            row.alpha.unwrap_or(f64::NAN),
            row.env_steps_per_sec
        );
    }

    /// The run summary after the last evaluation; `target` is the task's target return and the
    /// first evaluation at it ([`crate::RunDir::env_steps_to_target`]).
    pub fn summary(
        &self,
        algo: &str,
        sac: &Sac,
        seconds_per_env_step: Option<f64>,
        target: (Option<f64>, Option<u64>),
    ) -> Summary {
        Summary {
            algo: algo.into(),
            env: self.env_id.clone(),
            seed: self.seed,
            env_steps: self.env_steps,
            sac_updates: sac.updates(),
            final_eval_return: self.final_return,
            best_eval_return: self.best_return,
            target_return: target.0,
            env_steps_to_target: target.1,
            policy_sha256: policy_sha256(&sac.actor_params),
            wall_seconds: self.start.elapsed().as_secs_f64(),
            median_seconds_per_env_step: seconds_per_env_step,
            status: "completed".into(),
            episodes_cut_by_resume: 0,
            episodes_lost_to_env_exit: 0,
        }
    }
}
