//! `mbpo-actor`: acts in the real environment with the newest policy it is allowed to use and
//! publishes every transition (reliable, sequence-numbered). With `--eval` it is the
//! evaluation actor: deterministic policy, stream `eval.env`, evaluating policy version t at
//! the sequential evaluation points.
//!
//! Lockstep: the actor of global step t waits for policy version exactly t − 1. Pipelined: any
//! version ≥ t − 1 − policy_lag. The step loop is `acting.rs`, shared with MPC's planning
//! actors (`planning.rs`).

use std::time::Duration;

use mbpo_core::rng::stream;
use mbpo_core::TransitionSink;
use mbpo_sac::ActorPolicy;
use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::roles::ActorRole;
use mbpo_train::TrainError;
use mbpo_wire::*;

use super::acting::{self, ActingRole, Finish};
use crate::barrier::{self, ActorCheckpoint, EvaluatorCheckpoint};
use crate::error::ensure_protocol;
use crate::{Result, *};

/// The SAC actor on the shared step loop: it acts with the learner's policy; step g needs
/// version g − 1 (pipelined: at least g − 1 − `policy_lag`).
struct PolicyActing {
    role: ActorRole,
    policy_lag: u64,
}

impl ActingRole for PolicyActing {
    const ROLE: RoleKind = RoleKind::Actor;
    const WEIGHTS: WeightsKind = WeightsKind::Policy;
    type Checkpoint = ActorCheckpoint;

    fn checkpoint(&self, steps: u64) -> ActorCheckpoint {
        ActorCheckpoint {
            role: self.role.checkpoint(),
            steps,
        }
    }
    fn restore(&mut self, state: ActorCheckpoint) -> Result<u64> {
        self.role.restore(state.role)?;
        Ok(state.steps)
    }
    fn take_newest<S: Transport>(&mut self, policy: &WeightsSubscriber<S>, _: &Dims) -> Result<()> {
        if let Some(w) = policy.receive_latest()? {
            let version = policy_version_of(w.version());
            self.role.set_policy_params(w.params(), version);
        }
        Ok(())
    }
    fn sequential_version(&self, g: u64) -> u64 {
        g - 1
    }
    fn oldest_allowed(&self, g: u64) -> u64 {
        (g - 1).saturating_sub(self.policy_lag)
    }
    fn holds(&self, version: u64) -> bool {
        self.role.has_policy(version)
    }
    fn version(&self) -> u64 {
        self.role.policy_version()
    }
    fn env_actor(&self) -> &EnvActor {
        self.role.env_actor()
    }
    fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn TransitionSink,
    ) -> std::result::Result<(), TrainError> {
        self.role.act_into(behaviour, sink)
    }
    fn finish(&mut self) -> Finish {
        Finish {
            work: self.role.env_actor().episodes,
            median_step_seconds: 0.0,
            log: String::new(),
        }
    }
}

/// An actor's service loop.
pub fn act<S: Transport>(args: &ServiceArgs) -> Result<()> {
    acting::act(args, |s: &Process<S>| {
        Ok(PolicyActing {
            role: ActorRole::new(&s.cfg, args.index as u64)?,
            policy_lag: s.slack.policy_lag,
        })
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
    // Every role's control subscriber (the role table's count, this evaluator's included);
    // our own one confirms only when asked to (same thread).
    control.sub.update_connections();
    let subscribers = s.pipeline.subscribers(Channel::Control, args.actors);
    acks.wait_for_subscribers(subscribers, Duration::from_secs(120))?;
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
