//! The experiment's configuration, the lowest layer of an experiment: what a run is asked to
//! do, before anything runs.
//!
//! Holds: [`config`] (the TOML experiment file, checked key by key: `ExperimentConfig`, its
//! sections, `--set` overrides, the algorithm's name `Algo`), [`env_config`] (the config's
//! environment, built-in or Python Gymnasium, and the termination rule of model rollouts) and
//! [`schedule`] (when trainings, rollouts, evaluations and updates happen: one rule each);
//! [`solved`] (when a run counts its task as solved and ends early);
//! [`tdmpc`] (the `[tdmpc]` table: TD-MPC2's sizes, loss weights and planner);
//! [`reference`] writes the configuration reference page from these types' doc comments.
//!
//! Must not hold anything that trains, writes a run or knows an algorithm's code: the
//! algorithm table, the trainers, the run's files and the roles are `mbpo-train`'s, above.
#![warn(missing_docs)]

pub mod config;
pub mod env_config;
pub mod reference;
pub mod schedule;
pub mod solved;
pub mod tdmpc;

pub use config::{
    Algo, CatchUp, ConfigError, ExperimentConfig, ImaginedStateClip, MpcConfig, PlanReward,
};
pub use env_config::RolloutTerminationError;
pub use schedule::Schedule;
pub use solved::SolvedRule;
pub use tdmpc::{LatentPlannerConfig, PlanPrecision, TdmpcConfig, TdmpcSize};
