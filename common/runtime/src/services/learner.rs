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

use crate::barrier::LearnerCheckpoint;
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, RuntimeError, *};

/// The learner's ports.
pub struct Ports<S: Transport> {
    real: TransitionSubscriber<S>,
    imagined: TransitionSubscriber<S>,
    policy: WeightsPublisher<S>,
}

type LearnerCx<'a, S> = Cx<'a, S, Ports<S>>;

/// The SAC learner on the serving loop.
pub struct Learner<S: Transport> {
    role: LearnerRole,
    limiter: RateLimiter,
    inbox: RealInbox<S>,
    /// The imagined batch being received (its rows are reused).
    batch: ImaginedBatch,
    consumed: u64,
    updates: u64,
    published: u64,
    model_batches: u64,
    total_updates: u64,
    /// Updates owed minus updates done when a step is consumed.
    owed: SlackTracker,
    step_seconds: Vec<f64>,
    last_publish: Instant,
    last_progress: Instant,
    started: Instant,
    ipc: Duration,
}

impl<S: Transport> Worker<S> for Learner<S> {
    const KIND: RoleKind = RoleKind::Learner;
    type Ports = Ports<S>;
    type Checkpoint = LearnerCheckpoint;

    fn ports(s: &Process<S>) -> Result<Ports<S>> {
        let d = s.dims;
        Ok(Ports {
            real: TransitionSubscriber::create(&s.node, Channel::Real, d.rows())?,
            imagined: TransitionSubscriber::create(&s.node, Channel::Imagined, d.rows())?,
            policy: WeightsPublisher::create(
                &s.node,
                WeightsKind::Policy,
                d.policy_hash,
                d.policy_len,
            )?,
        })
    }
    fn attach<'a>(p: &'a Ports<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.real).attach(&p.imagined).attach(&p.policy);
    }
    fn new(cx: &LearnerCx<'_, S>) -> Result<Self> {
        let (cfg, d, s) = (&cx.s.cfg, cx.s.dims, cx.s);
        // More than one thread competes with the other services for the cores (results/measurements.md).
        tracing::info!("SAC updates on {} thread(s) (sac.threads)", cfg.sac.threads);
        let g = cfg.mbpo.updates_per_step as f64;
        let warm = cfg.mbpo.init_random_steps;
        let limiter = match s.mode {
            Mode::Lockstep => RateLimiter::lockstep(g, warm),
            Mode::Pipelined => RateLimiter::pipelined(g, warm, s.slack.update_buffer as f64),
        };
        Ok(Self {
            role: LearnerRole::new(cfg, d.obs, d.act),
            limiter,
            inbox: RealInbox::new(d.rows()),
            batch: ImaginedBatch {
                model_version: 0,
                policy_version: 0,
                rollout_length: 0,
                rows: Batch::default(),
            },
            consumed: 0,
            updates: 0,
            published: 0,
            model_batches: 0,
            total_updates: s.schedule.updates_owed(cfg.steps),
            owed: SlackTracker::default(),
            step_seconds: Vec::with_capacity(cfg.steps as usize),
            last_publish: Instant::now(),
            last_progress: Instant::now(),
            started: Instant::now(),
            ipc: Duration::ZERO,
        })
    }
    fn restore(&mut self, state: LearnerCheckpoint, cx: &LearnerCx<'_, S>) -> Result<()> {
        let (cfg, d) = (&cx.s.cfg, cx.s.dims);
        // A checkpoint of `mbpo train` may store D_model as the branches that made it: this
        // process does them again with a rollout generator of its own.
        let mut replayer = match state.d_model_branches {
            Some(_) => Some(RolloutRole::new(cfg, d.obs, d.act)?),
            None => None,
        };
        self.role
            .restore(state.role, state.d_model_branches, replayer.as_mut())?;
        (self.consumed, self.published) = (state.consumed, state.consumed);
        (self.updates, self.model_batches) = (state.updates, state.model_batches);
        self.batch.model_version = state.model_version;
        self.inbox.resume_at(self.consumed);
        // The evaluator acknowledged this eval point before the checkpoint was written.
        cx.control.assume_ack(self.consumed);
        Ok(())
    }
    /// Version 0: the initial parameters (actors of step 1 use them when there is no
    /// warm-up); a resumed learner republishes the version of its checkpoint. Readers that
    /// connect later get it too (latest value, see mbpo_wire::weights).
    fn start(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        self.publish(cx, self.published)
    }
    fn step(&mut self, cx: &LearnerCx<'_, S>) -> Result<Step> {
        // Every step consumed and every update paid (a run restarted from its last step's
        // checkpoint has nothing left).
        if self.published == cx.s.cfg.steps && self.updates >= self.total_updates {
            return Ok(Step::Finished);
        }
        let t0 = Instant::now();
        self.receive(cx)?;
        self.ipc += t0.elapsed();
        if let Some(step) = self.try_publish(cx)? {
            return Ok(step);
        }
        if self.try_consume(cx) {
            return Ok(Step::Worked);
        }
        let warm = cx.s.cfg.mbpo.init_random_steps;
        let (consumed, updates) = (self.consumed, self.updates);
        if consumed > warm
            && self.limiter.can_sample(consumed, updates)
            && updates < self.total_updates
        {
            self.role.update()?;
            self.updates += 1;
            return Ok(Step::Worked);
        }
        Ok(Step::Waiting)
    }
    fn done_so_far(&self) -> u64 {
        self.consumed
    }
    /// At the cut: step T consumed and published, the K imagined batches in D_model. No
    /// transition after T exists while the actors are paused.
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        _: &LearnerCx<'_, S>,
    ) -> Result<AtCut<LearnerCheckpoint>> {
        let at = (self.consumed, self.published, self.model_batches);
        if at != (cut.env_steps, cut.env_steps, cut.model_trainings) {
            return Ok(AtCut::Work);
        }
        let (role, d_model_branches) = self.role.checkpoint();
        Ok(AtCut::Write(LearnerCheckpoint {
            role,
            consumed: cut.env_steps,
            updates: self.updates,
            model_batches: cut.model_trainings,
            model_version: self.batch.model_version,
            d_model_branches,
        }))
    }
    fn finish(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        let median = mbpo_core::stats::median(&mut self.step_seconds).unwrap_or(0.0);
        let lost = cx.ports.real.stats().missing;
        cx.stats.report(Done {
            real: self.inbox.received(),
            lost,
            real_spilled: self.inbox.spilled(),
            work: self.updates,
            median_step_seconds: median as f32,
            ipc_seconds: self.ipc.as_secs_f32(),
            wall_seconds: self.started.elapsed().as_secs_f32(),
            ..Done::with_slack(&self.owed)
        })?;
        tracing::info!(
            "done: {} steps, {} updates, {lost} real lost, median {median:.4} s per step, {:.3} s of {:.1} s in IPC calls",
            self.consumed,
            self.updates,
            self.ipc.as_secs_f64(),
            self.started.elapsed().as_secs_f64()
        );
        Ok(())
    }
    fn waiting_for(&self) -> String {
        format!(
            "real transition {} or imagined batch {} (published version {}, {} updates)",
            self.consumed + 1,
            self.model_batches + 1,
            self.published,
            self.updates
        )
    }
}

impl<S: Transport> Learner<S> {
    /// Take what arrived: the warm-up's transitions go into D_env as they arrive (nothing
    /// samples it before they are all consumed), later ones when their step is consumed; every
    /// imagined batch into D_model.
    fn receive(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        let (cfg, schedule) = (&cx.s.cfg, cx.s.schedule);
        let warm = cfg.mbpo.init_random_steps;
        self.inbox.pull(&cx.ports.real, warm, &mut self.role)?;
        while let Some(b) = cx.ports.imagined.receive()? {
            b.to_batch(&mut self.batch.rows);
            let tp = b.header().env_steps + 1;
            let epoch = schedule.train_point(tp).ok_or_else(|| {
                RuntimeError::protocol(format!("imagined batch for step {tp}, not a train point"))
            })?;
            self.batch.rollout_length = rollout_length(epoch, cfg.mbpo.rollout_schedule);
            self.batch.model_version = b.header().model_version;
            self.batch.policy_version = b.header().policy_version;
            self.role.add_imagined(&self.batch);
            self.model_batches += 1;
        }
        Ok(())
    }

    /// Publish version `consumed` once its updates are paid (within the buffer); the last
    /// version only when every update is paid. `Some(step)`: the step ends here.
    fn try_publish(&mut self, cx: &LearnerCx<'_, S>) -> Result<Option<Step>> {
        let (cfg, schedule) = (&cx.s.cfg, cx.s.schedule);
        let (consumed, published) = (self.consumed, self.published);
        let paid = consumed < cfg.steps || self.updates >= self.total_updates;
        if published >= consumed || !paid || !self.limiter.can_insert(consumed, self.updates) {
            return Ok(None);
        }
        // Lockstep: the evaluator must have copied the previous version if it evaluates it.
        if cx.s.mode == Mode::Lockstep
            && published > 0
            && schedule.is_eval_point(published)
            && !cx.control.take_ack(published)
        {
            return Ok(Some(Step::Waiting));
        }
        let t0 = Instant::now();
        self.publish(cx, consumed)?;
        self.ipc += t0.elapsed();
        if published > cfg.mbpo.init_random_steps {
            self.step_seconds
                .push(self.last_publish.elapsed().as_secs_f64());
        }
        self.last_publish = Instant::now();
        self.published = consumed;
        self.report(cx)?;
        Ok((consumed == cfg.steps).then_some(Step::Worked))
    }

    /// After publishing: the metrics row at an eval point, progress twice a second.
    fn report(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        let (role, consumed) = (&self.role, self.consumed);
        if cx.s.schedule.is_eval_point(consumed) {
            cx.stats.report(LearnerRow {
                env_steps: consumed,
                sac_updates: role.sac().updates(),
                critic_loss: role.last_stats.critic_loss,
                actor_loss: role.last_stats.actor_loss,
                alpha: role.sac().alpha(),
                entropy: role.last_stats.entropy,
                q_mean: role.last_stats.q_mean,
                consistency_loss: f32::NAN,
                reward_loss: f32::NAN,
                rollout_length: role.rollout_length,
                model_buffer: role.model_buffer_len(),
                model_version: self.batch.model_version,
            })?;
        }
        if self.last_progress.elapsed() >= Duration::from_millis(500) {
            self.last_progress = Instant::now();
            cx.stats.report(Progress {
                env_steps: consumed,
                sac_updates: self.updates,
                model_version: self.batch.model_version,
                policy_version: self.published,
            })?;
        }
        Ok(())
    }

    /// Consume the next step when it arrived, its imagined batches are in and the rate
    /// limiter allows it.
    fn try_consume(&mut self, cx: &LearnerCx<'_, S>) -> bool {
        let (s, schedule) = (cx.s, cx.s.schedule);
        let next = self.consumed + 1;
        // At a cut, the K imagined batches it holds are enough for every step ≤ T: pipelined,
        // K may miss a training the model trainer abandoned for the barrier (lockstep K covers
        // every train point ≤ T).
        let imagined_ready = self.model_batches
            >= schedule.train_points_upto(next.saturating_sub(s.slack.model_lag))
            || cx
                .control
                .cut()
                .is_some_and(|c| next <= c.env_steps && self.model_batches >= c.model_trainings);
        let ready = self.consumed < s.cfg.steps
            && self.inbox.received() > self.consumed
            && imagined_ready
            && self.limiter.can_insert(self.consumed, self.updates)
            && self.published == self.consumed;
        if !ready {
            return false;
        }
        let n = next.saturating_sub(self.inbox.taken()) as usize;
        self.inbox.take(n, &mut self.role);
        if !schedule.is_warm_up(next) {
            self.owed
                .see(schedule.updates_owed(next) as f64 - self.updates as f64);
        }
        self.consumed = next;
        true
    }

    /// Publish the policy as version `version` with the counters that go with it.
    fn publish(&self, cx: &LearnerCx<'_, S>, version: u64) -> Result<()> {
        let counters = WeightsCounters {
            env_steps: version,
            sac_updates: self.updates,
            model_trainings: self.model_batches,
        };
        let params = &self.role.sac().actor_params;
        cx.ports
            .policy
            .publish(params, policy_wire_version(version), counters)?;
        Ok(())
    }
}
