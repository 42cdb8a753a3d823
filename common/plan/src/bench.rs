//! Planning latency: wall time of one MPC step (one plan) with a randomly initialised ensemble
//! of the configured size (the cost does not depend on the weights' values).

use crate::config::{PlannerConfig, PlannerKind};
use crate::configured::build;
use crate::error::PlanError;
use crate::model::{EnsembleModel, RewardSource};
use crate::mpc::Mpc;
use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_model::{ModelConfig, ProbabilisticEnsemble};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// What to measure.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanLatencyConfig {
    /// Environment whose dimensions, action box and known reward are used.
    pub env: String,
    /// The planner (kind, horizon, particles, candidates, iterations).
    pub planner: PlannerConfig,
    /// Ensemble members (all of them elites, so particles use every member).
    pub members: usize,
    /// Hidden widths of each member.
    pub hidden: Vec<usize>,
    /// Use the task's known reward (true) or the model's reward head.
    pub known_reward: bool,
    /// Timed plans (after two untimed warm-up plans).
    pub plans: usize,
}

impl Default for PlanLatencyConfig {
    fn default() -> Self {
        Self {
            env: "Pendulum-v1".into(),
            planner: PlannerConfig::default(),
            members: 5,
            hidden: vec![200; 4],
            known_reward: true,
            plans: 10,
        }
    }
}

/// One JSON line of `mbpo bench plan-latency`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PlanLatencyReport {
    /// Always "plan-latency".
    pub bench: String,
    /// Environment.
    pub env: String,
    /// Planner kind.
    pub planner: PlannerKind,
    /// Horizon H.
    pub horizon: usize,
    /// Candidates (sequences for the gradient planner) per iteration.
    pub candidates: usize,
    /// Iterations per plan.
    pub iterations: usize,
    /// Particles per candidate.
    pub particles: usize,
    /// Ensemble members.
    pub members: usize,
    /// Hidden widths.
    pub hidden: Vec<usize>,
    /// Rows per batched model step (candidates x particles).
    pub rows_per_model_step: usize,
    /// GEMM GFLOP of one plan (forward passes; the gradient planner's backward pass is counted
    /// as two more forward passes).
    pub gflop_per_plan: f64,
    /// Median milliseconds per plan (one MPC step).
    pub ms_per_plan_median: f64,
    /// Fastest plan, ms.
    pub ms_per_plan_best: f64,
    /// GEMM GFLOP/s at the best plan.
    pub gflops: f64,
    /// Timed plans.
    pub plans: usize,
    /// Threads (always 1: one process owns one core).
    pub threads: usize,
}

/// GFLOP of one plan's model passes: the ensemble's forward per row, times the rows of a
/// model step, the horizon and the passes of the planner's iterations.
fn gflop_per_plan(cfg: &PlanLatencyConfig, o: usize, a: usize) -> f64 {
    let p = &cfg.planner;
    let rows = p.candidates() * p.particles;
    let dims: Vec<usize> = std::iter::once(o + a)
        .chain(cfg.hidden.iter().copied())
        .chain(std::iter::once(2 * (o + 1)))
        .collect();
    let flop_per_row: f64 = dims.windows(2).map(|w| 2.0 * (w[0] * w[1]) as f64).sum();
    // Forward passes per plan; the gradient planner adds one input-only backward pass per Adam
    // step (dX = dY Wᵀ per layer, the forward's flops; no weight gradients) and evaluates once
    // more after its last step.
    let passes = if p.kind == PlannerKind::Grad {
        2 * p.iterations() + 1
    } else {
        p.iterations()
    };
    flop_per_row * (rows * p.horizon * passes) as f64 / 1e9
}

/// Time `cfg.plans` closed-loop MPC steps from random Pendulum-like observations.
pub fn plan_latency(cfg: &PlanLatencyConfig) -> Result<PlanLatencyReport, PlanError> {
    let env = mbpo_envs::make(&cfg.env).map_err(|e| PlanError::Dims(e.to_string()))?;
    let (o, a) = (env.obs_dim(), env.act_dim());
    let model_cfg = ModelConfig {
        members: cfg.members,
        elites: cfg.members,
        weight_decay: vec![0.0; cfg.hidden.len() + 1],
        hidden: cfg.hidden.clone(),
        ..ModelConfig::default()
    };
    let mut rng = stream(0, "bench.plan", 0);
    let ensemble = ProbabilisticEnsemble::new(o, a, model_cfg, &mut rng)
        .map_err(|e| PlanError::Dims(e.to_string()))?;
    let reward = match (cfg.known_reward, mbpo_envs::reward_fn(&cfg.env)) {
        (true, Some(f)) => RewardSource::Known(f),
        (true, None) => {
            return Err(PlanError::Dims(format!(
                "{} has no known reward function",
                cfg.env
            )))
        }
        (false, _) => RewardSource::Model,
    };
    let space = env.action_space();
    let mut model = EnsembleModel::new(
        ensemble,
        reward,
        mbpo_envs::termination_fn(&cfg.env).map(mbpo_model::RolloutRule::Rule),
        &space.low,
        &space.high,
    )?;
    let mut mpc = Mpc::new(build(&cfg.planner, a)?, false);
    let high = env.observation_space().high.clone();
    let mut obs = vec![0.0f32; o];
    let mut action = vec![0.0f32; a];
    let mut times = Vec::with_capacity(cfg.plans);
    for i in 0..cfg.plans + 2 {
        for (v, &h) in obs.iter_mut().zip(&high) {
            *v = uniform_range_f32(&mut rng, -h.min(10.0), h.min(10.0));
        }
        let start = Instant::now();
        mpc.act(&mut model, &obs, &mut rng, &mut action)?;
        if i >= 2 {
            times.push(start.elapsed().as_secs_f64());
        }
    }
    // Sorts `times`, so `times[0]` is the best plan.
    let median = mbpo_core::stats::median(&mut times)
        .ok_or_else(|| PlanError::Dims("plan-latency: plans must be at least 1".into()))?;
    let p = &cfg.planner;
    let rows = p.candidates() * p.particles;
    let gflop = gflop_per_plan(cfg, o, a);
    let best = times[0];
    Ok(PlanLatencyReport {
        bench: "plan-latency".into(),
        env: cfg.env.clone(),
        planner: p.kind,
        horizon: p.horizon,
        candidates: p.candidates(),
        iterations: p.iterations(),
        particles: p.particles,
        members: cfg.members,
        hidden: cfg.hidden.clone(),
        rows_per_model_step: rows,
        gflop_per_plan: (gflop * 1000.0).round() / 1000.0,
        ms_per_plan_median: (median * 1e5).round() / 100.0,
        ms_per_plan_best: (best * 1e5).round() / 100.0,
        gflops: (gflop / best * 10.0).round() / 10.0,
        plans: cfg.plans,
        threads: 1,
    })
}
