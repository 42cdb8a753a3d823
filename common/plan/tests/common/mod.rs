//! Toy models with known optimal action sequences.
#![allow(dead_code)]

use mbpo_core::rng::normal_f32;
use mbpo_core::Rng;
use mbpo_plan::{PlanError, PlanningModel};

/// Amplitude and frequency of the targets: |g(k+1) − g(k)| ≤ 0.2, reachable with |a| ≤ 0.4.
const AMP: f32 = 0.4;
const FREQ: f32 = 0.5;
/// Step gain: x' = x + GAIN·a.
pub const GAIN: f32 = 0.5;

/// Target of dimension j at time k.
pub fn target(j: usize, k: f32) -> f32 {
    AMP * (FREQ * k + j as f32).sin()
}

fn target_slope(j: usize, k: f32) -> f32 {
    AMP * FREQ * (FREQ * k + j as f32).cos()
}

/// A deterministic tracking task: obs = [x_0 … x_{A−1}, k], x' = x + GAIN·a + drift, k' = k + 1,
/// reward = −Σ_j (x'_j − g_j(k + 1))². From x = g(k) the unique optimum is
/// a_t = (g(k+t+1) − g(k+t))/GAIN, with return 0 (without drift).
#[derive(Debug, Clone)]
pub struct Tracker {
    pub act_dim: usize,
    /// Added to every x' (a model error when the planner's model has none and the world has).
    pub drift: f32,
    /// Recorded next_obs per slot (the reward's gradient needs x' − g).
    recorded: Vec<Vec<f32>>,
}

impl Tracker {
    pub fn new(act_dim: usize) -> Self {
        Self {
            act_dim,
            drift: 0.0,
            recorded: Vec::new(),
        }
    }

    /// Observation at time k with x on the target.
    pub fn start(&self, k: f32) -> Vec<f32> {
        let mut o: Vec<f32> = (0..self.act_dim).map(|j| target(j, k)).collect();
        o.push(k);
        o
    }

    /// The optimal plan of length h from `start(k)`.
    pub fn optimum(&self, k: f32, h: usize) -> Vec<f32> {
        let mut a = Vec::new();
        for t in 0..h {
            let kt = k + t as f32;
            for j in 0..self.act_dim {
                a.push((target(j, kt + 1.0) - target(j, kt)) / GAIN);
            }
        }
        a
    }

    /// One true step of one row.
    pub fn step_row(&self, obs: &[f32], act: &[f32], next: &mut [f32]) -> f32 {
        let a = self.act_dim;
        let k1 = obs[a] + 1.0;
        let mut r = 0.0;
        for j in 0..a {
            next[j] = obs[j] + GAIN * act[j] + self.drift;
            r -= (next[j] - target(j, k1)).powi(2);
        }
        next[a] = k1;
        r
    }

    /// True return of a plan from `obs`.
    pub fn rollout_return(&self, obs: &[f32], plan: &[f32]) -> f32 {
        let mut s = obs.to_vec();
        let mut next = s.clone();
        let mut ret = 0.0;
        for a in plan.chunks_exact(self.act_dim) {
            ret += self.step_row(&s, a, &mut next);
            s.copy_from_slice(&next);
        }
        ret
    }
}

impl PlanningModel for Tracker {
    fn obs_dim(&self) -> usize {
        self.act_dim + 1
    }
    fn act_dim(&self) -> usize {
        self.act_dim
    }
    fn members(&self) -> usize {
        1
    }
    fn step(
        &mut self,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        _rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        let (o, a) = (self.act_dim + 1, self.act_dim);
        for i in 0..members.len() {
            reward[i] = self.step_row(
                &obs[i * o..(i + 1) * o],
                &act[i * a..(i + 1) * a],
                &mut next_obs[i * o..(i + 1) * o],
            );
        }
        Ok(())
    }
    fn mean_step_recorded(
        &mut self,
        t: usize,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        let mut rng = mbpo_core::stream(0, "unused", 0);
        self.step(obs, act, members, &mut rng, reward, next_obs)?;
        if self.recorded.len() <= t {
            self.recorded.resize(t + 1, Vec::new());
        }
        self.recorded[t] = next_obs.to_vec();
        Ok(())
    }
    fn mean_step_backward(
        &mut self,
        t: usize,
        d_reward: &[f32],
        d_next_obs: &[f32],
        d_obs: &mut [f32],
        d_act: &mut [f32],
    ) -> Result<(), PlanError> {
        let (o, a) = (self.act_dim + 1, self.act_dim);
        let next = &self.recorded[t];
        for i in 0..d_reward.len() {
            let k1 = next[i * o + a];
            let mut dk = d_next_obs[i * o + a];
            for j in 0..a {
                let err = next[i * o + j] - target(j, k1);
                // r = −Σ err², err = x' − g(k + 1).
                let dx1 = d_next_obs[i * o + j] - 2.0 * err * d_reward[i];
                d_obs[i * o + j] = dx1;
                d_act[i * a + j] = GAIN * dx1;
                dk += 2.0 * err * target_slope(j, k1) * d_reward[i];
            }
            d_obs[i * o + a] = dk;
        }
        Ok(())
    }
}

/// A one-dimensional ensemble: member e moves x' = x + GAIN·a + bias[e] + noise·ε,
/// reward −x'². The expected-return optimum over members (one step) is
/// a* = −(x + mean(bias))/GAIN; member 0 alone would give −(x + bias[0])/GAIN.
#[derive(Debug, Clone)]
pub struct BiasedEnsemble {
    pub bias: Vec<f32>,
    pub noise: f32,
}

impl PlanningModel for BiasedEnsemble {
    fn obs_dim(&self) -> usize {
        1
    }
    fn act_dim(&self) -> usize {
        1
    }
    fn members(&self) -> usize {
        self.bias.len()
    }
    fn step(
        &mut self,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        for (i, &m) in members.iter().enumerate() {
            let x1 = obs[i] + GAIN * act[i] + self.bias[m] + self.noise * normal_f32(rng);
            next_obs[i] = x1;
            reward[i] = -x1 * x1;
        }
        Ok(())
    }
}
