//! `mbpo train`: single-process training.

use crate::cli::{CommonTrainArgs, TrainArgs};
use anyhow::Context;
use mbpo_train::{train_mbpo, train_sac, Algo, ExperimentConfig};
use std::path::PathBuf;

/// Resolve the config from the file and the command-line overrides, validated.
pub fn resolve_config(
    common: &CommonTrainArgs,
    algo: Option<&str>,
    env: Option<&str>,
) -> anyhow::Result<ExperimentConfig> {
    let mut cfg = match &common.config {
        Some(path) => ExperimentConfig::load(path)?,
        None => ExperimentConfig::default(),
    };
    if let Some(a) = algo {
        cfg.algo = if a == "sac" { Algo::Sac } else { Algo::Mbpo };
    }
    if let Some(e) = env {
        cfg.env = e.to_string();
    }
    if let Some(s) = common.seed {
        cfg.seed = s;
    }
    if let Some(s) = common.steps {
        cfg.steps = s;
    }
    cfg.validate("command line")?;
    Ok(cfg)
}

/// The run directory: `--out`, or `runs/<algo>-<env>-s<seed>`.
pub fn run_dir(common: &CommonTrainArgs, cfg: &ExperimentConfig) -> PathBuf {
    common.out.clone().unwrap_or_else(|| {
        let algo = if cfg.algo == Algo::Sac { "sac" } else { "mbpo" };
        PathBuf::from(format!("runs/{algo}-{}-s{}", cfg.env, cfg.seed))
    })
}

pub fn run(args: &TrainArgs) -> anyhow::Result<()> {
    let cfg = resolve_config(&args.common, args.algo.as_deref(), args.env.as_deref())?;
    let out = run_dir(&args.common, &cfg);
    crate::logging::also_to_file(&out.join("logs").join("train.log"))?;
    let summary = match cfg.algo {
        Algo::Sac => train_sac(&cfg, &out).with_context(|| format!("run {}", out.display()))?,
        Algo::Mbpo => train_mbpo(&cfg, &out).with_context(|| format!("run {}", out.display()))?,
    };
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}
