//! The SAC agent and its update.
//!
//! One update is four steps, each a method below, in the paper's order: critic step, actor
//! step, temperature step, Polyak targets (done right after each critic's Adam step, in the
//! same pass over memory: it reads only the new critic parameters, which the actor step does
//! not change, and nothing reads the targets in between). The work runs on a small
//! [`WorkerPool`] (`sac.threads`), cut two ways ([`crate::shard`]): the actor's by rows, one
//! row shard per thread, whose partial gradients are added in shard order before the actor's
//! Adam step, cut into one parameter range per thread; the critics' by network, one lane per
//! critic, each with its own Adam and Polyak step. The agent draws all random noise itself in
//! stream order, so an update is a deterministic function of the parameters, the batch and the
//! random stream for a given thread count, and the critics' results do not depend on it.

use crate::actor::{ActorCache, TanhGaussianActor};
use crate::config::SacConfig;
use crate::critic::TwinCritic;
use crate::shard::{assign_min_rows, gather_action_gradients, CriticLane, Nets, RowShard};
use mbpo_core::rng::normal_f32;
use mbpo_core::{Batch, Rng};
use mbpo_nn::adam::{part_len, AdamPart};
use mbpo_nn::{Adam, AdamConfig, AdamState, WorkerPool};
use serde::{Deserialize, Serialize};

/// What one update measured (means over the batch).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SacStats {
    /// ½·MSE(Q₁, y) + ½·MSE(Q₂, y).
    pub critic_loss: f32,
    /// mean(α log π − min Q).
    pub actor_loss: f32,
    /// −mean(log α · (log π + H̄)).
    pub alpha_loss: f32,
    /// Temperature α used in this update.
    pub alpha: f32,
    /// −mean(log π), the policy entropy estimate.
    pub entropy: f32,
    /// mean(Q₁) on the batch.
    pub q_mean: f32,
}

/// Everything of a [`Sac`] that training changes: what a checkpoint stores. The architecture
/// and hyper-parameters come from the config; scratch buffers are rebuilt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SacState {
    /// Actor parameters θ_π.
    pub actor_params: Vec<f32>,
    /// Critic parameters θ_Q.
    pub critic_params: Vec<f32>,
    /// Target critic parameters θ̄_Q.
    pub target_params: Vec<f32>,
    /// log α.
    pub log_alpha: f32,
    /// The actor's Adam moments.
    pub actor_opt: AdamState,
    /// The critics' Adam moments.
    pub critic_opt: AdamState,
    /// The temperature's Adam moments.
    pub alpha_opt: AdamState,
    /// Updates performed.
    pub updates: u64,
}

/// Networks, optimisers and scratch buffers of one SAC learner.
#[derive(Debug, Clone)]
pub struct Sac {
    /// Hyper-parameters.
    pub config: SacConfig,
    /// Actor architecture.
    pub actor: TanhGaussianActor,
    /// Critic architecture.
    pub critic: TwinCritic,
    /// Actor parameters θ_π.
    pub actor_params: Vec<f32>,
    /// Critic parameters θ_Q (both critics).
    pub critic_params: Vec<f32>,
    /// Target critic parameters θ̄_Q.
    pub target_params: Vec<f32>,
    /// log α.
    pub log_alpha: f32,
    /// H̄.
    pub target_entropy: f32,
    actor_opt: Adam,
    critic_opt: Adam,
    alpha_opt: Adam,
    updates: u64,
    buf: Scratch,
}

/// The agent's stochastic policy a ~ π(·|s), computed exactly as [`crate::ActorPolicy`] computes
/// it from the same parameters (the pipeline's actors rely on that equality).
pub struct SacPolicy<'a>(&'a mut Sac);

impl mbpo_core::BatchPolicy for SacPolicy<'_> {
    fn act_batch(&mut self, obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng) {
        let _flush = mbpo_nn::FlushSubnormals::new();
        let sac = &mut *self.0;
        if batch == 1 {
            sac.act(obs, false, rng, actions);
        } else {
            let mut cache = sac.actor.cache(batch);
            sac.actor
                .sample(&sac.actor_params, obs, batch, &mut cache, Some(rng));
            let n = batch * sac.actor.act_dim();
            actions[..n].copy_from_slice(&cache.action[..n]);
        }
    }
}

/// Buffers and threads reused by every update so the update allocates nothing. Holds no
/// learning state (a checkpoint does not need it).
#[derive(Debug, Clone)]
struct Scratch {
    pool: WorkerPool,
    /// The actor's row shards, one per thread.
    shards: Vec<RowShard>,
    /// The critics' lanes: Q₁, Q₂.
    lanes: [CriticLane; 2],
    /// ε for a' ~ π(·|s') and for a ~ π(·|s) (`B x A` each), drawn in this order.
    noise_next: Vec<f32>,
    noise: Vec<f32>,
    /// a' ~ π(·|s') and log π(a'|s') of the whole batch, gathered from the shards.
    next_action: Vec<f32>,
    next_log_prob: Vec<f32>,
    /// a ~ π(·|s) and log π(a|s) of the whole batch, gathered from the shards.
    pi_action: Vec<f32>,
    pi_log_prob: Vec<f32>,
    /// TD targets of the whole batch ([`Sac::td_targets`]).
    y: Vec<f32>,
    /// ∂L_π/∂a of the whole batch, gathered from the lanes (`B x A`).
    d_act: Vec<f32>,
    act_cache: ActorCache,
}

impl Sac {
    /// A freshly initialised agent; all initial parameters are drawn from `rng`.
    pub fn new(obs_dim: usize, act_dim: usize, config: SacConfig, rng: &mut Rng) -> Self {
        let actor = TanhGaussianActor::new(
            obs_dim,
            act_dim,
            &config.hidden,
            config.log_std_min,
            config.log_std_max,
        );
        let critic = TwinCritic::new(obs_dim, act_dim, &config.hidden, config.critic_layer_norm);
        let mut actor_params = vec![0.0; actor.num_params()];
        actor.init(&mut actor_params, rng);
        let mut critic_params = vec![0.0; critic.num_params()];
        critic.init(&mut critic_params, rng);
        let b = config.batch_size;
        // Shard i holds rows [i·B/T, (i+1)·B/T).
        let threads = config.threads.clamp(1, b.max(1));
        let shards = (0..threads)
            .map(|i| RowShard::new(&actor, i * b / threads..(i + 1) * b / threads))
            .collect();
        let buf = Scratch {
            pool: WorkerPool::new(threads),
            shards,
            lanes: [
                CriticLane::new(&critic, 0, b),
                CriticLane::new(&critic, 1, b),
            ],
            noise_next: vec![0.0; b * act_dim],
            noise: vec![0.0; b * act_dim],
            next_action: vec![0.0; b * act_dim],
            next_log_prob: vec![0.0; b],
            pi_action: vec![0.0; b * act_dim],
            pi_log_prob: vec![0.0; b],
            y: vec![0.0; b],
            d_act: vec![0.0; b * act_dim],
            act_cache: actor.cache(1),
        };
        Self {
            target_entropy: config.target_entropy.unwrap_or(-(act_dim as f32)),
            log_alpha: config.init_alpha.ln(),
            actor_opt: Adam::new(actor.num_params(), AdamConfig::with_lr(config.actor_lr)),
            critic_opt: Adam::new(critic.num_params(), AdamConfig::with_lr(config.critic_lr)),
            alpha_opt: Adam::new(1, AdamConfig::with_lr(config.alpha_lr)),
            target_params: critic_params.clone(),
            actor_params,
            critic_params,
            actor,
            critic,
            config,
            updates: 0,
            buf,
        }
    }

    /// The training state (allocates; for checkpoints).
    pub fn checkpoint(&self) -> SacState {
        SacState {
            actor_params: self.actor_params.clone(),
            critic_params: self.critic_params.clone(),
            target_params: self.target_params.clone(),
            log_alpha: self.log_alpha,
            actor_opt: self.actor_opt.state().clone(),
            critic_opt: self.critic_opt.state().clone(),
            alpha_opt: self.alpha_opt.state().clone(),
            updates: self.updates,
        }
    }

    /// Continue from a [`Sac::checkpoint`] of an agent with the same architecture; a state of
    /// another architecture is an error naming the vector that does not fit.
    pub fn restore(&mut self, state: SacState) -> Result<(), String> {
        let fits = |name: &str, found: usize, expected: usize| {
            if found == expected {
                Ok(())
            } else {
                Err(format!(
                    "SAC checkpoint: {name} has {found} values, this architecture needs {expected}"
                ))
            }
        };
        let (na, nc) = (self.actor_params.len(), self.critic_params.len());
        fits("actor parameters", state.actor_params.len(), na)?;
        fits("critic parameters", state.critic_params.len(), nc)?;
        fits("target critic parameters", state.target_params.len(), nc)?;
        for (name, opt, n) in [
            ("actor Adam", &state.actor_opt, na),
            ("critic Adam", &state.critic_opt, nc),
            ("temperature Adam", &state.alpha_opt, 1),
        ] {
            fits(name, opt.m.len(), n)?;
            fits(name, opt.v.len(), n)?;
        }
        self.actor_params = state.actor_params;
        self.critic_params = state.critic_params;
        self.target_params = state.target_params;
        self.log_alpha = state.log_alpha;
        self.actor_opt.set_state(state.actor_opt);
        self.critic_opt.set_state(state.critic_opt);
        self.alpha_opt.set_state(state.alpha_opt);
        self.updates = state.updates;
        Ok(())
    }

    /// Updates performed.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Threads an update runs on (`sac.threads`, at most the batch size).
    pub fn threads(&self) -> usize {
        self.buf.pool.threads()
    }

    /// Current temperature α.
    pub fn alpha(&self) -> f32 {
        self.log_alpha.exp()
    }

    /// Action for one observation: sampled, or tanh μ when `deterministic` (evaluation).
    pub fn act(&mut self, obs: &[f32], deterministic: bool, rng: &mut Rng, action: &mut [f32]) {
        // Flushed as in `ActorPolicy`, whose actions these must equal bit for bit.
        let _flush = mbpo_nn::FlushSubnormals::new();
        let rng = if deterministic { None } else { Some(rng) };
        self.actor
            .sample(&self.actor_params, obs, 1, &mut self.buf.act_cache, rng);
        action.copy_from_slice(&self.buf.act_cache.action[..self.actor.act_dim()]);
    }

    /// The current stochastic policy as a [`BatchPolicy`] (borrowing the agent's parameters).
    pub fn policy(&mut self) -> SacPolicy<'_> {
        SacPolicy(self)
    }

    /// One SAC update on `batch` (any source: real, model, or mixed).
    pub fn update(&mut self, batch: &Batch, rng: &mut Rng) -> SacStats {
        // Subnormals flushed, as every job of the pool (mbpo_nn::subnormal says why).
        let _flush = mbpo_nn::FlushSubnormals::new();
        assert_eq!(
            batch.len, self.config.batch_size,
            "batch size differs from the config"
        );
        let alpha = self.alpha();
        // The noise of a' ~ π(·|s') and then of a ~ π(·|s): the stream order of drawing them
        // where they are used, one after the other. Both samples use the current actor, so
        // they are drawn together, before the critic step.
        fill_normal(&mut self.buf.noise_next, rng);
        fill_normal(&mut self.buf.noise, rng);
        self.sample_policy(batch, alpha, true);
        let critic_loss = self.update_critics(batch, alpha);
        let (actor_loss, mean_log_prob, q_mean) = self.update_actor(batch, alpha);
        let alpha_loss = self.update_temperature(mean_log_prob);
        self.updates += 1;
        SacStats {
            critic_loss,
            actor_loss,
            alpha_loss,
            alpha,
            entropy: -mean_log_prob,
            q_mean,
        }
    }

    /// a' ~ π(·|s') with the noise in `buf.noise_next` and, when `with_pi`, a ~ π(·|s) with
    /// the noise in `buf.noise`, on the row shards at once; gathered into the whole-batch
    /// buffers.
    fn sample_policy(&mut self, batch: &Batch, alpha: f32, with_pi: bool) {
        let n = nets_of!(self, alpha);
        let buf = &mut self.buf;
        let (noise_next, noise) = (&buf.noise_next, with_pi.then_some(&buf.noise[..]));
        buf.pool.for_each_mut(&mut buf.shards, |_, s| {
            s.sample(&n, batch, noise_next, noise)
        });
        let a = self.actor.act_dim();
        for s in &buf.shards {
            let (rows, r) = (s.rows.clone(), s.rows.len());
            let acts = rows.start * a..rows.end * a;
            buf.next_action[acts.clone()].copy_from_slice(&s.next_pi.action[..r * a]);
            buf.next_log_prob[rows.clone()].copy_from_slice(&s.next_pi.log_prob[..r]);
            if with_pi {
                buf.pi_action[acts].copy_from_slice(&s.pi.action[..r * a]);
                buf.pi_log_prob[rows].copy_from_slice(&s.pi.log_prob[..r]);
            }
        }
    }

    /// Soft TD targets y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')) into `buf.y`,
    /// for the a' of the last [`Sac::sample_policy`]; each lane computes its Q̄_e. `d` is
    /// `terminated`: a time-limit truncation is not terminal, so such rows bootstrap.
    fn targets_of_samples(&mut self, batch: &Batch, alpha: f32) {
        let n = nets_of!(self, alpha);
        let Scratch {
            pool,
            lanes,
            next_action,
            next_log_prob,
            y,
            ..
        } = &mut self.buf;
        let (critic, target) = (&self.critic, &self.target_params);
        for_each_lane(pool, lanes, |lane| {
            let target_e = &target[critic.member_range(lane.e)];
            lane.target_values(&n, target_e, batch, next_action)
        });
        let (q1t, q2t) = (lanes[0].target_q(&n), lanes[1].target_q(&n));
        let (reward, done) = (&batch.reward, &batch.terminated);
        for i in 0..batch.len {
            let soft_v = q1t[i].min(q2t[i]) - alpha * next_log_prob[i];
            y[i] = reward[i] + n.gamma * (1.0 - done[i]) * soft_v;
        }
    }

    /// Soft TD targets y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')), a' ~ π(·|s'),
    /// for every row of `batch`. `d` is `terminated`: a time-limit truncation is not terminal,
    /// so such rows bootstrap.
    pub fn td_targets(&mut self, batch: &Batch, alpha: f32, rng: &mut Rng) -> &[f32] {
        let _flush = mbpo_nn::FlushSubnormals::new();
        fill_normal(&mut self.buf.noise_next, rng);
        self.sample_policy(batch, alpha, false);
        self.targets_of_samples(batch, alpha);
        &self.buf.y[..batch.len]
    }

    /// Critic step: y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')) with the a' of
    /// the last [`Sac::sample_policy`], then descend ½·MSE(Q₁, y) + ½·MSE(Q₂, y), each critic
    /// by its own lane: its gradient, its Adam step, its Polyak step θ̄_e ← (1 − τ)·θ̄_e + τ·θ_e
    /// and, with the new θ_e, its values on the policy's actions for the actor step.
    /// Bootstrapping stops only at termination. Returns the loss.
    fn update_critics(&mut self, batch: &Batch, alpha: f32) -> f32 {
        self.targets_of_samples(batch, alpha);
        let n = nets_of!(self, alpha);
        let Scratch {
            pool,
            lanes,
            y,
            pi_action,
            ..
        } = &mut self.buf;
        let p = self.critic.mlp().num_params();
        let tau = self.config.tau;
        // Adam's two halves are exactly the two critics (`TwinCritic` stores Q₁ then Q₂).
        let mut steps: [Option<CriticStep>; 2] = Default::default();
        let parts = self.critic_opt.step_parts(&mut self.critic_params, 2);
        for (((slot, lane), adam), target) in steps
            .iter_mut()
            .zip(lanes.iter_mut())
            .zip(parts)
            .zip(self.target_params.chunks_mut(p))
        {
            debug_assert_eq!(adam.range(), self.critic.member_range(lane.e));
            *slot = Some(CriticStep { lane, adam, target });
        }
        let (y, pi_action) = (&y[..], &pi_action[..]);
        for_each_lane(pool, &mut steps, |step| {
            let Some(CriticStep { lane, adam, target }) = step.take() else {
                return;
            };
            lane.gradient(&n, adam.params(), batch, y);
            let theta = lane.step(adam, target, tau);
            lane.policy_values(&n, theta, batch, pi_action);
        });
        critic_loss(lanes, y, batch.len, self.config.batch_size)
    }

    /// Actor step: descend mean(α log π(a|s) − min_e Q_e(s, a)) with the a ~ π(·|s) of the
    /// last [`Sac::sample_policy`] (reparameterised) and the lanes' Q_e(s, a). Returns (loss,
    /// mean log π, mean Q₁).
    fn update_actor(&mut self, batch: &Batch, alpha: f32) -> (f32, f32, f32) {
        let out = self.actor_gradient_of_samples(batch, alpha);
        let Sac {
            buf,
            actor_opt,
            actor_params,
            ..
        } = self;
        actor_step(buf, actor_opt, actor_params);
        out
    }

    /// The actor loss mean(α log π(a|s) − min_e Q_e(s, a)) and the shards' partial
    /// gradients, from the samples of the last [`Sac::sample_policy`] and the lanes' last
    /// [`CriticLane::policy_values`]. Returns (loss, mean log π, mean Q₁).
    fn actor_gradient_of_samples(&mut self, batch: &Batch, alpha: f32) -> (f32, f32, f32) {
        let n = nets_of!(self, alpha);
        let inv_b = 1.0 / self.config.batch_size as f32;
        let buf = &mut self.buf;
        let (mut loss, mut log_prob, mut q1_sum) = (0.0f32, 0.0f32, 0.0f32);
        {
            let (q1, q2) = (buf.lanes[0].policy_q(&n), buf.lanes[1].policy_q(&n));
            for i in 0..batch.len {
                let lp = buf.pi_log_prob[i];
                loss += (alpha * lp - q1[i].min(q2[i])) * inv_b;
                log_prob += lp * inv_b;
                q1_sum += q1[i] * inv_b;
            }
        }
        // ∂L/∂a through min(Q₁, Q₂): each row through its minimum's critic, on its lane.
        assign_min_rows(&mut buf.lanes, &self.critic, -inv_b);
        let (critic, theta) = (&self.critic, &self.critic_params);
        for_each_lane(&mut buf.pool, &mut buf.lanes, |lane| {
            lane.action_gradient(&n, &theta[critic.member_range(lane.e)])
        });
        gather_action_gradients(&buf.lanes, self.actor.act_dim(), &mut buf.d_act);
        let d_act = &buf.d_act;
        buf.pool
            .for_each_mut(&mut buf.shards, |_, s| s.actor_gradient(&n, batch, d_act));
        (loss, log_prob, q1_sum)
    }

    /// Temperature step: descend −mean(log α · (log π + H̄)); ∂/∂log α = −(mean log π + H̄).
    fn update_temperature(&mut self, mean_log_prob: f32) -> f32 {
        let gap = mean_log_prob + self.target_entropy;
        let loss = -self.log_alpha * gap;
        if self.config.autotune_alpha {
            let mut p = [self.log_alpha];
            self.alpha_opt.step(&mut p, &[-gap]);
            self.log_alpha = p[0];
        }
        loss
    }
}

/// [`nets`] of a [`Sac`]'s fields (a macro, so that each field is borrowed on its own and the
/// scratch buffers stay free to borrow mutably).
macro_rules! nets_of {
    ($sac:expr, $alpha:expr) => {
        nets(
            &$sac.actor,
            &$sac.critic,
            &$sac.actor_params,
            &$sac.config,
            $alpha,
        )
    };
}
use nets_of;

/// What the threads of an update read: architectures, the actor's parameters, constants.
fn nets<'a>(
    actor: &'a TanhGaussianActor,
    critic: &'a TwinCritic,
    actor_params: &'a [f32],
    config: &SacConfig,
    alpha: f32,
) -> Nets<'a> {
    Nets {
        actor,
        critic,
        actor_params,
        gamma: config.gamma,
        alpha,
        batch_size: config.batch_size,
    }
}

/// One critic's step as its lane runs it: the lane, the critic's piece of Adam and its target
/// parameters.
struct CriticStep<'a> {
    lane: &'a mut CriticLane,
    adam: AdamPart<'a>,
    target: &'a mut [f32],
}

/// `f` on each of the two critic lanes: each on its own thread when there are two or more,
/// else one after the other on the caller.
fn for_each_lane<T: Send>(pool: &mut WorkerPool, lanes: &mut [T; 2], f: impl Fn(&mut T) + Sync) {
    if pool.threads() >= lanes.len() {
        pool.for_each_mut(lanes, |_, lane| f(lane));
    } else {
        lanes.iter_mut().for_each(f);
    }
}

/// ½·MSE(Q₁, y) + ½·MSE(Q₂, y) over the first `rows` rows from the lanes' last
/// [`CriticLane::gradient`], summed critic by critic and row by row.
fn critic_loss(lanes: &[CriticLane; 2], y: &[f32], rows: usize, batch_size: usize) -> f32 {
    let b = batch_size as f32;
    let mut loss = 0.0f32;
    for lane in lanes {
        for i in 0..rows {
            let err = lane.q_data[i] - y[i];
            loss += 0.5 * err * err / b;
        }
    }
    loss
}

/// Standard normals from `rng` into `out`, in order.
fn fill_normal(out: &mut [f32], rng: &mut Rng) {
    out.iter_mut().for_each(|v| *v = normal_f32(rng));
}

/// The actor's optimiser step is cut into at most this many parameter ranges (one per thread).
const MAX_PARTS: usize = 16;

/// One thread's range of the actor's optimiser step: the Adam piece and the first shard's
/// partial gradient of the range (which becomes the sum).
struct StepPart<'a> {
    adam: AdamPart<'a>,
    grads: &'a mut [f32],
}

/// Adam on the actor's `params` with the sum of the shards' partial gradients, cut into one
/// parameter range per thread; each range adds the shards' partial gradients in shard order
/// and takes its Adam step.
fn actor_step(buf: &mut Scratch, opt: &mut Adam, params: &mut [f32]) {
    let parts = buf.pool.threads().min(MAX_PARTS);
    let len = part_len(params.len(), parts);
    let (first, rest) = buf.shards.split_at_mut(1);
    let mut items: [Option<StepPart>; MAX_PARTS] = Default::default();
    let pieces = opt
        .step_parts(params, parts)
        .zip(first[0].actor_grads.chunks_mut(len));
    for (slot, (adam, grads)) in items.iter_mut().zip(pieces) {
        *slot = Some(StepPart { adam, grads });
    }
    let rest: &[RowShard] = rest;
    buf.pool.for_each_mut(&mut items[..parts], |_, item| {
        let Some(part) = item.take() else { return };
        let range = part.adam.range();
        for shard in rest {
            part.grads
                .iter_mut()
                .zip(&shard.actor_grads[range.clone()])
                .for_each(|(g, &s)| *g += s);
        }
        part.adam.apply(part.grads);
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::{normal_f32, stream};

    fn small_sac(seed: u64) -> Sac {
        sac_with_threads(seed, 1)
    }

    fn sac_with_threads(seed: u64, threads: usize) -> Sac {
        sac_with(seed, threads, false)
    }

    /// A small SAC, its critics LayerNormed when `layer_norm`.
    fn sac_with(seed: u64, threads: usize, layer_norm: bool) -> Sac {
        let config = SacConfig {
            batch_size: 6,
            hidden: vec![8, 8],
            threads,
            critic_layer_norm: layer_norm,
            ..SacConfig::default()
        };
        Sac::new(3, 2, config, &mut stream(seed, "test.init", 0))
    }

    /// Which gradient a test reads.
    #[derive(Clone, Copy)]
    enum Grads {
        Critic,
        Actor,
    }

    /// The whole gradient of `kind` after [`actor_loss`] or [`critic_loss`]: the actor
    /// shards' partial gradients added up, or the critic lanes' gradients one after the other.
    fn total(sac: &Sac, kind: Grads) -> Vec<f32> {
        match kind {
            Grads::Actor => {
                let mut sum = vec![0.0f32; sac.actor_params.len()];
                for s in &sac.buf.shards {
                    sum.iter_mut()
                        .zip(&s.actor_grads)
                        .for_each(|(t, &g)| *t += g);
                }
                sum
            }
            Grads::Critic => sac.buf.lanes.iter().flat_map(|l| l.grads.clone()).collect(),
        }
    }

    /// The actor loss and gradient with the noise of `rng` (a pure function of θ_π for a seed).
    fn actor_loss(sac: &mut Sac, batch: &Batch, alpha: f32, rng: &mut Rng) -> f32 {
        fill_normal(&mut sac.buf.noise, rng);
        sac.sample_policy(batch, alpha, true);
        let n = nets_of!(sac, alpha);
        for lane in &mut sac.buf.lanes {
            let theta = &sac.critic_params[sac.critic.member_range(lane.e)];
            lane.policy_values(&n, theta, batch, &sac.buf.pi_action);
        }
        sac.actor_gradient_of_samples(batch, alpha).0
    }

    /// The critic loss and gradient with the noise of `rng` (a pure function of θ_Q).
    fn critic_loss(sac: &mut Sac, batch: &Batch, alpha: f32, rng: &mut Rng) -> f32 {
        fill_normal(&mut sac.buf.noise_next, rng);
        sac.sample_policy(batch, alpha, false);
        sac.targets_of_samples(batch, alpha);
        let n = nets_of!(sac, alpha);
        for lane in &mut sac.buf.lanes {
            let theta = &sac.critic_params[sac.critic.member_range(lane.e)];
            lane.gradient(&n, theta, batch, &sac.buf.y);
        }
        super::critic_loss(&sac.buf.lanes, &sac.buf.y, batch.len, sac.config.batch_size)
    }

    /// Central differences of `loss` over every parameter against the analytic gradient.
    fn check_gradient(
        sac: &Sac,
        analytic: &[f32],
        params: fn(&mut Sac) -> &mut Vec<f32>,
        loss: &dyn Fn(&mut Sac) -> f32,
    ) {
        let eps = 2e-3f32;
        let scale = analytic.iter().fold(0.0f32, |m, g| m.max(g.abs())) as f64;
        assert!(scale > 0.0);
        for i in 0..analytic.len() {
            let eval = |delta: f32| {
                let mut s = sac.clone();
                params(&mut s)[i] += delta;
                loss(&mut s) as f64
            };
            let numeric = (eval(eps) - eval(-eps)) / (2.0 * eps as f64);
            let err = (analytic[i] as f64 - numeric).abs() / (0.05 * scale + numeric.abs());
            assert!(
                err < 3e-2,
                "param {i}: analytic {} numeric {numeric}",
                analytic[i]
            );
        }
    }

    fn random_batch(len: usize, seed: u64) -> Batch {
        let mut g = stream(seed, "test.batch", 0);
        let mut b = Batch::new(3, 2, len);
        for v in b.obs.iter_mut().chain(&mut b.next_obs).chain(&mut b.reward) {
            *v = normal_f32(&mut g);
        }
        for v in b.act.iter_mut() {
            *v = normal_f32(&mut g).tanh();
        }
        b
    }

    #[test]
    fn actor_loss_gradient_through_the_critic_matches_finite_differences() {
        // Two threads: the shards' partial gradients must add up to the whole gradient. The
        // critics' LayerNorm is in the path: ∂Q/∂a goes through it.
        for (threads, layer_norm) in [(1, false), (2, false), (1, true), (2, true)] {
            let mut sac = sac_with(1, threads, layer_norm);
            let batch = random_batch(6, 2);
            let alpha = 0.3;
            // Same ε draws in every evaluation: the loss is a deterministic function of θ_π.
            let loss = |s: &mut Sac| actor_loss(s, &batch, alpha, &mut stream(0, "eps", 0));
            assert!(loss(&mut sac).is_finite());
            let analytic = total(&sac, Grads::Actor);
            check_gradient(&sac, &analytic, |s| &mut s.actor_params, &loss);
        }
    }

    #[test]
    fn critic_loss_gradient_matches_finite_differences() {
        for (threads, layer_norm) in [(1, false), (2, false), (1, true), (2, true)] {
            let mut sac = sac_with(2, threads, layer_norm);
            assert_eq!(sac.critic.mlp().has_layer_norm(), layer_norm);
            let batch = random_batch(6, 3);
            let loss = |s: &mut Sac| critic_loss(s, &batch, 0.2, &mut stream(0, "eps", 1));
            assert!(loss(&mut sac) > 0.0);
            let analytic = total(&sac, Grads::Critic);
            check_gradient(&sac, &analytic, |s| &mut s.critic_params, &loss);
        }
    }

    #[test]
    fn two_threads_compute_the_one_thread_update_up_to_rounding() {
        for layer_norm in [false, true] {
            one_and_two_threads_up_to_rounding(layer_norm);
        }
    }

    fn one_and_two_threads_up_to_rounding(layer_norm: bool) {
        let sac_with_threads = |seed, threads| sac_with(seed, threads, layer_norm);
        let batch = random_batch(6, 5);
        let (mut one, mut two) = (sac_with_threads(4, 1), sac_with_threads(4, 2));
        assert_eq!((one.threads(), two.threads()), (1, 2));
        let a = one.update(&batch, &mut stream(1, "upd", 0));
        let b = two.update(&batch, &mut stream(1, "upd", 0));
        let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * (1.0 + x.abs());
        for (x, y) in [
            (a.critic_loss, b.critic_loss),
            (a.actor_loss, b.actor_loss),
            (a.entropy, b.entropy),
            (a.q_mean, b.q_mean),
        ] {
            assert!(close(x, y), "{a:?} vs {b:?}");
        }
        // The gradients themselves, before Adam's division by √v amplifies rounding in tiny ones.
        let (mut one, mut two) = (sac_with_threads(4, 1), sac_with_threads(4, 2));
        for (x, y) in [
            (
                critic_loss(&mut one, &batch, 0.2, &mut stream(2, "g", 0)),
                critic_loss(&mut two, &batch, 0.2, &mut stream(2, "g", 0)),
            ),
            (
                actor_loss(&mut one, &batch, 0.2, &mut stream(3, "g", 0)),
                actor_loss(&mut two, &batch, 0.2, &mut stream(3, "g", 0)),
            ),
        ] {
            assert!(close(x, y), "{x} vs {y}");
        }
        for kind in [Grads::Critic, Grads::Actor] {
            let (a, b) = (total(&one, kind), total(&two, kind));
            let scale = a.iter().fold(0.0f32, |m, g| m.max(g.abs()));
            for (x, y) in a.iter().zip(b.iter()) {
                assert!((x - y).abs() <= 1e-5 * scale, "{x} vs {y}");
            }
        }
    }

    /// `rows` transitions of 11-dim observations and 3-dim actions: standard normal
    /// observations and rewards, tanh-squashed normal actions, row 5 terminal.
    fn normal_batch(rows: usize) -> Batch {
        let mut g = stream(6, "test.batch", 0);
        let mut batch = Batch::new(11, 3, rows);
        for v in batch
            .obs
            .iter_mut()
            .chain(&mut batch.next_obs)
            .chain(&mut batch.reward)
        {
            *v = normal_f32(&mut g);
        }
        for v in batch.act.iter_mut() {
            *v = normal_f32(&mut g).tanh();
        }
        batch.terminated[5] = 1.0;
        batch
    }

    #[test]
    fn the_critic_step_gives_the_same_bits_on_any_thread_count() {
        // Each critic is one lane over all rows whatever the thread count, and the actor's
        // samples are per row: so after one update the critics and their targets must be the
        // one-thread bits on 2 and 3 threads (the actor's gradient is a sum over row shards
        // and may differ in rounding). Sizes where the products take the blocked GEMM paths.
        let config = |threads, critic_layer_norm| SacConfig {
            batch_size: 64,
            hidden: vec![96, 96],
            threads,
            critic_layer_norm,
            ..SacConfig::default()
        };
        let batch = normal_batch(64);
        // With LayerNormed critics the actor's gradient sums differently rounded shards too,
        // and one of its 11,046 parameters after Adam's first step (which divides a gradient
        // by its own magnitude, so a tiny one's rounding becomes a step's) differs by 1e-5 on 3
        // threads: its gradients are compared to rounding instead, scaled, in
        // `two_threads_compute_the_one_thread_update_up_to_rounding`.
        critic_step_bits_on_thread_counts(&|t| config(t, false), &batch, true);
        critic_step_bits_on_thread_counts(&|t| config(t, true), &batch, false);
    }

    /// One update of SAC of `config(threads)` on 1, 2 and 3 threads: the critics the same bits,
    /// and the actor's parameters within 1e-6 when `actor_close`.
    fn critic_step_bits_on_thread_counts(
        config: &dyn Fn(usize) -> SacConfig,
        batch: &Batch,
        actor_close: bool,
    ) {
        let run = |threads| {
            let mut sac = Sac::new(11, 3, config(threads), &mut stream(7, "test.init", 0));
            let stats = sac.update(batch, &mut stream(8, "upd", 0));
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (
                bits(&sac.critic_params),
                bits(&sac.target_params),
                stats.critic_loss.to_bits(),
                bits(&sac.actor_params),
            )
        };
        let one = run(1);
        for threads in [2, 3] {
            let many = run(threads);
            assert!(
                one.0 == many.0,
                "critic parameters differ on {threads} threads"
            );
            assert!(
                one.1 == many.1,
                "target parameters differ on {threads} threads"
            );
            assert_eq!(one.2, many.2, "critic loss differs on {threads} threads");
            // The actor did move, and the same way up to rounding.
            let close = one
                .3
                .iter()
                .zip(&many.3)
                .all(|(&x, &y)| (f32::from_bits(x) - f32::from_bits(y)).abs() <= 1e-6);
            assert!(
                close || !actor_close,
                "actor parameters differ beyond rounding on {threads} threads"
            );
        }
    }

    #[test]
    fn an_update_gives_the_same_bits_on_every_simd_level() {
        // Activations, Adam and the tanh-Gaussian head run through the widest instruction set
        // the CPU has; the bits must not depend on it (a run resumed on another CPU goes on
        // the same). Odd widths leave tails in every vector width.
        use mbpo_nn::simd::{cap_simd_level, SimdLevel};
        let config = SacConfig {
            batch_size: 37,
            hidden: vec![45, 45],
            ..SacConfig::default()
        };
        let batch = normal_batch(37);
        let run = |level| {
            cap_simd_level(level);
            let mut sac = Sac::new(11, 3, config.clone(), &mut stream(7, "test.init", 0));
            let mut rng = stream(8, "upd", 0);
            let mut losses = Vec::new();
            for _ in 0..3 {
                let stats = sac.update(&batch, &mut rng);
                losses.extend([stats.critic_loss, stats.actor_loss, stats.alpha].map(f32::to_bits));
            }
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (
                bits(&sac.critic_params),
                bits(&sac.target_params),
                bits(&sac.actor_params),
                losses,
            )
        };
        let levels: Vec<SimdLevel> = SimdLevel::ALL
            .into_iter()
            .filter(|l| l.supported())
            .collect();
        let results: Vec<_> = levels.iter().map(|&l| run(l)).collect();
        cap_simd_level(SimdLevel::Avx512);
        for (level, r) in levels.iter().zip(&results) {
            assert!(
                *r == results[0],
                "{} differs from the baseline",
                level.name()
            );
        }
    }

    #[test]
    fn td_target_bootstraps_through_truncation_and_stops_at_termination() {
        let mut sac = small_sac(3);
        let mut batch = random_batch(6, 4);
        batch.terminated = vec![1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let alpha = 0.2;
        let y = sac
            .td_targets(&batch, alpha, &mut stream(0, "td", 0))
            .to_vec();
        // Recompute by hand from the public pieces with the same noise.
        let actor = sac.actor.clone();
        let mut cache = actor.cache(6);
        actor.sample(
            &sac.actor_params,
            &batch.next_obs,
            6,
            &mut cache,
            Some(&mut stream(0, "td", 0)),
        );
        let mut qc = sac.critic.cache(6);
        sac.critic.forward(
            &sac.target_params,
            &batch.next_obs,
            &cache.action,
            6,
            &mut qc,
        );
        for r in 0..6 {
            let v =
                sac.critic.q(&qc, 0)[r].min(sac.critic.q(&qc, 1)[r]) - alpha * cache.log_prob[r];
            let want = if batch.terminated[r] == 1.0 {
                batch.reward[r]
            } else {
                batch.reward[r] + 0.99 * v
            };
            assert!((y[r] - want).abs() < 1e-6, "row {r}: {} vs {want}", y[r]);
        }
        assert_eq!(y[0], batch.reward[0], "terminated row is exactly r");
        assert_ne!(
            y[1], batch.reward[1],
            "a truncated (non-terminal) row bootstraps"
        );
    }

    #[test]
    fn temperature_rises_when_entropy_is_below_target_and_falls_above() {
        let mut sac = small_sac(5);
        sac.target_entropy = -2.0;
        let before = sac.log_alpha;
        // mean log π = 3 → entropy −3 < H̄ = −2: α must grow.
        sac.update_temperature(3.0);
        assert!(sac.log_alpha > before);
        let mid = sac.log_alpha;
        // mean log π = −5 → entropy 5 > H̄: α must shrink.
        sac.update_temperature(-5.0);
        assert!(sac.log_alpha < mid);
    }

    #[test]
    fn actor_policy_with_copied_params_acts_bit_identically() {
        // The pipeline's actors hold a copy of the learner's parameters; their actions must be
        // the very bits the single-process agent would produce.
        use mbpo_core::BatchPolicy;
        let mut sac = small_sac(11);
        let mut copy = crate::ActorPolicy::new(sac.actor.clone(), sac.actor_params.clone(), false);
        let obs = [0.3f32, -1.2, 0.7];
        let (mut a, mut b) = ([0.0f32; 2], [0.0f32; 2]);
        for i in 0..10 {
            sac.policy()
                .act_batch(&obs, 1, &mut a, &mut stream(i, "p", 0));
            copy.act_batch(&obs, 1, &mut b, &mut stream(i, "p", 0));
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
        }
    }

    #[test]
    fn update_is_deterministic_given_the_stream() {
        let batch = random_batch(6, 7);
        for threads in [1, 2] {
            let run = || {
                let mut sac = sac_with_threads(8, threads);
                let mut rng = stream(9, "upd", 0);
                for _ in 0..5 {
                    sac.update(&batch, &mut rng);
                }
                (
                    sac.actor_params,
                    sac.critic_params,
                    sac.target_params,
                    sac.log_alpha,
                )
            };
            assert_eq!(run(), run());
        }
    }

    #[test]
    fn restored_checkpoint_continues_bit_identically() {
        for layer_norm in [false, true] {
            restore_continues_bit_identically(layer_norm);
        }
    }

    fn restore_continues_bit_identically(layer_norm: bool) {
        let small_sac = |seed| sac_with(seed, 1, layer_norm);
        let batch = random_batch(6, 10);
        let mut rng = stream(11, "upd", 0);
        let mut original = small_sac(12);
        for _ in 0..3 {
            original.update(&batch, &mut rng);
        }
        // Through bytes, as a checkpoint file carries it.
        let bytes =
            bincode::serde::encode_to_vec(original.checkpoint(), bincode::config::standard())
                .unwrap();
        let (state, _): (SacState, usize) =
            bincode::serde::decode_from_slice(&bytes, bincode::config::standard()).unwrap();
        let mut restored = small_sac(99); // other initial weights: all must be overwritten
        restored.restore(state).unwrap();
        let mut rng2 = rng.clone();
        for _ in 0..3 {
            original.update(&batch, &mut rng);
            restored.update(&batch, &mut rng2);
        }
        assert_eq!(restored.checkpoint(), original.checkpoint());
        assert_eq!(restored.updates(), 6);
    }

    #[test]
    fn checkpoint_of_another_architecture_is_rejected() {
        let other = Sac::new(
            3,
            2,
            SacConfig {
                batch_size: 6,
                hidden: vec![8, 16],
                ..SacConfig::default()
            },
            &mut stream(1, "test.init", 0),
        );
        let err = small_sac(1).restore(other.checkpoint()).unwrap_err();
        assert!(err.contains("actor parameters"), "{err}");
        // Critics with LayerNorm have γ and β the plain ones lack: refused, not misread.
        let normed = sac_with(1, 1, true);
        let err = small_sac(1).restore(normed.checkpoint()).unwrap_err();
        assert!(err.contains("critic"), "{err}");
    }
}
