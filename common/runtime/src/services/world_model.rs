//! `mbpo-sac-learner --world-model`: TD-MPC2's learner. It consumes real transitions one env
//! step at a time into its episodes, pays the updates the schedule owes for the step (none in
//! the seed steps, as many as the seed steps at the last of them, then `updates_per_step`), and
//! publishes the world model's parameters as version t (= env steps consumed).
//!
//! Lockstep: consume t, every update of t, publish t, then t + 1 -- the order of `mbpo train`.
//! Pipelined: updates may trail the steps consumed by `update_buffer` (and run ahead of them
//! by as many). Lockstep also waits, before publishing version t + 1, until the evaluator
//! confirmed it copied version t at an eval point (latest-value weights would skip it).

use std::time::{Duration, Instant};

use mbpo_train::run_files::WorldModelLearnerCheckpoint;
use mbpo_train::tdmpc::roles::WorldModelLearner;
use mbpo_wire::*;

use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// The learner's ports.
pub struct Ports<S: Transport> {
    real: TransitionSubscriber<S>,
    weights: WeightsPublisher<S>,
}

type LearnerCx<'a, S> = Cx<'a, S, Ports<S>>;

/// TD-MPC2's world-model learner on the serving loop.
pub struct WorldModelLearnerWorker<S: Transport> {
    role: WorldModelLearner,
    inbox: RealInbox<S>,
    consumed: u64,
    published: u64,
    total_updates: u64,
    /// Updates the consumed steps may owe unpaid, and may be done ahead (0 in lockstep).
    slack: u64,
    /// Updates owed minus updates done when a step is consumed.
    owed: SlackTracker,
    step_seconds: Vec<f64>,
    last_publish: Instant,
    last_progress: Instant,
    started: Instant,
    ipc: Duration,
}

impl<S: Transport> Worker<S> for WorldModelLearnerWorker<S> {
    const KIND: RoleKind = RoleKind::WorldModelLearner;
    type Ports = Ports<S>;
    type Checkpoint = WorldModelLearnerCheckpoint;

    fn ports(s: &Process<S>) -> Result<Ports<S>> {
        let d = s.dims;
        let (hash, len) = d.weights_layout(WeightsKind::WorldModel);
        Ok(Ports {
            real: TransitionSubscriber::create(&s.node, Channel::Real, d.rows())?,
            weights: WeightsPublisher::create(&s.node, WeightsKind::WorldModel, hash, len)?,
        })
    }
    fn attach<'a>(p: &'a Ports<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.real).attach(&p.weights);
    }
    fn new(cx: &LearnerCx<'_, S>) -> Result<Self> {
        let (cfg, d, s) = (&cx.s.cfg, cx.s.dims, cx.s);
        let slack = match s.mode {
            Mode::Lockstep => 0,
            Mode::Pipelined => s.slack.update_buffer,
        };
        Ok(Self {
            role: WorldModelLearner::with_dims(cfg, (d.obs, d.act), d.episode_length),
            inbox: RealInbox::new(d.rows()),
            consumed: 0,
            published: 0,
            total_updates: s.schedule.updates_owed(cfg.steps),
            slack,
            owed: SlackTracker::default(),
            step_seconds: Vec::with_capacity(cfg.steps as usize),
            last_publish: Instant::now(),
            last_progress: Instant::now(),
            started: Instant::now(),
            ipc: Duration::ZERO,
        })
    }
    fn restore(&mut self, state: WorldModelLearnerCheckpoint, cx: &LearnerCx<'_, S>) -> Result<()> {
        let consumed = state.consumed;
        state.restore_into(&mut self.role)?;
        (self.consumed, self.published) = (consumed, consumed);
        self.inbox.resume_at(self.consumed);
        // The evaluator acknowledged this eval point before the checkpoint was written.
        cx.control.assume_ack(self.consumed);
        Ok(())
    }
    /// Version 0: the initial parameters (the seed steps' actors need none, but the first plan
    /// after them may come before any update in a pipelined run); a resumed learner
    /// republishes the version of its checkpoint.
    fn start(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        self.publish(cx, self.published)
    }
    fn step(&mut self, cx: &LearnerCx<'_, S>) -> Result<Step> {
        if self.published == cx.s.cfg.steps && self.role.updates() >= self.total_updates {
            return Ok(Step::Finished);
        }
        let t0 = Instant::now();
        // Rows of the seed steps go into the episodes as they arrive (nothing samples them
        // before the last is consumed), later ones when their step is consumed.
        let seed = cx.s.schedule.init_random_steps;
        self.inbox.pull(&cx.ports.real, seed, &mut self.role)?;
        self.ipc += t0.elapsed();
        if let Some(step) = self.try_publish(cx)? {
            return Ok(step);
        }
        if self.try_consume(cx) {
            return Ok(Step::Worked);
        }
        // Ahead of the steps consumed only once the seed steps are in (nothing to learn from
        // before).
        let schedule = cx.s.schedule;
        let owed = schedule.updates_owed(self.consumed) + self.slack;
        let seeded = self.consumed >= schedule.init_random_steps;
        if seeded && self.role.updates() < owed.min(self.total_updates) {
            self.role.update(1)?;
            return Ok(Step::Worked);
        }
        Ok(Step::Waiting)
    }
    fn done_so_far(&self) -> u64 {
        self.consumed
    }
    /// At the cut: step T consumed and published (no transition after T exists while the
    /// actors are paused).
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        _: &LearnerCx<'_, S>,
    ) -> Result<AtCut<WorldModelLearnerCheckpoint>> {
        if (self.consumed, self.published) != (cut.env_steps, cut.env_steps) {
            return Ok(AtCut::Work);
        }
        Ok(AtCut::Write(WorldModelLearnerCheckpoint::of(
            &self.role,
            cut.env_steps,
        )))
    }
    fn finish(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        let median = mbpo_core::stats::median(&mut self.step_seconds).unwrap_or(0.0);
        let lost = cx.ports.real.stats().missing;
        let updates = self.role.updates();
        cx.stats.report(Done {
            real: self.inbox.received(),
            lost,
            real_spilled: self.inbox.spilled(),
            work: updates,
            median_step_seconds: median as f32,
            ipc_seconds: self.ipc.as_secs_f32(),
            wall_seconds: self.started.elapsed().as_secs_f32(),
            ..Done::with_slack(&self.owed)
        })?;
        tracing::info!(
            "done: {} steps, {updates} world-model updates, {lost} real lost, median {median:.4} s per step",
            self.consumed,
        );
        Ok(())
    }
    fn waiting_for(&self) -> String {
        format!(
            "real transition {} (published version {}, {} updates)",
            self.consumed + 1,
            self.published,
            self.role.updates()
        )
    }
}

impl<S: Transport> WorldModelLearnerWorker<S> {
    /// Whether the updates owed by the steps consumed are paid (within the slack; the last
    /// version only when every update is).
    fn paid(&self, cx: &LearnerCx<'_, S>) -> bool {
        let owed = cx.s.schedule.updates_owed(self.consumed);
        let updates = self.role.updates();
        match self.consumed < cx.s.cfg.steps {
            true => updates + self.slack >= owed,
            false => updates >= self.total_updates,
        }
    }

    /// Publish version `consumed` once its updates are paid. `Some(step)`: the step ends here.
    fn try_publish(&mut self, cx: &LearnerCx<'_, S>) -> Result<Option<Step>> {
        let (cfg, schedule) = (&cx.s.cfg, cx.s.schedule);
        let (consumed, published) = (self.consumed, self.published);
        if published >= consumed || !self.paid(cx) {
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
        if published > schedule.init_random_steps {
            self.step_seconds
                .push(self.last_publish.elapsed().as_secs_f64());
        }
        self.last_publish = Instant::now();
        self.published = consumed;
        self.report(cx)?;
        Ok((consumed == cfg.steps).then_some(Step::Worked))
    }

    /// Consume the next step when it arrived and the last one is published.
    fn try_consume(&mut self, cx: &LearnerCx<'_, S>) -> bool {
        let (s, schedule) = (cx.s, cx.s.schedule);
        let next = self.consumed + 1;
        let ready = self.consumed < s.cfg.steps
            && self.inbox.received() > self.consumed
            && self.published == self.consumed;
        if !ready {
            return false;
        }
        let n = next.saturating_sub(self.inbox.taken()) as usize;
        self.inbox.take(n, &mut self.role);
        if !schedule.is_warm_up(next) {
            let owed = schedule.updates_owed(next) as f64;
            self.owed.see(owed - self.role.updates() as f64);
        }
        self.consumed = next;
        true
    }

    /// After publishing: the metrics row at an eval point (the world model's losses; SAC's α,
    /// entropy and mean Q are NaN, empty cells), progress twice a second.
    fn report(&mut self, cx: &LearnerCx<'_, S>) -> Result<()> {
        let (consumed, updates) = (self.consumed, self.role.updates());
        if cx.s.schedule.is_eval_point(consumed) {
            let losses = self.role.reported_losses();
            cx.stats.report(LearnerRow {
                env_steps: consumed,
                sac_updates: updates,
                critic_loss: losses.value,
                actor_loss: losses.policy,
                alpha: f32::NAN,
                entropy: f32::NAN,
                q_mean: f32::NAN,
                consistency_loss: losses.consistency,
                reward_loss: losses.reward,
                rollout_length: 0,
                model_buffer: 0,
                model_version: 0,
            })?;
        }
        if self.last_progress.elapsed() >= Duration::from_millis(500) {
            self.last_progress = Instant::now();
            cx.stats.report(Progress {
                env_steps: consumed,
                sac_updates: updates,
                model_version: 0,
                policy_version: self.published,
            })?;
        }
        Ok(())
    }

    /// Publish the parameters as version `version` with the counters that go with it.
    fn publish(&self, cx: &LearnerCx<'_, S>, version: u64) -> Result<()> {
        let counters = WeightsCounters {
            env_steps: version,
            sac_updates: self.role.updates(),
            model_trainings: 0,
        };
        let wire = policy_wire_version(version);
        cx.ports
            .weights
            .publish(self.role.params(), wire, counters)?;
        Ok(())
    }
}
