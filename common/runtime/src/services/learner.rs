//! `mbpo-sac-learner`: consumes real transitions one env step at a time and imagined batches,
//! runs G SAC updates per env step after the warm-up, and publishes policy version r (= env
//! steps consumed) once those updates are paid.
//!
//! The G ratio is a Reverb-style [`RateLimiter`] between steps consumed (inserts) and updates
//! (samples): lockstep = zero slack (consume t, G updates, publish t, consume t + 1: Algorithm 2);
//! pipelined = ± `update_buffer` updates. Before consuming step t the imagined batches of every
//! train point ≤ t − model_lag must be in D_model (lockstep: the one branched for t itself).
//! Lockstep also waits, before publishing version t + 1, until the evaluator confirmed it
//! copied version t at an eval point (latest-value weights would otherwise skip it).

use std::time::{Duration, Instant};

use mbpo_core::rate_limit::RateLimiter;
use mbpo_core::Batch;
use mbpo_model::rollout_length;
use mbpo_train::roles::{ImaginedBatch, LearnerRole, RolloutRole};
use mbpo_wire::*;

use crate::barrier::{self, LearnerCheckpoint};
use crate::{Result, RuntimeError, *};

/// The learner's service loop.
pub fn run<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::Learner)?;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let real = TransitionSubscriber::create(&s.node, Channel::Real, d.rows())?;
    let imagined = TransitionSubscriber::create(&s.node, Channel::Imagined, d.rows())?;
    let policy =
        WeightsPublisher::create(&s.node, WeightsKind::Policy, d.policy_hash, d.policy_len)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    let mut waiter = Waiter::new()?;
    waiter
        .attach(&control.sub)
        .attach(&real)
        .attach(&imagined)
        .attach(&policy);

    let mut role = LearnerRole::new(cfg, d.obs, d.act);
    // More than one thread competes with the other services for the cores (results/measurements.md).
    tracing::info!("SAC updates on {} thread(s) (sac.threads)", cfg.sac.threads);
    let schedule = s.schedule;
    let g = cfg.mbpo.updates_per_step as f64;
    let warm = cfg.mbpo.init_random_steps;
    let total_updates = schedule.updates_owed(cfg.steps);
    let limiter = match s.mode {
        Mode::Lockstep => RateLimiter::lockstep(g, warm),
        Mode::Pipelined => RateLimiter::pipelined(g, warm, s.slack.update_buffer as f64),
    };
    let mut inbox = RealInbox::new(d.rows());
    let mut batch = ImaginedBatch {
        model_version: 0,
        policy_version: 0,
        rollout_length: 0,
        rows: Batch::default(),
    };
    let (mut consumed, mut updates, mut published) = (0u64, 0u64, 0u64);
    let mut model_batches = 0u64;
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::file::LEARNER,
        barrier::kind::LEARNER,
    );
    if let Some(dir) = &args.resume_from {
        let state: LearnerCheckpoint = file.read(dir)?;
        // A checkpoint of `mbpo train` may store D_model as the branches that made it: this
        // process does them again with a rollout generator of its own.
        let mut replayer = match state.d_model_branches {
            Some(_) => Some(RolloutRole::new(cfg, d.obs, d.act)?),
            None => None,
        };
        role.restore(state.role, state.d_model_branches, replayer.as_mut())?;
        (consumed, published) = (state.consumed, state.consumed);
        (updates, model_batches) = (state.updates, state.model_batches);
        batch.model_version = state.model_version;
        inbox.resume_at(consumed);
        // The evaluator acknowledged this eval point before the checkpoint was written.
        control.assume_ack(consumed);
    }
    let mut owed = SlackTracker::default();
    let mut step_seconds = Vec::with_capacity(cfg.steps as usize);
    let mut last_publish = Instant::now();
    let mut last_progress = Instant::now();
    let publish =
        |version: u64, role: &LearnerRole, updates: u64, model_version: u64| -> Result<()> {
            let counters = WeightsCounters {
                env_steps: version,
                sac_updates: updates,
                model_trainings: model_version,
            };
            policy.publish(
                &role.sac().actor_params,
                policy_wire_version(version),
                counters,
            )?;
            Ok(())
        };
    let started = Instant::now();
    let mut ipc = Duration::ZERO;
    // Version 0: the initial parameters (actors of step 1 use them when there is no warm-up);
    // a resumed learner republishes the version of its checkpoint.
    // Readers that connect later get it too (latest value, see mbpo_wire::weights).
    publish(published, &role, updates, model_batches)?;
    // Every step consumed and every update paid (a run restarted from its last step's
    // checkpoint has nothing left): straight to the Done report.
    let finished =
        |published: u64, updates: u64| published == cfg.steps && updates >= total_updates;
    while !finished(published, updates) {
        let t0 = Instant::now();
        control.poll()?;
        if control.stopped() {
            tracing::info!("stopped after {consumed} steps");
            return Ok(());
        }
        if let Some(cut) = control.cut() {
            // The cut: step T consumed and published, the K imagined batches in D_model. No
            // transition after T exists while the actors are paused.
            if consumed == cut.env_steps
                && published == cut.env_steps
                && model_batches == cut.model_trainings
            {
                let state = checkpoint_at(&role, cut, updates, batch.model_version);
                if !barrier::write_and_await_resume(
                    &waiter, &control, &stats_pub, &file, cut, &state,
                )? {
                    tracing::info!("stopped after the checkpoint at step {consumed}");
                    return Ok(());
                }
                continue;
            }
        }
        // The warm-up's transitions go into D_env as they arrive (nothing samples it before
        // they are all consumed); later ones when the step is consumed.
        inbox.pull(&real, warm, &mut role)?;
        while let Some(b) = imagined.receive()? {
            b.to_batch(&mut batch.rows);
            let tp = b.header().env_steps + 1;
            let epoch = schedule.train_point(tp).ok_or_else(|| {
                RuntimeError::protocol(format!("imagined batch for step {tp}, not a train point"))
            })?;
            batch.rollout_length = rollout_length(epoch, cfg.mbpo.rollout_schedule);
            batch.model_version = b.header().model_version;
            batch.policy_version = b.header().policy_version;
            role.add_imagined(&batch);
            model_batches += 1;
        }
        ipc += t0.elapsed();
        // Publish version `consumed` once its updates are paid (within the buffer).
        // The last version is published only when every update is paid.
        let paid = consumed < cfg.steps || updates >= total_updates;
        if published < consumed && paid && limiter.can_insert(consumed, updates) {
            // Lockstep: the evaluator must have copied the previous version if it evaluates it.
            if s.mode == Mode::Lockstep
                && published > 0
                && schedule.is_eval_point(published)
                && !control.take_ack(published)
            {
                waiter.wait(Duration::from_secs(1))?;
                continue;
            }
            let t0 = Instant::now();
            publish(consumed, &role, updates, model_batches)?;
            ipc += t0.elapsed();
            if published > warm {
                step_seconds.push(last_publish.elapsed().as_secs_f64());
            }
            last_publish = Instant::now();
            published = consumed;
            if schedule.is_eval_point(consumed) {
                stats_pub.report(LearnerRow {
                    env_steps: consumed,
                    sac_updates: role.sac().updates(),
                    critic_loss: role.last_stats.critic_loss,
                    actor_loss: role.last_stats.actor_loss,
                    alpha: role.sac().alpha(),
                    entropy: role.last_stats.entropy,
                    q_mean: role.last_stats.q_mean,
                    rollout_length: role.rollout_length,
                    model_buffer: role.model_buffer_len(),
                    model_version: batch.model_version,
                })?;
            }
            if last_progress.elapsed() >= Duration::from_millis(500) {
                last_progress = Instant::now();
                stats_pub.report(Progress {
                    env_steps: consumed,
                    sac_updates: updates,
                    model_version: batch.model_version,
                    policy_version: published,
                })?;
            }
            if consumed == cfg.steps {
                break;
            }
        }
        let next = consumed + 1;
        // At a cut, the K imagined batches it holds are enough for every step ≤ T: pipelined,
        // K may miss a training the model trainer abandoned for the barrier (lockstep K covers
        // every train point ≤ T).
        let imagined_ready = model_batches
            >= schedule.train_points_upto(next.saturating_sub(s.slack.model_lag))
            || control
                .cut()
                .is_some_and(|c| next <= c.env_steps && model_batches >= c.model_trainings);
        if consumed < cfg.steps
            && inbox.received() > consumed
            && imagined_ready
            && limiter.can_insert(consumed, updates)
            && published == consumed
        {
            inbox.take(next.saturating_sub(inbox.taken()) as usize, &mut role);
            if !schedule.is_warm_up(next) {
                owed.see(schedule.updates_owed(next) as f64 - updates as f64);
            }
            consumed = next;
            continue;
        }
        if consumed > warm && limiter.can_sample(consumed, updates) && updates < total_updates {
            role.update()?;
            updates += 1;
            continue;
        }
        waiter.wait(Duration::from_secs(1))?;
    }
    let median = mbpo_core::stats::median(&mut step_seconds).unwrap_or(0.0);
    let (lo, hi, mean) = owed.get();
    let lost = real.stats().missing;
    let done = Done {
        real: inbox.received(),
        lost,
        real_spilled: inbox.spilled(),
        work: updates,
        median_step_seconds: median as f32,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ipc_seconds: ipc.as_secs_f32(),
        wall_seconds: started.elapsed().as_secs_f32(),
        ..Default::default()
    };
    stats_pub.report(done)?;
    tracing::info!(
        "done: {consumed} steps, {updates} updates, {lost} real lost, median {median:.4} s per step, {:.3} s of {:.1} s in IPC calls",
        ipc.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
    barrier::idle_until_stop(&waiter, &control, &stats_pub, None, |cut| {
        crate::error::ensure_protocol!(
            (cut.env_steps, cut.model_trainings) == (consumed, model_batches),
            "checkpoint after step {} with {} model trainings, but the learner is done: {consumed} steps, {model_batches} imagined batches",
            cut.env_steps,
            cut.model_trainings
        );
        let state = checkpoint_at(&role, cut, updates, batch.model_version);
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    })
}

/// The learner's file at `cut`: it has consumed and published step T and holds the K imagined
/// batches.
fn checkpoint_at(
    role: &LearnerRole,
    cut: barrier::Cut,
    updates: u64,
    model_version: u64,
) -> LearnerCheckpoint {
    let (role, d_model_branches) = role.checkpoint();
    LearnerCheckpoint {
        role,
        consumed: cut.env_steps,
        updates,
        model_batches: cut.model_trainings,
        model_version,
        d_model_branches,
    }
}
