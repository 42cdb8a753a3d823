//! `mbpo bench ...`: the benchmarks' commands, each printing one JSON object per line on
//! stdout ([`args`] are their command-line arguments, [`realtime`] the paced-actor benchmark).

pub mod args;
mod realtime;

pub use args::*;

use crate::out;
use mbpo_core::rng::uniform_range_f32;
use mbpo_envs::{make, ENV_IDS};
use mbpo_nn::gemm::Op;
use mbpo_train::{ExperimentConfig, Summary, TrainError};
use serde_json::json;
use std::path::Path;
use std::time::{Duration, Instant};

/// One seed of `mbpo bench learning` into its run directory: `mbpo`'s resumable run (which
/// also logs into the seed's own `logs/train.log`).
pub type SeedRun = fn(&ExperimentConfig, &Path) -> Result<Summary, TrainError>;

/// Run the benchmark `cmd`; `seed_run` runs one seed of a learning benchmark.
pub fn run(cmd: BenchCommand, seed_run: SeedRun) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Gemm(t) => gemm(&t),
        BenchCommand::Env(args) => env(&args),
        BenchCommand::Learning(args) => learning(&args, seed_run),
        BenchCommand::Breakdown(args) => breakdown(&args),
        BenchCommand::Diagnose(args) => diagnose(&args),
        BenchCommand::Checkpoint(args) => checkpoint(&args),
        BenchCommand::PlanLatency(args) => plan_latency(&args),
        BenchCommand::TdmpcStep(args) => tdmpc_step(&args),
        BenchCommand::Realtime(args) => realtime::run(&args),
        BenchCommand::Termination(args) => {
            let env = make(&args.env)?;
            let report = crate::termination_bench::termination_benchmark(
                env,
                args.train_steps,
                args.test_steps,
                args.seed,
            )?;
            out!("{}", serde_json::to_string(&report)?)?;
            Ok(())
        }
        BenchCommand::ModelTrain(r) => {
            let mut cfg = model_bench_config(&r.reps);
            cfg.model.threads = r.threads;
            cfg.model.batch_size = r.batch_size;
            set_simd_levels(&mut cfg, &r.simd);
            for report in mbpo_model::bench::model_train(10_000, &cfg)? {
                out!("{}", serde_json::to_string(&report)?)?;
            }
            Ok(())
        }
        BenchCommand::ModelRollout(r) => {
            let mut cfg = model_bench_config(&r.reps);
            cfg.model.threads = r.threads;
            set_simd_levels(&mut cfg, &r.simd);
            for report in mbpo_model::bench::model_rollout(100_000, &cfg)? {
                out!("{}", serde_json::to_string(&report)?)?;
            }
            Ok(())
        }
        BenchCommand::SacUpdate(t) => {
            let r = mbpo_sac::bench::sac_update(
                17,
                6,
                &[256, 256],
                256,
                t.threads.max(1),
                t.critic_layer_norm,
                Duration::from_secs_f64(t.seconds),
            );
            out!("{}", serde_json::to_string(&r)?)?;
            Ok(())
        }
    }
}

/// The GEMM shapes of the networks: (m, k, n) = (batch, fan-in, fan-out).
pub const GEMM_SHAPES: &[(usize, usize, usize)] =
    &[(256, 256, 256), (256, 23, 256), (256, 200, 200)];

/// The products of one member's training minibatch in `bench model-train` (HalfCheetah: 23
/// inputs, 4 x 200 hidden, 2 x 18 outputs; 256 rows), each layer's forward `X W`, weight
/// gradient `X^T dZ` and input gradient `dZ W^T`: which of them keeps an epoch below the
/// roofline.
const MODEL_TRAIN_LAYERS: &[(usize, usize)] = &[(23, 200), (200, 200), (200, 36)];

fn gemm(t: &BenchTime) -> anyhow::Result<()> {
    let time = Duration::from_secs_f64(t.seconds);
    for &(m, k, n) in GEMM_SHAPES {
        let gflops = mbpo_nn::bench::gemm_gflops(m, k, n, time);
        out!(
            "{}",
            json!({"bench": "gemm", "m": m, "k": k, "n": n, "threads": 1,
                   "gflops": (gflops * 10.0).round() / 10.0})
        )?;
    }
    // The bf16 products a TD-MPC2 plan makes (512 candidates through 1M-preset layers), and a
    // square one, where the CPU has AMX.
    for &(m, k, n) in &[
        (512, 512, 512),
        (512, 134, 384),
        (512, 384, 384),
        (512, 384, 101),
    ] {
        if let Some(gflops) = mbpo_nn::bench::gemm_bf16_gflops(m, k, n, time) {
            out!(
                "{}",
                json!({"bench": "gemm", "precision": "bf16 (AMX)", "m": m, "k": k, "n": n,
                       "threads": 1, "gflops": (gflops * 10.0).round() / 10.0})
            )?;
        }
    }
    let batch = 256;
    for &(n_in, n_out) in MODEL_TRAIN_LAYERS {
        let products = [
            ("forward X W", batch, n_in, n_out, Op::N, Op::N),
            ("weight gradient X^T dZ", n_in, batch, n_out, Op::T, Op::N),
            ("input gradient dZ W^T", batch, n_out, n_in, Op::N, Op::T),
        ];
        for (product, m, k, n, op_a, op_b) in products {
            if product.starts_with("input") && n_in == 23 {
                continue; // the first layer's input gradient is never computed
            }
            let gflops = mbpo_nn::bench::gemm_gflops_with(m, k, n, op_a, op_b, time);
            out!(
                "{}",
                json!({"bench": "gemm", "model_train_layer": format!("{n_in}x{n_out}"),
                       "product": product, "m": m, "k": k, "n": n, "threads": 1,
                       "gflops": (gflops * 10.0).round() / 10.0})
            )?;
        }
    }
    Ok(())
}

fn env(args: &EnvBenchArgs) -> anyhow::Result<()> {
    let t = &args.time;
    let ids: Vec<&str> = match args.envs.is_empty() {
        true => ENV_IDS.to_vec(),
        false => args.envs.iter().map(String::as_str).collect(),
    };
    for id in ids {
        if id.starts_with(mbpo_envs::GYM_PREFIX) {
            // As `mbpo run` places an actor and its Python env (see the supervisor).
            pin_to_current_cpu();
        }
        let mut env = make(id)?;
        let mut rng = mbpo_core::stream(0, "bench.env", 0);
        let mut obs = vec![0.0f32; env.obs_dim()];
        let space = env.action_space().clone();
        // Pre-drawn actions so the figure is the environment's cost, not the RNG's.
        let actions: Vec<f32> = (0..4096 * space.dim())
            .map(|i| {
                let d = i % space.dim();
                uniform_range_f32(&mut rng, space.low[d], space.high[d])
            })
            .collect();
        env.reset(&mut rng, &mut obs)?;
        let (mut steps, mut episodes) = (0u64, 0u64);
        let start = Instant::now();
        let budget = Duration::from_secs_f64(t.seconds);
        while start.elapsed() < budget {
            for a in actions.chunks_exact(space.dim()) {
                let s = env.step(a, &mut obs)?;
                if s.terminated || s.truncated {
                    env.reset(&mut rng, &mut obs)?;
                    episodes += 1;
                }
            }
            steps += 4096;
        }
        let secs = start.elapsed().as_secs_f64();
        // A `gym:` env is Gymnasium's own, stepped through the bridge from Rust.
        let implementation = match id.starts_with(mbpo_envs::GYM_PREFIX) {
            true => "gymnasium-over-bridge",
            false => "rust",
        };
        out!(
            "{}",
            json!({"bench": "env", "impl": implementation, "env": id,
                   "steps_per_sec": (steps as f64 / secs).round(), "episodes": episodes, "threads": 1})
        )?;
    }
    Ok(())
}

/// Keep this thread (and the processes it starts) on the CPU it runs on.
fn pin_to_current_cpu() {
    // SAFETY: sched_getcpu has no arguments; cpu_set_t is plain data; sched_setaffinity on
    // the calling thread (pid 0).
    unsafe {
        let cpu = libc::sched_getcpu();
        if cpu < 0 {
            return;
        }
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu as usize, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set);
    }
}

fn learning(args: &LearningArgs, seed_run: SeedRun) -> anyhow::Result<()> {
    let mut cfg = mbpo_train::ExperimentConfig::resolve(Some(&args.config), &args.overrides)?;
    if let Some(s) = args.steps {
        cfg.steps = s;
    }
    let seeds: Vec<u64> = (0..args.seeds).collect();
    let name = args.config.display().to_string();
    if let Some(&b) = args.budgets.iter().find(|&&b| b > cfg.steps) {
        anyhow::bail!(
            "--budgets: {b} is beyond the run length of {} env steps (set --steps)",
            cfg.steps
        );
    }
    if let Some(&s) = args.only_seeds.iter().find(|&&s| s >= args.seeds) {
        anyhow::bail!(
            "--only-seeds: seed {s} is not one of the benchmark's seeds 0..{} (raise --seeds)",
            args.seeds
        );
    }
    let peers = crate::published::read_peers(&cfg, &args.peers)?;
    if !args.only_seeds.is_empty() {
        let done = crate::learning_bench::run_seeds(
            &cfg,
            &args.only_seeds,
            args.threads,
            &args.out,
            seed_run,
            &args.budgets,
        )?;
        out!(
            "{}",
            json!({"bench": "learning", "env": cfg.env, "config": name, "steps": cfg.steps,
                   "only_seeds": args.only_seeds,
                   "final_returns": done.iter().map(|s| s.final_return).collect::<Vec<_>>(),
                   "wall_seconds": done.iter().map(|s| s.wall_seconds).collect::<Vec<_>>(),
                   "results": "none written: run without --only-seeds once every seed is done"})
        )?;
        return Ok(());
    }
    let r = crate::learning_bench::learning_benchmark_at(
        &cfg,
        &name,
        &seeds,
        args.threads,
        &args.out,
        seed_run,
        &args.budgets,
    )?;
    let published =
        crate::learning_bench::attach_published(&args.out, &cfg, &peers, &args.budgets)?;
    let published: Vec<_> = published
        .iter()
        .map(|c| json!({"label": c.label, "at_budgets": c.at_budgets}))
        .collect();
    out!(
        "{}",
        json!({"bench": "learning", "env": cfg.env, "config": name, "steps": cfg.steps,
               "median_final_return": r.median_final_return,
               "target_return": r.target_return,
               "median_env_steps_to_target": r.median_env_steps_to_target,
               "final_returns": r.seeds.iter().map(|s| s.final_return).collect::<Vec<_>>(),
               "env_steps_to_target": r.seeds.iter().map(|s| s.env_steps_to_target).collect::<Vec<_>>(),
               "budgets": r.budgets,
               "published": published,
               "wall_seconds": r.seeds.iter().map(|s| s.wall_seconds).collect::<Vec<_>>(),
               "results": args.out.join(format!("learning-{}.json", cfg.env_file_name()))})
    )?;
    Ok(())
}

/// The config of the MBPO run `run` (its config.toml) with `overrides`, for a bench that
/// continues or inspects it (`bench` names it in the error for another algorithm).
fn mbpo_run_config(
    run: &std::path::Path,
    overrides: &[String],
    bench: &str,
) -> anyhow::Result<mbpo_train::ExperimentConfig> {
    let config = run.join("config.toml");
    let cfg = mbpo_train::ExperimentConfig::resolve(Some(&config), overrides)?;
    anyhow::ensure!(
        cfg.algo == mbpo_train::Algo::MBPO,
        "{}: algo is {}; the {bench} is of MBPO runs",
        config.display(),
        cfg.algo.name()
    );
    Ok(cfg)
}

fn breakdown(args: &BreakdownArgs) -> anyhow::Result<()> {
    use crate::breakdown::{breakdown_at, Projection};
    let cfg = mbpo_run_config(&args.run, &args.overrides, "breakdown")?;
    let mut points = Vec::new();
    let mut pipelines = Vec::new();
    for &at in &args.at {
        let p = breakdown_at(&cfg, &args.run, at, args.window)?;
        eprintln!("{}", p.summary_line());
        eprintln!("{}", p.epoch_caps_line());
        out!("{}", serde_json::to_string(&p)?)?;
        if let Some(mode) = args.pipeline {
            let ipc = pipeline_ipc(&cfg, &args.run, at, args.window, mode)?;
            eprintln!("at {at:>6}: mbpo run --mode {}: {ipc}", mode.name());
            pipelines.push(ipc);
        }
        points.push(p);
    }
    let projection = Projection::of(&points, &args.run, cfg.mbpo.init_random_steps, args.project);
    let report = json!({
        "bench": "breakdown", "env": cfg.env, "run": args.run, "window": args.window,
        "model_threads": cfg.model.threads, "sac_threads": cfg.sac.threads,
        "points": points,
        "pipeline": args.pipeline.map(|m| json!({"mode": m.name(), "points": pipelines})),
        "projection": projection,
    });
    eprintln!(
        "model.threads {}, sac.threads {}:",
        cfg.model.threads, cfg.sac.threads
    );
    projection.lines().iter().for_each(|l| eprintln!("{l}"));
    if args.out.as_os_str() != "-" {
        std::fs::create_dir_all(&args.out)?;
        let file = args
            .out
            .join(format!("breakdown-{}.json", cfg.env_file_name()));
        std::fs::write(&file, serde_json::to_string_pretty(&report)? + "\n")?;
        eprintln!("wrote {}", file.display());
    }
    Ok(())
}

/// `mbpo bench checkpoint`: one JSON line, and a summary line on stderr.
fn checkpoint(args: &CheckpointBenchArgs) -> anyhow::Result<()> {
    let cfg = mbpo_run_config(&args.run, &[], "checkpoint benchmark")?;
    anyhow::ensure!(args.repeats > 0, "--repeats must be at least 1");
    let scratch = args.scratch.clone().unwrap_or_else(|| {
        let mut name = args.run.as_os_str().to_owned();
        name.push(".checkpoint-bench");
        name.into()
    });
    anyhow::ensure!(
        !scratch.exists(),
        "{}: the scratch directory exists; remove it or pass another --scratch",
        scratch.display()
    );
    let cost =
        crate::checkpoint_bench::checkpoint_cost(&cfg, &args.run, args.at, args.repeats, &scratch)?;
    eprintln!("{}", cost.summary_line());
    out!(
        "{}",
        json!({"bench": "checkpoint", "env": cfg.env, "run": args.run, "cost": cost})
    )?;
    Ok(())
}

/// `mbpo bench diagnose`: one JSON line per checkpoint, a summary line each on stderr, and
/// all of them in `<out>/diagnose-<run>.json`.
fn diagnose(args: &DiagnoseArgs) -> anyhow::Result<()> {
    use crate::diagnose::diagnose_at;
    let cfg = mbpo_run_config(&args.run, &args.overrides, "diagnosis")?;
    let at = match args.at.is_empty() {
        true => mbpo_train::checkpoint::complete_steps(&args.run),
        false => args.at.clone(),
    };
    anyhow::ensure!(
        !at.is_empty(),
        "{}: no complete checkpoint to diagnose",
        args.run.display()
    );
    let mut points = Vec::new();
    for &at in &at {
        let d = diagnose_at(&cfg, &args.run, at, args.episodes)?;
        eprintln!("{}", d.summary_line());
        let m = &d.model;
        if m.termination_disagreements > 0 {
            tracing::warn!(
                "at {at}: the rollouts' termination rule disagrees with the environment on {} of \
                 {} real transitions",
                m.termination_disagreements,
                m.transitions
            );
        }
        out!("{}", serde_json::to_string(&d)?)?;
        points.push(d);
    }
    if args.out.as_os_str() != "-" {
        std::fs::create_dir_all(&args.out)?;
        let name = args
            .run
            .file_name()
            .map_or("run".into(), |n| n.to_string_lossy().into_owned());
        let file = args.out.join(format!("diagnose-{name}.json"));
        let report = json!({
            "bench": "diagnose", "env": cfg.env, "run": args.run, "episodes": args.episodes,
            "points": points,
        });
        std::fs::write(&file, serde_json::to_string_pretty(&report)? + "\n")?;
        eprintln!("wrote {}", file.display());
    }
    Ok(())
}

/// Continue `run` from its checkpoint at `at` for `window` steps as `mbpo run --mode MODE` in a
/// scratch copy (config with the bench's overrides, the metrics and that checkpoint), and
/// report per env step its wall-clock (start-up and shutdown included) and each process's
/// time inside IPC calls.
fn pipeline_ipc(
    cfg: &mbpo_train::ExperimentConfig,
    run: &std::path::Path,
    at: u64,
    window: u64,
    mode: mbpo_runtime::Mode,
) -> anyhow::Result<serde_json::Value> {
    use anyhow::Context;
    use mbpo_train::checkpoint;
    let scratch = std::env::temp_dir().join(format!("mbpo-breakdown-{}-{at}", std::process::id()));
    let _ = std::fs::remove_dir_all(&scratch);
    let to = checkpoint::dir_for(&scratch, at);
    std::fs::create_dir_all(&to)?;
    std::fs::write(scratch.join("config.toml"), cfg.to_toml())?;
    std::fs::copy(run.join("metrics.csv"), scratch.join("metrics.csv"))
        .with_context(|| format!("copying {}/metrics.csv", run.display()))?;
    for entry in std::fs::read_dir(checkpoint::dir_for(run, at))? {
        let entry = entry?;
        std::fs::copy(entry.path(), to.join(entry.file_name()))?;
    }
    let started = Instant::now();
    let status = std::process::Command::new(std::env::current_exe()?)
        .arg("run")
        .arg("--resume")
        .arg(&scratch)
        .args(["--steps", &(at + window).to_string()])
        .args(["--mode", mode.name(), "--quiet"])
        .status()
        .context("starting mbpo run")?;
    // The whole command: start-up and shutdown of the processes included.
    let wall = started.elapsed().as_secs_f64();
    anyhow::ensure!(
        status.success(),
        "mbpo run --resume {} failed ({status}); its logs are in {}/logs",
        scratch.display(),
        scratch.display()
    );
    let text = std::fs::read_to_string(scratch.join("summary.json"))?;
    let summary: serde_json::Value = serde_json::from_str(&text)?;
    let per_step = |s: f64| 1e3 * s / window as f64;
    let ipc: serde_json::Map<String, serde_json::Value> = summary["ipc"]
        .as_object()
        .into_iter()
        .flatten()
        .map(|(who, share)| {
            let s = share["ipc_seconds"].as_f64().unwrap_or(0.0);
            (who.clone(), json!(per_step(s)))
        })
        .collect();
    std::fs::remove_dir_all(&scratch)?;
    Ok(
        json!({"at": at, "window": window, "wall_ms_per_step": per_step(wall),
              "ipc_ms_per_step": ipc}),
    )
}

/// `--simd`'s levels, when given (the config's default is the widest the CPU has).
fn set_simd_levels(
    cfg: &mut mbpo_model::bench::ModelBenchConfig,
    levels: &[mbpo_nn::simd::SimdLevel],
) {
    if !levels.is_empty() {
        cfg.simd = levels.to_vec();
    }
}

fn model_bench_config(r: &Repetitions) -> mbpo_model::bench::ModelBenchConfig {
    mbpo_model::bench::ModelBenchConfig {
        repetitions: r.repetitions,
        ..Default::default()
    }
}

fn plan_latency(args: &PlanLatencyArgs) -> anyhow::Result<()> {
    use mbpo_plan::{PlannerConfig, PlannerKind};
    let kind: PlannerKind = serde_json::from_value(json!(args.planner)).map_err(|_| {
        anyhow::anyhow!(
            "--planner must be random, cem, mppi or grad, found {:?}",
            args.planner
        )
    })?;
    let mut planner = PlannerConfig {
        kind,
        horizon: args.horizon,
        particles: args.particles,
        ..PlannerConfig::default()
    };
    planner.random.candidates = args.candidates;
    planner.cem.candidates = args.candidates;
    planner.cem.elites = planner.cem.elites.min(args.candidates).max(1);
    planner.cem.iterations = args.iterations;
    planner.mppi.candidates = args.candidates;
    planner.mppi.iterations = args.iterations;
    planner.grad.sequences = args.candidates;
    planner.grad.iterations = args.iterations;
    let cfg = mbpo_plan::bench::PlanLatencyConfig {
        env: args.env.clone(),
        planner,
        members: args.members,
        hidden: args.hidden.clone(),
        known_reward: !args.model_reward,
        plans: args.plans,
    };
    let report = mbpo_plan::bench::plan_latency(&cfg)?;
    out!("{}", serde_json::to_string(&report)?)?;
    Ok(())
}

/// `mbpo bench tdmpc-step`: one plan and one update of TD-MPC2 at a preset's sizes.
fn tdmpc_step(args: &TdmpcStepArgs) -> anyhow::Result<()> {
    use mbpo_train::tdmpc::roles::{model_config, mppi_config};
    let size: mbpo_train::TdmpcSize = serde_json::from_value(json!(args.size))
        .map_err(|_| anyhow::anyhow!("--size {}: expected \"1m\" or \"5m\"", args.size))?;
    let precision: mbpo_train::PlanPrecision = serde_json::from_value(json!(args.plan_precision))
        .map_err(|_| {
        anyhow::anyhow!(
            "--plan-precision {}: expected \"f32\" or \"bf16\"",
            args.plan_precision
        )
    })?;
    let mut cfg = ExperimentConfig::default();
    cfg.tdmpc.size = size;
    cfg.tdmpc.planner.precision = precision;
    let cost = mbpo_latent::bench::step_cost(
        (args.obs, args.act),
        model_config(&cfg, args.episode_length),
        mppi_config(&cfg),
        cfg.tdmpc.batch_size,
        args.episode_length,
        args.calls,
    );
    let mut line = serde_json::to_value(&cost)?;
    line["bench"] = json!("tdmpc-step");
    line["size"] = json!(args.size);
    out!("{line}")?;
    Ok(())
}
