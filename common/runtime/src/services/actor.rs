//! `mbpo-actor`: acts in the real environment with the newest policy it is allowed to use and
//! publishes every transition (reliable, sequence-numbered). With `--eval` it is the
//! evaluation actor: deterministic policy, stream `eval.env`, evaluating policy version t at
//! the sequential evaluation points.
//!
//! Lockstep: the actor of global step t waits for policy version exactly t − 1. Pipelined: any
//! version ≥ t − 1 − policy_lag. (MPC's planning actors: `planning.rs`.)

use std::time::{Duration, Instant};

use mbpo_core::rng::stream;
use mbpo_sac::ActorPolicy;
use mbpo_train::actor::Behaviour;
use mbpo_train::roles::ActorRole;
use mbpo_wire::*;

use crate::barrier::{self, ActorCheckpoint, EvaluatorCheckpoint};
use crate::error::ensure_protocol;
use crate::{Result, *};

/// An actor's service loop.
pub fn act<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::Actor)?;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let policy =
        WeightsSubscriber::create(&s.node, WeightsKind::Policy, d.policy_hash, d.policy_len)?;
    let real = TransitionPublisher::create(&s.node, Channel::Real, d.rows(), 1)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // Model trainer, rollout generator and learner (or this host's gateway): nothing sent
    // afterwards can be lost.
    real.wait_for_subscribers(s.real_consumers(), Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&policy);

    let mut role = ActorRole::new(cfg, args.index as u64)?;
    let schedule = s.schedule;
    let mut lag = SlackTracker::default();
    let mut last_progress = Instant::now();
    let steps = actor_steps(cfg.steps, args.actors, args.index);
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::actor_file(args.index),
        barrier::kind::ACTOR,
    );
    let mut first = 1;
    if let Some(dir) = &args.resume_from {
        let state: ActorCheckpoint = file.read(dir)?;
        role.restore(state.role)?;
        first = state.steps + 1;
    }
    // At the cut: write the state after `done` local steps, wait for the resume.
    let write_at = |role: &ActorRole, done: u64, cut| {
        let state = ActorCheckpoint {
            role: role.checkpoint(),
            steps: done,
        };
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    };
    // At a barrier: report the steps done, then as above.
    let at_barrier = |role: &ActorRole, done: u64| -> Result<bool> {
        match barrier::report_paused(&waiter, &control, &stats_pub, done)? {
            Some(cut) => write_at(role, done, cut),
            None => Ok(false),
        }
    };
    let started = Instant::now();
    let mut ipc = Duration::ZERO;
    for t in first..=steps {
        let g = global_step(t, args.actors, args.index);
        let behaviour = loop {
            control.poll()?;
            if control.stopped() {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if control.pause_requested() {
                if !at_barrier(&role, t - 1)? {
                    tracing::info!("stopped after the checkpoint, before step {g}");
                    return Ok(());
                }
                continue;
            }
            if schedule.is_warm_up(g) {
                break Behaviour::Uniform;
            }
            let need = (g - 1).saturating_sub(s.slack.policy_lag);
            let ok = wait_for(
                &waiter,
                &control,
                &|| format!("policy version {need}"),
                || {
                    if let Some(w) = policy.receive_latest()? {
                        role.set_policy_params(w.params(), policy_version_of(w.version()));
                    }
                    Ok(role.has_policy(need) || control.pause_requested())
                },
            )?;
            if !ok {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if control.pause_requested() {
                continue;
            }
            if s.mode == Mode::Lockstep {
                ensure_protocol!(
                    role.policy_version() == g - 1,
                    "lockstep actor at step {g} got policy version {}",
                    role.policy_version()
                );
            }
            lag.see((g - 1) as f64 - role.policy_version() as f64);
            break Behaviour::Policy;
        };
        let episodes = role.env_actor().episodes;
        // The env step writes its transition straight into the sample it is sent in.
        let t0 = Instant::now();
        let mut loan = real.loan_rows(1)?;
        ipc += t0.elapsed();
        if let Err(e) = role.act_into(behaviour, &mut loan) {
            drop(loan);
            let (w, c, p) = (&waiter, &control, &stats_pub);
            return barrier::after_env_failure(w, c, p, e, g, t - 1, |cut| {
                write_at(&role, t - 1, cut)
            });
        }
        let a = role.env_actor();
        if a.episodes > episodes {
            // Before the transition: the supervisor may rely on having every episode ≤ t.
            let ret = a.last_return.unwrap_or(f64::NAN);
            stats_pub.report(EpisodeEnd {
                env_steps: g,
                episode_return: ret,
                version: role.policy_version(),
            })?;
        }
        let meta = TransitionMeta {
            policy_version: role.policy_version(),
            model_version: 0,
            env_steps: g,
        };
        let t0 = Instant::now();
        loan.send(meta)?;
        ipc += t0.elapsed();
        if last_progress.elapsed() >= Duration::from_millis(500) {
            last_progress = Instant::now();
            stats_pub.report(Progress {
                env_steps: g,
                policy_version: role.policy_version(),
                ..Default::default()
            })?;
        }
    }
    let (lo, hi, mean) = lag.get();
    let done = Done {
        real: steps,
        work: role.env_actor().episodes,
        episodes_cut: role.env_actor().episodes_cut,
        episodes_lost: role.env_actor().episodes_lost,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ipc_seconds: ipc.as_secs_f32(),
        wall_seconds: started.elapsed().as_secs_f32(),
        ..Default::default()
    };
    stats_pub.report(done)?;
    tracing::info!("done: {steps} steps, policy lag {lo}..{hi} (mean {mean:.2})");
    barrier::idle_until_stop(&waiter, &control, &stats_pub, Some(steps), |cut| {
        write_at(&role, steps, cut)
    })
}

/// The evaluator's service loop.
pub fn evaluate<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::Evaluator)?;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let acks = ControlPublisher::<S>::create(&s.node)?;
    let policy =
        WeightsSubscriber::create(&s.node, WeightsKind::Policy, d.policy_hash, d.policy_len)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // Every service's control subscriber (actors, evaluator, model trainer, rollouts, learner);
    // our own one confirms only when asked to (same thread).
    control.sub.update_connections();
    acks.wait_for_subscribers(args.actors as usize + 4, Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&policy);

    let mut env = cfg.make_env()?;
    let mut rng = stream(cfg.seed, "eval.env", 0);
    let mut pol = ActorPolicy::new(s.actor_net(), vec![0.0; d.policy_len], true);
    let learner = ProducerId::new(Role::Learner, 0);
    let mut version = 0;
    let mut evals = 0;
    let mut after = 0;
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::file::EVALUATOR,
        barrier::kind::EVALUATOR,
    );
    if let Some(dir) = &args.resume_from {
        let state: EvaluatorCheckpoint = file.read(dir)?;
        (rng, version, evals, after) = (state.rng, state.version, state.evals, state.env_steps);
    }
    for t in (after + 1..=cfg.steps).filter(|&t| s.schedule.is_eval_point(t)) {
        // Wait for policy version t, writing the checkpoint of a cut before t meanwhile.
        loop {
            let ok = wait_for(
                &waiter,
                &control,
                &|| format!("policy version {t} to evaluate"),
                || {
                    if let Some(h) = policy.receive_latest_into(&mut pol.params)? {
                        version = policy_version_of(h.version);
                    }
                    Ok(version >= t || control.cut().is_some_and(|c| c.env_steps < t))
                },
            )?;
            if !ok {
                return Ok(());
            }
            match control.cut() {
                Some(cut) if cut.env_steps < t => {
                    let state = evaluator_state(&rng, version, evals, cut);
                    let (w, c) = (&waiter, &control);
                    if !barrier::write_and_await_resume(w, c, &stats_pub, &file, cut, &state)? {
                        return Ok(());
                    }
                }
                _ => break,
            }
        }
        if s.mode == Mode::Lockstep {
            ensure_protocol!(
                version == t,
                "lockstep evaluator expected policy version {t}, got {version}"
            );
            // The learner publishes version t + 1 only after this: no version is skipped.
            send_ack(&acks, learner, t)?;
        }
        let ret = mbpo_train::eval::evaluate(&mut pol, env.as_mut(), cfg.eval.episodes, &mut rng)?;
        stats_pub.report(EvalResult {
            env_steps: t,
            policy_version: version,
            model_version: 0,
            mean_return: ret,
            episodes: cfg.eval.episodes as u32,
        })?;
        tracing::info!("eval after step {t} (policy version {version}): {ret:.2}");
        evals += 1;
    }
    stats_pub.report(Done {
        work: evals,
        ..Default::default()
    })?;
    barrier::idle_until_stop(&waiter, &control, &stats_pub, None, |cut| {
        let state = evaluator_state(&rng, version, evals, cut);
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    })
}

/// The evaluator's file at `cut` (every eval point ≤ T evaluated).
fn evaluator_state(
    rng: &mbpo_core::Rng,
    version: u64,
    evals: u64,
    cut: barrier::Cut,
) -> EvaluatorCheckpoint {
    EvaluatorCheckpoint {
        rng: rng.clone(),
        version,
        evals,
        env_steps: cut.env_steps,
    }
}
