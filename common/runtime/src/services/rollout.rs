//! `mbpo-rollout-generator`: at every train point t, loads model version v (the v-th training)
//! and the newest allowed policy, branches M · model_train_freq k-step rollouts from start
//! states drawn from its copy of the real data, and publishes them as one imagined batch
//! (reliable; header `env_steps` = t − 1 names the train point, versions say what made it).
//!
//! Lockstep: model version exactly v, policy version exactly t − 1, exactly t − 1 real
//! transitions. Pipelined: policy ≥ t − 1 − policy_lag, every real transition received.

use std::time::{Duration, Instant};

use mbpo_train::roles::RolloutRole;
use mbpo_wire::*;

use crate::barrier::{self, RolloutCheckpoint};
use crate::error::ensure_protocol;
use crate::{Result, *};

/// The rollout generator's service loop.
pub fn run<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::RolloutGenerator)?;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let real = TransitionSubscriber::create(&s.node, Channel::Real, d.rows())?;
    let model = WeightsSubscriber::create(
        &s.node,
        WeightsKind::Model,
        d.model.layout_hash,
        d.model.len(),
    )?;
    let policy =
        WeightsSubscriber::create(&s.node, WeightsKind::Policy, d.policy_hash, d.policy_len)?;
    let n_rollouts = cfg.mbpo.rollouts_per_step * cfg.mbpo.model_train_freq as usize;
    let imagined = TransitionPublisher::create(&s.node, Channel::Imagined, d.rows(), n_rollouts)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    imagined.wait_for_subscribers(1, Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter
        .attach(&control.sub)
        .attach(&real)
        .attach(&model)
        .attach(&policy);

    let mut role = RolloutRole::new(cfg, d.obs, d.act)?;
    let schedule = s.schedule;
    let mut inbox = RealInbox::new(d.rows());
    let mut model_version = 0;
    let mut staleness = SlackTracker::default();
    let mut branches = 0;
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::file::ROLLOUT,
        barrier::kind::ROLLOUT,
    );
    if let Some(dir) = &args.resume_from {
        let state: RolloutCheckpoint = file.read(dir)?;
        branches = state.branches;
        role.restore(state.role)?;
        model_version = role.model_version();
        inbox.resume_at(role.real_received());
    }
    // At the cut the branches done are the cut's K.
    let at_cut = |role: &mut RolloutRole, cut: barrier::Cut| {
        let state = RolloutCheckpoint {
            role: role.checkpoint(),
            branches: cut.model_trainings,
        };
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    };
    let gate = barrier::DataGate::new(&waiter, &control, &stats_pub, &real, s.mode, at_cut);
    let train_points = (1..=cfg.steps).filter(|&t| schedule.train_point(t).is_some());
    for t in train_points.skip(branches as usize) {
        let epoch = schedule.train_point(t).expect("train point");
        let v = branches + 1;
        let need_policy = (t - 1).saturating_sub(s.slack.policy_lag);
        let what = || {
            format!(
                "model v{v}, policy v{need_policy}, {} real transitions",
                t - 1
            )
        };
        let ready = |role: &mut RolloutRole, inbox: &RealInbox<S>| {
            if let Some(w) = model.receive_latest()? {
                role.load_model(w.version(), |m| d.model.load_into(w.params(), m))?;
                model_version = w.version();
            }
            if let Some(w) = policy.receive_latest()? {
                role.set_policy_params(w.params(), policy_version_of(w.version()));
            }
            Ok(model_version >= v && role.has_policy(need_policy) && inbox.received() >= t - 1)
        };
        if !gate.wait_until(&mut inbox, &mut role, branches, t - 1, &what, ready)? {
            return Ok(());
        }
        if s.mode == Mode::Lockstep {
            ensure_protocol!(
                model_version == v && role.policy_version() == t - 1,
                "lockstep rollouts for step {t}: model v{model_version} (want v{v}), policy v{} (want v{})",
                role.policy_version(),
                t - 1
            );
        }
        staleness.see((t - 1) as f64 - role.policy_version() as f64);
        let n = match s.mode {
            Mode::Lockstep => (t - 1 - inbox.taken()) as usize,
            Mode::Pipelined => inbox.pending(),
        };
        inbox.take(n, &mut role);
        let started = Instant::now();
        let batch = role.branch(epoch)?;
        let seconds = started.elapsed().as_secs_f64();
        stats_pub.report(RolloutBranch {
            env_steps: t - 1,
            model_version: batch.model_version,
            policy_version: batch.policy_version,
            rows: batch.rows.len as u32,
            length: batch.rollout_length as u32,
            seconds: seconds as f32,
        })?;
        let meta = TransitionMeta {
            policy_version: batch.policy_version,
            model_version: batch.model_version,
            env_steps: t - 1,
        };
        imagined.send_batch(&batch.rows, meta)?;
        branches += 1;
        tracing::info!(
            "step {t}: {} rollouts of k={} with model v{} and policy v{}: {} rows in {seconds:.2} s",
            n_rollouts,
            batch.rollout_length,
            batch.model_version,
            batch.policy_version,
            batch.rows.len
        );
    }
    let total = cfg.steps;
    if !gate.wait_for_real(&mut inbox, &mut role, total, branches)? {
        return Ok(());
    }
    let (lo, hi, mean) = staleness.get();
    let lost = real.stats().missing;
    let done = Done {
        real: inbox.received(),
        lost,
        real_spilled: inbox.spilled(),
        work: branches,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ..Default::default()
    };
    stats_pub.report(done)?;
    tracing::info!(
        "done: {} real transitions received, {lost} lost, {branches} branches",
        inbox.received()
    );
    gate.idle_until_stop(&mut inbox, &mut role, Some(branches))
}
