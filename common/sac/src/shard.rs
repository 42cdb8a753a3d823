//! One row shard of a SAC update.
//!
//! Every per-row quantity of the update (TD targets, critic errors, the actor's sample, the
//! gradient of min(Q₁, Q₂) with respect to the action) depends on its own row only; the rows
//! meet only in the parameter gradients and the loss means, which are sums over rows. So
//! [`crate::Sac`] splits its minibatch into contiguous row ranges, one per thread, and each
//! shard computes its rows' share of every gradient and mean into its own buffers; the agent
//! adds the shards' partial gradients in shard order (deterministic for a thread count) before
//! each Adam step. With one thread there is one shard holding the whole batch.

use crate::actor::{ActorCache, TanhGaussianActor};
use crate::critic::{CriticCache, TwinCritic};
use mbpo_core::Batch;
use std::ops::Range;

/// What a shard reads during a phase: architectures, current parameters, constants.
pub(crate) struct Nets<'a> {
    pub actor: &'a TanhGaussianActor,
    pub critic: &'a TwinCritic,
    pub actor_params: &'a [f32],
    pub critic_params: &'a [f32],
    pub target_params: &'a [f32],
    pub gamma: f32,
    /// Temperature α of this update.
    pub alpha: f32,
    /// The whole minibatch's size B: losses are means over B, whatever a shard's share.
    pub batch_size: usize,
}

/// A shard's share of the update's scalar means (each term already divided by B).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ShardSums {
    /// ½·MSE(Q₁, y) + ½·MSE(Q₂, y).
    pub critic_loss: f32,
    /// α log π − min Q.
    pub actor_loss: f32,
    /// log π(a|s).
    pub log_prob: f32,
    /// Q₁(s, a~π).
    pub q1: f32,
}

/// Which network's gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Grads {
    Critic,
    Actor,
}

/// Activations, targets and partial gradients for rows `rows` of the minibatch.
#[derive(Debug, Clone)]
pub(crate) struct Shard {
    pub rows: Range<usize>,
    next_pi: ActorCache,
    pi: ActorCache,
    q_target: CriticCache,
    q: CriticCache,
    /// TD targets of the shard's rows.
    pub y: Vec<f32>,
    d_q: [Vec<f32>; 2],
    d_min: Vec<f32>,
    d_act: Vec<f32>,
    d_log_prob: Vec<f32>,
    /// The shard's share of ∂L_Q/∂θ_Q (after a critic phase).
    pub critic_grads: Vec<f32>,
    /// The shard's share of ∂L_π/∂θ_π (after an actor phase).
    pub actor_grads: Vec<f32>,
    pub sums: ShardSums,
}

/// Rows `rows` of a row-major matrix of width `w`.
fn rows_of<'x>(x: &'x [f32], w: usize, rows: &Range<usize>) -> &'x [f32] {
    &x[rows.start * w..rows.end * w]
}

impl Shard {
    pub fn new(actor: &TanhGaussianActor, critic: &TwinCritic, rows: Range<usize>) -> Self {
        let r = rows.len();
        Self {
            next_pi: actor.cache(r),
            pi: actor.cache(r),
            q_target: critic.cache(r),
            q: critic.cache(r),
            y: vec![0.0; r],
            d_q: [vec![0.0; r], vec![0.0; r]],
            d_min: vec![0.0; r],
            d_act: vec![0.0; r * actor.act_dim()],
            d_log_prob: vec![0.0; r],
            critic_grads: vec![0.0; critic.num_params()],
            actor_grads: vec![0.0; actor.num_params()],
            sums: ShardSums::default(),
            rows,
        }
    }

    /// The shard's partial gradient of `kind`.
    pub fn grads(&self, kind: Grads) -> &[f32] {
        match kind {
            Grads::Critic => &self.critic_grads,
            Grads::Actor => &self.actor_grads,
        }
    }

    /// [`Shard::grads`], writable.
    pub fn grads_mut(&mut self, kind: Grads) -> &mut [f32] {
        match kind {
            Grads::Critic => &mut self.critic_grads,
            Grads::Actor => &mut self.actor_grads,
        }
    }

    /// Soft TD targets y = r + γ(1 − d)(min_e Q̄_e(s', a') − α log π(a'|s')) with a' ~ π(·|s')
    /// drawn with the noise `noise_next` (whole batch, `B x A`). `d` is `terminated`: a
    /// time-limit truncation is not terminal, so such rows bootstrap.
    pub fn td_targets(&mut self, n: &Nets, batch: &Batch, noise_next: &[f32]) {
        let (o, a, rows) = (n.actor.obs_dim(), n.actor.act_dim(), self.rows.clone());
        let r = rows.len();
        let next_obs = rows_of(&batch.next_obs, o, &rows);
        n.actor.ensure(&mut self.next_pi, r);
        self.next_pi.eps[..r * a].copy_from_slice(rows_of(noise_next, a, &rows));
        n.actor
            .sample_with_noise(n.actor_params, next_obs, r, &mut self.next_pi);
        n.critic.forward(
            n.target_params,
            next_obs,
            &self.next_pi.action,
            r,
            &mut self.q_target,
        );
        let (q1t, q2t) = (n.critic.q(&self.q_target, 0), n.critic.q(&self.q_target, 1));
        let (reward, done) = (&batch.reward[rows.clone()], &batch.terminated[rows]);
        for i in 0..r {
            let soft_v = q1t[i].min(q2t[i]) - n.alpha * self.next_pi.log_prob[i];
            self.y[i] = reward[i] + n.gamma * (1.0 - done[i]) * soft_v;
        }
    }

    /// Critic phase: TD targets, then the shard's share of ∂/∂θ_Q of
    /// ½·MSE(Q₁, y) + ½·MSE(Q₂, y) into `critic_grads`, and of the loss into `sums`.
    pub fn critic_gradient(&mut self, n: &Nets, batch: &Batch, noise_next: &[f32]) {
        self.td_targets(n, batch, noise_next);
        let (o, a, rows) = (n.actor.obs_dim(), n.actor.act_dim(), self.rows.clone());
        let r = rows.len();
        let obs = rows_of(&batch.obs, o, &rows);
        let act = rows_of(&batch.act, a, &rows);
        n.critic.forward(n.critic_params, obs, act, r, &mut self.q);
        let b = n.batch_size as f32;
        let mut loss = 0.0f32;
        for e in 0..2 {
            let q = n.critic.q(&self.q, e);
            for i in 0..r {
                let err = q[i] - self.y[i];
                loss += 0.5 * err * err / b;
                self.d_q[e][i] = err / b;
            }
        }
        self.sums.critic_loss = loss;
        n.critic.backward_params(
            n.critic_params,
            &mut self.q,
            [&self.d_q[0], &self.d_q[1]],
            &mut self.critic_grads,
        );
    }

    /// Actor phase: a ~ π(·|s) with the noise `noise` (whole batch, `B x A`), then the shard's
    /// share of ∂/∂θ_π of mean(α log π(a|s) − min_e Q_e(s, a)) into `actor_grads`, and of the
    /// loss, log π and Q₁ means into `sums`.
    pub fn actor_gradient(&mut self, n: &Nets, batch: &Batch, noise: &[f32]) {
        let (o, a, rows) = (n.actor.obs_dim(), n.actor.act_dim(), self.rows.clone());
        let r = rows.len();
        let obs = rows_of(&batch.obs, o, &rows);
        n.actor.ensure(&mut self.pi, r);
        self.pi.eps[..r * a].copy_from_slice(rows_of(noise, a, &rows));
        n.actor
            .sample_with_noise(n.actor_params, obs, r, &mut self.pi);
        n.critic
            .forward(n.critic_params, obs, &self.pi.action, r, &mut self.q);
        let (q1, q2) = (n.critic.q(&self.q, 0), n.critic.q(&self.q, 1));
        let inv_b = 1.0 / n.batch_size as f32;
        let mut sums = ShardSums {
            critic_loss: self.sums.critic_loss,
            ..ShardSums::default()
        };
        for i in 0..r {
            let lp = self.pi.log_prob[i];
            sums.actor_loss += (n.alpha * lp - q1[i].min(q2[i])) * inv_b;
            sums.log_prob += lp * inv_b;
            sums.q1 += q1[i] * inv_b;
            self.d_min[i] = -inv_b;
            self.d_log_prob[i] = n.alpha * inv_b;
        }
        self.sums = sums;
        n.critic.backward_action_min(
            n.critic_params,
            &mut self.q,
            &self.d_min[..r],
            &mut self.d_act,
        );
        n.actor.backward(
            n.actor_params,
            obs,
            &mut self.pi,
            &self.d_act,
            &self.d_log_prob,
            &mut self.actor_grads,
        );
    }
}
