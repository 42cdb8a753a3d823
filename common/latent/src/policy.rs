//! TD-MPC2's policy prior π(a | z) and the two things it is used for besides planning: the TD
//! targets of the Q heads, and its own loss.
//!
//! π's output is a mean μ and a raw log-std per action value; log σ = m + ½(M − m)·(1 +
//! tanh(raw)) with (m, M) = (−10, 2); an action is a = tanh(μ + σ·ε), ε ~ N(0, 1), with
//! log π(a) = Σ (−½ε² − log σ − ½ ln 2π) − Σ ln(1 − a² + 10⁻⁶).
//!
//! * TD targets: q_t = r_t + γ · min over two Q heads of the *target* parameters at
//!   (z'_t, a'), with z'_t = h(o_{t+1}) and a' ~ π(· | z'_t) (no gradient anywhere).
//! * The policy loss over the (detached) latents z₀..z_H of the model loss:
//!   L_π = mean_t ρᵗ · mean_rows (α · log π(a) − Q̄(z, a) / S), with Q̄ the mean of two Q heads
//!   (their parameters held fixed: only the action carries gradient), α = 10⁻⁴ and S the
//!   running scale of Q (the caller's), so the loss is on the same scale on every task.

use mbpo_core::rng::Rng;

use crate::normed_mlp::NormedCache;
use crate::two_hot::TwoHot;
use crate::world_model::{concat_rows, WorldModel};

/// log σ's bounds (TD-MPC2's `log_std_min`, `log_std_max`).
pub const LOG_STD_MIN: f32 = -10.0;
/// See [`LOG_STD_MIN`].
pub const LOG_STD_MAX: f32 = 2.0;
/// α, the entropy weight of the policy loss (TD-MPC2's `entropy_coef`).
pub const ENTROPY_COEF: f32 = 1e-4;

/// Buffers of the policy's computations for `rows` latents at once.
#[derive(Debug, Clone)]
pub struct PolicyWorkspace {
    rows: usize,
    policy: NormedCache,
    q: [NormedCache; 2],
    /// (z, a) rows.
    za: Vec<f32>,
    /// π's outputs (μ, raw log σ) per row, the actions and log π.
    policy_out: Vec<f32>,
    act: Vec<f32>,
    log_pi: Vec<f32>,
    /// A Q value per row (the TD targets' smaller head).
    q_value: Vec<f32>,
    /// ∂L/∂(policy output), ∂L/∂(z, a), ∂L/∂Q-logits.
    d_out: Vec<f32>,
    d_za: Vec<f32>,
    d_logits: Vec<f32>,
    /// ∂L/∂a summed over the two Q heads.
    d_act: Vec<f32>,
}

impl PolicyWorkspace {
    /// Fresh dropout masks of probability `p` for the two Q heads of the next policy loss.
    pub fn draw_q_dropout(&mut self, model: &WorldModel, p: f32, rng: &mut Rng) {
        for cache in &mut self.q {
            cache.draw_dropout(&model.q, self.rows, p, rng);
        }
    }

    /// The policy network's forward cache (the planner makes it multiply in bf16).
    pub(crate) fn policy_cache(&mut self) -> &mut NormedCache {
        &mut self.policy
    }

    /// Buffers for `rows` latents of `model`.
    pub fn new(model: &WorldModel, rows: usize) -> Self {
        let (z, a, bins) = (model.cfg.latent, model.act_dim(), model.cfg.two_hot.bins);
        Self {
            rows,
            policy: NormedCache::new(&model.policy, rows),
            q: [
                NormedCache::new(&model.q, rows),
                NormedCache::new(&model.q, rows),
            ],
            za: vec![0.0; rows * (z + a)],
            policy_out: vec![0.0; rows * 2 * a],
            act: vec![0.0; rows * a],
            log_pi: vec![0.0; rows],
            q_value: vec![0.0; rows],
            d_out: vec![0.0; rows * 2 * a],
            d_za: vec![0.0; rows * (z + a)],
            d_logits: vec![0.0; rows * bins],
            d_act: vec![0.0; rows * a],
        }
    }
}

impl PolicyWorkspace {
    /// The Q values (the mean of the two heads) of the last [`WorldModel::policy_loss`], per
    /// row: what the running scale of Q follows.
    pub fn q_values(&self) -> &[f32] {
        &self.q_value
    }
}

/// log σ of a raw output, and ∂ log σ / ∂ raw.
fn log_std(raw: f32) -> (f32, f32) {
    let t = raw.tanh();
    let half_range = 0.5 * (LOG_STD_MAX - LOG_STD_MIN);
    (
        LOG_STD_MIN + half_range * (t + 1.0),
        half_range * (1.0 - t * t),
    )
}

/// The scalar of a two-hot head's `logits` and, into `d_logits`, ∂ scalar / ∂ logits.
fn decode_with_gradient(two_hot: &TwoHot, logits: &[f32], d_logits: &mut [f32]) -> f32 {
    mbpo_nn::simd_dispatch!(decode_with_gradient_kernel[two_hot, logits, d_logits])
}

#[inline(always)]
fn decode_with_gradient_kernel(two_hot: &TwoHot, logits: &[f32], d_logits: &mut [f32]) -> f32 {
    let max = logits.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    let mut sum = 0.0f32;
    for (d, &l) in d_logits.iter_mut().zip(logits) {
        *d = mbpo_nn::math::exp_neg_f32(max - l);
        sum += *d;
    }
    let bin = |i: usize| {
        two_hot.v_min + i as f32 * (two_hot.v_max - two_hot.v_min) / (two_hot.bins - 1) as f32
    };
    let mut m = 0.0f32;
    for (i, d) in d_logits.iter_mut().enumerate() {
        *d /= sum;
        m += *d * bin(i);
    }
    // Q = symexp(m): dQ/dm = e^|m|; dm/dl_i = p_i (b_i − m).
    let slope = m.abs().exp();
    for (i, d) in d_logits.iter_mut().enumerate() {
        *d *= slope * (bin(i) - m);
    }
    crate::two_hot::symexp(m)
}

impl WorldModel {
    /// Actions a ~ π(· | z) for `ws.rows` latents `z` with noise `eps` (rows x act) into
    /// `ws.act`, and log π(a) into `ws.log_pi`.
    pub fn sample_policy(&self, params: &[f32], z: &[f32], eps: &[f32], ws: &mut PolicyWorkspace) {
        self.sample_policy_rows(params, z, eps, ws.rows, ws);
    }

    /// [`WorldModel::sample_policy`] for the first `rows` latents (at most the workspace's);
    /// returns their actions (rows x act).
    pub fn sample_policy_rows<'w>(
        &self,
        params: &[f32],
        z: &[f32],
        eps: &[f32],
        rows: usize,
        ws: &'w mut PolicyWorkspace,
    ) -> &'w [f32] {
        let a = self.act_dim();
        let out = self
            .policy
            .forward(&params[self.policy_range()], z, rows, &mut ws.policy);
        ws.policy_out[..rows * 2 * a].copy_from_slice(out);
        let out = &ws.policy_out;
        let norm = -0.5 * (2.0 * std::f32::consts::PI).ln();
        for r in 0..rows {
            let (mu, raw) = out[r * 2 * a..(r + 1) * 2 * a].split_at(a);
            let mut log_pi = 0.0;
            for j in 0..a {
                let (ls, _) = log_std(raw[j]);
                let e = eps[r * a + j];
                let act = (mu[j] + ls.exp() * e).tanh();
                ws.act[r * a + j] = act;
                log_pi += -0.5 * e * e - ls + norm - (1.0 - act * act + 1e-6).ln();
            }
            ws.log_pi[r] = log_pi;
        }
        &ws.act[..rows * a]
    }

    /// The TD targets q_t = r_t + γ · min of the two Q heads `heads` of `target_q` (the target
    /// copies of the Q heads' parameters, laid out as the model's) at (z', a'), a' ~ π(· | z'),
    /// for the latents `next_z` (rows x latent) and `rewards` (rows), into `out`.
    #[allow(clippy::too_many_arguments)]
    pub fn td_targets(
        &self,
        params: &[f32],
        target_q: &[f32],
        heads: [usize; 2],
        next_z: &[f32],
        rewards: &[f32],
        eps: &[f32],
        ws: &mut PolicyWorkspace,
        out: &mut [f32],
    ) {
        self.sample_policy(params, next_z, eps, ws);
        let (z, a, bins) = (self.cfg.latent, self.act_dim(), self.cfg.two_hot.bins);
        concat_rows(next_z, z, &ws.act, a, &mut ws.za);
        for (k, &head) in heads.iter().enumerate() {
            let p = &target_q[self.q_head_range(head)];
            let logits = self.q.forward(p, &ws.za, ws.rows, &mut ws.q[k]);
            for r in 0..ws.rows {
                let v = self.cfg.two_hot.decode(&logits[r * bins..(r + 1) * bins]);
                // First head: the value; second: the smaller of the two.
                ws.q_value[r] = if k == 0 { v } else { ws.q_value[r].min(v) };
            }
        }
        for r in 0..ws.rows {
            out[r] = rewards[r] + self.cfg.discount * ws.q_value[r];
        }
    }

    /// The policy loss over `zs` ((H+1)·B latents, time-major, B per step) with noise `eps`,
    /// Q heads `heads` of `params` averaged, Q's running scale `q_scale`; its gradient is
    /// added into the policy's part of `grads`. Returns the loss.
    #[allow(clippy::too_many_arguments)]
    pub fn policy_loss(
        &self,
        params: &[f32],
        zs: &[f32],
        eps: &[f32],
        heads: [usize; 2],
        q_scale: f32,
        ws: &mut PolicyWorkspace,
        grads: &mut [f32],
    ) -> f32 {
        self.sample_policy(params, zs, eps, ws);
        let (z, a, bins) = (self.cfg.latent, self.act_dim(), self.cfg.two_hot.bins);
        let steps = self.cfg.horizon + 1;
        let batch = ws.rows / steps;
        concat_rows(zs, z, &ws.act, a, &mut ws.za);
        ws.d_act.fill(0.0);
        let mut loss = 0.0f64;
        for (k, &head) in heads.iter().enumerate() {
            let p = &params[self.q_head_range(head)];
            let logits = self.q.forward(p, &ws.za, ws.rows, &mut ws.q[k]);
            for r in 0..ws.rows {
                let w = self.cfg.rho.powi((r / batch) as i32) / (steps * batch) as f32;
                let rows = r * bins..(r + 1) * bins;
                let q = decode_with_gradient(
                    &self.cfg.two_hot,
                    &logits[rows.clone()],
                    &mut ws.d_logits[rows.clone()],
                );
                loss -= (w * 0.5 * q / q_scale) as f64;
                // The mean of the two heads' values, for the running scale.
                ws.q_value[r] = if k == 0 {
                    0.5 * q
                } else {
                    ws.q_value[r] + 0.5 * q
                };
                // ∂L/∂Q of this head: −w / (2 S).
                ws.d_logits[rows]
                    .iter_mut()
                    .for_each(|d| *d *= -w * 0.5 / q_scale);
            }
            self.q.backward(
                p,
                &ws.za,
                &mut ws.q[k],
                &ws.d_logits,
                None,
                Some(&mut ws.d_za),
            );
            for (da, dza) in ws
                .d_act
                .chunks_exact_mut(a)
                .zip(ws.d_za.chunks_exact(z + a))
            {
                da.iter_mut().zip(&dza[z..]).for_each(|(x, y)| *x += y);
            }
        }
        loss += self.policy_output_gradient(eps, batch, ws);
        let range = self.policy_range();
        self.policy.backward(
            &params[range.clone()],
            zs,
            &mut ws.policy,
            &ws.d_out,
            Some(&mut grads[range]),
            None,
        );
        loss as f32
    }

    /// The entropy term's loss, and ∂L/∂(μ, raw log σ) into `ws.d_out` from ∂L/∂a (in
    /// `ws.d_act`) and the entropy term.
    fn policy_output_gradient(&self, eps: &[f32], batch: usize, ws: &mut PolicyWorkspace) -> f64 {
        let a = self.act_dim();
        let steps = self.cfg.horizon + 1;
        let mut loss = 0.0f64;
        for r in 0..ws.rows {
            let w = self.cfg.rho.powi((r / batch) as i32) / (steps * batch) as f32;
            loss += (w * ENTROPY_COEF * ws.log_pi[r]) as f64;
            for j in 0..a {
                let raw = ws.policy_out[r * 2 * a + a + j];
                let (ls, d_ls_raw) = log_std(raw);
                let (e, act) = (eps[r * a + j], ws.act[r * a + j]);
                let d_a =
                    ws.d_act[r * a + j] + w * ENTROPY_COEF * 2.0 * act / (1.0 - act * act + 1e-6);
                let d_u = d_a * (1.0 - act * act);
                let d_ls = d_u * e * ls.exp() - w * ENTROPY_COEF;
                ws.d_out[r * 2 * a + j] = d_u;
                ws.d_out[r * 2 * a + a + j] = d_ls * d_ls_raw;
            }
        }
        loss
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::{normal_f32, stream};

    fn small() -> (WorldModel, Vec<f32>) {
        let cfg = crate::world_model::tests::small_config();
        let model = WorldModel::new(3, 2, cfg);
        let mut params = vec![0.0; model.num_params()];
        model.init(&mut params, &mut stream(4, "test.pi", 0));
        for (i, p) in params.iter_mut().enumerate() {
            *p += 0.25 * ((i as f32) * 0.61).sin();
        }
        (model, params)
    }

    fn draws(n: usize, seed: u64) -> Vec<f32> {
        let mut g = stream(seed, "test.pi.draws", 0);
        (0..n).map(|_| normal_f32(&mut g)).collect()
    }

    #[test]
    fn the_policy_loss_gradient_matches_finite_differences() {
        let (model, params) = small();
        let rows = (model.cfg.horizon + 1) * 3;
        let zs = draws(rows * model.cfg.latent, 1);
        let eps = draws(rows * model.act_dim(), 2);
        let mut ws = PolicyWorkspace::new(&model, rows);
        let mut loss =
            |p: &[f32], g: &mut [f32]| model.policy_loss(p, &zs, &eps, [0, 1], 1.7, &mut ws, g);
        let mut grads = vec![0.0; model.num_params()];
        loss(&params, &mut grads);
        let range = model.policy_range();
        let scale = grads[range.clone()]
            .iter()
            .fold(0.0f32, |m, g| m.max(g.abs())) as f64;
        assert!(scale > 0.0);
        let (eps_fd, mut sink) = (1e-3f32, vec![0.0; model.num_params()]);
        for i in range {
            let mut at = |d: f32| {
                let mut p = params.clone();
                p[i] += d;
                loss(&p, &mut sink) as f64
            };
            let numeric = (at(eps_fd) - at(-eps_fd)) / (2.0 * eps_fd as f64);
            let err = (grads[i] as f64 - numeric).abs() / (0.05 * scale + numeric.abs());
            assert!(
                err < 3e-2,
                "param {i}: analytic {} numeric {numeric}",
                grads[i]
            );
        }
        // Only the policy learns from this loss.
        let others = grads
            .iter()
            .enumerate()
            .filter(|(i, _)| !model.policy_range().contains(i));
        assert!(others.map(|(_, g)| g).all(|&g| g == 0.0));
    }

    #[test]
    fn a_td_target_is_the_reward_plus_the_discounted_smaller_target_value() {
        let (model, params) = small();
        let rows = 5;
        let (next_z, eps, rewards) = (
            draws(rows * model.cfg.latent, 3),
            draws(rows * 2, 4),
            draws(rows, 5),
        );
        let mut target_q = params.clone();
        // The second head's targets shifted so the two differ.
        for p in &mut target_q[model.q_head_range(1)] {
            *p += 0.05;
        }
        let mut ws = PolicyWorkspace::new(&model, rows);
        let mut out = vec![0.0; rows];
        model.td_targets(
            &params,
            &target_q,
            [0, 1],
            &next_z,
            &rewards,
            &eps,
            &mut ws,
            &mut out,
        );
        // By hand: the same sampled actions through each head, decoded.
        model.sample_policy(&params, &next_z, &eps, &mut ws);
        let z = model.cfg.latent;
        for r in 0..rows {
            let mut za = next_z[r * z..(r + 1) * z].to_vec();
            za.extend_from_slice(&ws.act[r * 2..r * 2 + 2]);
            let value = |k: usize| {
                let mut c = NormedCache::new(&model.q, 1);
                let logits = model
                    .q
                    .forward(&target_q[model.q_head_range(k)], &za, 1, &mut c);
                model.cfg.two_hot.decode(logits)
            };
            let want = rewards[r] + model.cfg.discount * value(0).min(value(1));
            assert!(
                (out[r] - want).abs() <= 1e-5 * want.abs().max(1.0),
                "row {r}: {} vs {want}",
                out[r]
            );
        }
    }
}
