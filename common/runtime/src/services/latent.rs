//! TD-MPC2's actors and evaluator on the pipeline: they plan in the latent space of the
//! world-model learner's parameters (`WeightsKind::WorldModel`, on the policy channel).
//!
//! As SAC's: the actor of global step g acts with the parameters after step g − 1 (lockstep:
//! exactly those; pipelined: at least g − 1 − `policy_lag`), and the evaluator evaluates
//! version t at eval point t (lockstep: acknowledging it, so the learner never skips it).

use mbpo_core::TransitionSink;
use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::run_files::{LatentActorCheckpoint, LatentEvaluatorCheckpoint};
use mbpo_train::tdmpc::roles::{TdmpcActor, TdmpcEvaluator};
use mbpo_train::TrainError;
use mbpo_wire::*;

use super::acting::{ActingRole, Finish};
use super::actor::wait_for_control_subscribers;
use super::eval_points::EvalPoints;
use crate::barrier;
use crate::error::ensure_protocol;
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// A planning actor of TD-MPC2 on the shared step loop.
pub struct LatentActing {
    role: TdmpcActor,
    policy_lag: u64,
}

impl ActingRole for LatentActing {
    const ROLE: RoleKind = RoleKind::LatentActor;
    const WEIGHTS: WeightsKind = WeightsKind::WorldModel;
    type Checkpoint = LatentActorCheckpoint;

    fn new<S: Transport>(s: &Process<S>) -> Result<Self> {
        Ok(Self {
            role: TdmpcActor::new(&s.cfg, s.args.index as u64)?,
            policy_lag: s.slack.policy_lag,
        })
    }
    fn checkpoint(&self, steps: u64) -> LatentActorCheckpoint {
        LatentActorCheckpoint {
            role: self.role.checkpoint(),
            steps,
        }
    }
    fn restore(&mut self, state: LatentActorCheckpoint) -> Result<u64> {
        self.role.restore(state.role)?;
        Ok(state.steps)
    }
    fn take_newest<S: Transport>(
        &mut self,
        weights: &WeightsSubscriber<S>,
        _: &Dims,
    ) -> Result<()> {
        let planner = self.role.planner();
        if let Some(h) = weights.receive_latest_into(planner.params_mut())? {
            planner.received(policy_version_of(h.version));
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
        self.role.planner_ref().holds(version)
    }
    fn version(&self) -> u64 {
        self.role.planner_ref().version()
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
        let log = match self.role.planner_ref().iterations_per_plan() {
            Some((plans, lo, mean, hi)) => {
                format!("{plans} plans (iterations per plan {lo}..{hi}, mean {mean:.2}), ")
            }
            None => "no plans, ".into(),
        };
        Finish {
            work: self.role.env_actor().episodes,
            median_step_seconds: 0.0,
            log,
        }
    }
}

/// The evaluator's ports: the parameters it plans with, and its acknowledgements (lockstep).
pub struct LatentEvaluatorPorts<S: Transport> {
    acks: ControlPublisher<S>,
    weights: WeightsSubscriber<S>,
}

type EvalCx<'a, S> = Cx<'a, S, LatentEvaluatorPorts<S>>;

/// The evaluator on the serving loop: one step evaluates the next eval point t once version t
/// arrived.
pub struct LatentEvaluator {
    role: TdmpcEvaluator,
    points: EvalPoints,
}

impl<S: Transport> Worker<S> for LatentEvaluator {
    const KIND: RoleKind = RoleKind::LatentEvaluator;
    type Ports = LatentEvaluatorPorts<S>;
    type Checkpoint = LatentEvaluatorCheckpoint;

    fn ports(s: &Process<S>) -> Result<LatentEvaluatorPorts<S>> {
        let (hash, len) = s.dims.weights_layout(WeightsKind::WorldModel);
        Ok(LatentEvaluatorPorts {
            acks: ControlPublisher::<S>::create(&s.node)?,
            weights: WeightsSubscriber::create(&s.node, WeightsKind::WorldModel, hash, len)?,
        })
    }
    fn connect(
        s: &Process<S>,
        control: &ControlInbox<S>,
        p: &LatentEvaluatorPorts<S>,
    ) -> Result<()> {
        wait_for_control_subscribers(s, control, &p.acks)
    }
    fn attach<'a>(p: &'a LatentEvaluatorPorts<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.weights);
    }
    fn new(cx: &EvalCx<'_, S>) -> Result<Self> {
        Ok(Self {
            role: TdmpcEvaluator::new(&cx.s.cfg)?,
            points: EvalPoints::after(&cx.s.schedule, 0, 0),
        })
    }
    fn restore(&mut self, state: LatentEvaluatorCheckpoint, cx: &EvalCx<'_, S>) -> Result<()> {
        self.role.restore(state.role);
        self.points = EvalPoints::after(&cx.s.schedule, state.evals, state.env_steps);
        Ok(())
    }
    fn step(&mut self, cx: &EvalCx<'_, S>) -> Result<Step> {
        let Some(t) = self.points.next else {
            return Ok(Step::Finished);
        };
        // Copy a snapshot only when it is the one to evaluate (the learner publishes one per
        // env step; a world model is megabytes).
        if let Some(w) = cx.ports.weights.receive_latest()? {
            let version = policy_version_of(w.version());
            if version >= t {
                let planner = self.role.planner();
                planner.params_mut().copy_from_slice(w.params());
                planner.received(version);
            }
        }
        let planner = self.role.planner();
        if !planner.holds(t) {
            return Ok(Step::Waiting);
        }
        let version = planner.version();
        if cx.s.mode == Mode::Lockstep {
            ensure_protocol!(
                version == t,
                "lockstep evaluator expected world-model version {t}, got {version}"
            );
            // The learner publishes version t + 1 only after this: no version is skipped.
            send_ack(&cx.ports.acks, ProducerId::new(Role::Learner, 0), t)?;
        }
        let episodes = cx.s.cfg.eval.episodes;
        let ret = self.role.evaluate(episodes)?;
        cx.stats.report(EvalResult {
            env_steps: t,
            policy_version: version,
            model_version: 0,
            mean_return: ret,
            episodes: episodes as u32,
        })?;
        tracing::info!("eval after step {t} (world-model version {version}): {ret:.2}");
        self.points.evaluated(&cx.s.schedule, t);
        Ok(Step::Worked)
    }
    fn done_so_far(&self) -> u64 {
        self.points.evals
    }
    /// At the cut every eval point ≤ T is evaluated.
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        _: &EvalCx<'_, S>,
    ) -> Result<AtCut<LatentEvaluatorCheckpoint>> {
        if self.points.behind(cut) {
            return Ok(AtCut::Work);
        }
        Ok(AtCut::Write(LatentEvaluatorCheckpoint {
            role: self.role.checkpoint(),
            version: self.role.planner_ref().version(),
            evals: self.points.evals,
            env_steps: cut.env_steps,
        }))
    }
    fn finish(&mut self, cx: &EvalCx<'_, S>) -> Result<()> {
        self.points.report_done(cx.stats)
    }
    fn waiting_for(&self) -> String {
        let t = self.points.next.unwrap_or_default();
        format!("world-model version {t} to evaluate")
    }
}
