//! Reward-weighted refinement with filtered noise: MPPI as PDDM uses it (Nagabandi et al. 2019,
//! "Deep Dynamics Models for Learning Dexterous Manipulation", §4, eqs. 3–4; Williams et al.
//! 2017 for MPPI).
//!
//! ```text
//! μ ← warm start (previous plan shifted by one step; the last step repeated)
//! repeat `iterations` times:
//!     u_t^i ~ N(0, σ²)                                  sample_noise: raw noise
//!     n_t^i = β·u_t^i + (1 − β)·n_{t−1}^i,  n_{−1} = 0     filtered (temporally smooth) noise
//!     a_t^i = clip(μ_t + n_t^i, −1, 1)
//!     R_i = trajectory-sampled return of a^i            evaluate
//!     μ_t ← Σ_i e^{γ(R_i − max R)}·a_t^i / Σ_i e^{γ(R_i − max R)}     reward_weighted_mean
//! plan = μ
//! ```
//!
//! γ (the temperature's inverse) trades averaging for greed: γ → ∞ keeps only the best sample,
//! γ → 0 averages all of them. β < 1 correlates the noise over time, which suits actuators that
//! cannot change instantly (PDDM's hands); β = 1 is independent noise per step. Subtracting
//! max R before exponentiating changes nothing but keeps the weights finite.

use crate::config::{MppiConfig, PlannerConfig};
use crate::error::PlanError;
use crate::model::PlanningModel;
use crate::planner::{restore_sequence, Budget, Planner};
use crate::sampler::TrajectorySampler;
use mbpo_core::rng::normal_f32;
use mbpo_core::Rng;

/// The PDDM planner.
#[derive(Debug, Clone)]
pub struct Mppi {
    horizon: usize,
    act_dim: usize,
    cfg: MppiConfig,
    sampler: TrajectorySampler,
    mean: Vec<f32>,
    /// N x H x A.
    population: Vec<f32>,
    returns: Vec<f32>,
    weights: Vec<f64>,
    /// n_{t−1} of the candidate being sampled.
    prev: Vec<f32>,
    best_return: f32,
    budget: Option<std::time::Duration>,
    iterations_done: usize,
}

impl Mppi {
    /// MPPI per `cfg` (`mppi.*`, `horizon`, `particles`).
    pub fn new(cfg: &PlannerConfig, act_dim: usize) -> Self {
        let (h, n) = (cfg.horizon, cfg.mppi.candidates);
        Self {
            horizon: h,
            act_dim,
            cfg: cfg.mppi.clone(),
            sampler: TrajectorySampler::new(cfg.particles),
            mean: vec![0.0; h * act_dim],
            population: vec![0.0; n * h * act_dim],
            returns: vec![0.0; n],
            weights: vec![0.0; n],
            prev: vec![0.0; act_dim],
            best_return: f32::NEG_INFINITY,
            budget: cfg.budget(),
            iterations_done: 0,
        }
    }

    /// The current mean sequence (`H x A`).
    pub fn mean(&self) -> &[f32] {
        &self.mean
    }

    /// a^i = clip(μ + n^i) with n^i the β-filtered Gaussian noise (see the module docs).
    fn sample_population(&mut self, rng: &mut Rng) {
        let Self {
            act_dim,
            cfg,
            mean,
            population,
            prev,
            ..
        } = self;
        let len = mean.len();
        for cand in population.chunks_exact_mut(len) {
            prev.fill(0.0); // n_{−1} = 0
            for (row, mu) in cand
                .chunks_exact_mut(*act_dim)
                .zip(mean.chunks_exact(*act_dim))
            {
                for ((v, &m), n) in row.iter_mut().zip(mu).zip(prev.iter_mut()) {
                    let u = cfg.sigma * normal_f32(rng);
                    *n = cfg.beta * u + (1.0 - cfg.beta) * *n;
                    *v = (m + *n).clamp(-1.0, 1.0);
                }
            }
        }
    }

    /// μ_t = Σ_i w_i·a_t^i / Σ_i w_i with w_i = exp(γ·(R_i − max R)).
    fn reward_weighted_mean(&mut self) {
        let max = self
            .returns
            .iter()
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        self.best_return = max;
        if !max.is_finite() {
            return; // every sample diverged: keep μ
        }
        let gamma = self.cfg.temperature as f64;
        let mut total = 0.0f64;
        for (w, &r) in self.weights.iter_mut().zip(&self.returns) {
            *w = (gamma * (r as f64 - max as f64)).exp();
            total += *w;
        }
        let len = self.mean.len();
        for j in 0..len {
            let mut s = 0.0f64;
            for (i, &w) in self.weights.iter().enumerate() {
                s += w * self.population[i * len + j] as f64;
            }
            self.mean[j] = (s / total) as f32;
        }
    }

    /// One refinement (sample, evaluate, reweight); returns the best sampled return.
    pub fn iteration(
        &mut self,
        model: &mut dyn PlanningModel,
        obs: &[f32],
        rng: &mut Rng,
    ) -> Result<f32, PlanError> {
        self.sample_population(rng);
        self.sampler.evaluate(
            model,
            obs,
            &self.population,
            self.cfg.candidates,
            self.horizon,
            rng,
            &mut self.returns,
        )?;
        self.reward_weighted_mean();
        Ok(self.best_return)
    }
}

impl Planner for Mppi {
    fn horizon(&self) -> usize {
        self.horizon
    }
    fn act_dim(&self) -> usize {
        self.act_dim
    }

    fn plan(
        &mut self,
        model: &mut dyn PlanningModel,
        obs: &[f32],
        rng: &mut Rng,
    ) -> Result<&[f32], PlanError> {
        let budget = Budget::start(self.budget);
        self.sampler.bind_particles(model.members(), rng);
        self.iterations_done = 0;
        while self.iterations_done < self.cfg.iterations && budget.allows(self.iterations_done) {
            self.iteration(model, obs, rng)?;
            self.iterations_done += 1;
        }
        Ok(&self.mean)
    }

    fn iterations_done(&self) -> usize {
        self.iterations_done
    }

    fn predicted_return(&self) -> f32 {
        self.best_return
    }

    /// PDDM's warm start: μ_t ← μ_{t+k}; the freed tail repeats the last kept step.
    fn shift(&mut self, k: usize) {
        let (a, h) = (self.act_dim, self.horizon);
        if k >= h {
            self.mean.fill(0.0);
            return;
        }
        self.mean.copy_within(k * a.., 0);
        let last = (h - k - 1) * a;
        for t in h - k..h {
            self.mean.copy_within(last..last + a, t * a);
        }
    }

    fn reset(&mut self) {
        self.mean.fill(0.0);
    }

    fn warm_start(&self) -> Option<&[f32]> {
        Some(&self.mean)
    }

    fn set_warm_start(&mut self, warm: Option<&[f32]>) -> Result<(), PlanError> {
        restore_sequence(&mut self.mean, warm)
    }
}
