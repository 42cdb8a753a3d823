//! Which roles a pipeline run has: the one list the launcher spawns, the in-process pipeline
//! starts as threads, the coordinator counts and the checkpoint barrier names files after.
//! MBPO runs a learner, a model trainer, a rollout generator, an evaluator and the actors; MPC
//! plans on the model trainer's ensemble, so it has no learner or rollout generator.

use mbpo_train::Algo;
use mbpo_wire::Transport;

use crate::barrier::{actor_file, file, kind};
use crate::services::{actor, learner, model_trainer, rollout};
use crate::{Result, ServiceArgs};

/// What a role does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RoleKind {
    /// The SAC learner.
    Learner,
    /// The dynamics-model trainer.
    ModelTrainer,
    /// The synthetic-rollout generator.
    RolloutGenerator,
    /// The evaluation actor.
    Evaluator,
    /// An environment actor.
    Actor,
}

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
    /// The binary that runs it, as installed next to `mbpo`.
    pub fn binary(&self) -> &'static str {
        match self.kind {
            RoleKind::Learner => "mbpo-sac-learner",
            RoleKind::ModelTrainer => "mbpo-model-trainer",
            RoleKind::RolloutGenerator => "mbpo-rollout-generator",
            RoleKind::Evaluator | RoleKind::Actor => "mbpo-actor",
        }
    }
    /// Its arguments besides the [`ServiceArgs`] every role takes.
    pub fn binary_args(&self) -> Vec<String> {
        match self.kind {
            RoleKind::Evaluator => vec!["--eval".into()],
            RoleKind::Actor => vec!["--index".into(), self.index.to_string()],
            _ => Vec::new(),
        }
    }
    /// Its service loop on transport `S`.
    pub fn service_loop<S: Transport>(&self) -> fn(&ServiceArgs) -> Result<()> {
        match self.kind {
            RoleKind::Learner => learner::run::<S>,
            RoleKind::ModelTrainer => model_trainer::run::<S>,
            RoleKind::RolloutGenerator => rollout::run::<S>,
            RoleKind::Evaluator => actor::evaluate::<S>,
            RoleKind::Actor => actor::act::<S>,
        }
    }
    /// Steps an environment (actors and the evaluator).
    pub fn steps_an_env(&self) -> bool {
        matches!(self.kind, RoleKind::Actor | RoleKind::Evaluator)
    }
    /// Pauses at a checkpoint barrier and reports a counter (actors, model trainer, rollout
    /// generator); the learner and evaluator only follow the cut.
    pub fn pauses(&self) -> bool {
        matches!(
            self.kind,
            RoleKind::Actor | RoleKind::ModelTrainer | RoleKind::RolloutGenerator
        )
    }
}

/// Whether the pipeline runs `algo`: MBPO and MPC have role lists; SAC and algorithms
/// registered at run time (`mbpo_train::algorithm::register`) run under `mbpo train` only.
pub fn runs(algo: Algo) -> bool {
    algo == Algo::MBPO || algo == Algo::MPC
}

/// The roles of a run of `algo` (one [`runs`] runs) with `actors` actors, in start order.
pub fn roles(algo: Algo, actors: u16) -> Vec<RoleSpec> {
    let mpc = algo == Algo::MPC;
    let one = |kind, name: &str, checkpoint_kind| RoleSpec {
        kind,
        index: 0,
        name: name.into(),
        checkpoint_kind,
    };
    let mut roles = Vec::new();
    if !mpc {
        roles.push(one(RoleKind::Learner, file::LEARNER, kind::LEARNER));
    }
    roles.push(one(
        RoleKind::ModelTrainer,
        file::MODEL_TRAINER,
        kind::MODEL_TRAINER,
    ));
    if !mpc {
        roles.push(one(
            RoleKind::RolloutGenerator,
            file::ROLLOUT,
            kind::ROLLOUT,
        ));
    }
    let (evaluator, actor) = match mpc {
        true => (kind::PLANNING_EVALUATOR, kind::PLANNING_ACTOR),
        false => (kind::EVALUATOR, kind::ACTOR),
    };
    roles.push(one(RoleKind::Evaluator, file::EVALUATOR, evaluator));
    roles.extend((0..actors).map(|index| RoleSpec {
        kind: RoleKind::Actor,
        index,
        name: actor_file(index),
        checkpoint_kind: actor,
    }));
    roles
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mbpo_has_five_kinds_of_role_and_mpc_three() {
        let names = |algo, actors| -> Vec<String> {
            roles(algo, actors).into_iter().map(|r| r.name).collect()
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
        let actor = &roles(Algo::MBPO, 3)[6];
        assert_eq!(
            (actor.binary(), actor.binary_args()),
            ("mbpo-actor", vec!["--index".to_string(), "2".to_string()])
        );
        assert_eq!(
            roles(Algo::MBPO, 3).iter().filter(|r| r.pauses()).count(),
            5
        );
        assert_eq!(roles(Algo::MPC, 3).iter().filter(|r| r.pauses()).count(), 4);
    }
}
