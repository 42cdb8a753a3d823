//! Benchmarks of the model's two hot paths, for `mbpo bench model-train` / `model-rollout`.
//!
//! Both run the MBPO-sized model (7 members, 4 x 200 SiLU) at HalfCheetah's dimensions
//! (obs 17, act 6), both on `model.threads` (`--threads N`: the training's members in blocks,
//! the rollouts' grouped chunks in runs), and compare the achieved GEMM throughput with the roofline
//! measured in the same run: [`mbpo_nn::bench::gemm_gflops`] on the model's hidden-layer shape
//! `256 x 200 x 200`. Only GEMM flops are counted (2 per multiply-add): a forward pass costs
//! `2·rows·in·out` per layer, a training step adds the weight gradient of every layer and the
//! input gradient of every layer but the first (which needs none). Everything else the timed
//! call does (activations, the loss, Adam, gathers, sampling, the replay pushes) is overhead
//! the figure includes, which is the point: the fraction of the roofline says how much of the
//! time goes to anything but multiply-adds.
//!
//! The data are synthetic (a smooth random function of the inputs): speed does not depend on
//! what is learnt.
//!
//! Timing on a shared machine: each repetition is preceded by a slice of the roofline
//! measurement, and both figures are the best over the run, so a quiet moment anywhere in the run
//! counts for both and the fraction stays meaningful when other processes come and go.

use crate::{
    ModelConfig, ModelConfigError, ProbabilisticEnsemble, RolloutFilter, RolloutTermination,
    TrainError,
};
use mbpo_core::rng::{normal_f32, uniform_range_f32};
use mbpo_core::{stream, Batch, ReplayBuffer, UniformPolicy};
use mbpo_nn::simd::{cap_simd_level, SimdLevel};
use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// HalfCheetah's observation width.
pub const OBS_DIM: usize = 17;
/// HalfCheetah's action width.
pub const ACT_DIM: usize = 6;

/// Result of one benchmark, one JSON object when serialised.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelBenchReport {
    /// `model-train` or `model-rollout`.
    pub bench: String,
    /// What was timed, e.g. "one training epoch over 10000 transitions".
    pub what: String,
    /// Best wall-clock seconds of one timed call over the repetitions.
    pub seconds: f64,
    /// Every repetition's seconds, in order.
    pub seconds_all: Vec<f64>,
    /// GEMM GFLOP in one timed call.
    pub gflop: f64,
    /// Achieved GFLOP/s of the best repetition.
    pub gflops: f64,
    /// Single-thread GEMM roofline (`256 x 200 x 200`) measured in the same run (while the
    /// other threads idle).
    pub roofline_gflops: f64,
    /// `gflops / (roofline_gflops · threads)`.
    pub fraction_of_roofline: f64,
    /// Ensemble members.
    pub members: usize,
    /// Hidden widths.
    pub hidden: Vec<usize>,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Threads used.
    pub threads: usize,
    /// The element-wise kernels' instruction-set level (`baseline`, `avx2`, `avx512`).
    pub simd: String,
}

/// Why a benchmark could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ModelBenchError {
    /// The benchmark's model configuration is invalid.
    #[error("invalid model configuration: {0}")]
    Config(#[from] ModelConfigError),
    /// Training rejected the synthetic data (e.g. too few transitions for a holdout).
    #[error("training failed: {0}")]
    Train(#[from] TrainError),
    /// A `--simd` level the CPU cannot run, or none.
    #[error("--simd: {0}")]
    Simd(String),
}

/// Settings shared by both benchmarks.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelBenchConfig {
    /// Timed repetitions (after one untimed warm-up); the best is reported.
    pub repetitions: usize,
    /// Total measurement time of the roofline GEMM, split evenly before the repetitions.
    pub roofline_time: Duration,
    /// Model configuration (MBPO's by default).
    pub model: ModelConfig,
    /// The element-wise kernels' levels to time, interleaved within each repetition (so a
    /// busy moment of the machine hits all of them alike); one report per level. Each must be
    /// supported by the CPU.
    pub simd: Vec<SimdLevel>,
}

impl Default for ModelBenchConfig {
    fn default() -> Self {
        Self {
            repetitions: 5,
            roofline_time: Duration::from_secs(2),
            model: ModelConfig::default(),
            simd: vec![SimdLevel::best_supported()],
        }
    }
}

/// `n` synthetic HalfCheetah-sized transitions: Gaussian observations, uniform actions in
/// [−1, 1], a smooth nonlinear next state and reward.
pub fn synthetic_transitions(n: usize, seed: u64) -> Batch {
    let mut rng = stream(seed, "bench.model.data", 0);
    let mut b = Batch::new(OBS_DIM, ACT_DIM, n);
    for r in 0..n {
        let obs = &mut b.obs[r * OBS_DIM..(r + 1) * OBS_DIM];
        obs.iter_mut().for_each(|v| *v = normal_f32(&mut rng));
        let act = &mut b.act[r * ACT_DIM..(r + 1) * ACT_DIM];
        act.iter_mut()
            .for_each(|v| *v = uniform_range_f32(&mut rng, -1.0, 1.0));
        let (obs, act) = (
            &b.obs[r * OBS_DIM..(r + 1) * OBS_DIM],
            &b.act[r * ACT_DIM..(r + 1) * ACT_DIM],
        );
        for j in 0..OBS_DIM {
            b.next_obs[r * OBS_DIM + j] =
                obs[j] + 0.1 * (obs[(j + 1) % OBS_DIM] + act[j % ACT_DIM]).sin();
        }
        b.reward[r] = act.iter().map(|a| -0.1 * a * a).sum::<f32>() + obs[0];
    }
    b
}

/// `cfg.repetitions` rounds of a roofline slice and then `timed` once on each of `cfg.simd`'s
/// levels; the best roofline and each level's seconds, in `cfg.simd`'s order. The cap on the
/// level is put back as it was.
fn time_on_levels(cfg: &ModelBenchConfig, mut timed: impl FnMut() -> f64) -> (f64, Vec<Vec<f64>>) {
    let reps = cfg.repetitions.max(1);
    let mut roofline = 0.0f64;
    let mut seconds = vec![Vec::with_capacity(reps); cfg.simd.len()];
    let before = cap_simd_level(SimdLevel::Avx512);
    for _ in 0..reps {
        roofline = roofline.max(roofline_slice(cfg, reps));
        for (level, s) in cfg.simd.iter().zip(&mut seconds) {
            cap_simd_level(*level);
            s.push(timed());
        }
    }
    cap_simd_level(before);
    (roofline, seconds)
}

/// One of `reps` slices of the roofline measurement (the hidden-layer GEMM shape).
fn roofline_slice(cfg: &ModelBenchConfig, reps: usize) -> f64 {
    mbpo_nn::bench::gemm_gflops(256, 200, 200, cfg.roofline_time / reps as u32)
}

/// One report per level of `levels`, from that level's `seconds_all` (same order).
#[allow(clippy::too_many_arguments)]
fn reports(
    bench: &str,
    what: String,
    levels: &[SimdLevel],
    seconds_all: Vec<Vec<f64>>,
    flops: u64,
    roofline: f64,
    model: &ModelConfig,
    threads: usize,
) -> Vec<ModelBenchReport> {
    let gflop = flops as f64 / 1e9;
    levels
        .iter()
        .zip(seconds_all)
        .map(|(level, seconds_all)| {
            let seconds = seconds_all.iter().copied().fold(f64::INFINITY, f64::min);
            let gflops = gflop / seconds;
            ModelBenchReport {
                bench: bench.to_string(),
                what: what.clone(),
                seconds,
                seconds_all,
                gflop,
                gflops,
                roofline_gflops: roofline,
                fraction_of_roofline: gflops / (roofline * threads as f64),
                members: model.members,
                hidden: model.hidden.clone(),
                obs_dim: OBS_DIM,
                act_dim: ACT_DIM,
                threads,
                simd: level.name().to_string(),
            }
        })
        .collect()
}

/// (a) One training epoch over `transitions` transitions (MBPO: 10 000): the whole
/// [`ProbabilisticEnsemble::train`] call with `max_epochs = 1`, i.e. holdout split,
/// normaliser fit, bootstrap draw, every minibatch step of every member and the holdout
/// evaluation.
pub fn model_train(
    transitions: usize,
    cfg: &ModelBenchConfig,
) -> Result<Vec<ModelBenchReport>, ModelBenchError> {
    check_levels(cfg)?;
    let model_cfg = ModelConfig {
        max_epochs: Some(1),
        ..cfg.model.clone()
    };
    let data = synthetic_transitions(transitions, 0);
    let mut rng = stream(0, "bench.model.train", 0);
    let mut model = ProbabilisticEnsemble::new(OBS_DIM, ACT_DIM, model_cfg.clone(), &mut rng)?;
    // Warm-up: sizes every buffer and faer's packing memory.
    let warm = model.train(&data, &mut rng)?;
    let (n_train, n_hold) = (warm.n_train, warm.n_holdout);
    let mut failed = None;
    let (roofline, seconds) = time_on_levels(cfg, || {
        let start = Instant::now();
        if let Err(e) = model.train(&data, &mut rng) {
            failed = Some(e);
        }
        start.elapsed().as_secs_f64()
    });
    if let Some(e) = failed {
        return Err(e.into());
    }
    // Every member: one training step per minibatch, then one holdout pass.
    let b = model_cfg.batch_size;
    let mut step_flops = 0u64;
    let mut start = 0;
    while start < n_train {
        let rows = b.min(n_train - start);
        step_flops += model.net.train_step_flops(rows);
        start += rows;
    }
    let flops = model_cfg.members as u64 * (step_flops + model.net.forward_flops(n_hold));
    Ok(reports(
        "model-train",
        format!(
            "one training epoch over {transitions} transitions ({n_train} train, {n_hold} holdout)"
        ),
        &cfg.simd,
        seconds,
        flops,
        roofline,
        &model_cfg,
        // Threads beyond the members have no block to run.
        model_cfg.threads.min(model_cfg.members),
    ))
}

/// (b) `rollouts` one-step model rollouts (MBPO: 100 000 per model training): the whole
/// [`ProbabilisticEnsemble::rollout`] call with k = 1, a uniform policy and no termination,
/// pushing into a model buffer.
pub fn model_rollout(
    rollouts: usize,
    cfg: &ModelBenchConfig,
) -> Result<Vec<ModelBenchReport>, ModelBenchError> {
    check_levels(cfg)?;
    let mut rng = stream(0, "bench.model.rollout", 0);
    let mut model = ProbabilisticEnsemble::new(OBS_DIM, ACT_DIM, cfg.model.clone(), &mut rng)?;
    let start_obs: Vec<f32> = (0..rollouts * OBS_DIM)
        .map(|_| normal_f32(&mut rng))
        .collect();
    let mut policy = UniformPolicy {
        low: vec![-1.0; ACT_DIM],
        high: vec![1.0; ACT_DIM],
    };
    let mut pool = ReplayBuffer::new(OBS_DIM, ACT_DIM, rollouts.max(1));
    let never = |_: &[f32], _: &[f32], _: &[f32]| false;
    let mut run = |model: &mut ProbabilisticEnsemble, rng: &mut mbpo_core::Rng| {
        let start = Instant::now();
        model
            .rollout(
                &start_obs,
                rollouts,
                &mut policy,
                1,
                RolloutTermination::Rule(&never),
                RolloutFilter::PAPER,
                rng,
                &mut pool,
            )
            .expect("start states and pool are built for the model's dimensions");
        start.elapsed().as_secs_f64()
    };
    run(&mut model, &mut rng);
    let (roofline, seconds) = time_on_levels(cfg, || run(&mut model, &mut rng));
    let flops = model.net.forward_flops(rollouts);
    Ok(reports(
        "model-rollout",
        format!("{rollouts} one-step model rollouts"),
        &cfg.simd,
        seconds,
        flops,
        roofline,
        &cfg.model,
        // The runs of chunks use the training's threads: at most two per member.
        cfg.model.threads.min(2 * cfg.model.members),
    ))
}

/// Refuses levels this CPU cannot run (their kernels would fault) and an empty list.
fn check_levels(cfg: &ModelBenchConfig) -> Result<(), ModelBenchError> {
    if cfg.simd.is_empty() {
        return Err(ModelBenchError::Simd("no SIMD level to time".into()));
    }
    match cfg.simd.iter().find(|l| !l.supported()) {
        Some(l) => Err(ModelBenchError::Simd(format!(
            "this CPU cannot run the `{}` kernels; it supports up to `{}`",
            l.name(),
            SimdLevel::best_supported().name()
        ))),
        None => Ok(()),
    }
}
