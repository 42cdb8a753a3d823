//! TD-MPC2's world model and its loss (Hansen et al. 2024, eq. 3-4): from a sampled
//! subsequence (o₀..o_H, a₀..a_{H−1}, r₀..r_{H−1}) the encoder gives z₀ = h(o₀), the latent
//! dynamics roll z_{t+1} = d(z_t, a_t) forward, and
//!
//! L = Σ_t ρᵗ [ c_d · ‖z_{t+1} − sg(h(o_{t+1}))‖² / H
//!            + c_r · CE(R(z_t, a_t), r_t) / H
//!            + c_q · Σ_k CE(Q_k(z_t, a_t), q_t) / (H · K) ]
//!
//! with two-hot cross-entropies, TD targets q_t = r_t + γ · min of two target Q heads at
//! (h(o_{t+1}), π(h(o_{t+1}))) computed without gradient ([`WorldModel::td_targets`]), and the
//! paper's weights c_d = 20, c_r = c_q = 0.1, ρ = 0.5. Every z_t carries gradient from the
//! reward and Q heads as well: the latent is shaped by all three terms.

use std::ops::Range;

use mbpo_core::rng::Rng;

use crate::normed_mlp::{Head, NormedCache, NormedMlp};
use crate::two_hot::TwoHot;

/// Sizes and loss weights of a world model (TD-MPC2's defaults; its 1M preset's widths).
#[derive(Debug, Clone, PartialEq)]
pub struct WorldModelConfig {
    /// Latent width (a multiple of the SimNorm group, 8).
    pub latent: usize,
    /// The encoder's hidden width.
    pub encoder_hidden: usize,
    /// The hidden width of the dynamics, reward, Q and policy networks (two layers each).
    pub hidden: usize,
    /// Q heads.
    pub q_heads: usize,
    /// Horizon H of the loss (and of planning).
    pub horizon: usize,
    /// ρ: the weight of step t is ρᵗ.
    pub rho: f32,
    /// c_d, the consistency weight.
    pub consistency_coef: f32,
    /// c_r, the reward weight.
    pub reward_coef: f32,
    /// c_q, the value weight.
    pub value_coef: f32,
    /// γ of the TD targets.
    pub discount: f32,
    /// The reward and value bins.
    pub two_hot: TwoHot,
    /// Dropout of the Q heads' first layer while learning (TD-MPC2: 1 %; not in the TD
    /// targets' heads nor in planning).
    pub q_dropout: f32,
}

impl Default for WorldModelConfig {
    fn default() -> Self {
        Self {
            latent: 128,
            encoder_hidden: 256,
            hidden: 384,
            q_heads: 2,
            horizon: 3,
            rho: 0.5,
            consistency_coef: 20.0,
            reward_coef: 0.1,
            value_coef: 0.1,
            discount: 0.99,
            two_hot: TwoHot::default(),
            q_dropout: 0.01,
        }
    }
}

/// The networks of a world model and where each one's parameters lie in the one vector.
#[derive(Debug, Clone)]
pub struct WorldModel {
    /// Sizes and weights.
    pub cfg: WorldModelConfig,
    obs: usize,
    act: usize,
    /// h: observation → latent.
    pub encoder: NormedMlp,
    /// d: (latent, action) → latent.
    pub dynamics: NormedMlp,
    /// R: (latent, action) → reward logits.
    pub reward: NormedMlp,
    /// Q_k: (latent, action) → value logits (one architecture, `q_heads` parameter sets).
    pub q: NormedMlp,
    /// π: latent → mean and log-std of the action.
    pub policy: NormedMlp,
    ranges: Ranges,
}

/// Where each network's parameters are in the model's vector.
#[derive(Debug, Clone)]
struct Ranges {
    encoder: Range<usize>,
    dynamics: Range<usize>,
    reward: Range<usize>,
    q: Vec<Range<usize>>,
    policy: Range<usize>,
}

/// What the loss came to.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Losses {
    /// Σ_t ρᵗ ‖z_{t+1} − sg(h(o_{t+1}))‖² / H (mean over rows and latent values).
    pub consistency: f32,
    /// Σ_t ρᵗ CE(R, r_t) / H.
    pub reward: f32,
    /// Σ_t ρᵗ Σ_k CE(Q_k, q_t) / (H · K).
    pub value: f32,
    /// c_d · consistency + c_r · reward + c_q · value.
    pub total: f32,
}

/// A batch of subsequences, time-major: `obs` (H+1) x B x obs, `act` H x B x act, `reward`
/// H x B.
#[derive(Debug, Clone)]
pub struct Sequences {
    /// Rows per step.
    pub batch: usize,
    /// Observations o₀..o_H.
    pub obs: Vec<f32>,
    /// Actions a₀..a_{H−1} in [−1, 1].
    pub act: Vec<f32>,
    /// Rewards r₀..r_{H−1}.
    pub reward: Vec<f32>,
}

impl Sequences {
    /// `batch` zeroed subsequences of `horizon` steps of `obs`- and `act`-wide transitions (a
    /// buffer for `EpisodeBuffer::sample`).
    pub fn zeros(batch: usize, horizon: usize, obs: usize, act: usize) -> Self {
        Self {
            batch,
            obs: vec![0.0; (horizon + 1) * batch * obs],
            act: vec![0.0; horizon * batch * act],
            reward: vec![0.0; horizon * batch],
        }
    }
}

impl WorldModel {
    /// A world model of `cfg` for observations of `obs` values and actions of `act`.
    pub fn new(obs: usize, act: usize, cfg: WorldModelConfig) -> Self {
        let (z, h, bins) = (cfg.latent, cfg.hidden, cfg.two_hot.bins);
        let encoder = NormedMlp::new(&[obs, cfg.encoder_hidden, z], Head::SimNorm);
        let dynamics = NormedMlp::new(&[z + act, h, h, z], Head::SimNorm);
        let reward = NormedMlp::new(&[z + act, h, h, bins], Head::Linear);
        let q = NormedMlp::new(&[z + act, h, h, bins], Head::Linear);
        let policy = NormedMlp::new(&[z, h, h, 2 * act], Head::Linear);
        let mut at = 0;
        let mut next = |n: usize| {
            at += n;
            at - n..at
        };
        let ranges = Ranges {
            encoder: next(encoder.num_params()),
            dynamics: next(dynamics.num_params()),
            reward: next(reward.num_params()),
            q: (0..cfg.q_heads).map(|_| next(q.num_params())).collect(),
            policy: next(policy.num_params()),
        };
        Self {
            cfg,
            obs,
            act,
            encoder,
            dynamics,
            reward,
            q,
            policy,
            ranges,
        }
    }

    /// Parameters of the whole model.
    pub fn num_params(&self) -> usize {
        self.ranges.policy.end
    }

    /// FNV-1a of the widths the parameter vector is laid out by: two processes exchange
    /// parameters only when theirs agree.
    pub fn layout_hash(&self) -> u64 {
        let c = &self.cfg;
        let text = format!(
            "tdmpc obs={} act={} latent={} encoder={} hidden={} q={} bins={} params={}",
            self.obs,
            self.act,
            c.latent,
            c.encoder_hidden,
            c.hidden,
            c.q_heads,
            c.two_hot.bins,
            self.num_params()
        );
        mbpo_core::rng::fnv1a(text.as_bytes())
    }

    /// TD-MPC2's initialisation of every network (reward and Q outputs start at 0).
    pub fn init(&self, params: &mut [f32], rng: &mut Rng) {
        let r = &self.ranges;
        self.encoder
            .init(&mut params[r.encoder.clone()], false, rng);
        self.dynamics
            .init(&mut params[r.dynamics.clone()], false, rng);
        self.reward.init(&mut params[r.reward.clone()], true, rng);
        for q in &r.q {
            self.q.init(&mut params[q.clone()], true, rng);
        }
        self.policy.init(&mut params[r.policy.clone()], false, rng);
    }

    /// Observation width.
    pub fn obs_dim(&self) -> usize {
        self.obs
    }
    /// Action width.
    pub fn act_dim(&self) -> usize {
        self.act
    }
    /// The encoder's parameters within the model's vector (the first).
    pub fn encoder_range(&self) -> Range<usize> {
        self.ranges.encoder.clone()
    }
    /// The latent targets sg(h(o₁..o_H)) of the last [`WorldModel::encode_targets`]
    /// (H x B x latent).
    pub fn latent_targets<'w>(&self, ws: &'w LossWorkspace) -> &'w [f32] {
        &ws.next_z
    }
    /// The dynamics' parameters within the model's vector.
    pub fn dynamics_range(&self) -> Range<usize> {
        self.ranges.dynamics.clone()
    }
    /// The reward head's parameters within the model's vector.
    pub fn reward_range(&self) -> Range<usize> {
        self.ranges.reward.clone()
    }
    /// The policy's parameters within the model's vector.
    pub fn policy_range(&self) -> Range<usize> {
        self.ranges.policy.clone()
    }
    /// Q head `k`'s parameters within the model's vector.
    pub fn q_head_range(&self, k: usize) -> Range<usize> {
        self.ranges.q[k].clone()
    }
    /// The latents z₀..z_H of the last loss evaluation ((H+1) x B x latent, time-major): the
    /// policy loss's inputs, detached.
    pub fn rolled_latents<'w>(&self, ws: &'w LossWorkspace) -> &'w [f32] {
        &ws.zs
    }
    /// The Q heads' parameters within the model's vector (what the target copies track).
    pub fn q_range(&self) -> Range<usize> {
        self.ranges.q[0].start..self.ranges.q[self.cfg.q_heads - 1].end
    }
}

/// The buffers of one loss evaluation, sized once for a batch.
#[derive(Debug, Clone)]
pub struct LossWorkspace {
    batch: usize,
    encoder: NormedCache,
    targets: NormedCache,
    dynamics: Vec<NormedCache>,
    reward: Vec<NormedCache>,
    q: Vec<NormedCache>,
    /// z₀..z_H, (H+1) x B x latent.
    zs: Vec<f32>,
    /// sg(h(o₁..o_H)), H x B x latent.
    next_z: Vec<f32>,
    /// (z_t, a_t) rows, H x B x (latent + act).
    za: Vec<f32>,
    /// ∂L/∂z_t, (H+1) x B x latent.
    d_zs: Vec<f32>,
    /// ∂L/∂(z_t, a_t) of one step.
    d_za: Vec<f32>,
    /// ∂L/∂logits of one step.
    d_logits: Vec<f32>,
    /// ∂L/∂z_{t+1} of the dynamics' output.
    d_next: Vec<f32>,
}

impl LossWorkspace {
    /// Fresh dropout masks of probability `p` for every Q head at every step of the next loss.
    pub fn draw_q_dropout(&mut self, model: &WorldModel, p: f32, rng: &mut Rng) {
        for cache in &mut self.q {
            cache.draw_dropout(&model.q, self.batch, p, rng);
        }
    }

    /// Buffers for batches of `batch` rows of `model`.
    pub fn new(model: &WorldModel, batch: usize) -> Self {
        let (h, z, za) = (
            model.cfg.horizon,
            model.cfg.latent,
            model.cfg.latent + model.act,
        );
        let steps =
            |net: &NormedMlp, n: usize| (0..n).map(|_| NormedCache::new(net, batch)).collect();
        Self {
            batch,
            encoder: NormedCache::new(&model.encoder, batch),
            targets: NormedCache::new(&model.encoder, batch * h),
            dynamics: steps(&model.dynamics, h),
            reward: steps(&model.reward, h),
            q: steps(&model.q, h * model.cfg.q_heads),
            zs: vec![0.0; (h + 1) * batch * z],
            next_z: vec![0.0; h * batch * z],
            za: vec![0.0; h * batch * za],
            d_zs: vec![0.0; (h + 1) * batch * z],
            d_za: vec![0.0; batch * za],
            d_logits: vec![0.0; batch * model.cfg.two_hot.bins],
            d_next: vec![0.0; batch * z],
        }
    }
}

impl WorldModel {
    /// The world-model loss of `seq` against the TD targets `q_targets` (H x B), with its
    /// gradient **added** into `grads` (the policy's part is left alone).
    pub fn loss(
        &self,
        params: &[f32],
        seq: &Sequences,
        q_targets: &[f32],
        ws: &mut LossWorkspace,
        grads: &mut [f32],
    ) -> Losses {
        self.encode_targets(params, seq, ws);
        self.loss_given_targets(params, seq, q_targets, ws, grads)
    }

    /// [`WorldModel::loss`] with the latent targets sg(h(o₁..o_H)) already in `ws`
    /// ([`WorldModel::encode_targets`]): held fixed, as the stop-gradient says.
    pub fn loss_given_targets(
        &self,
        params: &[f32],
        seq: &Sequences,
        q_targets: &[f32],
        ws: &mut LossWorkspace,
        grads: &mut [f32],
    ) -> Losses {
        assert_eq!(
            seq.batch, ws.batch,
            "the workspace is sized for another batch"
        );
        let consistency = self.roll_forward(params, seq, ws);
        ws.d_zs.fill(0.0);
        let (reward, value) = self.heads_backward(params, seq, q_targets, ws, grads);
        self.dynamics_backward(params, ws, grads);
        let (b, z) = (ws.batch, self.cfg.latent);
        let enc = self.ranges.encoder.clone();
        self.encoder.backward(
            &params[enc.clone()],
            &seq.obs[..b * self.obs],
            &mut ws.encoder,
            &ws.d_zs[..b * z],
            Some(&mut grads[enc]),
            None,
        );
        let c = &self.cfg;
        Losses {
            consistency,
            reward,
            value,
            total: c.consistency_coef * consistency + c.reward_coef * reward + c.value_coef * value,
        }
    }

    /// The latent targets sg(h(o₁..o_H)) of `seq` into `ws`.
    pub fn encode_targets(&self, params: &[f32], seq: &Sequences, ws: &mut LossWorkspace) {
        let (b, h) = (ws.batch, self.cfg.horizon);
        let p = &params[self.ranges.encoder.clone()];
        let next = &seq.obs[b * self.obs..(h + 1) * b * self.obs];
        let z = self.encoder.forward(p, next, b * h, &mut ws.targets);
        ws.next_z.copy_from_slice(z);
    }

    /// z₀ = h(o₀), z_{t+1} = d(z_t, a_t); the (z_t, a_t) rows kept; returns the consistency
    /// term Σ_t ρᵗ mean((z_{t+1} − next_z_t)²) / H.
    fn roll_forward(&self, params: &[f32], seq: &Sequences, ws: &mut LossWorkspace) -> f32 {
        let (b, z, a, h) = (ws.batch, self.cfg.latent, self.act, self.cfg.horizon);
        let enc = &params[self.ranges.encoder.clone()];
        let z0 = self
            .encoder
            .forward(enc, &seq.obs[..b * self.obs], b, &mut ws.encoder);
        ws.zs[..b * z].copy_from_slice(z0);
        let dynamics = &params[self.ranges.dynamics.clone()];
        let mut consistency = 0.0f64;
        for t in 0..h {
            let za = &mut ws.za[t * b * (z + a)..(t + 1) * b * (z + a)];
            concat_rows(
                &ws.zs[t * b * z..(t + 1) * b * z],
                z,
                &seq.act[t * b * a..(t + 1) * b * a],
                a,
                za,
            );
            let next = self.dynamics.forward(dynamics, za, b, &mut ws.dynamics[t]);
            ws.zs[(t + 1) * b * z..(t + 2) * b * z].copy_from_slice(next);
            let target = &ws.next_z[t * b * z..(t + 1) * b * z];
            let sq: f64 = next
                .iter()
                .zip(target)
                .map(|(p, q)| ((p - q) * (p - q)) as f64)
                .sum();
            consistency += self.cfg.rho.powi(t as i32) as f64 * sq / (b * z) as f64;
        }
        (consistency / h as f64) as f32
    }

    /// The reward and Q heads at every step: their losses, their parameters' gradients, and
    /// their ∂L/∂z_t added into `ws.d_zs`. Returns (reward term, value term).
    fn heads_backward(
        &self,
        params: &[f32],
        seq: &Sequences,
        q_targets: &[f32],
        ws: &mut LossWorkspace,
        grads: &mut [f32],
    ) -> (f32, f32) {
        let (b, h, k) = (ws.batch, self.cfg.horizon, self.cfg.q_heads);
        let (z, za_w) = (self.cfg.latent, self.cfg.latent + self.act);
        let (mut reward, mut value) = (0.0f64, 0.0f64);
        for t in 0..h {
            let w = self.cfg.rho.powi(t as i32) / h as f32;
            let mut step = HeadStep {
                za: &ws.za[t * b * za_w..(t + 1) * b * za_w],
                d_logits: &mut ws.d_logits,
                d_za: &mut ws.d_za,
                d_z: &mut ws.d_zs[t * b * z..(t + 1) * b * z],
                latent: z,
            };
            let rewards = &seq.reward[t * b..(t + 1) * b];
            let r = self.ranges.reward.clone();
            let (p, g) = (&params[r.clone()], &mut grads[r]);
            let scale = self.cfg.reward_coef * w;
            let ce = self.head_step(
                &self.reward,
                p,
                g,
                &mut ws.reward[t],
                rewards,
                scale,
                &mut step,
            );
            reward += (w as f64) * ce;
            for q in 0..k {
                let range = self.ranges.q[q].clone();
                let (p, g) = (&params[range.clone()], &mut grads[range]);
                let scale = self.cfg.value_coef * w / k as f32;
                let targets = &q_targets[t * b..(t + 1) * b];
                let ce = self.head_step(
                    &self.q,
                    p,
                    g,
                    &mut ws.q[t * k + q],
                    targets,
                    scale,
                    &mut step,
                );
                value += (w / k as f32) as f64 * ce;
            }
        }
        (reward as f32, value as f32)
    }

    /// One head at one step: its logits on the (z_t, a_t) rows, their mean two-hot
    /// cross-entropy against `targets` (returned), and the gradient of `scale` times it passed
    /// back into the head's `grads` and added into ∂L/∂z_t.
    #[allow(clippy::too_many_arguments)]
    fn head_step(
        &self,
        net: &NormedMlp,
        params: &[f32],
        grads: &mut [f32],
        cache: &mut NormedCache,
        targets: &[f32],
        scale: f32,
        step: &mut HeadStep<'_>,
    ) -> f64 {
        let (b, bins) = (targets.len(), self.cfg.two_hot.bins);
        let logits = net.forward(params, step.za, b, cache);
        let mut ce = 0.0f64;
        for (r, &target) in targets.iter().enumerate() {
            let rows = r * bins..(r + 1) * bins;
            let d = &mut step.d_logits[rows.clone()];
            ce += self.cfg.two_hot.cross_entropy(&logits[rows], target, d) as f64;
        }
        let per_row = scale / b as f32;
        step.d_logits.iter_mut().for_each(|d| *d *= per_row);
        net.backward(
            params,
            step.za,
            cache,
            step.d_logits,
            Some(grads),
            Some(step.d_za),
        );
        add_latent_part(step.d_za, step.latent, step.d_z);
        ce / b as f64
    }

    /// Back through the dynamics from the last step to the first: ∂L/∂z_{t+1} is the
    /// consistency term's plus what reached z_{t+1} already; what passes through d(z_t, a_t)
    /// is added into ∂L/∂z_t.
    fn dynamics_backward(&self, params: &[f32], ws: &mut LossWorkspace, grads: &mut [f32]) {
        let (b, z, h) = (ws.batch, self.cfg.latent, self.cfg.horizon);
        let za_w = z + self.act;
        let range = self.ranges.dynamics.clone();
        let (p, g) = (&params[range.clone()], &mut grads[range]);
        for t in (0..h).rev() {
            let coef = self.cfg.consistency_coef * self.cfg.rho.powi(t as i32) / h as f32;
            let per_value = 2.0 * coef / (b * z) as f32;
            let next = &ws.zs[(t + 1) * b * z..(t + 2) * b * z];
            let target = &ws.next_z[t * b * z..(t + 1) * b * z];
            let reached = &ws.d_zs[(t + 1) * b * z..(t + 2) * b * z];
            for (((d, &p), &q), &r) in ws.d_next.iter_mut().zip(next).zip(target).zip(reached) {
                *d = per_value * (p - q) + r;
            }
            let za = &ws.za[t * b * za_w..(t + 1) * b * za_w];
            self.dynamics.backward(
                p,
                za,
                &mut ws.dynamics[t],
                &ws.d_next,
                Some(g),
                Some(&mut ws.d_za),
            );
            add_latent_part(&ws.d_za, z, &mut ws.d_zs[t * b * z..(t + 1) * b * z]);
        }
    }
}

/// The buffers one head's step shares with the others.
struct HeadStep<'a> {
    za: &'a [f32],
    d_logits: &'a mut [f32],
    d_za: &'a mut [f32],
    d_z: &'a mut [f32],
    latent: usize,
}

/// Add the latent part (the first `latent` values) of each (z, a) row of `d_za` into `d_z`.
fn add_latent_part(d_za: &[f32], latent: usize, d_z: &mut [f32]) {
    let width = d_za.len() / (d_z.len() / latent);
    for (dz, dza) in d_z.chunks_exact_mut(latent).zip(d_za.chunks_exact(width)) {
        dz.iter_mut().zip(&dza[..latent]).for_each(|(a, b)| *a += b);
    }
}

/// Concatenate rows of `x` (width `nx`) and `y` (width `ny`) into `out`.
pub(crate) fn concat_rows(x: &[f32], nx: usize, y: &[f32], ny: usize, out: &mut [f32]) {
    for ((o, x), y) in out
        .chunks_exact_mut(nx + ny)
        .zip(x.chunks_exact(nx))
        .zip(y.chunks_exact(ny))
    {
        o[..nx].copy_from_slice(x);
        o[nx..].copy_from_slice(y);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use mbpo_core::rng::{normal_f32, stream};

    /// A world model small enough to check every parameter by finite differences.
    pub(crate) fn small_config() -> WorldModelConfig {
        WorldModelConfig {
            latent: 16,
            encoder_hidden: 10,
            hidden: 12,
            q_heads: 2,
            two_hot: TwoHot {
                bins: 11,
                v_min: -3.0,
                v_max: 3.0,
            },
            ..Default::default()
        }
    }

    /// `batch` subsequences for `model` drawn from `g`: N(0, 1) observations and rewards,
    /// tanh of N(0, 1) actions.
    pub(crate) fn random_sequences(model: &WorldModel, batch: usize, g: &mut Rng) -> Sequences {
        let (h, obs, act) = (model.cfg.horizon, model.obs_dim(), model.act_dim());
        let mut draw = |n: usize| (0..n).map(|_| normal_f32(g)).collect::<Vec<f32>>();
        Sequences {
            batch,
            obs: draw((h + 1) * batch * obs),
            act: draw(h * batch * act).iter().map(|a| a.tanh()).collect(),
            reward: draw(h * batch),
        }
    }

    fn small() -> (WorldModel, Sequences, Vec<f32>) {
        let model = WorldModel::new(3, 2, small_config());
        let mut g = stream(5, "test.seq", 0);
        let seq = random_sequences(&model, 4, &mut g);
        let targets = (0..model.cfg.horizon * 4)
            .map(|_| 3.0 * normal_f32(&mut g))
            .collect();
        (model, seq, targets)
    }

    #[test]
    fn the_world_model_loss_gradient_matches_finite_differences() {
        let (model, seq, targets) = small();
        let mut params = vec![0.0; model.num_params()];
        model.init(&mut params, &mut stream(2, "test.wm", 0));
        // Away from the init's small weights and zero heads, so every path carries gradient.
        for (i, p) in params.iter_mut().enumerate() {
            *p += 0.25 * ((i as f32) * 0.77).sin();
        }
        let mut ws = LossWorkspace::new(&model, seq.batch);
        let mut grads = vec![0.0; model.num_params()];
        let losses = model.loss(&params, &seq, &targets, &mut ws, &mut grads);
        assert!(losses.consistency > 0.0 && losses.reward > 0.0 && losses.value > 0.0);
        let scale = grads.iter().fold(0.0f32, |m, g| m.max(g.abs())) as f64;
        // The latent targets stay those of `params`: the loss does not differentiate them.
        let eps = 3e-3f32;
        let mut sink = vec![0.0; model.num_params()];
        let mut worst = (0.0f64, 0usize);
        for i in 0..params.len() {
            let mut at = |d: f32| {
                let mut p = params.clone();
                p[i] += d;
                model
                    .loss_given_targets(&p, &seq, &targets, &mut ws, &mut sink)
                    .total as f64
            };
            let numeric = (at(eps) - at(-eps)) / (2.0 * eps as f64);
            let err = (grads[i] as f64 - numeric).abs() / (0.05 * scale + numeric.abs());
            if err > worst.0 {
                worst = (err, i);
            }
        }
        let (err, i) = worst;
        assert!(
            err < 3e-2,
            "param {i}: analytic {} (scale {scale}), relative error {err}",
            grads[i]
        );
        // The policy is not in this loss.
        let policy = model.ranges.policy.clone();
        assert!(grads[policy].iter().all(|&g| g == 0.0));
    }

    #[test]
    fn a_second_evaluation_adds_the_same_gradient_again() {
        let (model, seq, targets) = small();
        let mut params = vec![0.0; model.num_params()];
        model.init(&mut params, &mut stream(3, "test.wm", 0));
        let mut ws = LossWorkspace::new(&model, seq.batch);
        let mut once = vec![0.0; model.num_params()];
        let a = model.loss(&params, &seq, &targets, &mut ws, &mut once);
        let mut twice = once.clone();
        let b = model.loss(&params, &seq, &targets, &mut ws, &mut twice);
        assert_eq!(a, b, "the loss is a function of its inputs");
        for (o, t) in once.iter().zip(&twice) {
            assert!((2.0 * o - t).abs() <= 1e-6 * o.abs().max(1e-3));
        }
    }
}
