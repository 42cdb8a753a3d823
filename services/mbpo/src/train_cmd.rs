//! `mbpo train`: single-process training.

use crate::cli::{CommonTrainArgs, TrainArgs};
use anyhow::Context;
use mbpo_train::run_dir::holds_a_run;
use mbpo_train::{algorithm, Algo, ConfigError, ExperimentConfig, RunOptions, Summary, TrainError};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// Resolve the config from the file and the command-line overrides, validated.
pub fn resolve_config(
    common: &CommonTrainArgs,
    algo: Option<&str>,
    env: Option<&str>,
) -> anyhow::Result<ExperimentConfig> {
    let source = &common.source;
    let algo = algo.map(Algo::parse).transpose();
    let algo = algo.map_err(|e| anyhow::anyhow!("--algo: {e}"))?;
    let flags = |cfg: &mut ExperimentConfig| -> Result<(), ConfigError> {
        if let Some(a) = algo {
            cfg.algo = a;
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
        Ok(())
    };
    let cfg = ExperimentConfig::resolve_with(source.config.as_deref(), &source.overrides, flags)?;
    Ok(cfg)
}

/// `mbpo train` runs acting and learning in one process, so it cannot act on a clock: a
/// config's `actor.control_hz` (for `mbpo run --mode pipelined`) is said to be ignored here.
fn warn_unpaced(cfg: &ExperimentConfig) {
    if cfg.actor.control_hz > 0.0 {
        tracing::warn!(
            "actor.control_hz = {} is for `mbpo run --mode pipelined`; `mbpo train` steps as fast as it computes (one process cannot act on a clock while it trains)",
            cfg.actor.control_hz
        );
    }
}

/// The directory of a fresh run. The default, `runs/<algo>-<env>-s<seed>`, moves on to the
/// first free `…-2`, `…-3`, … when it holds an earlier run, so running the same command
/// twice keeps both runs (a new directory is claimed with `create_dir`, so two runs started
/// at once do not pick the same one). An explicit `--out` that holds an earlier run is refused
/// unless `--overwrite` ([`overwrite_earlier_run`] removes it once the run is known to be able
/// to start): writing over it would replace its results, and a later `--resume` would take its
/// checkpoints with this run's metrics.
pub fn fresh_run_dir(common: &CommonTrainArgs, cfg: &ExperimentConfig) -> anyhow::Result<PathBuf> {
    let Some(out) = &common.out else {
        let base = format!(
            "runs/{}-{}-s{}",
            cfg.algo.name(),
            cfg.env_file_name(),
            cfg.seed
        );
        for n in 1.. {
            let dir = match n {
                1 => PathBuf::from(&base),
                n => PathBuf::from(format!("{base}-{n}")),
            };
            if holds_a_run(&dir) {
                continue;
            }
            std::fs::create_dir_all("runs").context("creating runs/")?;
            match std::fs::create_dir(&dir) {
                // Claimed by a run started just now (or left empty): take the next one.
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(e).with_context(|| format!("creating {}", dir.display())),
                Ok(()) => {}
            }
            if n > 1 {
                tracing::info!("{base} holds an earlier run: writing {}", dir.display());
            }
            return Ok(dir);
        }
        unreachable!("some numbered run directory is free");
    };
    if out.is_file() {
        anyhow::bail!(
            "--out {} is a file; a run writes a directory (pick another --out)",
            out.display()
        );
    }
    if common.overwrite {
        return Ok(out.clone());
    }
    if !holds_a_run(out) {
        // Not a run, but a run would replace these (a project directory's config.toml, say).
        let replaced: Vec<&str> = ["config.toml", "metrics.csv"]
            .into_iter()
            .filter(|f| out.join(f).exists())
            .collect();
        if !replaced.is_empty() {
            anyhow::bail!(
                "--out {} holds {} that a run would replace; pick another --out, or add \
                 --overwrite to replace them",
                out.display(),
                replaced.join(" and ")
            );
        }
    }
    if holds_a_run(out) {
        let newest = match mbpo_train::checkpoint::latest(out) {
            Ok(Some((_, m))) => format!(" (newest checkpoint after {} env steps)", m.env_steps),
            _ => String::new(),
        };
        anyhow::bail!(
            "{} holds an earlier run{newest}; continue it with `--resume {}`, \
             pick another --out, or add --overwrite to delete it and start afresh",
            out.display(),
            out.display()
        );
    }
    Ok(out.clone())
}

/// `--overwrite`: remove the earlier run in `out` (only the files a run writes), after checking
/// what could still keep the new run from starting -- its environment can be built (a MuJoCo
/// task needs `deploy/setup_mujoco.sh`) -- so a run that fails at once leaves the old one whole.
pub fn overwrite_earlier_run(
    common: &CommonTrainArgs,
    cfg: &ExperimentConfig,
    out: &Path,
) -> anyhow::Result<()> {
    if !common.overwrite || !holds_a_run(out) {
        return Ok(());
    }
    cfg.make_env().with_context(|| {
        format!(
            "--overwrite: {} is kept, the new run could not start",
            out.display()
        )
    })?;
    mbpo_train::run_dir::remove_earlier_run(out)
        .with_context(|| format!("--overwrite: removing the earlier run in {}", out.display()))
}

/// Start the run's environment once and describe it in `<out>/env.json` (spaces, time limit,
/// the parts of a Dict observation): a Python env that cannot start fails here, with its
/// error, before anything else starts.
pub fn record_env(cfg: &ExperimentConfig, out: &Path) -> anyhow::Result<()> {
    let env = cfg.make_env()?;
    mbpo_train::run_dir::write_env_file(out, env.as_ref()).with_context(|| {
        format!(
            "writing {}",
            out.join(mbpo_train::run_dir::ENV_FILE).display()
        )
    })
}

/// The config of the run in `dir` being resumed (`mbpo train/run --resume`): its own resolved
/// `config.toml`, with `--steps` the only change allowed.
pub fn resumed_config(dir: &Path, steps: Option<u64>) -> anyhow::Result<ExperimentConfig> {
    let path = dir.join("config.toml");
    let mut cfg = ExperimentConfig::load(&path)
        .with_context(|| format!("resuming {}: its resolved config", dir.display()))?;
    if let Some(steps) = steps {
        cfg.steps = steps;
        cfg.validate("command line --steps")?;
    }
    Ok(cfg)
}

pub fn run(args: &TrainArgs) -> anyhow::Result<()> {
    let (cfg, out, resume) = match &args.resume {
        Some(dir) => (resumed_config(dir, args.common.steps)?, dir.clone(), true),
        None => {
            let cfg = resolve_config(&args.common, args.algo.as_deref(), args.env.as_deref())?;
            warn_unpaced(&cfg);
            let out = fresh_run_dir(&args.common, &cfg)?;
            overwrite_earlier_run(&args.common, &cfg, &out)?;
            (cfg, out, false)
        }
    };
    crate::logging::also_to_file(&out.join("logs").join("train.log"))?;
    record_env(&cfg, &out)?;
    let opts = RunOptions {
        resume,
        stop: Some(stop_on_signals()),
    };
    let summary =
        algorithm::train(&cfg, &out, opts).with_context(|| format!("run {}", out.display()))?;
    crate::run_report::plot_and_point(&out);
    out!("{}", serde_json::to_string(&summary)?)?;
    Ok(())
}

/// One seed of `mbpo bench learning`, resumable: a run directory that already holds a
/// completed run of this config is reused, one with a checkpoint is continued from it, anything
/// else starts fresh. So a benchmark of several hours can be stopped (Ctrl-C checkpoints) and
/// rerun with the same command, even in another session, without losing what was done.
pub fn bench_run(cfg: &ExperimentConfig, dir: &Path) -> Result<Summary, TrainError> {
    // After Ctrl-C the seeds under way checkpoint and stop; a seed still queued is not begun.
    if stop_on_signals().load(Ordering::Relaxed) {
        return Err(TrainError::Config(format!(
            "{}: not started, a stop was requested; rerun the same command to continue",
            dir.display()
        )));
    }
    let stored = dir.join("config.toml");
    let resume = mbpo_train::checkpoint::latest(dir)?.is_some();
    // This seed's events (its thread's) also go to its run's log, as `mbpo train`'s do, once
    // the directory is known to hold this config's run (or none).
    let log_file = dir.join("logs").join("train.log");
    let mut _log = None;
    if resume || stored.exists() {
        // A run directory this build cannot read is not reused or overwritten blindly (it may
        // hold hours of work, e.g. from a newer build with config keys this one does not know).
        let mut before = ExperimentConfig::load(&stored).map_err(|e| {
            TrainError::Config(format!(
                "{e}; {} cannot be checked against this config: delete it or pick another --out",
                dir.display()
            ))
        })?;
        let steps_before = before.steps;
        before.steps = cfg.steps;
        // The model's thread count changes the result in f32 rounding at most (the same bits
        // for counts that cut members the same way, `model.threads`): a benchmark may
        // continue with the cores it has now.
        before.model.threads = cfg.model.threads;
        // Nor does the target return (the benchmark reads steps-to-target off the curve).
        before.eval.target_return = cfg.eval.target_return;
        // Nor the name in file names (the directory is already this run's).
        before.gym.name = cfg.gym.name.clone();
        if &before != cfg {
            return Err(TrainError::Config(format!(
                "{} holds a run of another config (see its config.toml); \
                 delete it or pick another --out to benchmark this one",
                dir.display()
            )));
        }
        _log = Some(crate::logging::thread_also_to_file(&log_file)?);
        if let Some(done) = completed_summary(dir) {
            let solved = done.status == mbpo_train::run_control::SOLVED;
            if steps_before == cfg.steps && (done.env_steps == cfg.steps || solved) {
                tracing::info!(run = %dir.display(), "already completed: reusing its results");
                return Ok(done);
            }
        }
    }
    if _log.is_none() {
        _log = Some(crate::logging::thread_also_to_file(&log_file)?);
    }
    if resume {
        tracing::info!(run = %dir.display(), "continuing from its newest checkpoint");
    }
    let opts = RunOptions {
        resume,
        stop: Some(stop_on_signals()),
    };
    let summary = algorithm::train(cfg, dir, opts)?;
    if summary.status != "completed" && summary.status != mbpo_train::run_control::SOLVED {
        return Err(TrainError::Config(format!(
            "{}: stopped at {} env steps (checkpointed); rerun the same command to continue",
            dir.display(),
            summary.env_steps
        )));
    }
    Ok(summary)
}

fn completed_summary(dir: &Path) -> Option<Summary> {
    let text = std::fs::read_to_string(dir.join("summary.json")).ok()?;
    let s: Summary = serde_json::from_str(&text).ok()?;
    (s.status == "completed" || s.status == mbpo_train::run_control::SOLVED).then_some(s)
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn request_stop(signal: libc::c_int) {
    // Only an atomic swap, signal(2) and raise(3): async-signal-safe.
    if STOP.swap(true, Ordering::Relaxed) {
        // A second signal: the user does not want to wait for the step under way (an MPC
        // evaluation can take minutes) -- die of it, without a checkpoint.
        // SAFETY: restoring the default disposition and re-raising are async-signal-safe.
        unsafe {
            libc::signal(signal, libc::SIG_DFL);
            libc::raise(signal);
        }
    }
}

/// SIGINT/SIGTERM set a flag the trainer checks after each env step and after each epoch of a
/// model training (which it then undoes): it writes a checkpoint and the summary (status
/// `stopped`) and returns, so `--resume` continues the run.
/// A second signal stops the process at once (no checkpoint).
fn stop_on_signals() -> &'static AtomicBool {
    let handler = request_stop as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: installs a handler that only stores to an atomic.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
    &STOP
}
