//! The experiment: the algorithm table, the roles and what their checkpoint files hold, and
//! the single-process trainers. The configuration is `mbpo-config`'s and a run's directory
//! (metrics, summary, checkpoints and their writer, TensorBoard, progress) `mbpo-rundir`'s,
//! both below this crate (their modules are re-exported here: [`config`], [`run_dir`],
//! [`checkpoint`], ...); benchmarks and diagnoses of runs are `mbpo-bench`'s, above it. Must
//! not hold a benchmark, a file format of the run directory or anything of the multi-process
//! pipeline (`mbpo-runtime`).
//!
//! * [`algorithm`]: the algorithm registry (`sac`, `mbpo`, `mpc`, `tdmpc`, and any registered).
//! * [`run_control`]: how a run starts (fresh or resumed), checkpoints and stops.
//! * `driver`: the one loop of a single-process run that the SAC, MBPO and MPC trainers share.
//! * [`run_files`]: the files of a checkpoint, one format for `mbpo train` and `mbpo run`.
//! * [`d_model_branches`]: the model buffer in a checkpoint as the rollout branches that filled
//!   it, done again on restore.
//! * [`error`]: the error of a training run, shared by every trainer and role.
//! * [`sac_checkpoint`]: the checkpoint file of a SAC run.
//! * [`sac_trainer`]: SAC alone on a real environment (the model-free baseline).
//! * [`eval`]: deterministic evaluation episodes.
//! * [`episodes`]: a planner's evaluation episodes (MPC, TD-MPC2).
//! * [`policy_file`]: a run's trained policy (the final one, or the newest checkpoint's).
//! * [`phase_times`]: seconds per phase of an MBPO run (model training, rollouts, SAC, acting).
//! * [`mpc_roles`]: the planning actor and evaluator of model predictive control.
//! * [`mpc`]: model predictive control on the learned model in one process.
//! * [`tdmpc`]: TD-MPC2, planning in a learned latent space, in one process.
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

pub mod actor;
pub mod algorithm;
pub mod cpu;
pub mod d_model_branches;
mod driver;
pub mod episodes;
pub mod error;
pub mod eval;
pub mod mbpo_trainer;
pub mod mpc;
pub mod mpc_roles;
pub mod phase_times;
pub mod policy_file;
pub mod roles;
pub mod run_control;
pub mod run_files;
pub mod sac_checkpoint;
pub mod sac_trainer;
pub mod tdmpc;

pub use error::TrainError;
pub use mbpo_config::SolvedRule;
/// The configuration (`mbpo-config`), re-exported: paths such as `mbpo_train::config::...` hold.
pub use mbpo_config::{config, env_config, reference as config_reference, schedule, solved};
pub use mbpo_config::{
    Algo, CatchUp, ConfigError, ExperimentConfig, ImaginedStateClip, MpcConfig, PlanPrecision,
    PlanReward, TdmpcConfig, TdmpcSize,
};
/// A run's directory (`mbpo-rundir`), re-exported: paths such as `mbpo_train::run_dir::...` hold.
pub use mbpo_rundir::{checkpoint, checkpoint_writer, progress, run_dir, tensorboard};
pub use mbpo_trainer::{train_mbpo, train_mbpo_with, Mbpo};
pub use mpc::{train_mpc, train_mpc_with};
pub use run_control::RunOptions;
pub use run_dir::{policy_sha256, RunDir, Summary};
pub use sac_trainer::{train_sac, train_sac_with};
pub use schedule::Schedule;
