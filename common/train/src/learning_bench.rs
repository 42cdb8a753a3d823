//! Learning benchmarks: one config over several seeds, summarised into one results file.
//!
//! `results/learning-<env>.json` holds one entry per algorithm (SAC, MBPO, ...), each with
//! every seed's evaluation curve, final return and env steps to reach −200, so sample
//! efficiency is compared in one place. Seeds run in parallel threads (each run is
//! single-threaded and deterministic, so parallelism does not change any result).

use crate::config::ExperimentConfig;
use crate::run_dir::{read_eval_curve, Summary};
use crate::sac_trainer::TrainError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One seed's outcome.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct SeedResult {
    /// Run seed.
    pub seed: u64,
    /// Evaluation curve: (env steps, return).
    pub curve: Vec<(u64, f64)>,
    /// Last evaluation return.
    pub final_return: f64,
    /// First evaluation point with return ≥ −200.
    pub env_steps_to_minus_200: Option<u64>,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
    /// The run directory.
    pub run_dir: PathBuf,
}

/// One algorithm's results over seeds.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct AlgoResult {
    /// The config file used.
    pub config: String,
    /// Env steps per run.
    pub steps: u64,
    /// Median over seeds of the final return.
    pub median_final_return: f64,
    /// Median over seeds of env steps to reach −200 (a seed that never did counts as +∞;
    /// `None` when more than half never did).
    pub median_env_steps_to_minus_200: Option<u64>,
    /// Per-seed results.
    pub seeds: Vec<SeedResult>,
}

/// Median of a sorted slice of options where `None` sorts last (+∞).
fn median_steps(values: &[Option<u64>]) -> Option<u64> {
    let mut v: Vec<u64> = values.iter().map(|x| x.unwrap_or(u64::MAX)).collect();
    v.sort_unstable();
    let m = v[(v.len() - 1) / 2];
    (m != u64::MAX).then_some(m)
}

/// Run `cfg` for `seeds` on `threads` threads, with run directories under `out/runs/`, and
/// merge the algorithm's entry into `out/learning-<env>.json`. Returns that entry.
pub fn learning_benchmark(
    cfg: &ExperimentConfig,
    config_name: &str,
    seeds: &[u64],
    threads: usize,
    out: &Path,
    train: fn(&ExperimentConfig, &Path) -> Result<Summary, TrainError>,
) -> Result<AlgoResult, TrainError> {
    // MPC entries are per planner (mpc-cem, mpc-mppi, ...), so each keeps its own results.
    let algo = match cfg.algo {
        crate::config::Algo::Mpc => format!("mpc-{}", cfg.mpc.planner.kind.name()),
        other => other.name().to_string(),
    };
    let queue = std::sync::Mutex::new(seeds.to_vec());
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            s.spawn(|| loop {
                let Some(seed) = queue.lock().unwrap().pop() else {
                    break;
                };
                let mut c = cfg.clone();
                c.seed = seed;
                let dir = out.join("runs").join(format!("{algo}-{}-s{seed}", cfg.env));
                let r = train(&c, &dir).and_then(|summary| {
                    Ok(SeedResult {
                        seed,
                        curve: read_eval_curve(&dir.join("metrics.csv"))?,
                        final_return: summary.final_eval_return,
                        env_steps_to_minus_200: summary.env_steps_to_minus_200,
                        wall_seconds: summary.wall_seconds,
                        run_dir: dir,
                    })
                });
                results.lock().unwrap().push(r);
            });
        }
    });
    let mut per_seed = results
        .into_inner()
        .unwrap()
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    per_seed.sort_by_key(|r| r.seed);
    let mut finals: Vec<f64> = per_seed.iter().map(|r| r.final_return).collect();
    finals.sort_by(f64::total_cmp);
    let entry = AlgoResult {
        config: config_name.to_string(),
        steps: cfg.steps,
        median_final_return: finals[(finals.len() - 1) / 2],
        median_env_steps_to_minus_200: median_steps(
            &per_seed
                .iter()
                .map(|r| r.env_steps_to_minus_200)
                .collect::<Vec<_>>(),
        ),
        seeds: per_seed,
    };
    let file = out.join(format!("learning-{}.json", cfg.env));
    let mut all: BTreeMap<String, AlgoResult> = std::fs::read_to_string(&file)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_default();
    all.insert(algo.clone(), entry.clone());
    std::fs::create_dir_all(out)?;
    std::fs::write(&file, serde_json::to_string_pretty(&all)? + "\n")?;
    Ok(entry)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_treats_never_as_infinity() {
        assert_eq!(median_steps(&[Some(3), Some(1), Some(2)]), Some(2));
        assert_eq!(
            median_steps(&[Some(3), None, Some(1), None, Some(2)]),
            Some(3)
        );
        assert_eq!(median_steps(&[None, None, Some(1)]), None);
    }
}
