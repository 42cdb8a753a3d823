//! `mbpo-actor`: acts in the real environment with the newest policy it is allowed to use and
//! publishes every transition (reliable, sequence-numbered). With `--eval` it is the
//! evaluation actor: deterministic policy, stream `eval.env`, evaluating policy version t at
//! the sequential evaluation points.
//!
//! Lockstep: the actor of global step t waits for policy version exactly t − 1. Pipelined: any
//! version ≥ t − 1 − policy_lag. With algo = "mpc" both plan on the model trainer's ensemble
//! instead (`planning.rs`).

use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Parser;
use mbpo_core::rng::stream;
use mbpo_sac::ActorPolicy;
use mbpo_service_kit::{stats, *};
use mbpo_train::actor::Behaviour;
use mbpo_train::roles::{ActorRole, PolicySnapshot, Schedule};
use mbpo_wire::*;

mod planning;

#[derive(Debug, Parser)]
#[command(name = "mbpo-actor", about = "MBPO pipeline actor")]
struct Args {
    #[command(flatten)]
    svc: ServiceArgs,
    /// Be the evaluation actor.
    #[arg(long)]
    eval: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    mbpo_service_kit::exit_code(if args.eval {
        evaluate(&args.svc)
    } else {
        act(&args.svc)
    })
}

fn act(args: &ServiceArgs) -> anyhow::Result<()> {
    let s = Process::start(args, Role::Actor)?;
    if s.cfg.algo == mbpo_train::Algo::Mpc {
        return planning::act(args, s);
    }
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::create(&s.node)?;
    let policy =
        WeightsSubscriber::create(&s.node, WeightsKind::Policy, d.policy_hash, d.policy_len)?;
    let real = TransitionPublisher::create(&s.node, Channel::Real, d.rows(), 1)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // Model trainer, rollout generator and learner: nothing sent afterwards can be lost.
    real.wait_for_subscribers(3, Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&policy);

    let mut role = ActorRole::new(cfg, args.index as u64)?;
    let schedule = Schedule::of(cfg);
    let mut snap = PolicySnapshot {
        version: 0,
        params: vec![0.0; d.policy_len],
    };
    let mut lag = stats::SlackTracker::default();
    let mut last_progress = Instant::now();
    let steps = actor_steps(cfg.steps, args.actors, args.index);
    let started = Instant::now();
    let mut ipc = Duration::ZERO;
    for t in 1..=steps {
        let g = global_step(t, args.actors, args.index);
        let behaviour = if schedule.is_warm_up(g) {
            Behaviour::Uniform
        } else {
            let need = (g - 1).saturating_sub(s.slack.policy_lag);
            let ok = wait_for(
                &waiter,
                &control,
                &|| format!("policy version {need}"),
                || {
                    if let Some(w) = policy.receive_latest()? {
                        snap.version = policy_version_of(w.version());
                        snap.params.copy_from_slice(w.params());
                        role.set_policy(&snap);
                    }
                    Ok(role.policy_version() >= need)
                },
            )?;
            if !ok {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if s.mode == Mode::Lockstep {
                anyhow::ensure!(
                    role.policy_version() == g - 1,
                    "lockstep actor at step {g} got policy version {}",
                    role.policy_version()
                );
            }
            lag.see((g - 1) as f64 - role.policy_version() as f64);
            Behaviour::Policy
        };
        let episodes = role.env_actor().episodes;
        let rows = role.act(behaviour);
        let a = role.env_actor();
        if a.episodes > episodes {
            // Before the transition: the supervisor may rely on having every episode ≤ t.
            let ret = a.last_return.unwrap_or(f64::NAN);
            stats_pub.send(&StatsRecord::episode(ret, 0, g, role.policy_version()))?;
        }
        let meta = TransitionMeta {
            policy_version: role.policy_version(),
            model_version: 0,
            env_steps: g,
        };
        let t0 = Instant::now();
        real.send_batch(&rows, meta)?;
        ipc += t0.elapsed();
        if last_progress.elapsed() >= Duration::from_millis(500) {
            last_progress = Instant::now();
            stats_pub.send(&stats::progress(g, 0, 0, role.policy_version()))?;
        }
    }
    let (lo, hi, mean) = lag.get();
    let done = stats::Done {
        real: steps,
        work: role.env_actor().episodes,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ipc_seconds: ipc.as_secs_f32(),
        wall_seconds: started.elapsed().as_secs_f32(),
        ..Default::default()
    };
    stats_pub.send(&done.record())?;
    tracing::info!("done: {steps} steps, policy lag {lo}..{hi} (mean {mean:.2})");
    wait_for_stop(&waiter, &control)
}

fn evaluate(args: &ServiceArgs) -> anyhow::Result<()> {
    let s = Process::start(args, Role::Evaluator)?;
    if s.cfg.algo == mbpo_train::Algo::Mpc {
        return planning::evaluate(args, s);
    }
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::create(&s.node)?;
    let acks = ControlPublisher::create(&s.node)?;
    let policy =
        WeightsSubscriber::create(&s.node, WeightsKind::Policy, d.policy_hash, d.policy_len)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // Every service's control subscriber (actors, evaluator, model trainer, rollouts, learner);
    // our own one confirms only when asked to (same thread).
    control.sub.update_connections();
    acks.wait_for_subscribers(args.actors as usize + 4, Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&policy);

    let mut env = mbpo_envs::make(&cfg.env)?;
    let mut rng = stream(cfg.seed, "eval.env", 0);
    let mut pol = ActorPolicy::new(d.actor_net(cfg), vec![0.0; d.policy_len], true);
    let learner = ProducerId::new(Role::Learner, 0);
    let mut version = 0;
    let mut evals = 0;
    for t in (1..=cfg.steps).filter(|&t| is_eval_point(cfg, t)) {
        let ok = wait_for(
            &waiter,
            &control,
            &|| format!("policy version {t} to evaluate"),
            || {
                if let Some(h) = policy.receive_latest_into(&mut pol.params)? {
                    version = policy_version_of(h.version);
                }
                Ok(version >= t)
            },
        )?;
        if !ok {
            return Ok(());
        }
        if s.mode == Mode::Lockstep {
            anyhow::ensure!(
                version == t,
                "lockstep evaluator expected policy version {t}, got {version}"
            );
            // The learner publishes version t + 1 only after this: no version is skipped.
            send_ack(&acks, learner, t)?;
        }
        let ret = mbpo_train::eval::evaluate(&mut pol, env.as_mut(), cfg.eval.episodes, &mut rng);
        stats_pub.send(&stats::eval(t, version, ret, cfg.eval.episodes))?;
        tracing::info!("eval after step {t} (policy version {version}): {ret:.2}");
        evals += 1;
    }
    stats_pub.send(
        &stats::Done {
            work: evals,
            ..Default::default()
        }
        .record(),
    )?;
    wait_for_stop(&waiter, &control)
}
