//! Model rollouts: the inner loop of MBPO's Alg. 2 (paraphrased: for M model rollouts, take a
//! start state s_t from D_env, roll the model out k steps under π_φ, add the transitions to
//! D_model). The caller samples the M start states; this runs the k steps.
//!
//! Follows `mbpo.py::_rollout_model` and `fake_env.py::step`: at each of k steps the policy acts
//! on the live batch, every sample is predicted by a uniformly random *elite*, the next state and
//! reward are drawn from that member's Gaussian (`μ + σ·ε`), `done` comes from the task's
//! hand-written termination function (or, here, the model's learned one), every transition is
//! pushed to the model buffer, and terminated samples are dropped before the next step.
//!
//! Two additions, off unless asked for ([`RolloutFilter`]): each predicted next state can be
//! clamped into the box of the real states seen ([`StateBox`], `mbpo.clip_imagined_states`)
//! before the termination rule and the buffer see it, and each step can keep only the
//! transitions the elites agree on most (`rollout_mask.rs`, `mbpo.rollout_keep_fraction`).

use crate::error::RolloutError;
use crate::model::{MaskBuffers, ProbabilisticEnsemble, RolloutBuffers};
use mbpo_core::{BatchPolicy, ReplayBuffer, Rng, StateBox};
use serde::{Deserialize, Serialize};

/// A termination predicate `done(obs, act, next_obs)` (see `mbpo_envs::termination_fn`).
pub type Termination<'a> = &'a dyn Fn(&[f32], &[f32], &[f32]) -> bool;

/// A termination rule over a batch: `done(obs, act, next_obs, n, out)` for n row-major
/// transitions (a Python function); an error ends the rollout.
pub type BatchTermination<'a> =
    &'a mut dyn FnMut(&[f32], &[f32], &[f32], usize, &mut [bool]) -> Result<(), String>;

/// How [`ProbabilisticEnsemble::rollout`] decides that a predicted transition is terminal.
pub enum RolloutTermination<'a> {
    /// The task's rule, per transition.
    Rule(Termination<'a>),
    /// A rule over each step's batch.
    Batch(BatchTermination<'a>),
    /// The model's learned rule ([`ModelConfig::learn_termination`](crate::ModelConfig::learn_termination)).
    Learned,
}

/// A termination rule as a rollout generator or a planner holds it (a config's `termination`,
/// built by `ExperimentConfig::rollout_termination`).
pub enum RolloutRule {
    /// A Rust function of one transition.
    Rule(mbpo_envs::TerminationFn),
    /// The model's learned rule.
    Learned,
    /// A Python function over each step's batch, in its own process.
    Python(mbpo_envs::PythonTermination),
}

impl RolloutRule {
    /// Run `f` with the rule as a rollout takes it (a Python rule as a closure that lives as
    /// long as the call).
    pub fn with<R>(&mut self, f: impl FnOnce(RolloutTermination) -> R) -> R {
        match self {
            RolloutRule::Rule(rule) => f(RolloutTermination::Rule(rule)),
            RolloutRule::Learned => f(RolloutTermination::Learned),
            RolloutRule::Python(p) => {
                let mut batch = |o: &[f32], a: &[f32], n: &[f32], k: usize, out: &mut [bool]| {
                    p.done_batch(o, a, n, k, out).map_err(|e| e.to_string())
                };
                f(RolloutTermination::Batch(&mut batch))
            }
        }
    }

    /// `done` of `n` transitions (row-major `obs`, `act`, `next_obs`) into `out`; the learned
    /// rule is `model`'s.
    pub fn done_batch(
        &mut self,
        model: &mut ProbabilisticEnsemble,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) -> Result<(), RolloutError> {
        let (o, a) = (model.obs_dim(), model.act_dim());
        match self {
            RolloutRule::Rule(rule) => {
                for (r, done) in out[..n].iter_mut().enumerate() {
                    let (s, s_next) = (&obs[r * o..(r + 1) * o], &next_obs[r * o..(r + 1) * o]);
                    *done = rule(s, &act[r * a..(r + 1) * a], s_next);
                }
                Ok(())
            }
            RolloutRule::Learned => model.predict_terminated(obs, act, next_obs, n, out),
            RolloutRule::Python(p) => p
                .done_batch(obs, act, next_obs, n, out)
                .map_err(|e| RolloutError::Termination(e.to_string())),
        }
    }
}

/// What a rollout does to the model's predictions beyond the paper (nothing, in
/// [`RolloutFilter::PAPER`]).
#[derive(Debug, Clone, Copy)]
pub struct RolloutFilter<'a> {
    /// Clamp every predicted next state into this box (`mbpo.clip_imagined_states`).
    pub clip: Option<&'a StateBox>,
    /// Keep this fraction of each step's live transitions, those the elites disagree on least,
    /// and end the others' rollouts (`mbpo.rollout_keep_fraction`; 1: all, the paper).
    pub keep_fraction: f64,
}

impl RolloutFilter<'_> {
    /// MBPO's rollouts: every prediction kept as it is.
    pub const PAPER: RolloutFilter<'static> = RolloutFilter {
        clip: None,
        keep_fraction: 1.0,
    };
}

/// What one call of [`ProbabilisticEnsemble::rollout`] produced.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutStats {
    /// Model steps run (≤ k; fewer when every rollout terminated).
    pub steps: usize,
    /// Transitions pushed into the model buffer.
    pub transitions: usize,
    /// Transitions whose next state is terminal.
    pub terminated: usize,
    /// Live rollouts at the start of each step run.
    pub alive_per_step: Vec<usize>,
    /// Mean model reward over the pushed transitions.
    pub mean_reward: f64,
    /// Transitions whose predicted next state was clamped into the real box (0 without one).
    pub clipped: usize,
    /// Transitions the mask dropped (0 without one).
    #[serde(default)]
    pub masked: usize,
}

impl ProbabilisticEnsemble {
    /// Run `n` model rollouts of up to `k` steps from `start_obs` (`n x obs_dim`) under
    /// `policy`, pushing every transition into `out` (the model buffer D_model); `termination`
    /// decides which transitions end their rollout; `filter` clamps or masks the predictions
    /// first ([`RolloutFilter::PAPER`]: neither).
    ///
    /// Random draws come from `rng` in a fixed order (per step: the policy's actions, one elite
    /// per sample, then the Gaussian noise), so a seed fixes the result.
    #[allow(clippy::too_many_arguments)]
    pub fn rollout(
        &mut self,
        start_obs: &[f32],
        n: usize,
        policy: &mut dyn BatchPolicy,
        k: usize,
        mut termination: RolloutTermination,
        filter: RolloutFilter,
        rng: &mut Rng,
        out: &mut ReplayBuffer,
    ) -> Result<RolloutStats, RolloutError> {
        let (o, a) = (self.obs_dim, self.act_dim);
        self.check_rollout(start_obs, n, &termination, out)?;
        let mut stats = RolloutStats::before(k);
        let (mut buf, mut members, mut mask) = self.take_rollout_buffers(start_obs, n);
        let mut reward_sum = 0.0f64;
        let mut alive = n;
        for _ in 0..k {
            if alive == 0 {
                break;
            }
            stats.steps += 1;
            stats.alive_per_step.push(alive);
            // a_t ~ π(s_t) on the live batch.
            policy.act_batch(&buf.obs[..alive * o], alive, &mut buf.act[..alive * a], rng);
            // One uniformly random elite per sample, then (r, s') ~ N(μ, σ²) of that member.
            self.sample_elite_members(rng, &mut members[..alive]);
            self.ws.group.build(&members[..alive], self.config.members);
            self.sample_grouped(
                &buf.obs[..alive * o],
                &buf.act[..alive * a],
                alive,
                rng,
                &mut buf.reward[..alive],
                &mut buf.next_obs[..alive * o],
            );
            if let Some(state_box) = filter.clip {
                for next in buf.next_obs[..alive * o].chunks_exact_mut(o) {
                    stats.clipped += usize::from(state_box.clip(next));
                }
            }
            let judged = self
                .mask_step(&filter, &buf, alive, &mut mask)
                .and_then(|kept| {
                    self.mark_batch_terminations(&mut termination, &mut buf, alive)?;
                    Ok(kept)
                });
            let keep = match judged {
                Ok(kept) => kept.map(|kept| {
                    stats.masked += alive - kept;
                    &mask.keep[..alive]
                }),
                Err(e) => {
                    (self.ws.rollout, self.ws.members, self.ws.mask) = (buf, members, mask);
                    return Err(e);
                }
            };
            let live = Live {
                termination: &termination,
                keep,
                alive,
            };
            alive = push_live(&mut buf, live, out, &mut stats, &mut reward_sum);
        }
        stats.mean_reward = if stats.transitions > 0 {
            reward_sum / stats.transitions as f64
        } else {
            0.0
        };
        (self.ws.rollout, self.ws.members, self.ws.mask) = (buf, members, mask);
        Ok(stats)
    }

    /// The workspace's rollout buffers, sized for `n` rollouts from `start_obs` (given back
    /// when the rollout ends).
    fn take_rollout_buffers(
        &mut self,
        start_obs: &[f32],
        n: usize,
    ) -> (RolloutBuffers, Vec<usize>, MaskBuffers) {
        let (o, a) = (self.obs_dim, self.act_dim);
        let mut buf = std::mem::take(&mut self.ws.rollout);
        buf.obs.clear();
        buf.obs.extend_from_slice(start_obs);
        buf.act.resize(n * a, 0.0);
        buf.next_obs.resize(n * o, 0.0);
        buf.reward.resize(n, 0.0);
        buf.done.resize(n, false);
        let mut members = std::mem::take(&mut self.ws.members);
        members.resize(n, 0);
        (buf, members, std::mem::take(&mut self.ws.mask))
    }

    /// The mask of one step's `alive` transitions when `filter` asks for one: `Some(kept)`
    /// with `mask.keep` marking them; `None` keeps all.
    fn mask_step(
        &mut self,
        filter: &RolloutFilter,
        buf: &RolloutBuffers,
        alive: usize,
        mask: &mut MaskBuffers,
    ) -> Result<Option<usize>, RolloutError> {
        if filter.keep_fraction >= 1.0 {
            return Ok(None);
        }
        let (o, a) = (self.obs_dim, self.act_dim);
        let (obs, act) = (&buf.obs[..alive * o], &buf.act[..alive * a]);
        self.keep_mask(obs, act, alive, filter.keep_fraction, mask)
            .map(Some)
            .map_err(RolloutError::Mask)
    }

    /// The rollout's inputs fit this model: a learned rule exists if asked for, `n` start
    /// states, a buffer of this model's widths.
    fn check_rollout(
        &self,
        start_obs: &[f32],
        n: usize,
        termination: &RolloutTermination,
        out: &ReplayBuffer,
    ) -> Result<(), RolloutError> {
        let (o, a) = (self.obs_dim, self.act_dim);
        if matches!(termination, RolloutTermination::Learned) && self.termination.is_none() {
            return Err(RolloutError::NoTerminationRule);
        }
        if start_obs.len() != n * o {
            return Err(RolloutError::StartObs {
                n,
                obs_dim: o,
                expected: n * o,
                found: start_obs.len(),
            });
        }
        if (out.obs_dim(), out.act_dim()) != (o, a) {
            return Err(RolloutError::BufferDims {
                obs_dim: o,
                act_dim: a,
                found_obs: out.obs_dim(),
                found_act: out.act_dim(),
            });
        }
        Ok(())
    }

    /// `buf.done` of the `alive` rows for the rules that judge a step's batch at once (the
    /// learned one, a batch rule); a per-transition rule is asked in [`push_live`].
    fn mark_batch_terminations(
        &mut self,
        termination: &mut RolloutTermination,
        buf: &mut RolloutBuffers,
        alive: usize,
    ) -> Result<(), RolloutError> {
        let (s, act, next) = (&buf.obs, &buf.act, &buf.next_obs);
        match (termination, self.termination.as_mut()) {
            (RolloutTermination::Learned, Some(learned)) => {
                learned.predict(s, act, next, alive, &mut buf.done[..alive])
            }
            (RolloutTermination::Batch(rule), _) => {
                rule(s, act, next, alive, &mut buf.done[..alive])
                    .map_err(RolloutError::Termination)?
            }
            _ => {}
        }
        Ok(())
    }
}

impl RolloutStats {
    /// Nothing rolled out yet, room for `k` steps.
    fn before(k: usize) -> Self {
        Self {
            steps: 0,
            transitions: 0,
            terminated: 0,
            alive_per_step: Vec::with_capacity(k),
            mean_reward: 0.0,
            clipped: 0,
            masked: 0,
        }
    }
}

/// One step's live transitions as [`push_live`] takes them.
struct Live<'a, 'r> {
    termination: &'a RolloutTermination<'r>,
    /// The mask's verdict per transition (`None`: all kept).
    keep: Option<&'a [bool]>,
    alive: usize,
}

/// Push the `alive` transitions of a step the mask keeps into `out` and keep their
/// non-terminated next states as the next step's states, compacted in place; returns how many
/// live on.
fn push_live(
    buf: &mut RolloutBuffers,
    live: Live,
    out: &mut ReplayBuffer,
    stats: &mut RolloutStats,
    reward_sum: &mut f64,
) -> usize {
    let (o, a) = (out.obs_dim(), out.act_dim());
    let Live {
        termination,
        keep,
        alive,
    } = live;
    let mut kept = 0;
    for i in 0..alive {
        if keep.is_some_and(|keep| !keep[i]) {
            continue; // masked: neither stored nor rolled on
        }
        let (s, act) = (&buf.obs[i * o..(i + 1) * o], &buf.act[i * a..(i + 1) * a]);
        let s_next = &buf.next_obs[i * o..(i + 1) * o];
        let done = match termination {
            RolloutTermination::Rule(rule) => rule(s, act, s_next),
            _ => buf.done[i],
        };
        out.push(s, act, buf.reward[i], s_next, done);
        stats.transitions += 1;
        *reward_sum += buf.reward[i] as f64;
        if done {
            stats.terminated += 1;
        } else {
            // Row `kept` ≤ i of obs has been pushed already, so it may be overwritten.
            let (dst, src) = (kept * o, i * o);
            let next = &buf.next_obs[src..src + o];
            buf.obs[dst..dst + o].copy_from_slice(next);
            kept += 1;
        }
    }
    kept
}

/// MBPO's rollout-length schedule `[e_min, e_max, k_min, k_max]` (`_set_rollout_length`):
/// k = k_min up to epoch e_min, then linear in the epoch up to k_max at e_max, truncated
/// towards zero with `int()`, and k_max afterwards.
///
/// A degenerate schedule with `e_max ≤ e_min` jumps to k_max after e_min (Python would divide
/// by zero).
pub fn rollout_length(epoch: usize, schedule: [usize; 4]) -> usize {
    let [e_min, e_max, k_min, k_max] = schedule;
    if epoch <= e_min {
        return k_min;
    }
    let dx = if e_max > e_min {
        ((epoch - e_min) as f64 / (e_max - e_min) as f64).min(1.0)
    } else {
        1.0
    };
    let y = dx * (k_max as f64 - k_min as f64) + k_min as f64;
    y as usize
}

/// The terms of MBPO's model-buffer capacity (`_reallocate_model_pool`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModelPoolSizing {
    /// Epochs of model data retained ("model_retain_epochs", 1; Humanoid 5).
    pub retain_epochs: usize,
    /// Model rollouts started per model training, M·train_freq ("rollout_batch_size", 100e3).
    pub rollout_batch_size: usize,
    /// Environment steps per epoch ("epoch_length", 1000).
    pub epoch_length: usize,
    /// Environment steps between model trainings ("model_train_freq", 250).
    pub model_train_freq: usize,
}

impl Default for ModelPoolSizing {
    /// MBPO's MuJoCo defaults: 1 epoch, 100k rollouts, 1000-step epochs, retrain every 250.
    fn default() -> Self {
        Self {
            retain_epochs: 1,
            rollout_batch_size: 100_000,
            epoch_length: 1000,
            model_train_freq: 250,
        }
    }
}

impl ModelPoolSizing {
    /// Capacity for rollout length k:
    /// `retain_epochs · int(k · rollout_batch_size · epoch_length / model_train_freq)`, i.e.
    /// one epoch's worth of rollouts, every step of each kept. Reallocate the buffer whenever k
    /// changes (`ReplayBuffer::set_capacity` keeps the newest transitions).
    ///
    /// # Panics
    /// If `model_train_freq` is 0.
    pub fn capacity(&self, k: usize) -> usize {
        assert!(
            self.model_train_freq > 0,
            "model_train_freq must be positive"
        );
        let rollouts_per_epoch = self.rollout_batch_size as f64 * self.epoch_length as f64
            / self.model_train_freq as f64;
        let model_steps_per_epoch = (k as f64 * rollouts_per_epoch) as usize;
        self.retain_epochs * model_steps_per_epoch
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rollout_length_follows_the_hopper_schedule() {
        let hopper = [20, 150, 1, 15];
        assert_eq!(rollout_length(0, hopper), 1);
        assert_eq!(rollout_length(20, hopper), 1);
        // Epoch 21: 1 + 14/130 = 1.107 → 1; epoch 30: 1 + 14·10/130 = 2.08 → 2.
        assert_eq!(rollout_length(21, hopper), 1);
        assert_eq!(rollout_length(30, hopper), 2);
        assert_eq!(rollout_length(85, hopper), 8); // 1 + 14·65/130 = 8.0
        assert_eq!(rollout_length(149, hopper), 14); // 14.89 truncates
        assert_eq!(rollout_length(150, hopper), 15);
        assert_eq!(rollout_length(1000, hopper), 15);
        let ant = [20, 100, 1, 25];
        assert_eq!(rollout_length(60, ant), 13); // 1 + 24·0.5
        let flat = [1, 15, 1, 1];
        assert!((0..100).all(|e| rollout_length(e, flat) == 1));
        assert_eq!(rollout_length(6, [5, 5, 1, 4]), 4, "degenerate schedule");
    }

    #[test]
    fn model_pool_capacity_is_400k_per_step_of_rollout() {
        let mujoco = ModelPoolSizing::default();
        assert_eq!(mujoco.capacity(1), 400_000);
        assert_eq!(mujoco.capacity(15), 6_000_000);
        let humanoid = ModelPoolSizing {
            retain_epochs: 5,
            model_train_freq: 1000,
            ..mujoco
        };
        assert_eq!(humanoid.capacity(25), 12_500_000);
        let inverted_pendulum = ModelPoolSizing {
            epoch_length: 250,
            ..mujoco
        };
        assert_eq!(inverted_pendulum.capacity(1), 100_000);
    }
}
