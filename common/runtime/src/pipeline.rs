//! How each algorithm runs as a pipeline: its roles (the one list the launcher spawns, the
//! in-process pipeline starts as threads, the coordinator counts and the checkpoint barrier
//! names files after) and the few facts the shared workers ask of it.
//!
//! The roles are the `pipeline` column of the algorithm table (`mbpo_train::algorithm`, one
//! row per algorithm, built in or registered); [`spec`] makes a [`PipelineSpec`] of it. The
//! workers and the coordinator read the spec, never the algorithm's name.

use std::sync::RwLock;

use mbpo_train::{algorithm, Algo};
use mbpo_wire::{Channel, Role, WeightsKind};

use crate::barrier::{file, kind};
use crate::{Mode, Result, RuntimeError};

pub use mbpo_core::roles::{PipelineRoles, RoleKind};

/// One role of a run: a process of `mbpo run`, a thread of the in-process pipeline.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RoleSpec {
    /// What it does.
    pub kind: RoleKind,
    /// Its index within its kind (actors: 0..N).
    pub index: u16,
    /// Its name: log file, thread name, checkpoint file (`actor-<i>`, `learner`, ...).
    pub name: String,
    /// The kind of its checkpoint file in a pipeline checkpoint.
    pub checkpoint_kind: &'static str,
}

impl RoleSpec {
    /// Role `index` of `kind`.
    pub fn new(kind: RoleKind, index: u16) -> Self {
        Self {
            kind,
            index,
            name: kind.name(index),
            checkpoint_kind: kind.checkpoint_kind(),
        }
    }
    /// The binary that runs it, as installed next to `mbpo`.
    pub fn binary(&self) -> &'static str {
        self.kind.binary()
    }
    /// Its arguments besides the [`crate::ServiceArgs`] every role takes.
    pub fn binary_args(&self) -> Vec<String> {
        let mut args = Vec::new();
        if self.kind.row().numbered {
            args.extend(["--index".into(), self.index.to_string()]);
        }
        args.extend(self.kind.binary_flags().iter().map(|f| f.to_string()));
        args
    }
    /// Steps an environment (actors and the evaluator).
    pub fn steps_an_env(&self) -> bool {
        self.kind.steps_an_env()
    }
    /// Pauses at a checkpoint barrier and reports a counter.
    pub fn pauses(&self) -> bool {
        self.kind.pauses()
    }
}

/// How one algorithm runs as a pipeline.
#[derive(Debug, PartialEq, Eq)]
pub struct PipelineSpec {
    /// The algorithm (the config's `algo`).
    pub algo: &'static str,
    /// Its roles besides the training actors, in start order (the actors start last).
    pub services: &'static [RoleKind],
    /// What its training actors are.
    pub actor: RoleKind,
}

/// The pipeline of `algo` (its row of the algorithm table), or an error that names the
/// algorithms the pipeline runs.
pub fn spec(algo: Algo) -> Result<&'static PipelineSpec> {
    // One spec per algorithm for the life of the process (a handful: the built-in and the
    // registered ones), so every holder can keep a `&'static`.
    static SPECS: RwLock<Vec<&'static PipelineSpec>> = RwLock::new(Vec::new());
    let known =
        |specs: &[&'static PipelineSpec]| specs.iter().copied().find(|p| p.algo == algo.name());
    if let Some(p) = known(&SPECS.read().unwrap_or_else(|e| e.into_inner())) {
        return Ok(p);
    }
    let row = algorithm::lookup(algo.name()).and_then(|a| Some((a.name, a.pipeline?)));
    let Some((name, roles)) = row else {
        let runs: Vec<&str> = algorithm::all()
            .iter()
            .filter(|a| a.pipeline.is_some())
            .map(|a| a.name)
            .collect();
        return Err(RuntimeError::protocol(format!(
            "the pipeline runs {}, not {} (run it with `mbpo train`)",
            runs.join(" or "),
            algo.name()
        )));
    };
    let mut specs = SPECS.write().unwrap_or_else(|e| e.into_inner());
    if let Some(p) = known(&specs) {
        return Ok(p);
    }
    let spec: &'static PipelineSpec = Box::leak(Box::new(PipelineSpec {
        algo: name,
        services: roles.services,
        actor: roles.actor,
    }));
    specs.push(spec);
    Ok(spec)
}

impl PipelineSpec {
    /// Its roles with `actors` training actors, in start order.
    pub fn roles(&self, actors: u16) -> Vec<RoleSpec> {
        let services = self.services.iter().map(|&k| RoleSpec::new(k, 0));
        let actors = (0..actors).map(|i| RoleSpec::new(self.actor, i));
        services.chain(actors).collect()
    }
    /// Whether it has a role of `kind`.
    pub fn has(&self, kind: RoleKind) -> bool {
        self.actor == kind || self.services.contains(&kind)
    }
    /// It has a learner (a role on the wire as `Role::Learner`: SAC's, TD-MPC2's world-model
    /// learner), which reports the learning rows and the run's progress. Without one (MPC) the
    /// rows come from the evaluations of model versions and the progress from the actors.
    pub fn has_learner(&self) -> bool {
        let roles = self.services.iter().chain([&self.actor]);
        roles.into_iter().any(|k| k.row().wire == Role::Learner)
    }
    /// Its actors act with the model trainer's models (they subscribe the model channel): a
    /// model version is what an evaluation and the run's result are of.
    pub fn acts_on_models(&self) -> bool {
        self.actor.subscribes(Channel::Model)
    }
    /// The weights whose final version is the run's result, hashed into `policy_sha256`: the
    /// SAC policy, or the model the planners plan on (what its actors act with).
    pub fn result(&self) -> WeightsKind {
        self.actor_weights()
    }
    /// The weights its actors act with: the learner's policy, or the model they plan on.
    pub fn actor_weights(&self) -> WeightsKind {
        match self.actor {
            RoleKind::PlanningActor => WeightsKind::Model,
            RoleKind::LatentActor => WeightsKind::WorldModel,
            _ => WeightsKind::Policy,
        }
    }
    /// How many of its roles receive every real transition (an actor's first send waits for
    /// them all, so nothing it sends is lost).
    pub fn real_consumers(&self) -> usize {
        self.subscribers(Channel::Real, 1)
    }
    /// How many of its roles, with `actors` actors, subscribe `channel` (a publisher that
    /// must not lose a message waits for them all).
    pub fn subscribers(&self, channel: Channel, actors: u16) -> usize {
        let roles = self.roles(actors).into_iter();
        roles.filter(|r| r.kind.subscribes(channel)).count()
    }
    /// The model trainer abandons a training under way when the run stops: in a pipelined run
    /// whose actors do not plan on it (one training can take minutes; the resumed run trains
    /// again). A planning run's evaluator needs the model of every eval point before the cut,
    /// and lockstep equals the sequential run, so those finish it.
    pub fn abandons_training_on_stop(&self, mode: Mode) -> bool {
        mode == Mode::Pipelined && !self.acts_on_models()
    }
}

/// The names of the roles of `algo` that receive every real transition (the keys of the
/// summary's `real_transitions.received`); none for an algorithm the pipeline does not run.
pub fn real_consumers(algo: Algo) -> Vec<String> {
    let roles = spec(algo).map(|p| p.roles(0)).unwrap_or_default();
    let consumers = roles.into_iter().filter(|r| r.kind.consumes_real());
    consumers.map(|r| r.name).collect()
}

/// The files a checkpoint of a run of `algo` with `actors` actors holds whichever command
/// wrote it, with their kinds: one per role ([`PipelineSpec::roles`]) and the run book.
pub fn role_files(pipeline: &PipelineSpec, actors: u16) -> Vec<(String, &'static str)> {
    let roles = pipeline.roles(actors).into_iter();
    let mut files: Vec<_> = roles.map(|r| (r.name, r.checkpoint_kind)).collect();
    files.push((file::RUN_BOOK.into(), kind::RUN_BOOK));
    files
}

/// Every file of a checkpoint written by the pipeline: [`role_files`] and the launcher's.
pub fn pipeline_files(pipeline: &PipelineSpec, actors: u16) -> Vec<(String, &'static str)> {
    let mut files = role_files(pipeline, actors);
    files.push((file::SUPERVISOR.into(), kind::SUPERVISOR));
    files
}

/// The processes that pause at a barrier and report a counter: the actors, the model trainer
/// and (MBPO) the rollout generator. The learner and evaluator only follow the cut.
pub fn pausing_processes(pipeline: &PipelineSpec, actors: u16) -> usize {
    let roles = pipeline.roles(actors);
    roles.iter().filter(|r| r.pauses()).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mbpo_has_five_kinds_of_role_and_mpc_three() {
        let names = |algo, actors| -> Vec<String> {
            let spec = spec(algo).unwrap();
            spec.roles(actors).into_iter().map(|r| r.name).collect()
        };
        assert_eq!(
            names(Algo::MBPO, 2),
            [
                "learner",
                "model-trainer",
                "rollout-generator",
                "evaluator",
                "actor-0",
                "actor-1"
            ]
        );
        assert_eq!(
            names(Algo::MPC, 1),
            ["model-trainer", "evaluator", "actor-0"]
        );
        let mbpo = spec(Algo::MBPO).unwrap();
        let mpc = spec(Algo::MPC).unwrap();
        let actor = &mbpo.roles(3)[6];
        assert_eq!(
            (actor.binary(), actor.binary_args()),
            ("mbpo-actor", vec!["--index".to_string(), "2".to_string()])
        );
        assert_eq!(mbpo.roles(3).iter().filter(|r| r.pauses()).count(), 5);
        assert_eq!(mpc.roles(3).iter().filter(|r| r.pauses()).count(), 4);
        assert!(mbpo.has_learner() && !mbpo.acts_on_models());
        assert!(!mpc.has_learner() && mpc.acts_on_models());
        let tdmpc = spec(Algo::TDMPC).unwrap();
        assert!(tdmpc.has_learner() && !tdmpc.acts_on_models());
    }

    #[test]
    fn the_actor_binary_runs_the_role_its_flags_name() {
        for spec in [spec(Algo::MBPO).unwrap(), spec(Algo::MPC).unwrap()] {
            for role in spec.roles(2).iter().filter(|r| r.binary() == "mbpo-actor") {
                let args = role.binary_args();
                let flags: Vec<&str> = args.iter().map(String::as_str).collect();
                let kind = RoleKind::of_binary(role.binary(), &flags);
                assert_eq!(kind, Some(role.kind), "{} {}", spec.algo, role.name);
            }
        }
    }

    #[test]
    fn subscriber_counts_follow_from_the_role_table() {
        let (mbpo, mpc) = (spec(Algo::MBPO).unwrap(), spec(Algo::MPC).unwrap());
        // Every role of a run subscribes control (the evaluator's acknowledgements wait for
        // them all); real transitions go to the learner, model trainer and rollout generator.
        assert_eq!(mbpo.subscribers(Channel::Control, 3), 3 + 4);
        assert_eq!(mpc.subscribers(Channel::Control, 3), 3 + 2);
        assert_eq!((mbpo.real_consumers(), mpc.real_consumers()), (3, 1));
    }

    #[test]
    fn an_algorithm_without_a_pipeline_is_refused_by_name() {
        let err = spec(Algo::SAC).unwrap_err().to_string();
        assert!(err.contains("mbpo or mpc or tdmpc, not sac"), "{err}");
    }
}

#[cfg(test)]
mod checkpoint_file_tests {
    use super::*;
    use mbpo_train::Algo;

    #[test]
    fn checkpoint_files_and_pausing_processes_follow_the_algorithm() {
        let names = |algo, actors| -> Vec<String> {
            pipeline_files(spec(algo).unwrap(), actors)
                .into_iter()
                .map(|(n, _)| n)
                .collect()
        };
        assert_eq!(
            names(Algo::MBPO, 2),
            [
                "learner",
                "model-trainer",
                "rollout-generator",
                "evaluator",
                "actor-0",
                "actor-1",
                "run-book",
                "supervisor"
            ]
        );
        assert_eq!(
            names(Algo::MPC, 1),
            [
                "model-trainer",
                "evaluator",
                "actor-0",
                "run-book",
                "supervisor"
            ]
        );
        // A checkpoint of `mbpo train` holds the same files but the launcher's.
        let sequential: Vec<String> = role_files(spec(Algo::MBPO).unwrap(), 1)
            .into_iter()
            .map(|(n, _)| n)
            .collect();
        assert_eq!(sequential, names(Algo::MBPO, 1)[..6]);
        let kind_of = |algo, name: &str| {
            pipeline_files(spec(algo).unwrap(), 1)
                .into_iter()
                .find(|(n, _)| n == name)
                .unwrap()
                .1
        };
        assert_eq!(kind_of(Algo::MPC, "actor-0"), kind::PLANNING_ACTOR);
        assert_eq!(kind_of(Algo::MPC, "evaluator"), kind::PLANNING_EVALUATOR);
        assert_eq!(kind_of(Algo::MBPO, "actor-0"), kind::ACTOR);
        assert_eq!(kind_of(Algo::MBPO, "evaluator"), kind::EVALUATOR);
        assert_eq!(pausing_processes(spec(Algo::MBPO).unwrap(), 3), 5);
        assert_eq!(pausing_processes(spec(Algo::MPC).unwrap(), 3), 4);
    }
}
