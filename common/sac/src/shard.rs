//! The two ways an update's work is cut across threads.
//!
//! * The **actor's** work is cut by rows. Every per-row quantity of the actor (its samples,
//!   log π, the backward pass to θ_π) depends on its own row only; rows meet only in the
//!   parameter gradient, a sum over rows. So [`crate::Sac`] splits the minibatch into
//!   contiguous row ranges, one [`RowShard`] per thread, each computing its rows' share of
//!   ∂L_π/∂θ_π; the agent adds the shares in shard order before Adam (deterministic for a
//!   thread count; with one thread there is one shard holding the whole batch).
//! * The **critics'** work is cut by network: Q₁ and Q₂ are separate networks that meet only
//!   in min(Q̄₁, Q̄₂) of the TD target and min(Q₁, Q₂) of the actor loss. So each critic is one
//!   [`CriticLane`] over all rows of the batch: its target values, its gradient, its own Adam
//!   and Polyak step and its values on the policy's actions, on one thread, with nothing to
//!   add up between threads. Each critic's products are as wide as the whole batch and its
//!   parameters and moments stay in one core's cache; the lane computes exactly what a single
//!   thread computes for that critic, so the critics' results do not depend on the thread
//!   count. With one thread both lanes run one after the other on it.

use crate::actor::{ActorCache, TanhGaussianActor};
use crate::critic::TwinCritic;
use mbpo_core::Batch;
use mbpo_nn::adam::AdamPart;
use mbpo_nn::ops::polyak;
use mbpo_nn::MlpCache;
use std::ops::Range;

/// What the threads read during a phase: architectures, the actor's parameters, constants.
pub(crate) struct Nets<'a> {
    pub actor: &'a TanhGaussianActor,
    pub critic: &'a TwinCritic,
    pub actor_params: &'a [f32],
    pub gamma: f32,
    /// Temperature α of this update.
    pub alpha: f32,
    /// The whole minibatch's size B: losses are means over B, whatever a shard's share.
    pub batch_size: usize,
}

/// Rows `rows` of a row-major matrix of width `w`.
fn rows_of<'x>(x: &'x [f32], w: usize, rows: &Range<usize>) -> &'x [f32] {
    &x[rows.start * w..rows.end * w]
}

/// The actor's samples and partial gradient for rows `rows` of the minibatch.
#[derive(Debug, Clone)]
pub(crate) struct RowShard {
    pub rows: Range<usize>,
    /// a' ~ π(·|s') of the shard's rows.
    pub next_pi: ActorCache,
    /// a ~ π(·|s) of the shard's rows, kept for the backward pass.
    pub pi: ActorCache,
    d_log_prob: Vec<f32>,
    /// The shard's share of ∂L_π/∂θ_π (after [`RowShard::actor_gradient`]).
    pub actor_grads: Vec<f32>,
}

impl RowShard {
    pub fn new(actor: &TanhGaussianActor, rows: Range<usize>) -> Self {
        let r = rows.len();
        Self {
            next_pi: actor.cache(r),
            pi: actor.cache(r),
            d_log_prob: vec![0.0; r],
            actor_grads: vec![0.0; actor.num_params()],
            rows,
        }
    }

    /// a' ~ π(·|s') with the noise `noise_next` and, given `noise`, a ~ π(·|s) (both whole
    /// batch, `B x A`), for the shard's rows, with the current actor.
    pub fn sample(&mut self, n: &Nets, batch: &Batch, noise_next: &[f32], noise: Option<&[f32]>) {
        let (o, a, rows) = (n.actor.obs_dim(), n.actor.act_dim(), self.rows.clone());
        let r = rows.len();
        let draws = [
            (&mut self.next_pi, &batch.next_obs, Some(noise_next)),
            (&mut self.pi, &batch.obs, noise),
        ];
        for (cache, obs, noise) in draws {
            let Some(noise) = noise else { continue };
            n.actor.ensure(cache, r);
            cache.eps[..r * a].copy_from_slice(rows_of(noise, a, &rows));
            n.actor
                .sample_with_noise(n.actor_params, rows_of(obs, o, &rows), r, cache);
        }
    }

    /// The shard's share of ∂/∂θ_π of mean(α log π(a|s) − min_e Q_e(s, a)) into
    /// `actor_grads`, for the samples of the last [`RowShard::sample`] and `d_act` =
    /// ∂L/∂a of the whole batch (`B x A`).
    pub fn actor_gradient(&mut self, n: &Nets, batch: &Batch, d_act: &[f32]) {
        let (o, a, rows) = (n.actor.obs_dim(), n.actor.act_dim(), self.rows.clone());
        let d_log_prob = n.alpha * (1.0 / n.batch_size as f32);
        self.d_log_prob.fill(d_log_prob);
        n.actor.backward(
            n.actor_params,
            rows_of(&batch.obs, o, &rows),
            &mut self.pi,
            rows_of(d_act, a, &rows),
            &self.d_log_prob,
            &mut self.actor_grads,
        );
    }
}

/// Hand each row's ∂L/∂min(Q₁, Q₂) = `d_min` to the critic whose value is the minimum
/// ([`TwinCritic::min_critic`]), from the lanes' last [`CriticLane::policy_values`]: fills
/// both lanes' `min_rows` and `min_grad`.
pub(crate) fn assign_min_rows(lanes: &mut [CriticLane; 2], critic: &TwinCritic, d_min: f32) {
    let [l1, l2] = lanes;
    let (q1, q2) = (l1.q.output(critic.mlp()), l2.q.output(critic.mlp()));
    let mut picks = [
        (&mut l1.min_rows, &mut l1.min_grad),
        (&mut l2.min_rows, &mut l2.min_grad),
    ];
    picks.iter_mut().for_each(|(rows, _)| rows.clear());
    for (r, (&v1, &v2)) in q1.iter().zip(q2).enumerate() {
        let (rows, grad) = &mut picks[TwinCritic::min_critic(v1, v2)];
        grad[rows.len()] = d_min;
        rows.push(r);
    }
}

/// The lanes' compact ∂L/∂a of their `min_rows` (after [`CriticLane::action_gradient`]) into
/// `d_act`, the whole batch's (`B x A`, every row written once).
pub(crate) fn gather_action_gradients(lanes: &[CriticLane; 2], a: usize, d_act: &mut [f32]) {
    for lane in lanes {
        for (&r, row) in lane.min_rows.iter().zip(lane.min_d_act.chunks_exact(a)) {
            d_act[r * a..(r + 1) * a].copy_from_slice(row);
        }
    }
}

/// One critic's work in an update, over all rows of the minibatch.
#[derive(Debug, Clone)]
pub(crate) struct CriticLane {
    /// Which critic: 0 for Q₁, 1 for Q₂.
    pub e: usize,
    /// Input rows [s, a] of the current pass (`B x (O + A)`).
    input: Vec<f32>,
    /// Q̄_e(s', a'), the target network's values.
    target: MlpCache,
    /// Q_e(s, a) for the batch's actions, then Q_e(s, a~π) for the policy's.
    q: MlpCache,
    /// Q_e(s, a) of the batch's own actions, kept for the loss.
    pub q_data: Vec<f32>,
    d_q: Vec<f32>,
    /// ∂L_Q/∂θ_e (after [`CriticLane::gradient`]).
    pub grads: Vec<f32>,
    /// The rows whose min(Q₁, Q₂) is Q_e, their ∂L/∂Q_e and (after
    /// [`CriticLane::action_gradient`]) their ∂L/∂a (`rows x A`), compact.
    pub min_rows: Vec<usize>,
    pub min_grad: Vec<f32>,
    pub min_d_act: Vec<f32>,
}

impl CriticLane {
    pub fn new(critic: &TwinCritic, e: usize, batch: usize) -> Self {
        let (mlp, a) = (critic.mlp(), critic.act_dim());
        Self {
            e,
            input: vec![0.0; batch * mlp.in_dim()],
            target: MlpCache::new(mlp, batch),
            q: MlpCache::new(mlp, batch),
            q_data: vec![0.0; batch],
            d_q: vec![0.0; batch],
            grads: vec![0.0; mlp.num_params()],
            min_rows: Vec::with_capacity(batch),
            min_grad: vec![0.0; batch],
            min_d_act: vec![0.0; batch * a],
        }
    }

    /// Q̄_e(s', a') for every row, with the target parameters `target_e` of this critic and
    /// the policy's actions `next_action` (`B x A`); read with [`CriticLane::target_q`].
    pub fn target_values(
        &mut self,
        n: &Nets,
        target_e: &[f32],
        batch: &Batch,
        next_action: &[f32],
    ) {
        let b = batch.len;
        n.critic
            .join_inputs(&batch.next_obs, next_action, b, &mut self.input);
        n.critic
            .mlp()
            .forward(target_e, &self.input, b, &mut self.target);
    }

    /// Q̄_e(s', a') of the last [`CriticLane::target_values`].
    pub fn target_q(&self, n: &Nets) -> &[f32] {
        self.target.output(n.critic.mlp())
    }

    /// ∂/∂θ_e of ½·MSE(Q_e(s, a), y) into `grads` for the critic's parameters `theta_e`
    /// and the TD targets `y`; Q_e(s, a) is kept in `q_data` (the loss is the agent's sum).
    pub fn gradient(&mut self, n: &Nets, theta_e: &[f32], batch: &Batch, y: &[f32]) {
        let b = batch.len;
        let mlp = n.critic.mlp();
        n.critic
            .join_inputs(&batch.obs, &batch.act, b, &mut self.input);
        let q = mlp.forward(theta_e, &self.input, b, &mut self.q);
        self.q_data[..b].copy_from_slice(&q[..b]);
        let b_all = n.batch_size as f32;
        for i in 0..b {
            self.d_q[i] = (self.q_data[i] - y[i]) / b_all;
        }
        mlp.backward(
            theta_e,
            &self.input,
            &mut self.q,
            &self.d_q[..b],
            Some(&mut self.grads),
            None,
        );
    }

    /// Adam on this critic's parameters with its gradient, then the Polyak step
    /// θ̄_e ← θ̄_e + τ(θ_e − θ̄_e); returns the new θ_e.
    pub fn step<'p>(&self, adam: AdamPart<'p>, target_e: &mut [f32], tau: f32) -> &'p mut [f32] {
        let theta = adam.apply(&self.grads);
        polyak(target_e, theta, tau);
        theta
    }

    /// Q_e(s, a) for the policy's actions `pi_action` (`B x A`) with parameters `theta_e`,
    /// kept for [`CriticLane::action_gradient`]; read with [`CriticLane::policy_q`].
    pub fn policy_values(&mut self, n: &Nets, theta_e: &[f32], batch: &Batch, pi_action: &[f32]) {
        let b = batch.len;
        n.critic
            .join_inputs(&batch.obs, pi_action, b, &mut self.input);
        n.critic.mlp().forward(theta_e, &self.input, b, &mut self.q);
    }

    /// Q_e(s, a~π) of the last [`CriticLane::policy_values`].
    pub fn policy_q(&self, n: &Nets) -> &[f32] {
        self.q.output(n.critic.mlp())
    }

    /// ∂L/∂a of the rows `min_rows` (whose minimum is this critic) for their ∂L/∂Q_e
    /// `min_grad`, into `min_d_act`: the backward pass of the last
    /// [`CriticLane::policy_values`] on those rows only.
    pub fn action_gradient(&mut self, n: &Nets, theta_e: &[f32]) {
        let (o, a) = (n.actor.obs_dim(), n.actor.act_dim());
        n.critic.mlp().input_grad_rows(
            theta_e,
            &mut self.q,
            &self.min_rows,
            &self.min_grad,
            o..o + a,
            &mut self.min_d_act,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::{normal_f32, stream};

    #[test]
    fn action_gradient_of_the_clipped_double_q_matches_finite_differences() {
        // The lanes' path of the actor step: Q_e(s, a) on each lane, each row's ∂/∂min handed
        // to its minimum's critic, each lane's backward pass on its own rows.
        let (o, a, batch) = (3, 2, 32);
        let critic = TwinCritic::new(o, a, &[16, 16], false);
        let actor = TanhGaussianActor::new(o, a, &[4], -20.0, 2.0);
        let mut params = vec![0.0; critic.num_params()];
        critic.init(&mut params, &mut stream(5, "q", 0));
        let mut g = stream(4, "q.data", 0);
        let mut data = Batch::new(o, a, batch);
        data.obs.iter_mut().for_each(|v| *v = normal_f32(&mut g));
        let act: Vec<f32> = (0..batch * a).map(|_| normal_f32(&mut g).tanh()).collect();
        let d_min: Vec<f32> = (0..batch).map(|_| normal_f32(&mut g)).collect();
        let n = Nets {
            actor: &actor,
            critic: &critic,
            actor_params: &[],
            gamma: 0.99,
            alpha: 0.1,
            batch_size: batch,
        };
        let loss = |act: &[f32]| {
            let mut cache = critic.cache(batch);
            critic.forward(&params, &data.obs, act, batch, &mut cache);
            let (q1, q2) = (critic.q(&cache, 0), critic.q(&cache, 1));
            (0..batch)
                .map(|r| d_min[r] as f64 * q1[r].min(q2[r]) as f64)
                .sum::<f64>()
        };
        let mut lanes = [
            CriticLane::new(&critic, 0, batch),
            CriticLane::new(&critic, 1, batch),
        ];
        for lane in &mut lanes {
            let theta = &params[critic.member_range(lane.e)];
            lane.policy_values(&n, theta, &data, &act);
        }
        // Per-row gradients: `assign_min_rows` hands out one constant, so scale afterwards.
        assign_min_rows(&mut lanes, &critic, 1.0);
        assert!(
            lanes.iter().all(|l| !l.min_rows.is_empty()),
            "both critics must own some rows"
        );
        let mut d_act = vec![f32::NAN; batch * a];
        for lane in &mut lanes {
            for (i, &r) in lane.min_rows.iter().enumerate() {
                lane.min_grad[i] = d_min[r];
            }
            let theta = &params[critic.member_range(lane.e)];
            lane.action_gradient(&n, theta);
        }
        gather_action_gradients(&lanes, a, &mut d_act);
        // Small steps: with 32 rows x 2 x 16 ReLUs, a step of 1e-3 already crosses a kink.
        let eps = 2e-4f32;
        let scale = d_act.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        for i in 0..batch * a {
            let mut x = act.clone();
            x[i] += eps;
            let up = loss(&x);
            x[i] -= 2.0 * eps;
            let numeric = (up - loss(&x)) / (2.0 * eps as f64);
            let err = (d_act[i] as f64 - numeric).abs() / (0.05 * scale + numeric.abs());
            assert!(err < 2e-2, "d_act[{i}]: {} vs {numeric}", d_act[i]);
        }
    }
}
