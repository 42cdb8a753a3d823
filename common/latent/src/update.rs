//! One TD-MPC2 update (Hansen et al. 2024, Algorithm 1's `update`): TD targets from the target
//! Q heads, the world-model loss and an Adam step (the encoder at 0.3 of the learning rate,
//! the gradient's norm clipped at 20), the policy loss on the rolled latents and its own Adam
//! step, then the target Q heads move towards the online ones by Polyak averaging (τ = 0.01).

use mbpo_core::rng::{index, normal_f32, Rng};
use mbpo_nn::ops::{clip_grad_norm, polyak};
use mbpo_nn::{Adam, AdamConfig, AdamState};
use serde::{Deserialize, Serialize};

use crate::policy::PolicyWorkspace;
use crate::world_model::{LossWorkspace, Losses, Sequences, WorldModel};

/// The optimiser's settings (TD-MPC2's defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateConfig {
    /// Adam's learning rate.
    pub lr: f32,
    /// The encoder's learning rate, as a fraction of `lr`.
    pub encoder_lr_scale: f32,
    /// The gradients' norm is clipped to this.
    pub grad_clip: f32,
    /// Polyak step of the target Q heads.
    pub tau: f32,
    /// Step of the running scale of Q (its 5-95 percentile range).
    pub scale_tau: f32,
}

impl Default for UpdateConfig {
    fn default() -> Self {
        Self {
            lr: 3e-4,
            encoder_lr_scale: 0.3,
            grad_clip: 20.0,
            tau: 0.01,
            scale_tau: 0.01,
        }
    }
}

/// What one update came to.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UpdateStats {
    /// The world-model loss before the step.
    pub model: Losses,
    /// The policy loss before its step.
    pub policy: f32,
    /// The model gradient's norm before clipping.
    pub grad_norm: f32,
    /// The running scale of Q after the update.
    pub q_scale: f32,
}

/// What a checkpoint keeps of a [`Learner`]: everything an update reads besides the batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LearnerState {
    /// The networks' parameters.
    pub params: Vec<f32>,
    /// The target Q heads (laid out as the whole model).
    pub target: Vec<f32>,
    /// The encoder's optimiser.
    pub encoder_adam: AdamState,
    /// The dynamics', reward's and Q heads' optimiser.
    pub model_adam: AdamState,
    /// The policy's optimiser.
    pub policy_adam: AdamState,
    /// The running scale of Q.
    pub q_scale: f32,
}

/// A world model with its parameters, target Q heads, optimisers and buffers for one batch size.
pub struct Learner {
    /// The networks.
    pub model: WorldModel,
    /// Their parameters.
    pub params: Vec<f32>,
    /// The target copies of the Q heads (laid out as the whole model: only the Q range is used).
    target: Vec<f32>,
    config: UpdateConfig,
    encoder_adam: Adam,
    model_adam: Adam,
    policy_adam: Adam,
    q_scale: f32,
    grads: Vec<f32>,
    loss_ws: LossWorkspace,
    target_ws: PolicyWorkspace,
    policy_ws: PolicyWorkspace,
    q_targets: Vec<f32>,
    noise: Vec<f32>,
    /// Scratch for the percentiles of Q (no allocation per update).
    sorted_q: Vec<f32>,
}

impl Learner {
    /// A learner of `model` with initial `params` for batches of `batch` subsequences.
    pub fn new(model: WorldModel, params: Vec<f32>, config: UpdateConfig, batch: usize) -> Self {
        let h = model.cfg.horizon;
        let enc = model.encoder_range();
        let rest = enc.end..model.policy_range().start;
        let adam = |n: usize, lr: f32| Adam::new(n, AdamConfig::with_lr(lr));
        // The policy's ε as TD-MPC2's (1e-5).
        let mut policy_adam = adam(model.policy_range().len(), config.lr);
        policy_adam.config.eps = 1e-5;
        Self {
            target: params.clone(),
            encoder_adam: adam(enc.len(), config.lr * config.encoder_lr_scale),
            model_adam: adam(rest.len(), config.lr),
            policy_adam,
            q_scale: 1.0,
            grads: vec![0.0; params.len()],
            loss_ws: LossWorkspace::new(&model, batch),
            target_ws: PolicyWorkspace::new(&model, h * batch),
            policy_ws: PolicyWorkspace::new(&model, (h + 1) * batch),
            q_targets: vec![0.0; h * batch],
            noise: vec![0.0; (h + 1) * batch * model.act_dim()],
            sorted_q: Vec::with_capacity((h + 1) * batch),
            model,
            params,
            config,
        }
    }

    /// The running scale of Q.
    pub fn q_scale(&self) -> f32 {
        self.q_scale
    }

    /// The state a checkpoint keeps.
    pub fn state(&self) -> LearnerState {
        LearnerState {
            params: self.params.clone(),
            target: self.target.clone(),
            encoder_adam: self.encoder_adam.state().clone(),
            model_adam: self.model_adam.state().clone(),
            policy_adam: self.policy_adam.state().clone(),
            q_scale: self.q_scale,
        }
    }

    /// Continue from [`Learner::state`]; a state of another model's size is refused (nothing
    /// changed).
    pub fn restore(&mut self, s: LearnerState) -> Result<(), String> {
        let sizes = [
            ("params", s.params.len(), self.params.len()),
            ("target", s.target.len(), self.target.len()),
            (
                "encoder Adam",
                s.encoder_adam.m.len(),
                self.encoder_adam.state().m.len(),
            ),
            (
                "model Adam",
                s.model_adam.m.len(),
                self.model_adam.state().m.len(),
            ),
            (
                "policy Adam",
                s.policy_adam.m.len(),
                self.policy_adam.state().m.len(),
            ),
        ];
        if let Some((what, found, expected)) = sizes.iter().find(|(_, f, e)| f != e) {
            return Err(format!(
                "the world model's {what} hold {found} values, this model {expected}: \
                 the checkpoint is of another model size"
            ));
        }
        self.params = s.params;
        self.target = s.target;
        self.encoder_adam.set_state(s.encoder_adam);
        self.model_adam.set_state(s.model_adam);
        self.policy_adam.set_state(s.policy_adam);
        self.q_scale = s.q_scale;
        Ok(())
    }

    /// One update on `seq`, its random draws from `rng`.
    pub fn update(&mut self, seq: &Sequences, rng: &mut Rng) -> UpdateStats {
        let m = &self.model;
        let (h, b, a) = (m.cfg.horizon, seq.batch, m.act_dim());
        // TD targets: the latent targets of o₁..o_H, their policy actions, the target heads.
        m.encode_targets(&self.params, seq, &mut self.loss_ws);
        self.noise.iter_mut().for_each(|e| *e = normal_f32(rng));
        let heads = two_heads(m.cfg.q_heads, rng);
        let next_z = m.latent_targets(&self.loss_ws);
        let eps = &self.noise[..h * b * a];
        let (params, target) = (&self.params, &self.target);
        m.td_targets(
            params,
            target,
            heads,
            next_z,
            &seq.reward,
            eps,
            &mut self.target_ws,
            &mut self.q_targets,
        );
        // The world model's step (the online Q heads with dropout).
        self.loss_ws.draw_q_dropout(m, m.cfg.q_dropout, rng);
        self.grads.fill(0.0);
        let losses = m.loss_given_targets(
            &self.params,
            seq,
            &self.q_targets,
            &mut self.loss_ws,
            &mut self.grads,
        );
        let policy = m.policy_range();
        let grad_norm = clip_grad_norm(&mut self.grads[..policy.start], self.config.grad_clip);
        let enc = m.encoder_range();
        let (enc_p, rest_p) = self.params[..policy.start].split_at_mut(enc.end);
        let (enc_g, rest_g) = self.grads[..policy.start].split_at(enc.end);
        self.encoder_adam.step(enc_p, enc_g);
        self.model_adam.step(rest_p, rest_g);
        // The policy's step on the rolled latents (detached), through the updated Q heads.
        let zs = m.rolled_latents(&self.loss_ws);
        let heads = two_heads(m.cfg.q_heads, rng);
        self.noise.iter_mut().for_each(|e| *e = normal_f32(rng));
        self.policy_ws.draw_q_dropout(m, m.cfg.q_dropout, rng);
        self.grads.fill(0.0);
        let pi_loss = m.policy_loss(
            &self.params,
            zs,
            &self.noise,
            heads,
            self.q_scale,
            &mut self.policy_ws,
            &mut self.grads,
        );
        self.q_scale = update_scale(
            self.q_scale,
            self.policy_ws.q_values(),
            self.config.scale_tau,
            &mut self.sorted_q,
        );
        clip_grad_norm(&mut self.grads[policy.clone()], self.config.grad_clip);
        self.policy_adam
            .step(&mut self.params[policy.clone()], &self.grads[policy]);
        let q = m.q_range();
        polyak(
            &mut self.target[q.clone()],
            &self.params[q],
            self.config.tau,
        );
        UpdateStats {
            model: losses,
            policy: pi_loss,
            grad_norm,
            q_scale: self.q_scale,
        }
    }
}

/// Two different Q heads of `k`, drawn uniformly (both when there are two).
fn two_heads(k: usize, rng: &mut Rng) -> [usize; 2] {
    if k == 2 {
        return [0, 1];
    }
    let first = index(rng, k);
    [first, (first + 1 + index(rng, k - 1)) % k]
}

/// TD-MPC2's running scale of Q: a step of `tau` towards the 5-95 percentile range of `q`
/// (at least 1, so a flat Q does not blow the loss up). `sorted` is scratch.
fn update_scale(scale: f32, q: &[f32], tau: f32, sorted: &mut Vec<f32>) -> f32 {
    sorted.clear();
    sorted.extend_from_slice(q);
    sorted.sort_by(f32::total_cmp);
    let at = |p: f64| sorted[((sorted.len() - 1) as f64 * p).round() as usize];
    let range = (at(0.95) - at(0.05)).max(1.0);
    scale + tau * (range - scale)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::two_hot::TwoHot;
    use crate::world_model::tests::random_sequences;
    use crate::world_model::WorldModelConfig;
    use mbpo_core::rng::stream;

    #[test]
    fn updates_on_one_batch_lower_its_loss_and_move_the_targets_slowly() {
        let cfg = WorldModelConfig {
            latent: 16,
            encoder_hidden: 16,
            hidden: 32,
            two_hot: TwoHot {
                bins: 21,
                v_min: -5.0,
                v_max: 5.0,
            },
            ..Default::default()
        };
        let (obs, act, batch) = (4, 2, 16);
        let model = WorldModel::new(obs, act, cfg);
        let mut params = vec![0.0; model.num_params()];
        model.init(&mut params, &mut stream(0, "test.update", 0));
        let seq = random_sequences(&model, batch, &mut stream(1, "test.update.seq", 0));
        let config = UpdateConfig {
            lr: 3e-3,
            ..Default::default()
        };
        let mut learner = Learner::new(model, params.clone(), config, batch);
        let mut rng = stream(2, "test.update.draws", 0);
        let first = learner.update(&seq, &mut rng);
        let mut last = first;
        for _ in 0..150 {
            last = learner.update(&seq, &mut rng);
        }
        assert!(first.model.total.is_finite() && last.model.total.is_finite());
        assert!(
            last.model.reward < 0.5 * first.model.reward,
            "the reward loss on a batch it keeps seeing falls: {first:?} -> {last:?}"
        );
        assert!(
            last.model.consistency < first.model.consistency,
            "{first:?} -> {last:?}"
        );
        // Targets follow the online heads at τ = 0.01 a step: behind them, not equal.
        let q = learner.model.q_range();
        let moved: f32 = learner.params[q.clone()]
            .iter()
            .zip(&params[q.clone()])
            .map(|(a, b)| (a - b).abs())
            .sum();
        let behind: f32 = learner.params[q.clone()]
            .iter()
            .zip(&learner.target[q])
            .map(|(a, b)| (a - b).abs())
            .sum();
        assert!(
            moved > 0.0 && behind > 0.0 && behind < moved,
            "moved {moved}, targets behind by {behind}"
        );
    }
}
