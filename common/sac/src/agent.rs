//! The SAC agent and its update.

use crate::actor::{ActorCache, TanhGaussianActor};
use crate::config::SacConfig;
use crate::critic::{CriticCache, TwinCritic};
use mbpo_core::{Batch, Rng};
use mbpo_nn::ops::polyak;
use mbpo_nn::{Adam, AdamConfig, AdamState};
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

/// Buffers reused by every update so the update allocates nothing.
#[derive(Debug, Clone)]
struct Scratch {
    next_pi: ActorCache,
    pi: ActorCache,
    act_cache: ActorCache,
    q: CriticCache,
    q_target: CriticCache,
    y: Vec<f32>,
    d_q: [Vec<f32>; 2],
    d_act: Vec<f32>,
    d_log_prob: Vec<f32>,
    actor_grads: Vec<f32>,
    critic_grads: Vec<f32>,
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
        let buf = Scratch {
            next_pi: actor.cache(b),
            pi: actor.cache(b),
            act_cache: actor.cache(1),
            q: critic.cache(b),
            q_target: critic.cache(b),
            y: vec![0.0; b],
            d_q: [vec![0.0; b], vec![0.0; b]],
            d_act: vec![0.0; b * act_dim],
            d_log_prob: vec![0.0; b],
            actor_grads: vec![0.0; actor.num_params()],
            critic_grads: vec![0.0; critic.num_params()],
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
        assert_eq!(
            batch.len, self.config.batch_size,
            "batch size differs from the config"
        );
        let alpha = self.alpha();
        let critic_loss = self.update_critics(batch, alpha, rng);
        let (actor_loss, mean_log_prob, q_mean) = self.update_actor(batch, alpha, rng);
        let alpha_loss = self.update_temperature(mean_log_prob);
        polyak(
            &mut self.target_params,
            &self.critic_params,
            self.config.tau,
        );
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

    /// Critic step: y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')) with a' ~ π(·|s'),
    /// then descend ½·MSE(Q₁, y) + ½·MSE(Q₂, y). Bootstrapping stops only at termination.
    fn update_critics(&mut self, batch: &Batch, alpha: f32, rng: &mut Rng) -> f32 {
        let b = batch.len;
        self.td_targets(batch, alpha, rng);
        let buf = &mut self.buf;
        self.critic
            .forward(&self.critic_params, &batch.obs, &batch.act, b, &mut buf.q);
        let mut loss = 0.0f32;
        for e in 0..2 {
            let q = self.critic.q(&buf.q, e);
            for r in 0..b {
                let err = q[r] - buf.y[r];
                loss += 0.5 * err * err / b as f32;
                buf.d_q[e][r] = err / b as f32;
            }
        }
        self.critic.backward_params(
            &self.critic_params,
            &mut buf.q,
            [&buf.d_q[0], &buf.d_q[1]],
            &mut buf.critic_grads,
        );
        self.critic_opt
            .step(&mut self.critic_params, &buf.critic_grads);
        loss
    }

    /// Soft TD targets y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')), a' ~ π(·|s'),
    /// for every row of `batch`. `d` is `terminated`: a time-limit truncation is not terminal,
    /// so such rows bootstrap.
    pub fn td_targets(&mut self, batch: &Batch, alpha: f32, rng: &mut Rng) -> &[f32] {
        let (b, gamma) = (batch.len, self.config.gamma);
        let buf = &mut self.buf;
        self.actor.sample(
            &self.actor_params,
            &batch.next_obs,
            b,
            &mut buf.next_pi,
            Some(rng),
        );
        self.critic.forward(
            &self.target_params,
            &batch.next_obs,
            &buf.next_pi.action,
            b,
            &mut buf.q_target,
        );
        let (q1t, q2t) = (
            self.critic.q(&buf.q_target, 0),
            self.critic.q(&buf.q_target, 1),
        );
        for r in 0..b {
            let soft_v = q1t[r].min(q2t[r]) - alpha * buf.next_pi.log_prob[r];
            buf.y[r] = batch.reward[r] + gamma * (1.0 - batch.terminated[r]) * soft_v;
        }
        &buf.y[..b]
    }

    /// Actor step: descend mean(α log π(a|s) − min_e Q_e(s, a)) with a ~ π(·|s)
    /// reparameterised. Returns (loss, mean log π, mean Q₁).
    fn update_actor(&mut self, batch: &Batch, alpha: f32, rng: &mut Rng) -> (f32, f32, f32) {
        let out = self.actor_gradient(batch, alpha, rng);
        self.actor_opt
            .step(&mut self.actor_params, &self.buf.actor_grads);
        out
    }

    /// The actor loss mean(α log π(a|s) − min_e Q_e(s, a)) and its gradient (left in the
    /// scratch buffer). Returns (loss, mean log π, mean Q₁).
    fn actor_gradient(&mut self, batch: &Batch, alpha: f32, rng: &mut Rng) -> (f32, f32, f32) {
        let b = batch.len;
        let buf = &mut self.buf;
        self.actor
            .sample(&self.actor_params, &batch.obs, b, &mut buf.pi, Some(rng));
        self.critic.forward(
            &self.critic_params,
            &batch.obs,
            &buf.pi.action,
            b,
            &mut buf.q,
        );
        let (q1, q2) = (self.critic.q(&buf.q, 0), self.critic.q(&buf.q, 1));
        let (mut loss, mut mean_lp, mut q_mean) = (0.0f32, 0.0f32, 0.0f32);
        let inv_b = 1.0 / b as f32;
        for r in 0..b {
            // The gradient of min(Q₁, Q₂) flows into the smaller one.
            let first = q1[r] <= q2[r];
            buf.d_q[0][r] = if first { -inv_b } else { 0.0 };
            buf.d_q[1][r] = if first { 0.0 } else { -inv_b };
            let lp = buf.pi.log_prob[r];
            loss += (alpha * lp - q1[r].min(q2[r])) * inv_b;
            mean_lp += lp * inv_b;
            q_mean += q1[r] * inv_b;
            buf.d_log_prob[r] = alpha * inv_b;
        }
        self.critic.backward_action(
            &self.critic_params,
            &mut buf.q,
            [&buf.d_q[0], &buf.d_q[1]],
            &mut buf.d_act,
        );
        self.actor.backward(
            &self.actor_params,
            &batch.obs,
            &mut buf.pi,
            &buf.d_act,
            &buf.d_log_prob,
            &mut buf.actor_grads,
        );
        (loss, mean_lp, q_mean)
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

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::{normal_f32, stream};

    fn small_sac(seed: u64) -> Sac {
        let config = SacConfig {
            batch_size: 6,
            hidden: vec![8, 8],
            ..SacConfig::default()
        };
        Sac::new(3, 2, config, &mut stream(seed, "test.init", 0))
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
        let mut sac = small_sac(1);
        let batch = random_batch(6, 2);
        let alpha = 0.3;
        let (loss, _, _) = sac.actor_gradient(&batch, alpha, &mut stream(0, "eps", 0));
        let analytic = sac.buf.actor_grads.clone();
        let eps = 2e-3f32;
        let mut worst = 0.0f64;
        let scale = analytic.iter().fold(0.0f32, |m, g| m.max(g.abs())) as f64;
        for i in 0..sac.actor_params.len() {
            let eval = |delta: f32| {
                let mut s = sac.clone();
                s.actor_params[i] += delta;
                // Same ε draws: the loss is a deterministic function of θ_π.
                s.actor_gradient(&batch, alpha, &mut stream(0, "eps", 0)).0 as f64
            };
            let numeric = (eval(eps) - eval(-eps)) / (2.0 * eps as f64);
            let err = (analytic[i] as f64 - numeric).abs() / (0.05 * scale + numeric.abs());
            worst = worst.max(err);
            assert!(
                err < 3e-2,
                "param {i}: analytic {} numeric {numeric}",
                analytic[i]
            );
        }
        assert!(loss.is_finite() && scale > 0.0, "worst {worst}");
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
        let run = || {
            let mut sac = small_sac(8);
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
