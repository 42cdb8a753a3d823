//! Model-free SAC on a real environment: the baseline MBPO is measured against.
//!
//! Per env step: act (uniform random for the first `random_steps`, then a ~ π(·|s)), store
//! (s, a, r, s', terminated), then `updates_per_step` SAC updates on uniform replay batches.
//! Every random draw comes from a named stream of the run seed, so a seed reproduces a run bit
//! for bit.

use crate::config::ExperimentConfig;
use crate::eval::evaluate;
use crate::run_dir::{policy_sha256, MetricsRow, RunDir, Summary};
use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_core::{Batch, ReplayBuffer};
use mbpo_envs::make;
use mbpo_sac::{ActionScale, Sac, SacStats};
use std::path::Path;
use std::time::Instant;

/// Errors of a training run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The environment could not be built.
    #[error(transparent)]
    Env(#[from] mbpo_envs::EnvError),
    /// The run directory could not be written.
    #[error("run directory: {0}")]
    Io(#[from] std::io::Error),
    /// A results file could not be encoded.
    #[error("results file: {0}")]
    Json(#[from] serde_json::Error),
}

/// Run SAC per `cfg`, writing the run directory `out`; returns the summary.
pub fn train_sac(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    let seed = cfg.seed;
    let mut env = make(&cfg.env)?;
    let mut eval_env = make(&cfg.env)?;
    let (obs_dim, act_dim) = (env.obs_dim(), env.act_dim());
    let scale = ActionScale::new(&env.action_space().low, &env.action_space().high);
    let mut run = RunDir::create(out, cfg)?;

    let mut sac = Sac::new(
        obs_dim,
        act_dim,
        cfg.sac.clone(),
        &mut stream(seed, "sac.init", 0),
    );
    let mut replay = ReplayBuffer::new(obs_dim, act_dim, cfg.sac_loop.replay_capacity);
    let mut batch = Batch::new(obs_dim, act_dim, cfg.sac.batch_size);
    let mut env_rng = stream(seed, "actor.env", 0);
    let mut policy_rng = stream(seed, "actor.policy", 0);
    let mut sample_rng = stream(seed, "learner.sample", 0);
    let mut update_rng = stream(seed, "learner.update", 0);
    let mut eval_rng = stream(seed, "eval.env", 0);

    let mut obs = vec![0.0f32; obs_dim];
    let mut next_obs = vec![0.0f32; obs_dim];
    let mut action = vec![0.0f32; act_dim];
    let mut env_action = vec![0.0f32; act_dim];
    env.reset(&mut env_rng, &mut obs);

    let start = Instant::now();
    let (mut last_row_time, mut last_row_steps) = (0.0f64, 0u64);
    let (mut episode_return, mut last_train_return) = (0.0f64, None);
    let mut episodes = 0u64;
    let mut stats = SacStats::default();
    let (mut final_eval, mut best_eval, mut to_minus_200) = (f64::NAN, f64::NEG_INFINITY, None);

    for t in 1..=cfg.steps {
        // Act: uniform over the action box during warm-up, then the stochastic policy.
        if t <= cfg.sac_loop.random_steps {
            action
                .iter_mut()
                .for_each(|a| *a = uniform_range_f32(&mut policy_rng, -1.0, 1.0));
        } else {
            sac.act(&obs, false, &mut policy_rng, &mut action);
        }
        scale.to_env(&action, &mut env_action);
        let step = env.step(&env_action, &mut next_obs);
        replay.push(
            &obs,
            &action,
            step.reward as f32,
            &next_obs,
            step.terminated,
        );
        episode_return += step.reward;
        if step.terminated || step.truncated {
            episodes += 1;
            last_train_return = Some(episode_return);
            episode_return = 0.0;
            env.reset(&mut env_rng, &mut obs);
        } else {
            obs.copy_from_slice(&next_obs);
        }

        // Learn.
        if t >= cfg.sac_loop.random_steps && replay.len() >= cfg.sac.batch_size {
            for _ in 0..cfg.sac_loop.updates_per_step {
                replay.sample_into(&mut sample_rng, &mut batch);
                stats = sac.update(&batch, &mut update_rng);
            }
        }

        // Evaluate and record.
        if t % cfg.eval.every == 0 || t == cfg.steps {
            let ret = evaluate(
                &mut sac,
                eval_env.as_mut(),
                cfg.eval.episodes,
                &mut eval_rng,
            );
            final_eval = ret;
            best_eval = best_eval.max(ret);
            if ret >= -200.0 && to_minus_200.is_none() {
                to_minus_200 = Some(t);
            }
            let now = start.elapsed().as_secs_f64();
            let sps = (t - last_row_steps) as f64 / (now - last_row_time).max(1e-9);
            (last_row_time, last_row_steps) = (now, t);
            let updated = sac.updates() > 0;
            let some = |v: f32| updated.then_some(v as f64);
            run.write_metrics(&MetricsRow {
                env_steps: t,
                episodes,
                eval_return: ret,
                train_return: last_train_return,
                sac_updates: sac.updates(),
                critic_loss: some(stats.critic_loss),
                actor_loss: some(stats.actor_loss),
                alpha: Some(sac.alpha() as f64),
                entropy: some(stats.entropy),
                q_mean: some(stats.q_mean),
                wall_seconds: now,
                env_steps_per_sec: sps,
                ..Default::default()
            })?;
            tracing::info!(
                "sac {} seed {seed}: step {t}/{} eval {ret:.1} alpha {:.3} ({sps:.0} steps/s)",
                cfg.env,
                cfg.steps,
                sac.alpha()
            );
        }
    }

    let summary = Summary {
        algo: "sac".into(),
        env: cfg.env.clone(),
        seed,
        env_steps: cfg.steps,
        sac_updates: sac.updates(),
        final_eval_return: final_eval,
        best_eval_return: best_eval,
        env_steps_to_minus_200: to_minus_200,
        policy_sha256: policy_sha256(&sac.actor_params),
        wall_seconds: start.elapsed().as_secs_f64(),
    };
    run.write_summary(&summary)?;
    Ok(summary)
}
