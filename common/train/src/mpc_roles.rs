//! The roles of model predictive control on the learned model: what a planning actor and the
//! planning evaluator run, in the pipeline's processes (`mbpo run`) and in the single-process
//! run ([`crate::mpc`]) alike.
//!
//! [`PlanningActorRole`] plans on the model trainer's newest model from the real observation
//! and executes the first action; [`PlanningEvaluator`] plays deterministic episodes with the
//! same planner. Random draws come from named streams: `actor.env` / `actor.policy`
//! (planning noise) of the actor, `eval.env` / `eval.plan` of the evaluator.

use crate::actor::{Behaviour, EnvActor, EnvActorState};
use crate::config::{ExperimentConfig, PlanReward};
use crate::error::TrainError;
use crate::roles::ModelSnapshot;
use mbpo_core::rng::stream;
use mbpo_core::{Batch, BatchPolicy, LastTransition, Rng, TransitionSink};
use mbpo_envs::Env;
use mbpo_model::ProbabilisticEnsemble;
use mbpo_plan::{build, EnsembleModel, Mpc, MpcState, PlanError, RewardSource};
use serde::{Deserialize, Serialize};
use std::time::Instant;

fn plan_err(e: PlanError) -> TrainError {
    TrainError::Config(format!("planning: {e}"))
}

/// A planning model of `cfg`'s architecture (weights arrive as snapshots) with the configured
/// reward source, the task's termination rule and action box.
pub fn planning_model(cfg: &ExperimentConfig, env: &dyn Env) -> Result<EnsembleModel, TrainError> {
    let (o, a) = (env.obs_dim(), env.act_dim());
    let ensemble = ProbabilisticEnsemble::new(
        o,
        a,
        cfg.model_config(),
        &mut stream(cfg.seed, "plan.model-shape", 0),
    )
    .map_err(|e| TrainError::Config(e.to_string()))?;
    let reward = match cfg.mpc.reward {
        PlanReward::Model => RewardSource::Model,
        PlanReward::Known => {
            RewardSource::Known(mbpo_envs::reward_fn(&cfg.env).ok_or_else(|| {
                TrainError::Config(format!("no known reward function for {}", cfg.env))
            })?)
        }
    };
    let space = env.action_space();
    EnsembleModel::new(
        ensemble,
        reward,
        Some(cfg.rollout_termination(o, a)?),
        &space.low,
        &space.high,
    )
    .map_err(plan_err)
}

/// The configured planner run as a controller (closed or open loop).
pub fn controller(cfg: &ExperimentConfig, act_dim: usize) -> Result<Mpc, TrainError> {
    let planner = build(&cfg.mpc.planner, act_dim).map_err(plan_err)?;
    Ok(Mpc::new(planner, cfg.mpc.open_loop))
}

/// MPC seen as a one-observation [`BatchPolicy`], so the shared [`EnvActor`] can act with it
/// (same streams, same transition bookkeeping as the SAC actors). A planning error is kept and
/// reported after the step.
struct MpcPolicy<'a> {
    mpc: &'a mut Mpc,
    model: &'a mut EnsembleModel,
    error: Option<PlanError>,
    seconds: f64,
}

impl BatchPolicy for MpcPolicy<'_> {
    fn act_batch(&mut self, obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng) {
        debug_assert_eq!(batch, 1, "MPC plans for one observation at a time");
        let start = Instant::now();
        if let Err(e) = self.mpc.act(self.model, obs, rng, actions) {
            self.error = Some(e);
            actions.fill(0.0);
        }
        self.seconds = start.elapsed().as_secs_f64();
    }
}

/// The ensemble a planner plans with, and the version of the weights it holds.
struct VersionedModel {
    model: EnsembleModel,
    version: u64,
}

impl VersionedModel {
    fn new(cfg: &ExperimentConfig, env: &dyn Env) -> Result<Self, TrainError> {
        Ok(Self {
            model: planning_model(cfg, env)?,
            version: 0,
        })
    }
    /// Take a newer model.
    fn set(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model
            .ensemble_mut()
            .load_weights(&snapshot.weights)
            .map_err(|e| TrainError::Config(e.to_string()))?;
        self.version = snapshot.version;
        Ok(())
    }
    fn load<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        load(self.model.ensemble_mut()).map_err(|e| TrainError::Config(e.to_string()))?;
        self.version = version;
        Ok(())
    }
}

/// A checkpointed [`PlanningActorRole`] (its model is the model trainer's current one).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanningActorState {
    /// The env actor (episode in progress, `actor.env` / `actor.policy` streams, counters).
    pub actor: EnvActorState,
    /// The controller's warm start and open-loop plan.
    pub mpc: MpcState,
}

/// Acting in the real environment with MPC on the newest model it was given.
pub struct PlanningActorRole {
    actor: EnvActor,
    mpc: Mpc,
    model: VersionedModel,
    staged: LastTransition,
    /// Wall seconds of the last plan (0 for a warm-up step).
    pub last_plan_seconds: f64,
}

impl PlanningActorRole {
    /// Planning actor `index` of the run (streams `actor.env` / `actor.policy`, index `index`).
    pub fn new(cfg: &ExperimentConfig, index: u64) -> Result<Self, TrainError> {
        let actor = EnvActor::new(cfg.make_env()?, cfg.seed, index)?;
        let env = cfg.make_env()?;
        Ok(Self {
            model: VersionedModel::new(cfg, env.as_ref())?,
            mpc: controller(cfg, env.act_dim())?,
            staged: LastTransition::new(env.obs_dim(), env.act_dim()),
            actor,
            last_plan_seconds: 0.0,
        })
    }
    /// Take a newer model.
    pub fn set_model(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model.set(snapshot)
    }
    /// Take model `version`, loaded in place by `load` (a receiver's one copy out of shared
    /// memory; `load` checks the snapshot before it writes anything).
    pub fn load_model<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        self.model.load(version, load)
    }
    /// Version of the model planned with (0: none yet).
    pub fn model_version(&self) -> u64 {
        self.model.version
    }
    /// The env actor (episode counters).
    pub fn env_actor(&self) -> &EnvActor {
        &self.actor
    }
    /// Plans made so far.
    pub fn plans(&self) -> u64 {
        self.mpc.plans()
    }
    /// Iterations per plan (fewest, mean, most) since the role was made.
    pub fn iterations_per_plan(&self) -> Option<(usize, f64, usize)> {
        self.mpc.iterations_per_plan()
    }
    /// The role's state (for checkpoints; the model is not in it).
    pub fn checkpoint(&self) -> PlanningActorState {
        PlanningActorState {
            actor: self.actor.checkpoint(),
            mpc: self.mpc.state(),
        }
    }
    /// Continue from [`PlanningActorRole::checkpoint`] (then give it the model with
    /// [`PlanningActorRole::set_model`]).
    pub fn restore(&mut self, s: PlanningActorState) -> Result<(), TrainError> {
        self.actor.restore(s.actor)?;
        self.mpc.restore(s.mpc).map_err(plan_err)
    }
    /// One real env step (uniform, or the planner's action); returns the transition. The
    /// planner's warm start is dropped at every episode end.
    pub fn act(&mut self, behaviour: Behaviour) -> Result<&Batch, TrainError> {
        let (actor, mpc, model) = (&mut self.actor, &mut self.mpc, &mut self.model);
        self.last_plan_seconds = plan_step(actor, mpc, model, behaviour, &mut self.staged)?;
        Ok(self.staged.batch())
    }
    /// One real env step whose transition goes straight into `sink` (a pipeline actor's
    /// loaned shared-memory sample). On an error `sink` may hold a partial row: drop it.
    pub fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn TransitionSink,
    ) -> Result<(), TrainError> {
        let (actor, mpc, model) = (&mut self.actor, &mut self.mpc, &mut self.model);
        self.last_plan_seconds = plan_step(actor, mpc, model, behaviour, sink)?;
        Ok(())
    }
}

/// One env step of a planning actor into `sink`; returns the plan's wall seconds (0 for a
/// warm-up step). A new episode starts with a reset planner.
fn plan_step(
    actor: &mut EnvActor,
    mpc: &mut Mpc,
    model: &mut VersionedModel,
    behaviour: Behaviour,
    sink: &mut dyn TransitionSink,
) -> Result<f64, TrainError> {
    let episodes = actor.episodes;
    let mut policy = MpcPolicy {
        mpc,
        model: &mut model.model,
        error: None,
        seconds: 0.0,
    };
    actor.step(behaviour, &mut policy, sink)?;
    let seconds = policy.seconds;
    if let Some(e) = policy.error {
        return Err(plan_err(e));
    }
    if actor.episodes > episodes {
        mpc.reset();
    }
    Ok(seconds)
}

/// A checkpointed [`PlanningEvaluator`]: its streams (each evaluation episode starts with a
/// reset planner, and the model is the trainer's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanningEvaluatorState {
    /// The `eval.env` stream.
    pub env_rng: Rng,
    /// The `eval.plan` stream.
    pub plan_rng: Rng,
}

/// Evaluation episodes with the planner: own environment (`eval.env`), own planning noise
/// (`eval.plan`), own copy of the model.
pub struct PlanningEvaluator {
    env: Box<dyn Env>,
    env_rng: Rng,
    plan_rng: Rng,
    mpc: Mpc,
    model: VersionedModel,
}

impl PlanningEvaluator {
    /// The evaluator of the run.
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, TrainError> {
        let env = cfg.make_env()?;
        Ok(Self {
            model: VersionedModel::new(cfg, env.as_ref())?,
            mpc: controller(cfg, env.act_dim())?,
            env,
            env_rng: stream(cfg.seed, "eval.env", 0),
            plan_rng: stream(cfg.seed, "eval.plan", 0),
        })
    }
    /// Take a newer model.
    pub fn set_model(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model.set(snapshot)
    }
    /// Take model `version`, loaded in place by `load` (a receiver's one copy out of shared
    /// memory; `load` checks the snapshot before it writes anything).
    pub fn load_model<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        self.model.load(version, load)
    }
    /// Version of the model evaluated.
    pub fn model_version(&self) -> u64 {
        self.model.version
    }
    /// The evaluator's state (for checkpoints).
    pub fn checkpoint(&self) -> PlanningEvaluatorState {
        PlanningEvaluatorState {
            env_rng: self.env_rng.clone(),
            plan_rng: self.plan_rng.clone(),
        }
    }
    /// Continue from [`PlanningEvaluator::checkpoint`].
    pub fn restore(&mut self, s: PlanningEvaluatorState) {
        self.env_rng = s.env_rng;
        self.plan_rng = s.plan_rng;
    }
    /// Mean undiscounted return of `episodes` MPC episodes (the warm start reset per episode).
    pub fn evaluate(&mut self, episodes: usize) -> Result<f64, TrainError> {
        let ret = self.evaluate_unless(episodes, || false)?;
        Ok(ret.expect(crate::episodes::NEVER_ABANDONED))
    }

    /// [`PlanningEvaluator::evaluate`], abandoned (`Ok(None)`) as soon as `abandon()` says so;
    /// it is asked before every planning step (an MPC evaluation can take minutes, a checkpoint
    /// barrier should not wait for one it will discard). An abandoned evaluation has moved the
    /// streams on: [`PlanningEvaluator::restore`] the state from before it to evaluate again.
    pub fn evaluate_unless(
        &mut self,
        episodes: usize,
        abandon: impl FnMut() -> bool,
    ) -> Result<Option<f64>, TrainError> {
        let (model, plan_rng) = (&mut self.model.model, &mut self.plan_rng);
        crate::episodes::evaluation_episodes(
            self.env.as_mut(),
            episodes,
            &mut self.env_rng,
            &mut self.mpc,
            |mpc| mpc.reset(),
            |mpc, _, obs, action| {
                mpc.act(model, obs, plan_rng, action).map_err(plan_err)?;
                Ok(())
            },
            abandon,
        )
    }
}
