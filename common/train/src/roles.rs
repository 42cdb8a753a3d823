//! MBPO split into the roles of the multi-process pipeline.
//!
//! Each role owns exactly the state its process will own (its own copy of the real data, its
//! own random streams) and talks to the others only through the messages below. The sequential
//! reference ([`crate::mbpo_trainer`]) calls the roles in Algorithm 2's order in one process;
//! the pipeline runs each role in its own process and passes the same messages over shared
//! memory. Both therefore execute the same code on the same inputs, which is what makes a
//! lockstep pipeline equal the sequential run bit for bit.
//!
//! | role | consumes | produces | streams |
//! |---|---|---|---|
//! | [`ActorRole`] | [`PolicySnapshot`] | real transitions | `actor.env`, `actor.policy` |
//! | [`ModelTrainerRole`] | real transitions | [`ModelSnapshot`] | `model.init`, `model.train` |
//! | [`RolloutRole`] | real transitions, [`ModelSnapshot`], [`PolicySnapshot`] | [`ImaginedBatch`] | `rollout` |
//! | [`LearnerRole`] | real transitions, [`ImaginedBatch`] | [`PolicySnapshot`] | `sac.init`, `learner.sample`, `learner.update` |

use crate::actor::{Behaviour, EnvActor, EnvActorState};
use crate::config::{ExperimentConfig, ImaginedStateClip};
use crate::d_model_branches::{BranchInputs, BranchLog, DModelBranches};
use crate::env_config::RolloutRule;
use crate::error::TrainError;
use mbpo_core::rng::stream;
use mbpo_core::{
    sample_mixed, Batch, LastTransition, ReplayBuffer, ReplaySnapshot, Rng, StateBox,
    TransitionSink,
};
use mbpo_envs::EnvError;
use mbpo_model::{
    rollout_length, ModelPoolSizing, ModelState, ModelWeights, ProbabilisticEnsemble,
    RolloutFilter, RolloutStats, TrainReport,
};
use mbpo_sac::{ActorPolicy, Sac, SacState, SacStats, TanhGaussianActor};
use serde::{Deserialize, Serialize};

fn restore_err(role: &str, e: impl std::fmt::Display) -> TrainError {
    TrainError::Config(format!(
        "cannot restore the {role} from its checkpoint: {e}"
    ))
}

/// The policy a role acts with, as received from the learner: its parameters, its version and
/// whether any snapshot arrived at all. The placeholder zeros a role starts with are not the
/// learner's version 0 (its random initialisation), and a restored role waits for the learner's
/// republished version too: a checkpoint taken in the warm-up holds those zeros.
struct ReceivedPolicy {
    net: ActorPolicy,
    version: u64,
    received: bool,
}

impl ReceivedPolicy {
    fn new(net: ActorPolicy) -> Self {
        Self {
            net,
            version: 0,
            received: false,
        }
    }
    /// Take `version` from `params` (one copy, out of shared memory).
    fn set(&mut self, params: &[f32], version: u64) {
        self.net.params.copy_from_slice(params);
        self.version = version;
        self.received = true;
    }
    /// Whether a received policy of at least `version` is in place.
    fn has(&self, version: u64) -> bool {
        self.received && self.version >= version
    }
    /// Continue from a checkpoint's `params` and `version` (then wait for the learner's).
    fn restore(&mut self, role: &str, params: Vec<f32>, version: u64) -> Result<(), TrainError> {
        if params.len() != self.net.params.len() {
            return Err(restore_err(
                role,
                format!(
                    "policy has {} parameters, expected {}",
                    params.len(),
                    self.net.params.len()
                ),
            ));
        }
        self.net.params = params;
        self.version = version;
        self.received = false;
        Ok(())
    }
}

/// A checkpointed [`ActorRole`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActorState {
    /// The env actor (episode, streams, counters).
    pub actor: EnvActorState,
    /// The policy acting and its version.
    pub policy: Vec<f32>,
    /// Version of that policy.
    pub policy_version: u64,
}

/// A checkpointed [`ModelTrainerRole`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelTrainerState {
    /// Its copy of D_env.
    pub d_env: ReplaySnapshot,
    /// Model weights and optimiser.
    pub model: ModelState,
    /// The `model.train` stream.
    pub rng: Rng,
    /// Trainings completed.
    pub version: u64,
}

/// A checkpointed [`RolloutRole`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutState {
    /// Its copy of D_env (start states).
    pub d_env: ReplaySnapshot,
    /// The model it branches with (`None` before the first training).
    pub model: Option<ModelWeights>,
    /// Version of that model.
    pub model_version: u64,
    /// The policy it rolls out.
    pub policy: Vec<f32>,
    /// Version of that policy.
    pub policy_version: u64,
    /// The `rollout` stream.
    pub rng: Rng,
}

/// A checkpointed [`LearnerRole`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LearnerState {
    /// Networks, optimisers, temperature.
    pub sac: SacState,
    /// Its copy of D_env.
    pub d_env: ReplaySnapshot,
    /// D_model.
    pub d_model: ReplaySnapshot,
    /// The `learner.sample` stream.
    pub sample_rng: Rng,
    /// The `learner.update` stream.
    pub update_rng: Rng,
    /// Learner steps completed (= policy version).
    pub steps: u64,
    /// Statistics of the last update.
    pub last_stats: SacStats,
    /// Rollout length of the last imagined batch.
    pub rollout_length: usize,
}

pub use crate::schedule::Schedule;

/// The policy after `version` learner steps: version 0 is the initial parameters, version t the
/// parameters after env step t was consumed (and, after the warm-up, its G updates done). The
/// actor of env step t acts with version t − 1.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicySnapshot {
    /// Learner steps completed.
    pub version: u64,
    /// Actor parameters.
    pub params: Vec<f32>,
}

/// The model after its `version`-th training.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSnapshot {
    /// Trainings completed.
    pub version: u64,
    /// Parameters, normaliser and elites.
    pub weights: ModelWeights,
}

/// Rollouts branched for one model training.
#[derive(Debug, Clone, PartialEq)]
pub struct ImaginedBatch {
    /// Model version that produced them.
    pub model_version: u64,
    /// Policy version that acted in them.
    pub policy_version: u64,
    /// Rollout length k in force (sizes the model buffer).
    pub rollout_length: usize,
    /// The transitions, in rollout order.
    pub rows: Batch,
}

/// Acting in the real environment.
pub struct ActorRole {
    actor: EnvActor,
    policy: ReceivedPolicy,
    staged: LastTransition,
}

impl ActorRole {
    /// Actor `index` of the run.
    pub fn new(cfg: &ExperimentConfig, index: u64) -> Result<Self, EnvError> {
        let actor = EnvActor::new(cfg.make_env()?, cfg.seed, index)?;
        let (o, a) = (actor.obs_dim(), actor.act_dim());
        let net = TanhGaussianActor::new(
            o,
            a,
            &cfg.sac.hidden,
            cfg.sac.log_std_min,
            cfg.sac.log_std_max,
        );
        let params = vec![0.0; net.num_params()];
        Ok(Self {
            actor,
            policy: ReceivedPolicy::new(ActorPolicy::new(net, params, false)),
            staged: LastTransition::new(o, a),
        })
    }
    /// Take a newer policy.
    pub fn set_policy(&mut self, snapshot: &PolicySnapshot) {
        self.set_policy_params(&snapshot.params, snapshot.version);
    }
    /// Take policy `version` straight from `params` (a receiver copies a snapshot once, out
    /// of shared memory into the policy).
    pub fn set_policy_params(&mut self, params: &[f32], version: u64) {
        self.policy.set(params, version);
    }
    /// Version of the policy acting.
    pub fn policy_version(&self) -> u64 {
        self.policy.version
    }
    /// Whether the role acts with a received policy of at least `version` (never the
    /// placeholder zeros it starts with, nor a restored copy of them).
    pub fn has_policy(&self, version: u64) -> bool {
        self.policy.has(version)
    }
    /// The env actor (episode counters).
    pub fn env_actor(&self) -> &EnvActor {
        &self.actor
    }
    /// The role's state (for checkpoints).
    pub fn checkpoint(&self) -> ActorState {
        ActorState {
            actor: self.actor.checkpoint(),
            policy: self.policy.net.params.clone(),
            policy_version: self.policy.version,
        }
    }
    /// Continue from [`ActorRole::checkpoint`].
    pub fn restore(&mut self, s: ActorState) -> Result<(), TrainError> {
        self.policy.restore("actor", s.policy, s.policy_version)?;
        self.actor.restore(s.actor)?;
        Ok(())
    }
    /// One real env step; returns the transition as a one-row batch (no allocation).
    pub fn act(&mut self, behaviour: Behaviour) -> Result<&Batch, TrainError> {
        self.actor
            .step(behaviour, &mut self.policy.net, &mut self.staged)?;
        Ok(self.staged.batch())
    }
    /// One real env step whose transition goes straight into `sink` (a pipeline actor's
    /// loaned shared-memory sample; no allocation, no staging copy).
    pub fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn TransitionSink,
    ) -> Result<(), TrainError> {
        self.actor.step(behaviour, &mut self.policy.net, sink)
    }
}

/// Training the dynamics model on its copy of the real data.
pub struct ModelTrainerRole {
    d_env: ReplayBuffer,
    model: ProbabilisticEnsemble,
    rng: Rng,
    version: u64,
}

impl ModelTrainerRole {
    /// The model trainer of the run.
    pub fn new(cfg: &ExperimentConfig, obs_dim: usize, act_dim: usize) -> Result<Self, TrainError> {
        let model = ProbabilisticEnsemble::new(
            obs_dim,
            act_dim,
            cfg.model_config(),
            &mut stream(cfg.seed, "model.init", 0),
        )
        .map_err(|e| TrainError::Config(e.to_string()))?;
        Ok(Self {
            d_env: ReplayBuffer::new(obs_dim, act_dim, cfg.mbpo.replay_capacity),
            model,
            rng: stream(cfg.seed, "model.train", 0),
            version: 0,
        })
    }
    /// Store real transitions.
    pub fn add_real(&mut self, rows: &Batch) {
        self.d_env.push_batch(rows);
    }
    /// Real transitions received.
    pub fn real_received(&self) -> u64 {
        self.d_env.pushed()
    }
    /// Trainings completed.
    pub fn version(&self) -> u64 {
        self.version
    }
    /// The role's state (for checkpoints).
    pub fn checkpoint(&self) -> ModelTrainerState {
        ModelTrainerState {
            d_env: self.d_env.snapshot(),
            model: self.model.checkpoint(),
            rng: self.rng.clone(),
            version: self.version,
        }
    }
    /// Continue from [`ModelTrainerRole::checkpoint`].
    pub fn restore(&mut self, s: ModelTrainerState) -> Result<(), TrainError> {
        let (o, a) = (self.d_env.obs_dim(), self.d_env.act_dim());
        self.d_env = ReplayBuffer::from_snapshot(&s.d_env, o, a)
            .map_err(|e| restore_err("model trainer", e))?;
        self.model
            .restore(&s.model)
            .map_err(|e| restore_err("model trainer", e))?;
        self.rng = s.rng;
        self.version = s.version;
        Ok(())
    }
    /// The current model as a snapshot (what a restarted trainer republishes).
    pub fn snapshot(&self) -> ModelSnapshot {
        ModelSnapshot {
            version: self.version,
            weights: self.model.weights(),
        }
    }
    /// Train p_θ on all real data by maximum likelihood; returns the new snapshot.
    pub fn train(&mut self) -> Result<(ModelSnapshot, TrainReport), TrainError> {
        let data = self.d_env.to_batch();
        let report = self
            .model
            .train(&data, &mut self.rng)
            .map_err(|e| TrainError::Config(e.to_string()))?;
        self.check_finite(&report)?;
        Ok(self.trained(report))
    }

    /// [`Self::train`], showing `after_epoch` where the training stands after each epoch;
    /// when it returns true the training is abandoned: the role is then exactly as before the
    /// call (model, optimiser and random stream restored) and `None` is returned, so a
    /// checkpoint written next is the one of the previous step.
    pub fn train_watched(
        &mut self,
        after_epoch: impl FnMut(&mbpo_model::EpochProgress) -> bool,
    ) -> Result<Option<(ModelSnapshot, TrainReport)>, TrainError> {
        let data = self.d_env.to_batch();
        let before = (self.model.checkpoint(), self.rng.clone());
        let trained = self
            .model
            .train_watched(&data, &mut self.rng, after_epoch)
            .map_err(|e| TrainError::Config(e.to_string()))?;
        let Some(report) = trained else {
            let (model, rng) = before;
            self.model
                .restore(&model)
                .map_err(|e| restore_err("model trainer", e))?;
            self.rng = rng;
            return Ok(None);
        };
        self.check_finite(&report)?;
        Ok(Some(self.trained(report)))
    }

    /// A training whose elites' holdout MSE is not finite stops the run.
    fn check_finite(&self, report: &TrainReport) -> Result<(), TrainError> {
        let bad = report
            .elites
            .iter()
            .map(|&e| (e, report.final_holdout_mse[e]))
            .find(|(_, m)| !m.is_finite());
        match bad {
            Some((member, value)) => Err(TrainError::NonFinite {
                role: "model trainer",
                quantity: format!("the holdout MSE of elite member {member}"),
                value: value as f64,
                at: format!(
                    "model training {} on {} transitions",
                    self.version + 1,
                    report.n_train + report.n_holdout
                ),
            }),
            None => Ok(()),
        }
    }

    /// The next version, after a completed training.
    fn trained(&mut self, report: TrainReport) -> (ModelSnapshot, TrainReport) {
        self.version += 1;
        let snapshot = ModelSnapshot {
            version: self.version,
            weights: self.model.weights(),
        };
        (snapshot, report)
    }
}

/// Branching model rollouts from real start states with the current policy.
pub struct RolloutRole {
    d_env: ReplayBuffer,
    model: ProbabilisticEnsemble,
    model_version: u64,
    policy: ReceivedPolicy,
    /// How rollouts end: the task's rule, the model's learned one or a Python function.
    termination: RolloutRule,
    schedule: [usize; 4],
    /// Whether imagined next states are clamped into the real box (`mbpo.clip_imagined_states`).
    clip: ImaginedStateClip,
    /// The fraction of each rollout step's transitions kept (`mbpo.rollout_keep_fraction`).
    keep_fraction: f64,
    starts: Batch,
    staged: ReplayBuffer,
    rng: Rng,
}

impl RolloutRole {
    /// The rollout generator of the run.
    pub fn new(cfg: &ExperimentConfig, obs_dim: usize, act_dim: usize) -> Result<Self, TrainError> {
        let termination = cfg.rollout_termination(obs_dim, act_dim)?;
        // Architecture only: the weights arrive as snapshots.
        let model = ProbabilisticEnsemble::new(
            obs_dim,
            act_dim,
            cfg.model_config(),
            &mut stream(cfg.seed, "rollout.model-shape", 0),
        )
        .map_err(|e| TrainError::Config(e.to_string()))?;
        let net = TanhGaussianActor::new(
            obs_dim,
            act_dim,
            &cfg.sac.hidden,
            cfg.sac.log_std_min,
            cfg.sac.log_std_max,
        );
        let params = vec![0.0; net.num_params()];
        let n = cfg.mbpo.rollouts_per_step * cfg.mbpo.model_train_freq as usize;
        Ok(Self {
            d_env: ReplayBuffer::new(obs_dim, act_dim, cfg.mbpo.replay_capacity),
            model,
            model_version: 0,
            // The rollouts' policy acts on the model's threads (its actions do not depend on
            // the count): a rollout's states are 100k rows, as many as the model's.
            policy: ReceivedPolicy::new(
                ActorPolicy::new(net, params, false).with_threads(cfg.model.threads),
            ),
            termination,
            schedule: cfg.mbpo.rollout_schedule,
            clip: cfg.mbpo.clip_imagined_states,
            keep_fraction: cfg.mbpo.rollout_keep_fraction,
            starts: Batch::new(obs_dim, act_dim, n),
            staged: ReplayBuffer::new(obs_dim, act_dim, 1),
            rng: stream(cfg.seed, "rollout", 0),
        })
    }
    /// Store real transitions (the start-state pool).
    pub fn add_real(&mut self, rows: &Batch) {
        self.d_env.push_batch(rows);
    }
    /// Take a newer model.
    pub fn set_model(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model
            .load_weights(&snapshot.weights)
            .map_err(|e| TrainError::Config(e.to_string()))?;
        self.model_version = snapshot.version;
        Ok(())
    }
    /// Take model `version`, loaded in place by `load` (a receiver's one copy out of shared
    /// memory; `load` checks the snapshot before it writes anything).
    pub fn load_model<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        load(&mut self.model).map_err(|e| TrainError::Config(e.to_string()))?;
        self.model_version = version;
        Ok(())
    }
    /// Take a newer policy.
    pub fn set_policy(&mut self, snapshot: &PolicySnapshot) {
        self.set_policy_params(&snapshot.params, snapshot.version);
    }
    /// Take policy `version` straight from `params` (a receiver copies a snapshot once, out
    /// of shared memory into the policy).
    pub fn set_policy_params(&mut self, params: &[f32], version: u64) {
        self.policy.set(params, version);
    }
    /// Whether the rollouts branch with a received policy of at least `version` (never the
    /// placeholder zeros, nor a restored copy of them).
    pub fn has_policy(&self, version: u64) -> bool {
        self.policy.has(version)
    }
    /// The model the rollouts use.
    pub fn model_mut(&mut self) -> &mut ProbabilisticEnsemble {
        &mut self.model
    }
    /// `done` of `n` transitions by the rollouts' termination rule (see
    /// [`RolloutRule::done_batch`]).
    pub fn done_batch(
        &mut self,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) -> Result<(), mbpo_model::RolloutError> {
        self.termination
            .done_batch(&mut self.model, obs, act, next_obs, n, out)
    }
    /// The role's state (for checkpoints).
    pub fn checkpoint(&self) -> RolloutState {
        RolloutState {
            d_env: self.d_env.snapshot(),
            model: (self.model_version > 0).then(|| self.model.weights()),
            model_version: self.model_version,
            policy: self.policy.net.params.clone(),
            policy_version: self.policy.version,
            rng: self.rng.clone(),
        }
    }
    /// Continue from [`RolloutRole::checkpoint`].
    pub fn restore(&mut self, s: RolloutState) -> Result<(), TrainError> {
        let (o, a) = (self.d_env.obs_dim(), self.d_env.act_dim());
        self.d_env = ReplayBuffer::from_snapshot(&s.d_env, o, a)
            .map_err(|e| restore_err("rollout generator", e))?;
        if let Some(w) = &s.model {
            self.model
                .load_weights(w)
                .map_err(|e| restore_err("rollout generator", e))?;
        }
        self.policy
            .restore("rollout generator", s.policy, s.policy_version)?;
        self.model_version = s.model_version;
        self.rng = s.rng;
        Ok(())
    }
    /// Version of the policy it branches with.
    pub fn policy_version(&self) -> u64 {
        self.policy.version
    }
    /// Version of the model it branches with.
    pub fn model_version(&self) -> u64 {
        self.model_version
    }
    /// Real transitions received.
    pub fn real_received(&self) -> u64 {
        self.d_env.pushed()
    }
    /// What [`RolloutRole::branch`] of `epoch` would start from now (a copy of the model and
    /// the policy), for [`crate::d_model_branches`]; `rows` and `digest` are filled in after.
    pub fn inputs_of_branch(&self, epoch: usize) -> BranchInputs {
        BranchInputs {
            epoch,
            d_env_rows: self.d_env.pushed(),
            model: self.model.weights(),
            policy: self.policy.net.params.clone(),
            rng: self.rng.clone(),
            rows: 0,
            digest: 0,
        }
    }
    /// Do the branch of `inputs` again, from the first `inputs.d_env_rows` transitions of
    /// `d_env`, and return its rows; the role's own state is as before afterwards.
    pub fn replay(
        &mut self,
        inputs: &BranchInputs,
        d_env: &ReplayBuffer,
    ) -> Result<Batch, TrainError> {
        let live = self.checkpoint();
        let starts = d_env
            .prefix(inputs.d_env_rows)
            .map_err(|e| restore_err("learner's D_model", e))?;
        let replayed = self.restore(RolloutState {
            d_env: starts.snapshot(),
            model: Some(inputs.model.clone()),
            model_version: live.model_version,
            policy: inputs.policy.clone(),
            policy_version: live.policy_version,
            rng: inputs.rng.clone(),
        });
        let rows = replayed.and_then(|()| self.branch(inputs.epoch).map(|b| b.rows));
        // (A role without a model yet keeps the loaded weights, unread until its first model.)
        self.restore(live)?;
        rows
    }
    /// What the options beyond the paper did to a branch's rollouts, when one is on.
    fn log_filtered(&self, stats: &RolloutStats, n: usize, k: usize, clipped: bool) {
        let share = |x: usize, of: usize| 100.0 * x as f64 / of.max(1) as f64;
        let v = self.model_version;
        if clipped {
            let (c, t) = (stats.clipped, stats.transitions);
            tracing::info!(
                "branched {n} rollouts of k = {k} with model {v}: {c} of {t} imagined next \
                 states ({:.2} %) clamped into the real box",
                share(c, t)
            );
        }
        if self.keep_fraction < 1.0 {
            let (m, t) = (stats.masked, stats.transitions);
            tracing::info!(
                "branched {n} rollouts of k = {k} with model {v}: kept {t} imagined transitions, \
                 masked {m} ({:.2} %) the elites disagreed on most (rollout_keep_fraction {})",
                share(m, m + t),
                self.keep_fraction
            );
        }
    }

    /// k = rollout_length(epoch); M · model_train_freq k-step rollouts of π in p_θ from start
    /// states drawn uniformly from the real data.
    pub fn branch(&mut self, epoch: usize) -> Result<ImaginedBatch, TrainError> {
        let k = rollout_length(epoch, self.schedule);
        let n = self.starts.len;
        if self.staged.capacity() != n * k {
            self.staged = ReplayBuffer::new(self.starts.obs_dim, self.starts.act_dim, n * k);
        }
        self.d_env.sample_into(&mut self.rng, &mut self.starts);
        // The box of what D_env holds now: one pass over it per branch (every 250 steps).
        let real_box = match self.clip {
            ImaginedStateClip::Off => None,
            ImaginedStateClip::RealBox => Some(StateBox::of(&self.d_env)),
        };
        let (model, policy, rng) = (&mut self.model, &mut self.policy.net, &mut self.rng);
        let (starts, staged) = (&self.starts.obs, &mut self.staged);
        let filter = RolloutFilter {
            clip: real_box.as_ref(),
            keep_fraction: self.keep_fraction,
        };
        let stats = self
            .termination
            .with(|rule| model.rollout(starts, n, policy, k, rule, filter, rng, staged))
            .map_err(|e| TrainError::Config(e.to_string()))?;
        self.log_filtered(&stats, n, k, real_box.is_some());
        let rows = self.staged.to_batch();
        self.staged = ReplayBuffer::new(self.starts.obs_dim, self.starts.act_dim, n * k);
        Ok(ImaginedBatch {
            model_version: self.model_version,
            policy_version: self.policy.version,
            rollout_length: k,
            rows,
        })
    }
}

/// SAC updates on mixed real and imagined data.
pub struct LearnerRole {
    sac: Sac,
    d_env: ReplayBuffer,
    d_model: ReplayBuffer,
    pool: ModelPoolSizing,
    real_ratio: f64,
    batch: Batch,
    sample_rng: Rng,
    update_rng: Rng,
    steps: u64,
    /// The branches behind D_model's rows, when they were handed over with them.
    branch_log: BranchLog,
    /// Statistics of the last update.
    pub last_stats: SacStats,
    /// Rollout length of the last imagined batch.
    pub rollout_length: usize,
}

impl LearnerRole {
    /// The SAC learner of the run.
    pub fn new(cfg: &ExperimentConfig, obs_dim: usize, act_dim: usize) -> Self {
        let m = &cfg.mbpo;
        let pool = ModelPoolSizing {
            rollout_batch_size: m.rollouts_per_step * m.model_train_freq as usize,
            epoch_length: m.epoch_length as usize,
            model_train_freq: m.model_train_freq as usize,
            retain_epochs: m.retain_epochs,
        };
        let k0 = rollout_length(0, m.rollout_schedule);
        Self {
            sac: Sac::new(
                obs_dim,
                act_dim,
                cfg.sac.clone(),
                &mut stream(cfg.seed, "sac.init", 0),
            ),
            d_env: ReplayBuffer::new(obs_dim, act_dim, m.replay_capacity),
            d_model: ReplayBuffer::new(obs_dim, act_dim, pool.capacity(k0).max(1)),
            pool,
            real_ratio: m.real_ratio,
            batch: Batch::new(obs_dim, act_dim, cfg.sac.batch_size),
            sample_rng: stream(cfg.seed, "learner.sample", 0),
            update_rng: stream(cfg.seed, "learner.update", 0),
            steps: 0,
            branch_log: BranchLog::default(),
            last_stats: SacStats::default(),
            rollout_length: k0,
        }
    }
    /// Store real transitions.
    pub fn add_real(&mut self, rows: &Batch) {
        self.d_env.push_batch(rows);
    }
    /// Real transitions received.
    pub fn real_received(&self) -> u64 {
        self.d_env.pushed()
    }
    /// Resize D_model for the batch's k (keeping the newest rows) and append the batch.
    pub fn add_imagined(&mut self, batch: &ImaginedBatch) {
        self.append_imagined(batch);
        self.branch_log.forget();
    }
    /// [`LearnerRole::add_imagined`] of a batch branched from `inputs`
    /// ([`RolloutRole::inputs_of_branch`]), so a checkpoint can store the inputs instead of
    /// the rows ([`crate::d_model_branches`]).
    pub fn add_imagined_from(&mut self, batch: &ImaginedBatch, inputs: BranchInputs) {
        self.append_imagined(batch);
        let inputs = BranchInputs {
            rows: batch.rows.len,
            digest: batch.rows.digest(),
            ..inputs
        };
        self.branch_log.record(inputs, self.d_model.capacity());
    }
    fn append_imagined(&mut self, batch: &ImaginedBatch) {
        self.rollout_length = batch.rollout_length;
        self.d_model
            .set_capacity(self.pool.capacity(batch.rollout_length).max(1));
        self.d_model.push_batch(&batch.rows);
    }
    /// Transitions in D_model.
    pub fn model_buffer_len(&self) -> usize {
        self.d_model.len()
    }
    /// One SAC update on a batch of `real_ratio` D_env and the rest D_model.
    pub fn update(&mut self) -> Result<(), TrainError> {
        sample_mixed(
            &self.d_env,
            &self.d_model,
            self.real_ratio,
            &mut self.sample_rng,
            &mut self.batch,
        );
        self.last_stats = self.sac.update(&self.batch, &mut self.update_rng);
        let s = &self.last_stats;
        let losses = [("critic loss", s.critic_loss), ("actor loss", s.actor_loss)];
        match losses.into_iter().find(|(_, v)| !v.is_finite()) {
            Some((quantity, value)) => Err(TrainError::NonFinite {
                role: "learner",
                quantity: quantity.into(),
                value: value as f64,
                at: format!("SAC update {}", self.sac.updates()),
            }),
            None => Ok(()),
        }
    }
    /// Mark one learner step complete: env step t consumed (with its G updates after warm-up).
    pub fn finish_step(&mut self) {
        self.steps += 1;
    }
    /// The current policy, versioned by completed learner steps.
    pub fn policy(&self) -> PolicySnapshot {
        PolicySnapshot {
            version: self.steps,
            params: self.sac.actor_params.clone(),
        }
    }
    /// The SAC agent.
    pub fn sac(&self) -> &Sac {
        &self.sac
    }
    /// The SAC agent (mutable, for its TD targets' scratch) with D_env and D_model.
    pub fn sac_and_buffers(&mut self) -> (&mut Sac, &ReplayBuffer, &ReplayBuffer) {
        (&mut self.sac, &self.d_env, &self.d_model)
    }
    /// Learner steps completed (= the version of [`LearnerRole::policy`]).
    pub fn steps(&self) -> u64 {
        self.steps
    }
    /// The role's state (for checkpoints). D_model's rows are left out of it when the branches
    /// that made them are known: then they come second, and the state's D_model holds only
    /// the buffer's positions ([`crate::d_model_branches`]).
    pub fn checkpoint(&self) -> (LearnerState, Option<DModelBranches>) {
        let branches = self.branch_log.covering(self.d_model.len(), &self.d_env);
        let state = LearnerState {
            sac: self.sac.checkpoint(),
            d_env: self.d_env.snapshot(),
            d_model: match branches {
                Some(_) => self.d_model.positions(),
                None => self.d_model.snapshot(),
            },
            sample_rng: self.sample_rng.clone(),
            update_rng: self.update_rng.clone(),
            steps: self.steps,
            last_stats: self.last_stats,
            rollout_length: self.rollout_length,
        };
        (state, branches)
    }
    /// Continue from [`LearnerRole::checkpoint`]; D_model's `branches`, when the checkpoint
    /// has them instead of its rows, are done again with `rollout` (a rollout generator of this
    /// run; its state is left as it was).
    pub fn restore(
        &mut self,
        s: LearnerState,
        branches: Option<DModelBranches>,
        rollout: Option<&mut RolloutRole>,
    ) -> Result<(), TrainError> {
        let (o, a) = (self.d_env.obs_dim(), self.d_env.act_dim());
        self.d_env =
            ReplayBuffer::from_snapshot(&s.d_env, o, a).map_err(|e| restore_err("learner", e))?;
        (self.d_model, self.branch_log) = match (branches, rollout) {
            (None, _) => (
                ReplayBuffer::from_snapshot(&s.d_model, o, a)
                    .map_err(|e| restore_err("learner", e))?,
                BranchLog::default(),
            ),
            (Some(branches), Some(rollout)) => {
                let dims = (self.d_env.obs_dim(), self.d_env.act_dim());
                let replayed = branches.replay(dims, &s.d_model, |inputs| {
                    rollout.replay(inputs, &self.d_env)
                })?;
                tracing::info!(
                    "D_model: {} rows from its {} branches done again{}",
                    replayed.buffer.len(),
                    branches.branches.len(),
                    match replayed.differing {
                        0 => String::new(),
                        n => format!(", {n} of them with other rows than the run had"),
                    }
                );
                (replayed.buffer, BranchLog::restore(branches))
            }
            (Some(_), None) => {
                return Err(restore_err(
                    "learner",
                    "its D_model is stored as the branches that made it and no rollout \
                     generator was given to do them again",
                ))
            }
        };
        self.sac
            .restore(s.sac)
            .map_err(|e| restore_err("learner", e))?;
        self.sample_rng = s.sample_rng;
        self.update_rng = s.update_rng;
        self.steps = s.steps;
        self.last_stats = s.last_stats;
        self.rollout_length = s.rollout_length;
        Ok(())
    }
}

/// The pipeline hands each consumer its real transitions straight from shared memory.
macro_rules! real_transitions_go_to_d_env {
    ($($role:ty),*) => {$(
        impl TransitionSink for $role {
            fn push(
                &mut self,
                obs: &[f32],
                act: &[f32],
                reward: f32,
                next_obs: &[f32],
                terminated: bool,
            ) {
                self.d_env.push(obs, act, reward, next_obs, terminated)
            }
        }
    )*};
}
real_transitions_go_to_d_env!(ModelTrainerRole, RolloutRole, LearnerRole);
