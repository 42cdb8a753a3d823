//! `mbpo train`: single-process training.

use crate::cli::{CommonTrainArgs, TrainArgs};
use anyhow::Context;
use mbpo_train::{train_mbpo, train_mpc, train_sac, Algo, ExperimentConfig};
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
        cfg.algo = match a {
            "sac" => Algo::Sac,
            "mpc" => Algo::Mpc,
            _ => Algo::Mbpo,
        };
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
        PathBuf::from(format!(
            "runs/{}-{}-s{}",
            cfg.algo.name(),
            cfg.env,
            cfg.seed
        ))
    })
}

pub fn run(args: &TrainArgs) -> anyhow::Result<()> {
    let cfg = resolve_config(&args.common, args.algo.as_deref(), args.env.as_deref())?;
    let out = run_dir(&args.common, &cfg);
    let summary = match cfg.algo {
        Algo::Sac => train_sac(&cfg, &out).with_context(|| format!("run {}", out.display()))?,
        Algo::Mbpo => train_mbpo(&cfg, &out).with_context(|| format!("run {}", out.display()))?,
        Algo::Mpc => train_mpc(&cfg, &out).with_context(|| format!("run {}", out.display()))?,
    };
    println!("{}", serde_json::to_string(&summary)?);
    Ok(())
}
