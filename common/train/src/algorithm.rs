//! The algorithm registry: what `mbpo train` runs for a config's `algo`.
//!
//! An algorithm is one [`AlgorithmSpec`] row: its name (the config key) and its single-process
//! run, which starts fresh or from the run directory's newest checkpoint, writes the metrics
//! rows, the checkpoints and the summary, and stops cleanly when asked ([`RunOptions`]).
//! `sac`, `mbpo` and `mpc` are built in; a program adds one with [`register`]
//! (`tests/tests/extension_points.rs` adds a random-policy baseline from the test file alone).
//! The multi-process `mbpo run` has the role lists of MBPO and MPC
//! (`mbpo_runtime::pipeline`).

use std::path::Path;
use std::sync::RwLock;

use crate::config::{Algo, ExperimentConfig};
use crate::run_control::RunOptions;
use crate::run_dir::Summary;
use crate::sac_trainer::TrainError;

/// Run an algorithm in one process: `cfg` into the run directory `out`.
pub type TrainFn = fn(&ExperimentConfig, &Path, RunOptions) -> Result<Summary, TrainError>;

/// One algorithm.
#[derive(Debug, Clone, Copy)]
pub struct AlgorithmSpec {
    /// Its name: the config's `algo`, the run directory's prefix.
    pub name: &'static str,
    /// Its single-process run (`mbpo train`).
    pub train: TrainFn,
}

const BUILT_IN: [AlgorithmSpec; 3] = [
    AlgorithmSpec {
        name: "sac",
        train: crate::sac_trainer::train_sac_with,
    },
    AlgorithmSpec {
        name: "mbpo",
        train: crate::mbpo_trainer::train_mbpo_with,
    },
    AlgorithmSpec {
        name: "mpc",
        train: crate::mpc::train_mpc_with,
    },
];

/// Algorithms added at run time (this process only).
static REGISTERED: RwLock<Vec<AlgorithmSpec>> = RwLock::new(Vec::new());

/// Add an algorithm; returns its config key. A name already taken is refused.
pub fn register(spec: AlgorithmSpec) -> Result<Algo, TrainError> {
    let mut registered = REGISTERED.write().unwrap_or_else(|e| e.into_inner());
    if lookup_in(&registered, spec.name).is_some() {
        return Err(TrainError::Config(format!(
            "an algorithm named '{}' is already registered: give yours another name",
            spec.name
        )));
    }
    registered.push(spec);
    Ok(Algo::of_registered(spec.name))
}

fn lookup_in(registered: &[AlgorithmSpec], name: &str) -> Option<AlgorithmSpec> {
    BUILT_IN
        .iter()
        .chain(registered)
        .find(|s| s.name == name)
        .copied()
}

/// The algorithm called `name`.
pub fn lookup(name: &str) -> Option<AlgorithmSpec> {
    lookup_in(&REGISTERED.read().unwrap_or_else(|e| e.into_inner()), name)
}

/// The names of every algorithm, built-in first.
pub fn names() -> Vec<&'static str> {
    let registered = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
    BUILT_IN
        .iter()
        .chain(registered.iter())
        .map(|s| s.name)
        .collect()
}

/// Run `cfg`'s algorithm in one process into `out` (what `mbpo train` does).
pub fn train(cfg: &ExperimentConfig, out: &Path, opts: RunOptions) -> Result<Summary, TrainError> {
    let spec = lookup(cfg.algo.name()).ok_or_else(|| {
        TrainError::Config(format!("algorithm '{}' is not registered", cfg.algo.name()))
    })?;
    (spec.train)(cfg, out, opts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_algorithms_parse_and_unknown_ones_are_named() {
        for algo in [Algo::SAC, Algo::MBPO, Algo::MPC] {
            assert_eq!(Algo::parse(algo.name()), Ok(algo));
        }
        let err = Algo::parse("ppo").unwrap_err();
        assert!(err.contains("unknown algorithm 'ppo'"), "{err}");
        assert!(err.contains("sac, mbpo, mpc"), "{err}");
        let dup = register(BUILT_IN[1]).unwrap_err().to_string();
        assert!(dup.contains("'mbpo' is already registered"), "{dup}");
    }
}
