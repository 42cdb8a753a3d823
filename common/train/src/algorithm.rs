//! The algorithm registry: what `mbpo train` runs for a config's `algo`.
//!
//! An algorithm is one [`AlgorithmSpec`] row: its name (the config key), its single-process
//! run, which starts fresh or from the run directory's newest checkpoint, writes the metrics
//! rows, the checkpoints and the summary, and stops cleanly when asked ([`RunOptions`]), and
//! the roles it runs as under `mbpo run` (none: `mbpo train` only; `mbpo_runtime::pipeline`
//! reads them, and the run plan carries them to the role processes). `sac`, `mbpo`, `mpc` and
//! `tdmpc` are built in; a program adds one with [`register`] (`tests/tests/extension_points.rs` adds
//! a random-policy baseline, and an algorithm on MBPO's roles that the in-process pipeline and
//! `mbpo run`'s launcher run, from the test file alone).

use std::path::Path;
use std::sync::RwLock;

use mbpo_core::roles::{PipelineRoles, RoleKind};

use crate::config::{Algo, ExperimentConfig};
use crate::error::TrainError;
use crate::run_control::RunOptions;
use crate::run_dir::Summary;

/// Run an algorithm in one process: `cfg` into the run directory `out`.
pub type TrainFn = fn(&ExperimentConfig, &Path, RunOptions) -> Result<Summary, TrainError>;

/// One algorithm.
#[derive(Debug, Clone, Copy)]
pub struct AlgorithmSpec {
    /// Its name: the config's `algo`, the run directory's prefix.
    pub name: &'static str,
    /// Its single-process run (`mbpo train`).
    pub train: TrainFn,
    /// Its roles under `mbpo run` (`None`: it runs under `mbpo train` only).
    pub pipeline: Option<PipelineRoles>,
}

/// The runs of [`Algo::BUILT_IN`].
const BUILT_IN: [AlgorithmSpec; 4] = [
    AlgorithmSpec {
        name: Algo::SAC.name(),
        train: crate::sac_trainer::train_sac_with,
        pipeline: None,
    },
    // A learner, a model trainer, a rollout generator, an evaluator and the actors.
    AlgorithmSpec {
        name: Algo::MBPO.name(),
        train: crate::mbpo_trainer::train_mbpo_with,
        pipeline: Some(PipelineRoles {
            services: &[
                RoleKind::Learner,
                RoleKind::ModelTrainer,
                RoleKind::RolloutGenerator,
                RoleKind::Evaluator,
            ],
            actor: RoleKind::Actor,
        }),
    },
    // Planning on the model trainer's ensemble: no learner or rollout generator, and its
    // actors and evaluator are planners.
    AlgorithmSpec {
        name: Algo::MPC.name(),
        train: crate::mpc::train_mpc_with,
        pipeline: Some(PipelineRoles {
            services: &[RoleKind::ModelTrainer, RoleKind::PlanningEvaluator],
            actor: RoleKind::PlanningActor,
        }),
    },
    // A world model learned in a latent space, planned on by MPPI: its learner, actors that
    // plan on its newest parameters and an evaluator that plans.
    AlgorithmSpec {
        name: Algo::TDMPC.name(),
        train: crate::tdmpc::train_tdmpc_with,
        pipeline: Some(PipelineRoles {
            services: &[RoleKind::WorldModelLearner, RoleKind::LatentEvaluator],
            actor: RoleKind::LatentActor,
        }),
    },
];

/// Algorithms added at run time (this process only).
static REGISTERED: RwLock<Vec<AlgorithmSpec>> = RwLock::new(Vec::new());

/// Add an algorithm; returns its config key. A name already taken is refused.
pub fn register(spec: AlgorithmSpec) -> Result<Algo, TrainError> {
    // Held while the name is added, so a name is never without its run.
    let mut registered = REGISTERED.write().unwrap_or_else(|e| e.into_inner());
    let algo = Algo::register(spec.name).map_err(TrainError::Config)?;
    registered.push(spec);
    Ok(algo)
}

/// The algorithm called `name`.
pub fn lookup(name: &str) -> Option<AlgorithmSpec> {
    let registered = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
    BUILT_IN
        .iter()
        .chain(registered.iter())
        .find(|s| s.name == name)
        .copied()
}

/// Every algorithm, built in and registered, in order.
pub fn all() -> Vec<AlgorithmSpec> {
    let registered = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
    BUILT_IN.iter().chain(registered.iter()).copied().collect()
}

/// Run `cfg`'s algorithm in one process into `out` (what `mbpo train` does).
pub fn train(cfg: &ExperimentConfig, out: &Path, opts: RunOptions) -> Result<Summary, TrainError> {
    let spec = lookup(cfg.algo.name()).ok_or_else(|| {
        TrainError::Config(format!("algorithm '{}' is not registered", cfg.algo.name()))
    })?;
    crate::cpu::log_cpu_kernels();
    (spec.train)(cfg, out, opts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_algorithms_parse_and_unknown_ones_are_named() {
        for algo in Algo::BUILT_IN {
            assert_eq!(Algo::parse(algo.name()), Ok(algo));
        }
        let err = Algo::parse("ppo").unwrap_err();
        assert!(err.contains("unknown algorithm 'ppo'"), "{err}");
        assert!(err.contains("sac, mbpo, mpc, tdmpc"), "{err}");
        let dup = register(BUILT_IN[1]).unwrap_err().to_string();
        assert!(dup.contains("'mbpo' is already registered"), "{dup}");
        for (spec, algo) in BUILT_IN.iter().zip(Algo::BUILT_IN) {
            assert_eq!(spec.name, algo.name(), "every built-in name has its run");
        }
    }
}
