//! The parts of a TD-MPC2 run, each with the state a checkpoint keeps: the world-model learner
//! (real episodes, the networks and their optimisers), the planning actor (an env and MPPI on
//! the learner's newest parameters) and the evaluator (deterministic planning episodes).
//!
//! Random draws come from named streams: `actor.env` / `actor.policy` (planning and its
//! exploration noise) of the actor, `tdmpc.init` (the first parameters) and `tdmpc.update`
//! (subsequences, Q heads, the policy's noise) of the learner, `eval.env` / `eval.plan` of the
//! evaluator.

use mbpo_core::rng::stream;
use mbpo_core::{Batch, BatchPolicy, LastTransition, Rng, TransitionSink};
use mbpo_envs::Env;
use mbpo_latent::mppi::{LatentMppi, MppiConfig};
use mbpo_latent::update::{Learner, LearnerState, UpdateConfig, UpdateStats};
use mbpo_latent::{
    EpisodeBuffer, EpisodeLinks, NormedCache, Sequences, TwoHot, WorldModel, WorldModelConfig,
};
use serde::{Deserialize, Serialize};

use crate::actor::{Behaviour, EnvActor, EnvActorState};
use crate::config::ExperimentConfig;
use crate::error::TrainError;
use crate::PlanPrecision;

/// The world model `cfg` describes for `env` (its widths, horizon, loss weights, and γ from
/// the task's episode length unless the config sets one).
pub fn world_model(cfg: &ExperimentConfig, env: &dyn Env) -> WorldModel {
    let model_cfg = model_config(cfg, env.max_episode_steps());
    WorldModel::new(env.obs_dim(), env.act_dim(), model_cfg)
}

/// The layout hash and length of the parameters of `cfg`'s world model for a task of these
/// widths (what crosses the wire; γ does not change it).
pub fn world_model_layout(cfg: &ExperimentConfig, obs: usize, act: usize) -> (u64, usize) {
    let model = WorldModel::new(obs, act, model_config(cfg, 1000));
    (model.layout_hash(), model.num_params())
}

/// The world model's settings in `cfg` for a task of `episode_length` steps.
pub fn model_config(cfg: &ExperimentConfig, episode_length: usize) -> WorldModelConfig {
    let (t, w) = (&cfg.tdmpc, cfg.tdmpc.widths());
    WorldModelConfig {
        latent: w.latent,
        encoder_hidden: w.encoder_hidden,
        hidden: w.hidden,
        q_heads: w.q_heads,
        horizon: t.horizon,
        rho: t.rho,
        consistency_coef: t.consistency_coef,
        reward_coef: t.reward_coef,
        value_coef: t.value_coef,
        discount: t.discount_for(episode_length),
        two_hot: TwoHot::default(),
        q_dropout: t.q_dropout,
    }
}

/// The planner's settings in `cfg`.
pub fn mppi_config(cfg: &ExperimentConfig) -> MppiConfig {
    let p = &cfg.tdmpc.planner;
    MppiConfig {
        samples: p.samples,
        policy_samples: p.policy_samples,
        elites: p.elites,
        iterations: p.iterations,
        min_std: p.min_std,
        max_std: p.max_std,
        temperature: p.temperature,
        budget: p.budget(),
        bf16: p.precision == PlanPrecision::Bf16,
    }
}

/// MPPI on a copy of the learner's parameters, as a one-observation [`BatchPolicy`] so the
/// shared [`EnvActor`] acts with it.
pub struct LatentPlanner {
    model: WorldModel,
    params: Vec<f32>,
    version: u64,
    mppi: LatentMppi,
    encoder: NormedCache,
    /// Add the plan's σ as exploration noise (the actor, not the evaluator).
    explore: bool,
    iterations: IterationCount,
    /// It holds parameters it was given (not the zeros it starts with).
    received: bool,
}

/// Iterations per plan since the planner was made: fewest, total, most, plans.
#[derive(Debug, Clone, Copy, Default)]
struct IterationCount {
    fewest: usize,
    total: u64,
    most: usize,
    plans: u64,
}

impl IterationCount {
    fn add(&mut self, n: usize) {
        self.fewest = if self.plans == 0 {
            n
        } else {
            self.fewest.min(n)
        };
        self.most = self.most.max(n);
        self.total += n as u64;
        self.plans += 1;
    }
}

impl LatentPlanner {
    fn new(cfg: &ExperimentConfig, env: &dyn Env, explore: bool) -> Self {
        let model = world_model(cfg, env);
        let planner = mppi_config(cfg);
        let mppi = LatentMppi::new(&model, planner);
        match (planner.bf16, mppi.multiplies_in_bf16()) {
            (true, true) => tracing::info!("planning with bf16 products on AMX"),
            (true, false) => tracing::warn!(
                "tdmpc.planner.precision = \"bf16\", but this CPU or kernel has no AMX bf16: \
                 planning in f32"
            ),
            _ => {}
        }
        Self {
            params: vec![0.0; model.num_params()],
            version: 0,
            mppi,
            encoder: NormedCache::new(&model.encoder, 1),
            model,
            explore,
            iterations: IterationCount::default(),
            received: false,
        }
    }
    /// Take parameters `version` (the learner's after `version` env steps), one copy.
    pub fn set_params(&mut self, params: &[f32], version: u64) {
        self.params.copy_from_slice(params);
        self.version = version;
        self.received = true;
    }
    /// The parameters, to load a snapshot into in place; then [`LatentPlanner::received`].
    pub fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }
    /// The parameters in place are version `version` of the learner's.
    pub fn received(&mut self, version: u64) {
        self.version = version;
        self.received = true;
    }
    /// Whether it holds given parameters of at least `version`.
    pub fn holds(&self, version: u64) -> bool {
        self.received && self.version >= version
    }
    /// The version planned with.
    pub fn version(&self) -> u64 {
        self.version
    }
    /// Forget the warm start (a new episode).
    pub fn reset(&mut self) {
        self.mppi.reset();
    }
    /// Plans made and their iterations (fewest, mean, most), `None` before the first: what a
    /// time budget let each plan do.
    pub fn iterations_per_plan(&self) -> Option<(u64, usize, f64, usize)> {
        let c = self.iterations;
        (c.plans > 0).then(|| (c.plans, c.fewest, c.total as f64 / c.plans as f64, c.most))
    }
}

impl BatchPolicy for LatentPlanner {
    fn act_batch(&mut self, obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng) {
        debug_assert_eq!(batch, 1, "MPPI plans for one observation at a time");
        let p = &self.params[self.model.encoder_range()];
        let z = self.model.encoder.forward(p, obs, 1, &mut self.encoder);
        let (model, params) = (&self.model, &self.params);
        self.mppi.plan(model, params, z, self.explore, rng, actions);
        self.iterations.add(self.mppi.iterations_done());
    }
}

/// What a checkpoint keeps of the [`WorldModelLearner`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldModelLearnerState {
    /// Networks, targets, optimisers, Q's scale.
    pub learner: LearnerState,
    /// The real transitions.
    pub buffer: EpisodeBuffer,
    /// The `tdmpc.update` stream.
    pub rng: Rng,
    /// Updates done.
    pub updates: u64,
}

/// A TD-MPC2 update's losses in the metrics row's terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReportedLosses {
    /// The Q heads' two-hot cross-entropy (the `critic_loss` column).
    pub value: f32,
    /// The policy prior's loss (the `actor_loss` column).
    pub policy: f32,
    /// The latent consistency loss.
    pub consistency: f32,
    /// The reward head's two-hot cross-entropy.
    pub reward: f32,
}

/// The world model learning from real episodes.
pub struct WorldModelLearner {
    learner: Learner,
    buffer: EpisodeBuffer,
    rng: Rng,
    seq: Sequences,
    updates: u64,
    /// The last update's losses.
    pub last: Option<UpdateStats>,
}

impl WorldModelLearner {
    /// The learner of `cfg` for `env`'s sizes, its parameters drawn from `tdmpc.init`.
    pub fn new(cfg: &ExperimentConfig, env: &dyn Env) -> Self {
        let widths = (env.obs_dim(), env.act_dim());
        Self::with_dims(cfg, widths, env.max_episode_steps())
    }
    /// [`WorldModelLearner::new`] from the task's widths and time limit alone (a pipeline
    /// learner does not make the env).
    pub fn with_dims(
        cfg: &ExperimentConfig,
        (o, a): (usize, usize),
        episode_length: usize,
    ) -> Self {
        let model = WorldModel::new(o, a, model_config(cfg, episode_length));
        let mut params = vec![0.0; model.num_params()];
        model.init(&mut params, &mut stream(cfg.seed, "tdmpc.init", 0));
        let t = &cfg.tdmpc;
        let seq = Sequences::zeros(t.batch_size, t.horizon, o, a);
        let update = UpdateConfig {
            lr: t.lr,
            ..Default::default()
        };
        Self {
            learner: Learner::new(model, params, update, t.batch_size),
            buffer: EpisodeBuffer::new(o, a, t.capacity_for(cfg.steps)),
            rng: stream(cfg.seed, "tdmpc.update", 0),
            seq,
            updates: 0,
            last: None,
        }
    }
    /// `n` updates, each on a fresh batch of subsequences.
    pub fn update(&mut self, n: u64) -> Result<(), TrainError> {
        let h = self.learner.model.cfg.horizon;
        for _ in 0..n {
            if !self.buffer.sample(h, &mut self.rng, &mut self.seq) {
                return Err(TrainError::Config(format!(
                    "tdmpc: no subsequence of {h} steps inside one episode among {} real \
                     transitions: lower tdmpc.horizon or raise tdmpc.seed_steps",
                    self.buffer.len()
                )));
            }
            self.last = Some(self.learner.update(&self.seq, &mut self.rng));
            self.updates += 1;
        }
        Ok(())
    }
    /// Updates done: the version of the parameters.
    pub fn updates(&self) -> u64 {
        self.updates
    }
    /// The last update's losses as a metrics row reports them, NaN before the first:
    /// the Q heads' (`critic_loss`), the policy prior's (`actor_loss`), consistency, reward.
    pub fn reported_losses(&self) -> ReportedLosses {
        let nan = ReportedLosses {
            value: f32::NAN,
            policy: f32::NAN,
            consistency: f32::NAN,
            reward: f32::NAN,
        };
        self.last.map_or(nan, |s| ReportedLosses {
            value: s.model.value,
            policy: s.policy,
            consistency: s.model.consistency,
            reward: s.model.reward,
        })
    }
    /// The current parameters.
    pub fn params(&self) -> &[f32] {
        &self.learner.params
    }
    /// The state a checkpoint keeps.
    pub fn checkpoint(&self) -> WorldModelLearnerState {
        WorldModelLearnerState {
            learner: self.learner.state(),
            buffer: self.buffer.clone(),
            rng: self.rng.clone(),
            updates: self.updates,
        }
    }
    /// How its buffer's rows join into episodes (a checkpoint keeps them beside the state).
    pub fn episode_links(&self) -> EpisodeLinks {
        self.buffer.links().clone()
    }
    /// Continue from [`WorldModelLearner::checkpoint`] and its [`Self::episode_links`] (`None`:
    /// a checkpoint written before them, by one actor).
    pub fn restore(
        &mut self,
        s: WorldModelLearnerState,
        links: Option<EpisodeLinks>,
    ) -> Result<(), TrainError> {
        let refuse = |e: String| TrainError::Config(format!("tdmpc checkpoint: {e}"));
        if !s.buffer.same_widths(&self.buffer) {
            return Err(refuse("its buffer is of another task's widths".into()));
        }
        let buffer = s.buffer.with_links(links).map_err(refuse)?;
        self.learner.restore(s.learner).map_err(refuse)?;
        // A run extended past its planned steps (`--resume --steps N`) keeps more of them.
        self.buffer = buffer.resized(self.buffer.capacity());
        self.rng = s.rng;
        self.updates = s.updates;
        Ok(())
    }
}

/// Real transitions in the order they arrive (the actors' rows interleaved in a pipeline): the
/// buffer joins each row to the open episode it starts from (`mbpo_latent::replay`), the same
/// rule in one process and in the pipeline's learner, which sees only rows.
impl TransitionSink for WorldModelLearner {
    fn push(&mut self, obs: &[f32], act: &[f32], reward: f32, next_obs: &[f32], terminated: bool) {
        self.buffer.push(obs, act, reward, next_obs, terminated);
    }
}

/// What a checkpoint keeps of the [`TdmpcActor`] (its parameters are the learner's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TdmpcActorState {
    /// The env actor (episode in progress, streams, counters).
    pub actor: EnvActorState,
    /// The planner's warm start.
    pub plan: Vec<f32>,
}

/// Acting in the real environment by planning in the latent space.
pub struct TdmpcActor {
    actor: EnvActor,
    planner: LatentPlanner,
    staged: LastTransition,
}

impl TdmpcActor {
    /// Actor `index` of the run.
    pub fn new(cfg: &ExperimentConfig, index: u64) -> Result<Self, TrainError> {
        let actor = EnvActor::new(cfg.make_env()?, cfg.seed, index)?;
        let env = cfg.make_env()?;
        Ok(Self {
            planner: LatentPlanner::new(cfg, env.as_ref(), true),
            staged: LastTransition::new(env.obs_dim(), env.act_dim()),
            actor,
        })
    }
    /// The planner (to give it parameters).
    pub fn planner(&mut self) -> &mut LatentPlanner {
        &mut self.planner
    }
    /// The planner (its version and counters).
    pub fn planner_ref(&self) -> &LatentPlanner {
        &self.planner
    }
    /// The env actor (episode counters).
    pub fn env_actor(&self) -> &EnvActor {
        &self.actor
    }
    /// One real env step (uniform, or the planner's action); returns the transition.
    pub fn act(&mut self, behaviour: Behaviour) -> Result<&Batch, TrainError> {
        let (actor, planner) = (&mut self.actor, &mut self.planner);
        step_planning(actor, planner, behaviour, &mut self.staged)?;
        Ok(self.staged.batch())
    }
    /// One real env step whose transition goes straight into `sink` (a pipeline actor's
    /// loaned shared-memory sample).
    pub fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn TransitionSink,
    ) -> Result<(), TrainError> {
        step_planning(&mut self.actor, &mut self.planner, behaviour, sink)
    }
    /// The state a checkpoint keeps.
    pub fn checkpoint(&self) -> TdmpcActorState {
        TdmpcActorState {
            actor: self.actor.checkpoint(),
            plan: self.planner.mppi.mean().to_vec(),
        }
    }
    /// Continue from [`TdmpcActor::checkpoint`] (then give it the learner's parameters).
    pub fn restore(&mut self, s: TdmpcActorState) -> Result<(), TrainError> {
        self.actor.restore(s.actor)?;
        self.planner
            .mppi
            .set_mean(&s.plan)
            .map_err(|e| TrainError::Config(format!("tdmpc checkpoint: {e}")))
    }
}

/// One env step of `actor` with `planner` into `sink`; the warm start is dropped at every
/// episode end.
fn step_planning(
    actor: &mut EnvActor,
    planner: &mut LatentPlanner,
    behaviour: Behaviour,
    sink: &mut dyn TransitionSink,
) -> Result<(), TrainError> {
    let episodes = actor.episodes;
    actor.step(behaviour, planner, sink)?;
    if actor.episodes > episodes {
        planner.reset();
    }
    Ok(())
}

/// What a checkpoint keeps of the [`TdmpcEvaluator`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TdmpcEvaluatorState {
    /// The `eval.env` stream.
    pub env_rng: Rng,
    /// The `eval.plan` stream.
    pub plan_rng: Rng,
}

/// Evaluation episodes: planning without exploration noise, own env and streams.
pub struct TdmpcEvaluator {
    env: Box<dyn Env>,
    env_rng: Rng,
    plan_rng: Rng,
    planner: LatentPlanner,
}

impl TdmpcEvaluator {
    /// The evaluator of the run.
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, TrainError> {
        let env = cfg.make_env()?;
        Ok(Self {
            planner: LatentPlanner::new(cfg, env.as_ref(), false),
            env,
            env_rng: stream(cfg.seed, "eval.env", 0),
            plan_rng: stream(cfg.seed, "eval.plan", 0),
        })
    }
    /// The planner (to give it parameters).
    pub fn planner(&mut self) -> &mut LatentPlanner {
        &mut self.planner
    }
    /// The planner (its version).
    pub fn planner_ref(&self) -> &LatentPlanner {
        &self.planner
    }
    /// The state a checkpoint keeps.
    pub fn checkpoint(&self) -> TdmpcEvaluatorState {
        TdmpcEvaluatorState {
            env_rng: self.env_rng.clone(),
            plan_rng: self.plan_rng.clone(),
        }
    }
    /// Continue from [`TdmpcEvaluator::checkpoint`].
    pub fn restore(&mut self, s: TdmpcEvaluatorState) {
        self.env_rng = s.env_rng;
        self.plan_rng = s.plan_rng;
    }
    /// Mean undiscounted return of `episodes` planning episodes.
    pub fn evaluate(&mut self, episodes: usize) -> Result<f64, TrainError> {
        let plan_rng = &mut self.plan_rng;
        crate::episodes::mean_return(
            self.env.as_mut(),
            episodes,
            &mut self.env_rng,
            &mut self.planner,
            |planner| planner.reset(),
            |planner, _, obs, action| {
                planner.act_batch(obs, 1, action, plan_rng);
                Ok::<(), TrainError>(())
            },
        )
    }
}
