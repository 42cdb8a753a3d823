//! MBPO's probabilistic ensemble dynamics model (Janner et al. 2019; the "PE" of Chua et al. 2018).
//!
//! * [`ProbabilisticEnsemble`]: E Gaussian MLPs `[obs, act] → N(μ, σ²)` over `[reward, Δobs]`
//!   with learned soft log-variance bounds (the passes and their math in `network.rs`, the
//!   fused element-wise kernels in `simd.rs`), configured by [`ModelConfig`] (MBPO's values by
//!   default).
//! * Training ([`ProbabilisticEnsemble::train`], `train.rs`): holdout split, bootstrap
//!   resamples drawn once per call, Adam with per-layer L2 decay, per-member snapshots on >1 %
//!   holdout improvement, patience 5, elites by holdout MSE.
//! * Prediction ([`ProbabilisticEnsemble::predict_gaussian`],
//!   [`ProbabilisticEnsemble::predict_sample`]) and model rollouts
//!   ([`ProbabilisticEnsemble::rollout`], `rollout.rs`): samples are grouped by their member so
//!   each member runs once on its own rows.
//! * Input gradients of the mean prediction for gradient-based planning
//!   ([`ProbabilisticEnsemble::mean_step_recorded`], [`ProbabilisticEnsemble::mean_step_backward`],
//!   `grad.rs`): the MLP's input gradient and the normaliser's chain rule.
//! * A learned termination rule for envs without a hand-written one
//!   ([`TerminationClassifier`], `termination.rs`; `ModelConfig::learn_termination`), trained
//!   with the ensemble and used by [`ProbabilisticEnsemble::rollout`] with
//!   [`RolloutTermination::Learned`].
//! * The rollout-length schedule ([`rollout_length`]) and model-buffer sizing
//!   ([`ModelPoolSizing`]).
//! * [`bench`](mod@bench): the training-epoch and rollout benchmarks (GFLOP/s against the GEMM roofline).
//!
//! ```
//! use mbpo_core::{stream, Batch, ReplayBuffer, UniformPolicy};
//! use mbpo_model::{ModelConfig, ProbabilisticEnsemble, RolloutFilter, RolloutTermination};
//!
//! let config = ModelConfig { members: 3, elites: 2, hidden: vec![16, 16],
//!                            weight_decay: vec![1e-4; 3], max_epochs: Some(2),
//!                            ..ModelConfig::default() };
//! let mut rng = stream(0, "doc", 0);
//! let mut model = ProbabilisticEnsemble::new(2, 1, config, &mut rng).unwrap();
//! let mut data = Batch::new(2, 1, 50);
//! for (i, v) in data.obs.iter_mut().enumerate() { *v = (i as f32 * 0.1).sin(); }
//! let report = model.train(&data, &mut rng).unwrap();
//! assert_eq!(report.elites.len(), 2);
//!
//! let mut policy = UniformPolicy { low: vec![-1.0], high: vec![1.0] };
//! let mut pool = ReplayBuffer::new(2, 1, 100);
//! let never = |_: &[f32], _: &[f32], _: &[f32]| false;
//! let stats = model.rollout(&data.obs[..20], 10, &mut policy, 3, RolloutTermination::Rule(&never), RolloutFilter::PAPER, &mut rng, &mut pool).unwrap();
//! assert_eq!((stats.transitions, pool.len()), (30, 30));
//! ```
#![warn(missing_docs)]

pub mod bench;
mod config;
mod error;
mod grad;
mod grouped;
mod model;
mod network;
mod normalizer;
mod parallel;
mod rollout;
mod rollout_mask;
mod simd;
pub mod termination;
mod train;

pub use config::{ModelConfig, ModelConfigError};
pub use error::{ParamsError, PredictError, RolloutError, TrainError};
pub use grad::MeanTape;
pub use model::{ModelState, ModelWeights, ProbabilisticEnsemble};
pub use normalizer::InputNormalizer;
pub use rollout::{
    rollout_length, BatchTermination, ModelPoolSizing, RolloutFilter, RolloutRule, RolloutStats,
    RolloutTermination, Termination,
};
pub use termination::{TerminationClassifier, TerminationReport, TerminationWeights};
pub use train::{
    elite_holdout_mse_if_capped, select_elites, BootstrapIndices, EarlyStopping, EpochProgress,
    StopReason, TrainReport,
};
