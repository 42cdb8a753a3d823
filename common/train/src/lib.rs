//! Experiments: the algorithm table, the roles, run directories and checkpoints, and the
//! single-process trainers. The configuration is `mbpo-config`'s, below this crate (its
//! modules [`config`], [`env_config`] and [`schedule`] are re-exported here); benchmarks and
//! diagnoses of runs are `mbpo-bench`'s, above it. Must not hold a benchmark or anything of
//! the multi-process pipeline (`mbpo-runtime`).
//!
//! * [`algorithm`]: the algorithm registry (`sac`, `mbpo`, `mpc`, and any registered).
//! * [`run_dir`]: `metrics.csv`, `summary.json` and the resolved config of one run.
//! * [`run_control`]: how a run starts (fresh or resumed), checkpoints and stops.
//! * `driver`: the one loop of a single-process run that the SAC, MBPO and MPC trainers share.
//! * [`run_files`]: the files of a checkpoint, one format for `mbpo train` and `mbpo run`.
//! * [`d_model_branches`]: the model buffer in a checkpoint as the rollout branches that filled
//!   it, done again on restore.
//! * [`checkpoint_writer`]: a checkpoint written on its own thread while the training goes on.
//! * [`error`]: the error of a training run, shared by every trainer and role.
//! * [`sac_checkpoint`]: the checkpoint file of a SAC run.
//! * [`sac_trainer`]: SAC alone on a real environment (the model-free baseline).
//! * [`eval`]: deterministic evaluation episodes.
//! * [`policy_file`]: a run's trained policy (the final one, or the newest checkpoint's).
//! * [`tensorboard`]: TensorBoard event files (scalars) without dependencies.
//! * [`phase_times`]: seconds per phase of an MBPO run (model training, rollouts, SAC, acting).
//! * [`progress`]: the live progress bar (terminal) or periodic progress lines (logs).
//! * [`mpc_roles`]: the planning actor and evaluator of model predictive control.
//! * [`mpc`]: model predictive control on the learned model in one process.
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

pub mod actor;
pub mod algorithm;
pub mod checkpoint;
pub mod checkpoint_writer;
pub mod cpu;
pub mod d_model_branches;
mod driver;
pub mod error;
pub mod eval;
pub mod mbpo_trainer;
pub mod mpc;
pub mod mpc_roles;
pub mod phase_times;
pub mod policy_file;
pub mod progress;
pub mod roles;
pub mod run_control;
pub mod run_dir;
pub mod run_files;
pub mod sac_checkpoint;
pub mod sac_trainer;
pub mod tensorboard;

pub use error::TrainError;
pub use mbpo_config::SolvedRule;
/// The configuration (`mbpo-config`), re-exported: paths such as `mbpo_train::config::...` hold.
pub use mbpo_config::{config, env_config, reference as config_reference, schedule, solved};
pub use mbpo_config::{
    Algo, CatchUp, ConfigError, ExperimentConfig, ImaginedStateClip, MpcConfig, PlanReward,
};
pub use mbpo_trainer::{train_mbpo, train_mbpo_with, Mbpo};
pub use mpc::{train_mpc, train_mpc_with};
pub use run_control::RunOptions;
pub use run_dir::{policy_sha256, RunDir, Summary};
pub use sac_trainer::{train_sac, train_sac_with};
pub use schedule::Schedule;
