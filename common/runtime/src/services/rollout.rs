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

use super::data;
use crate::barrier::{self, RolloutCheckpoint};
use crate::error::ensure_protocol;
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// The rollout generator's ports.
pub struct Ports<S: Transport> {
    real: TransitionSubscriber<S>,
    model: WeightsSubscriber<S>,
    policy: WeightsSubscriber<S>,
    imagined: TransitionPublisher<S>,
}

type RolloutCx<'a, S> = Cx<'a, S, Ports<S>>;

/// The rollout generator on the serving loop.
pub struct RolloutGenerator<S: Transport> {
    role: RolloutRole,
    inbox: RealInbox<S>,
    /// The version of the model it holds.
    model_version: u64,
    /// Branches done (= imagined batches sent).
    branches: u64,
    /// Policy staleness of each branch.
    staleness: SlackTracker,
}

/// Rollouts per branch: M per env step of the retrain period.
fn rollouts_per_branch(cfg: &mbpo_train::ExperimentConfig) -> usize {
    cfg.mbpo.rollouts_per_step * cfg.mbpo.model_train_freq as usize
}

impl<S: Transport> Worker<S> for RolloutGenerator<S> {
    const KIND: RoleKind = RoleKind::RolloutGenerator;
    type Ports = Ports<S>;
    type Checkpoint = RolloutCheckpoint;

    fn ports(s: &Process<S>) -> Result<Ports<S>> {
        let (d, node) = (s.dims, &s.node);
        let rows = rollouts_per_branch(&s.cfg);
        Ok(Ports {
            real: TransitionSubscriber::create(node, Channel::Real, d.rows())?,
            model: WeightsSubscriber::create(
                node,
                WeightsKind::Model,
                d.model.layout_hash,
                d.model.len(),
            )?,
            policy: WeightsSubscriber::create(
                node,
                WeightsKind::Policy,
                d.policy_hash,
                d.policy_len,
            )?,
            imagined: TransitionPublisher::create(node, Channel::Imagined, d.rows(), rows)?,
        })
    }
    fn connect(_: &Process<S>, _: &ControlInbox<S>, p: &Ports<S>) -> Result<()> {
        p.imagined
            .wait_for_subscribers(1, Duration::from_secs(120))?;
        Ok(())
    }
    fn attach<'a>(p: &'a Ports<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.real).attach(&p.model).attach(&p.policy);
    }
    fn new(cx: &RolloutCx<'_, S>) -> Result<Self> {
        let d = cx.s.dims;
        Ok(Self {
            role: RolloutRole::new(&cx.s.cfg, d.obs, d.act)?,
            inbox: RealInbox::new(d.rows()),
            model_version: 0,
            branches: 0,
            staleness: SlackTracker::default(),
        })
    }
    fn restore(&mut self, state: RolloutCheckpoint, _: &RolloutCx<'_, S>) -> Result<()> {
        self.branches = state.branches;
        self.role.restore(state.role)?;
        self.model_version = self.role.model_version();
        self.inbox.resume_at(self.role.real_received());
        Ok(())
    }
    fn step(&mut self, cx: &RolloutCx<'_, S>) -> Result<Step> {
        let s = cx.s;
        let Some(t) = s.schedule.nth_train_point(self.branches + 1) else {
            return data::the_rest(s, &cx.ports.real, &mut self.inbox, &mut self.role);
        };
        if !self.ready(cx, t)? {
            return Ok(Step::Waiting);
        }
        if s.mode == Mode::Lockstep {
            ensure_protocol!(
                self.model_version == self.branches + 1 && self.role.policy_version() == t - 1,
                "lockstep rollouts for step {t}: model v{} (want v{}), policy v{} (want v{})",
                self.model_version,
                self.branches + 1,
                self.role.policy_version(),
                t - 1
            );
        }
        self.staleness
            .see((t - 1) as f64 - self.role.policy_version() as f64);
        data::take_for(s.mode, &mut self.inbox, &mut self.role, t);
        self.branch(cx, t)?;
        Ok(Step::Worked)
    }
    fn done_so_far(&self) -> u64 {
        self.branches
    }
    /// At the cut the branches done are the cut's K.
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        cx: &RolloutCx<'_, S>,
    ) -> Result<AtCut<RolloutCheckpoint>> {
        if self.branches < cut.model_trainings {
            return Ok(AtCut::Work);
        }
        if !data::take_upto_cut(&cx.ports.real, &mut self.inbox, &mut self.role, cut)? {
            return Ok(AtCut::Wait);
        }
        Ok(AtCut::Write(RolloutCheckpoint {
            role: self.role.checkpoint(),
            branches: cut.model_trainings,
        }))
    }
    fn finish(&mut self, cx: &RolloutCx<'_, S>) -> Result<()> {
        let lost = cx.ports.real.stats().missing;
        cx.stats.report(Done {
            real: self.inbox.received(),
            lost,
            real_spilled: self.inbox.spilled(),
            work: self.branches,
            ..Done::with_slack(&self.staleness)
        })?;
        tracing::info!(
            "done: {} real transitions received, {lost} lost, {} branches",
            self.inbox.received(),
            self.branches
        );
        Ok(())
    }
    fn waiting_for(&self) -> String {
        format!(
            "model v{} and the policy and real transitions of branch {} ({} received)",
            self.branches + 1,
            self.branches + 1,
            self.inbox.received()
        )
    }
}

impl<S: Transport> RolloutGenerator<S> {
    /// Take the newest model and policy and what real data arrived; true once the branch of
    /// train point `t` has model v, a policy of at least t − 1 − policy_lag and t − 1 real
    /// transitions.
    fn ready(&mut self, cx: &RolloutCx<'_, S>, t: u64) -> Result<bool> {
        let (s, p, d) = (cx.s, cx.ports, cx.s.dims);
        data::pull(s.mode, &p.real, &mut self.inbox, &mut self.role, t - 1)?;
        if let Some(w) = p.model.receive_latest()? {
            let role = &mut self.role;
            role.load_model(w.version(), |m| d.model.load_into(w.params(), m))?;
            self.model_version = w.version();
        }
        if let Some(w) = p.policy.receive_latest()? {
            self.role
                .set_policy_params(w.params(), policy_version_of(w.version()));
        }
        let need_policy = (t - 1).saturating_sub(s.slack.policy_lag);
        Ok(self.model_version > self.branches
            && self.role.has_policy(need_policy)
            && self.inbox.received() >= t - 1)
    }

    /// Branch the rollouts of train point `t` and send them as one imagined batch.
    fn branch(&mut self, cx: &RolloutCx<'_, S>, t: u64) -> Result<()> {
        let epoch = cx.s.schedule.train_point(t).expect("a train point");
        let started = Instant::now();
        let batch = branch_receiving(&mut self.role, epoch, &cx.ports.real, &mut self.inbox)?;
        let seconds = started.elapsed().as_secs_f64();
        cx.stats.report(RolloutBranch {
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
        cx.ports.imagined.send_batch(&batch.rows, meta)?;
        self.branches += 1;
        tracing::info!(
            "step {t}: {} rollouts of k={} with model v{} and policy v{}: {} rows in {seconds:.2} s",
            rollouts_per_branch(&cx.s.cfg),
            batch.rollout_length,
            batch.model_version,
            batch.policy_version,
            batch.rows.len
        );
        Ok(())
    }
}

/// The branch of train point epoch `epoch`, computed on a thread of its own while this one
/// receives the real transitions arriving meanwhile into `inbox` (not into the data the branch
/// reads): a branch of M · model_train_freq rollouts can take many seconds, and the actors
/// must not block on a full real queue meanwhile (a paced actor least of all). The branch is
/// the same computation as on this thread, so its bits do not change.
fn branch_receiving<S: Transport>(
    role: &mut RolloutRole,
    epoch: usize,
    real: &TransitionSubscriber<S>,
    inbox: &mut RealInbox<S>,
) -> Result<mbpo_train::roles::ImaginedBatch> {
    std::thread::scope(|scope| {
        let work = std::thread::Builder::new()
            .name("branch".into())
            .spawn_scoped(scope, || role.branch(epoch))
            .map_err(|e| RuntimeError::protocol(format!("starting the branch's thread: {e}")))?;
        let mut received = Ok(());
        while !work.is_finished() {
            if received.is_ok() {
                received = inbox.receive(real).map(drop);
            }
            // A queue of 1024 transitions lasts 2 s at 500 Hz: a millisecond's sleep between
            // looks is far inside that, and costs nothing next to the branch.
            std::thread::sleep(RECEIVE_EVERY);
        }
        let batch = work
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))?;
        received.map(|()| batch)
    })
}

/// How often a branch under way looks for real transitions.
const RECEIVE_EVERY: Duration = Duration::from_millis(1);
