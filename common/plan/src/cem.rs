//! The cross-entropy method as PETS uses it (Chua et al. 2018, §5; Botev et al. 2013).
//!
//! A diagonal Gaussian over action sequences is refitted to its best samples:
//!
//! ```text
//! μ ← warm start (previous plan shifted by one step; 0 at the end)   σ² ← init_std²
//! repeat `iterations` times:
//!     σ̃² = min(σ², (μ − low)²/4, (high − μ)²/4)          keep μ ± 2σ̃ inside the box
//!     a_i = μ + σ̃·ε_i,  ε_i ~ N(0, 1) truncated to [−2, 2]     sample_population
//!     R_i = trajectory-sampled return of a_i                       evaluate
//!     E = the `elites` best a_i                                    select_elites
//!     μ ← α·μ + (1 − α)·mean(E),  σ² ← α·σ² + (1 − α)·var(E)      refit
//! plan = μ
//! ```
//!
//! The mean is the plan (PETS), not the best sample seen: it averages out the sampling noise of
//! the returns. The variance is reset every plan; only the mean is warm-started.

use crate::config::{CemConfig, PlannerConfig};
use crate::error::PlanError;
use crate::model::PlanningModel;
use crate::planner::{restore_sequence, shift_sequence, Budget, Planner};
use crate::sampler::TrajectorySampler;
use mbpo_core::rng::normal_f32;
use mbpo_core::Rng;

/// PETS' CEM planner.
#[derive(Debug, Clone)]
pub struct Cem {
    horizon: usize,
    act_dim: usize,
    cfg: CemConfig,
    sampler: TrajectorySampler,
    mean: Vec<f32>,
    var: Vec<f32>,
    /// N x H x A.
    population: Vec<f32>,
    returns: Vec<f32>,
    /// Candidate indices; the first `elites` are the elites after selection.
    order: Vec<usize>,
    elite_return: f32,
    budget: Option<std::time::Duration>,
    iterations_done: usize,
}

impl Cem {
    /// CEM per `cfg` (`cem.*`, `horizon`, `particles`).
    pub fn new(cfg: &PlannerConfig, act_dim: usize) -> Self {
        let (h, n) = (cfg.horizon, cfg.cem.candidates);
        Self {
            horizon: h,
            act_dim,
            cfg: cfg.cem.clone(),
            sampler: TrajectorySampler::new(cfg.particles),
            mean: vec![0.0; h * act_dim],
            var: vec![0.0; h * act_dim],
            population: vec![0.0; n * h * act_dim],
            returns: vec![0.0; n],
            order: Vec::with_capacity(n),
            elite_return: f32::NEG_INFINITY,
            budget: cfg.budget(),
            iterations_done: 0,
        }
    }

    /// The current mean sequence (`H x A`).
    pub fn mean(&self) -> &[f32] {
        &self.mean
    }

    /// Begin a plan: a fresh particle binding and σ² = init_std² (μ is kept: warm start).
    pub fn begin(&mut self, model: &dyn PlanningModel, rng: &mut Rng) {
        self.sampler.bind_particles(model.members(), rng);
        self.var.fill(self.cfg.init_std * self.cfg.init_std);
    }

    /// One CEM iteration (sample, evaluate, select, refit); returns the best return among this
    /// iteration's samples. Call [`Cem::begin`] first.
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
        self.select_elites();
        self.refit();
        Ok(self.returns[self.order[0]])
    }

    /// a_i = μ + σ̃·ε_i with σ̃ bounded so that μ ± 2σ̃ stays in [−1, 1] and ε_i truncated to
    /// [−2, 2] (by rejection): every sample is inside the box without clipping.
    fn sample_population(&mut self, rng: &mut Rng) {
        let len = self.mean.len();
        for cand in self.population.chunks_exact_mut(len) {
            for ((a, &m), &v) in cand.iter_mut().zip(&self.mean).zip(&self.var) {
                let to_bound = (m + 1.0).min(1.0 - m).max(0.0) * 0.5;
                let std = v.sqrt().min(to_bound);
                let eps = loop {
                    let e = normal_f32(rng);
                    if e.abs() <= 2.0 {
                        break e;
                    }
                };
                *a = m + std * eps;
            }
        }
    }

    /// Partially sort candidate indices so the `elites` best come first, best at index 0.
    fn select_elites(&mut self) {
        let k = self.cfg.elites;
        let returns = &self.returns;
        self.order.clear();
        self.order.extend(0..returns.len());
        let desc = |&i: &usize, &j: &usize| returns[j].total_cmp(&returns[i]);
        if k < self.order.len() {
            self.order.select_nth_unstable_by(k - 1, desc);
        }
        self.order[..k].sort_unstable_by(desc);
        self.elite_return = returns[self.order[0]];
    }

    /// μ ← α·μ + (1 − α)·mean(E), σ² ← α·σ² + (1 − α)·var(E) (population variance).
    fn refit(&mut self) {
        let (k, len, alpha) = (self.cfg.elites, self.mean.len(), self.cfg.alpha);
        let elites = &self.order[..k];
        for j in 0..len {
            let mut sum = 0.0f64;
            for &e in elites {
                sum += self.population[e * len + j] as f64;
            }
            let m = sum / k as f64;
            let mut sq = 0.0f64;
            for &e in elites {
                let d = self.population[e * len + j] as f64 - m;
                sq += d * d;
            }
            let v = sq / k as f64;
            self.mean[j] = alpha * self.mean[j] + (1.0 - alpha) * m as f32;
            self.var[j] = alpha * self.var[j] + (1.0 - alpha) * v as f32;
        }
    }
}

impl Planner for Cem {
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
        self.begin(model, rng);
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
        self.elite_return
    }

    fn shift(&mut self, k: usize) {
        shift_sequence(&mut self.mean, self.act_dim, k, 0.0);
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
