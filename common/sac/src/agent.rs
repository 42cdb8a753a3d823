//! The SAC agent and its update.
//!
//! One update is four steps, each a method below, in the paper's order: critic step, actor
//! step, temperature step, Polyak targets (done right after the critic's Adam step, in the same
//! pass over memory: it reads only the new critic parameters, which the actor step does not
//! change, and nothing reads the targets in between). The per-row work of the two gradient
//! steps runs on row shards ([`crate::shard`]), one per thread of a small [`WorkerPool`]
//! (`sac.threads`); each optimiser step is cut into parameter ranges, one per thread, which add
//! the shards' partial gradients in shard order and apply Adam. The agent draws all random
//! noise itself in stream order, so an update is a deterministic function of the parameters,
//! the batch and the random stream for a given thread count.

use crate::actor::{ActorCache, TanhGaussianActor};
use crate::config::SacConfig;
use crate::critic::TwinCritic;
use crate::shard::{Grads, Nets, Shard};
use mbpo_core::rng::normal_f32;
use mbpo_core::{Batch, Rng};
use mbpo_nn::adam::{part_len, AdamPart};
use mbpo_nn::ops::polyak;
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
    /// Row shards, one per thread.
    shards: Vec<Shard>,
    /// ε for a' ~ π(·|s') and for a ~ π(·|s) (`B x A` each), drawn in this order.
    noise_next: Vec<f32>,
    noise: Vec<f32>,
    /// TD targets gathered from the shards ([`Sac::td_targets`]).
    y: Vec<f32>,
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
        let critic = TwinCritic::new(obs_dim, act_dim, &config.hidden);
        let mut actor_params = vec![0.0; actor.num_params()];
        actor.init(&mut actor_params, rng);
        let mut critic_params = vec![0.0; critic.num_params()];
        critic.init(&mut critic_params, rng);
        let b = config.batch_size;
        // Shard i holds rows [i·B/T, (i+1)·B/T).
        let threads = config.threads.clamp(1, b.max(1));
        let shards = (0..threads)
            .map(|i| Shard::new(&actor, &critic, i * b / threads..(i + 1) * b / threads))
            .collect();
        let buf = Scratch {
            pool: WorkerPool::new(threads),
            shards,
            noise_next: vec![0.0; b * act_dim],
            noise: vec![0.0; b * act_dim],
            y: vec![0.0; b],
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
        // where they are used, one after the other.
        fill_normal(&mut self.buf.noise_next, rng);
        fill_normal(&mut self.buf.noise, rng);
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

    /// Run `phase` on every shard at once, each on its own thread, with what the shards read
    /// (architectures, current parameters, constants).
    fn run_shards(&mut self, alpha: f32, phase: impl Fn(&Nets, &mut Shard) + Sync) {
        let nets = Nets {
            actor: &self.actor,
            critic: &self.critic,
            actor_params: &self.actor_params,
            critic_params: &self.critic_params,
            target_params: &self.target_params,
            gamma: self.config.gamma,
            alpha,
            batch_size: self.config.batch_size,
        };
        let Scratch { pool, shards, .. } = &mut self.buf;
        pool.for_each_mut(shards, |_, shard| phase(&nets, shard));
    }

    /// Critic step: y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')) with a' ~ π(·|s'),
    /// then descend ½·MSE(Q₁, y) + ½·MSE(Q₂, y). Bootstrapping stops only at termination.
    /// Then the Polyak step θ̄_Q ← (1 − τ)·θ̄_Q + τ·θ_Q.
    fn update_critics(&mut self, batch: &Batch, alpha: f32) -> f32 {
        let loss = self.critic_gradient(batch, alpha);
        let Sac {
            buf,
            critic_opt,
            critic_params,
            target_params,
            config,
            ..
        } = self;
        optimizer_step(
            buf,
            critic_opt,
            critic_params,
            Grads::Critic,
            Some((target_params, config.tau)),
        );
        loss
    }

    /// The critic loss ½·MSE(Q₁, y) + ½·MSE(Q₂, y) and the shards' partial gradients, with
    /// the noise of a' already in `buf.noise_next`.
    fn critic_gradient(&mut self, batch: &Batch, alpha: f32) -> f32 {
        let noise_next = std::mem::take(&mut self.buf.noise_next);
        self.run_shards(alpha, |nets, shard| {
            shard.critic_gradient(nets, batch, &noise_next)
        });
        self.buf.noise_next = noise_next;
        self.buf.shards.iter().map(|s| s.sums.critic_loss).sum()
    }

    /// Soft TD targets y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')), a' ~ π(·|s'),
    /// for every row of `batch`. `d` is `terminated`: a time-limit truncation is not terminal,
    /// so such rows bootstrap.
    pub fn td_targets(&mut self, batch: &Batch, alpha: f32, rng: &mut Rng) -> &[f32] {
        fill_normal(&mut self.buf.noise_next, rng);
        let noise_next = std::mem::take(&mut self.buf.noise_next);
        self.run_shards(alpha, |nets, shard| {
            shard.td_targets(nets, batch, &noise_next)
        });
        self.buf.noise_next = noise_next;
        let buf = &mut self.buf;
        for s in &buf.shards {
            buf.y[s.rows.clone()].copy_from_slice(&s.y[..s.rows.len()]);
        }
        &buf.y[..batch.len]
    }

    /// Actor step: descend mean(α log π(a|s) − min_e Q_e(s, a)) with a ~ π(·|s)
    /// reparameterised. Returns (loss, mean log π, mean Q₁).
    fn update_actor(&mut self, batch: &Batch, alpha: f32) -> (f32, f32, f32) {
        let out = self.actor_gradient(batch, alpha);
        let Sac {
            buf,
            actor_opt,
            actor_params,
            ..
        } = self;
        optimizer_step(buf, actor_opt, actor_params, Grads::Actor, None);
        out
    }

    /// The actor loss mean(α log π(a|s) − min_e Q_e(s, a)) and the shards' partial gradients,
    /// with the noise already in `buf.noise`.
    /// Returns (loss, mean log π, mean Q₁).
    fn actor_gradient(&mut self, batch: &Batch, alpha: f32) -> (f32, f32, f32) {
        let noise = std::mem::take(&mut self.buf.noise);
        self.run_shards(alpha, |nets, shard| {
            shard.actor_gradient(nets, batch, &noise)
        });
        self.buf.noise = noise;
        let (mut loss, mut log_prob, mut q1) = (0.0f32, 0.0f32, 0.0f32);
        for s in &self.buf.shards {
            loss += s.sums.actor_loss;
            log_prob += s.sums.log_prob;
            q1 += s.sums.q1;
        }
        (loss, log_prob, q1)
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

/// Standard normals from `rng` into `out`, in order.
fn fill_normal(out: &mut [f32], rng: &mut Rng) {
    out.iter_mut().for_each(|v| *v = normal_f32(rng));
}

/// An optimiser step is cut into at most this many parameter ranges (one per thread).
const MAX_PARTS: usize = 16;

/// One thread's range of an optimiser step: the Adam piece, the first shard's partial gradient
/// of the range (which becomes the sum), and the target parameters of the range if any.
struct StepPart<'a> {
    adam: AdamPart<'a>,
    grads: &'a mut [f32],
    target: Option<&'a mut [f32]>,
}

/// Adam on `params` with the sum of the shards' `kind` gradients, cut into one parameter range
/// per thread; each range adds the shards' partial gradients in shard order, takes its Adam
/// step and, given `(θ̄, τ)`, its Polyak step θ̄ ← θ̄ + τ(θ − θ̄).
fn optimizer_step(
    buf: &mut Scratch,
    opt: &mut Adam,
    params: &mut [f32],
    kind: Grads,
    target: Option<(&mut Vec<f32>, f32)>,
) {
    let parts = buf.pool.threads().min(MAX_PARTS);
    let len = part_len(params.len(), parts);
    let (first, rest) = buf.shards.split_at_mut(1);
    let tau = target.as_ref().map_or(0.0, |t| t.1);
    let mut targets = target.map(|(t, _)| t.chunks_mut(len));
    let mut items: [Option<StepPart>; MAX_PARTS] = Default::default();
    let pieces = opt
        .step_parts(params, parts)
        .zip(first[0].grads_mut(kind).chunks_mut(len));
    for (slot, (adam, grads)) in items.iter_mut().zip(pieces) {
        let target = targets.as_mut().and_then(|t| t.next());
        *slot = Some(StepPart {
            adam,
            grads,
            target,
        });
    }
    let rest: &[Shard] = rest;
    buf.pool.for_each_mut(&mut items[..parts], |_, item| {
        let Some(part) = item.take() else { return };
        let range = part.adam.range();
        for shard in rest {
            part.grads
                .iter_mut()
                .zip(&shard.grads(kind)[range.clone()])
                .for_each(|(g, &s)| *g += s);
        }
        let new = part.adam.apply(part.grads);
        if let Some(t) = part.target {
            polyak(t, new, tau);
        }
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
        let config = SacConfig {
            batch_size: 6,
            hidden: vec![8, 8],
            threads,
            ..SacConfig::default()
        };
        Sac::new(3, 2, config, &mut stream(seed, "test.init", 0))
    }

    /// The shards' partial gradients added up.
    fn total(sac: &Sac, kind: Grads) -> Vec<f32> {
        let mut sum = vec![0.0f32; sac.buf.shards[0].grads(kind).len()];
        for s in &sac.buf.shards {
            sum.iter_mut()
                .zip(s.grads(kind))
                .for_each(|(t, &g)| *t += g);
        }
        sum
    }

    /// The actor loss and gradient with the noise of `rng` (a pure function of θ_π for a seed).
    fn actor_loss(sac: &mut Sac, batch: &Batch, alpha: f32, rng: &mut Rng) -> f32 {
        fill_normal(&mut sac.buf.noise, rng);
        sac.actor_gradient(batch, alpha).0
    }

    /// The critic loss and gradient with the noise of `rng` (a pure function of θ_Q).
    fn critic_loss(sac: &mut Sac, batch: &Batch, alpha: f32, rng: &mut Rng) -> f32 {
        fill_normal(&mut sac.buf.noise_next, rng);
        sac.critic_gradient(batch, alpha)
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
        // Two threads: the shards' partial gradients must add up to the whole gradient.
        for threads in [1, 2] {
            let mut sac = sac_with_threads(1, threads);
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
        for threads in [1, 2] {
            let mut sac = sac_with_threads(2, threads);
            let batch = random_batch(6, 3);
            let loss = |s: &mut Sac| critic_loss(s, &batch, 0.2, &mut stream(0, "eps", 1));
            assert!(loss(&mut sac) > 0.0);
            let analytic = total(&sac, Grads::Critic);
            check_gradient(&sac, &analytic, |s| &mut s.critic_params, &loss);
        }
    }

    #[test]
    fn two_threads_compute_the_one_thread_update_up_to_rounding() {
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
    }
}
