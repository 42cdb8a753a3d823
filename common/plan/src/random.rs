//! Random shooting (e.g. Nagabandi et al. 2018, "Neural Network Dynamics for Model-Based Deep
//! RL with Model-Free Fine-Tuning", §IV.C): draw N action sequences uniformly from the box,
//! score each by trajectory sampling, keep the best. Memoryless: there is nothing to warm-start.

use crate::config::PlannerConfig;
use crate::error::PlanError;
use crate::model::PlanningModel;
use crate::planner::{argmax, Planner};
use crate::sampler::TrajectorySampler;
use mbpo_core::rng::uniform_range_f32;
use mbpo_core::Rng;

/// The best of N uniform random sequences.
#[derive(Debug, Clone)]
pub struct RandomShooting {
    horizon: usize,
    act_dim: usize,
    candidates: usize,
    sampler: TrajectorySampler,
    /// N x H x A.
    population: Vec<f32>,
    returns: Vec<f32>,
    best: Vec<f32>,
    best_return: f32,
}

impl RandomShooting {
    /// Random shooting per `cfg` (`random.candidates`, `horizon`, `particles`).
    pub fn new(cfg: &PlannerConfig, act_dim: usize) -> Self {
        let (h, n) = (cfg.horizon, cfg.random.candidates);
        Self {
            horizon: h,
            act_dim,
            candidates: n,
            sampler: TrajectorySampler::new(cfg.particles),
            population: vec![0.0; n * h * act_dim],
            returns: vec![0.0; n],
            best: vec![0.0; h * act_dim],
            best_return: f32::NEG_INFINITY,
        }
    }

    /// Step 1: N sequences uniform in [−1, 1]^(H·A).
    fn sample_population(&mut self, rng: &mut Rng) {
        self.population
            .iter_mut()
            .for_each(|v| *v = uniform_range_f32(rng, -1.0, 1.0));
    }

    /// Step 2: keep the highest-scoring sequence.
    fn select_best(&mut self) {
        let b = argmax(&self.returns);
        let len = self.horizon * self.act_dim;
        self.best
            .copy_from_slice(&self.population[b * len..(b + 1) * len]);
        self.best_return = self.returns[b];
    }
}

impl Planner for RandomShooting {
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
        self.sampler.bind_particles(model.members(), rng);
        self.sample_population(rng);
        self.sampler.evaluate(
            model,
            obs,
            &self.population,
            self.candidates,
            self.horizon,
            rng,
            &mut self.returns,
        )?;
        self.select_best();
        Ok(&self.best)
    }

    fn predicted_return(&self) -> f32 {
        self.best_return
    }

    fn shift(&mut self, _k: usize) {}

    fn reset(&mut self) {}

    fn warm_start(&self) -> Option<&[f32]> {
        None
    }

    fn set_warm_start(&mut self, warm: Option<&[f32]>) -> Result<(), PlanError> {
        match warm {
            None => Ok(()),
            Some(_) => Err(PlanError::Dims(
                "planner warm start: random shooting carries none".into(),
            )),
        }
    }
}
