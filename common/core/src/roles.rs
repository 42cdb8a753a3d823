//! The one table of roles: who each role is on the wire, what its process, log and checkpoint
//! file are called, which binary runs it, which channels it publishes and subscribes, and
//! whether it pauses at a checkpoint barrier.
//!
//! It sits low in the crate order so that every crate asks it: `mbpo-wire` names nodes and
//! producers after [`Role`], `mbpo-train` names checkpoint files and their kinds after
//! [`RoleKind::file_name`] and [`RoleKind::checkpoint_kind`], the runtime's pipelines list
//! [`RoleKind`]s and count subscribers with [`RoleKind::subscribes`], the launcher starts
//! [`RoleKind::binary`] with [`RoleKind::binary_flags`]. A role's name is spelled once, in
//! [`Role::name`]; a new role is one [`RoleKind`] variant and one [`ROLES`] row.

use std::fmt;

/// Who a process is on the wire: its node name and the producer id of what it sends. The
/// numeric values are part of the wire format (`ProducerId`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[repr(u16)]
pub enum Role {
    /// The `mbpo` supervisor.
    Supervisor = 0,
    /// An environment actor (one per core).
    Actor = 1,
    /// The dynamics-model trainer.
    ModelTrainer = 2,
    /// The model-rollout generator.
    RolloutGenerator = 3,
    /// The SAC learner.
    Learner = 4,
    /// A separate evaluation actor.
    Evaluator = 5,
    /// Benchmarks and tests.
    Tool = 15,
}

impl Role {
    /// Every role.
    pub const ALL: [Role; 7] = [
        Role::Supervisor,
        Role::Actor,
        Role::ModelTrainer,
        Role::RolloutGenerator,
        Role::Learner,
        Role::Evaluator,
        Role::Tool,
    ];

    /// The role with numeric value `v`.
    pub fn from_u16(v: u16) -> Option<Role> {
        Role::ALL.into_iter().find(|r| *r as u16 == v)
    }

    /// Lower-case name used in node names, logs, process and checkpoint file names.
    pub const fn name(self) -> &'static str {
        match self {
            Role::Supervisor => "supervisor",
            Role::Actor => "actor",
            Role::ModelTrainer => "model-trainer",
            Role::RolloutGenerator => "rollout-generator",
            Role::Learner => "learner",
            Role::Evaluator => "evaluator",
            Role::Tool => "tool",
        }
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A channel a role publishes or subscribes (service names and QoS are `mbpo-wire`'s).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum Channel {
    /// Real environment transitions, actors -> model trainer, rollout generator, learner.
    Real,
    /// Imagined (model rollout) transitions, rollout generator -> learner.
    Imagined,
    /// Policy weights, learner -> actors, evaluator, rollout generator, coordinator (final policy).
    Policy,
    /// Dynamics-model weights (ensemble, normaliser, elites), model trainer -> rollout generator;
    /// MPC: -> planning actors, planning evaluator, coordinator (final model).
    Model,
    /// Reports (`Stats`), everyone -> coordinator.
    Stats,
    /// Stop / checkpoint commands and their acknowledgements, supervisor <-> everyone.
    Control,
}

impl Channel {
    /// Every channel, in table order.
    pub const ALL: [Channel; 6] = [
        Channel::Real,
        Channel::Imagined,
        Channel::Policy,
        Channel::Model,
        Channel::Stats,
        Channel::Control,
    ];

    /// The last component of the service name.
    pub fn suffix(self) -> &'static str {
        match self {
            Channel::Real => "real",
            Channel::Imagined => "imagined",
            Channel::Policy => "policy",
            Channel::Model => "model",
            Channel::Stats => "stats",
            Channel::Control => "control",
        }
    }

    /// The service name of this channel in run `run_id`: `mbpo/<run_id>/<suffix>`.
    pub fn service_name(self, run_id: &str) -> String {
        format!("mbpo/{run_id}/{}", self.suffix())
    }

    /// Stable numeric tag stored in headers (`TransitionHeader::stream`, ...).
    pub fn tag(self) -> u32 {
        match self {
            Channel::Real => 1,
            Channel::Imagined => 2,
            Channel::Policy => 3,
            Channel::Model => 4,
            Channel::Stats => 5,
            Channel::Control => 6,
        }
    }

    /// The channel with [`Channel::tag`] `tag`.
    pub fn from_tag(tag: u32) -> Option<Channel> {
        Channel::ALL.into_iter().find(|c| c.tag() == tag)
    }
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.suffix())
    }
}

/// What a role does: a process of `mbpo run`, a thread of the in-process pipeline, a set of
/// calls of `mbpo train`. (Serialized in kebab case in run plans and the gateways' protocol.)
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum RoleKind {
    /// The SAC learner.
    Learner,
    /// The dynamics-model trainer.
    ModelTrainer,
    /// The synthetic-rollout generator.
    RolloutGenerator,
    /// The evaluation actor (deterministic policy).
    Evaluator,
    /// An environment actor acting with the learner's policy.
    Actor,
    /// The evaluation actor of a planning run (plans on the model trainer's ensemble).
    PlanningEvaluator,
    /// An environment actor that plans on the model trainer's ensemble.
    PlanningActor,
    /// TD-MPC2's learner: trains the latent world model on real episodes, publishes it.
    WorldModelLearner,
    /// The evaluation actor of a TD-MPC2 run (plans in the learner's latent space).
    LatentEvaluator,
    /// An environment actor that plans in the world-model learner's latent space.
    LatentActor,
}

/// One row of [`ROLES`].
#[derive(Debug)]
pub struct RoleRow {
    /// The role of the row (rows are in [`RoleKind`] order).
    pub kind: RoleKind,
    /// Who it is on the wire; its process and checkpoint file are named after it.
    pub wire: Role,
    /// One per run (`learner`) or numbered (`actor-0`, `actor-1`, ...).
    pub numbered: bool,
    /// The binary that runs it, as installed next to `mbpo`.
    pub binary: &'static str,
    /// Its flags besides the service arguments every role takes (and `--index` if numbered).
    pub binary_flags: &'static [&'static str],
    /// The kind its checkpoint file carries (part of the checkpoint format).
    pub checkpoint_kind: &'static str,
    /// The channels it subscribes.
    pub subscribes: &'static [Channel],
    /// The channels it publishes.
    pub publishes: &'static [Channel],
    /// It pauses at a checkpoint barrier and reports a counter; the others follow the cut.
    pub pauses: bool,
}

use Channel::{Control, Imagined, Model, Policy, Real, Stats};

/// Every role, in [`RoleKind`] order.
pub const ROLES: [RoleRow; 10] = [
    RoleRow {
        kind: RoleKind::Learner,
        wire: Role::Learner,
        numbered: false,
        binary: "mbpo-sac-learner",
        binary_flags: &[],
        checkpoint_kind: "mbpo.role.learner",
        subscribes: &[Real, Imagined, Control],
        publishes: &[Policy, Stats],
        pauses: false,
    },
    RoleRow {
        kind: RoleKind::ModelTrainer,
        wire: Role::ModelTrainer,
        numbered: false,
        binary: "mbpo-model-trainer",
        binary_flags: &[],
        checkpoint_kind: "mbpo.role.model-trainer",
        subscribes: &[Real, Control],
        publishes: &[Model, Stats],
        pauses: true,
    },
    RoleRow {
        kind: RoleKind::RolloutGenerator,
        wire: Role::RolloutGenerator,
        numbered: false,
        binary: "mbpo-rollout-generator",
        binary_flags: &[],
        checkpoint_kind: "mbpo.role.rollout-generator",
        subscribes: &[Real, Model, Policy, Control],
        publishes: &[Imagined, Stats],
        pauses: true,
    },
    RoleRow {
        kind: RoleKind::Evaluator,
        wire: Role::Evaluator,
        numbered: false,
        binary: "mbpo-actor",
        binary_flags: &["--eval"],
        checkpoint_kind: "mbpo.role.evaluator",
        subscribes: &[Policy, Control],
        publishes: &[Stats, Control],
        pauses: false,
    },
    RoleRow {
        kind: RoleKind::Actor,
        wire: Role::Actor,
        numbered: true,
        binary: "mbpo-actor",
        binary_flags: &[],
        checkpoint_kind: "mbpo.role.actor",
        subscribes: &[Policy, Control],
        publishes: &[Real, Stats],
        pauses: true,
    },
    RoleRow {
        kind: RoleKind::PlanningEvaluator,
        wire: Role::Evaluator,
        numbered: false,
        binary: "mbpo-actor",
        binary_flags: &["--eval", "--plan"],
        checkpoint_kind: "mbpo.role.planning-evaluator",
        subscribes: &[Model, Control],
        publishes: &[Stats, Control],
        pauses: false,
    },
    RoleRow {
        kind: RoleKind::PlanningActor,
        wire: Role::Actor,
        numbered: true,
        binary: "mbpo-actor",
        binary_flags: &["--plan"],
        checkpoint_kind: "mbpo.role.planning-actor",
        subscribes: &[Model, Control],
        publishes: &[Real, Stats],
        pauses: true,
    },
    // TD-MPC2: the world model's parameters travel on the policy channel.
    RoleRow {
        kind: RoleKind::WorldModelLearner,
        wire: Role::Learner,
        numbered: false,
        binary: "mbpo-sac-learner",
        binary_flags: &["--world-model"],
        checkpoint_kind: "mbpo.role.world-model-learner",
        subscribes: &[Real, Control],
        publishes: &[Policy, Stats],
        pauses: false,
    },
    RoleRow {
        kind: RoleKind::LatentEvaluator,
        wire: Role::Evaluator,
        numbered: false,
        binary: "mbpo-actor",
        binary_flags: &["--eval", "--latent"],
        checkpoint_kind: "mbpo.role.latent-evaluator",
        subscribes: &[Policy, Control],
        publishes: &[Stats, Control],
        pauses: false,
    },
    RoleRow {
        kind: RoleKind::LatentActor,
        wire: Role::Actor,
        numbered: true,
        binary: "mbpo-actor",
        binary_flags: &["--latent"],
        checkpoint_kind: "mbpo.role.latent-actor",
        subscribes: &[Policy, Control],
        publishes: &[Real, Stats],
        pauses: true,
    },
];

/// The roles an algorithm runs as under `mbpo run`: its column of the algorithm table
/// (`mbpo_train::algorithm::AlgorithmSpec::pipeline`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PipelineRoles {
    /// Its roles besides the training actors, in start order (the actors start last).
    pub services: &'static [RoleKind],
    /// What its training actors are.
    pub actor: RoleKind,
}

impl RoleKind {
    /// Every role kind.
    pub const ALL: [RoleKind; 10] = [
        RoleKind::Learner,
        RoleKind::ModelTrainer,
        RoleKind::RolloutGenerator,
        RoleKind::Evaluator,
        RoleKind::Actor,
        RoleKind::PlanningEvaluator,
        RoleKind::PlanningActor,
        RoleKind::WorldModelLearner,
        RoleKind::LatentEvaluator,
        RoleKind::LatentActor,
    ];

    /// Its row of [`ROLES`].
    pub const fn row(self) -> &'static RoleRow {
        &ROLES[self as usize]
    }
    /// Who it is on the wire (its node and reports).
    pub const fn wire_role(self) -> Role {
        self.row().wire
    }
    /// The name of its checkpoint file, log and thread when it is not numbered (numbered:
    /// [`RoleKind::name`]).
    pub const fn file_name(self) -> &'static str {
        self.wire_role().name()
    }
    /// Its name (log file, thread, checkpoint file) as the `index`-th of its kind.
    pub fn name(self, index: u16) -> String {
        match self.row().numbered {
            true => format!("{}-{index}", self.file_name()),
            false => self.file_name().into(),
        }
    }
    /// The binary that runs it, as installed next to `mbpo`.
    pub const fn binary(self) -> &'static str {
        self.row().binary
    }
    /// Its flags besides the arguments every role takes.
    pub const fn binary_flags(self) -> &'static [&'static str] {
        self.row().binary_flags
    }
    /// The role `binary` runs with `flags` (the flags of [`RoleKind::binary_flags`] it was
    /// given; others are ignored).
    pub fn of_binary(binary: &str, flags: &[&str]) -> Option<RoleKind> {
        RoleKind::ALL.into_iter().find(|k| {
            let row = k.row();
            let same_flags = ROLES
                .iter()
                .filter(|r| r.binary == binary)
                .flat_map(|r| r.binary_flags.iter())
                .all(|f| row.binary_flags.contains(f) == flags.contains(f));
            row.binary == binary && same_flags
        })
    }
    /// The kind of its checkpoint file.
    pub const fn checkpoint_kind(self) -> &'static str {
        self.row().checkpoint_kind
    }
    /// Whether it subscribes `channel`.
    pub fn subscribes(self, channel: Channel) -> bool {
        self.row().subscribes.contains(&channel)
    }
    /// Whether it publishes `channel`.
    pub fn publishes(self, channel: Channel) -> bool {
        self.row().publishes.contains(&channel)
    }
    /// It receives every real transition.
    pub fn consumes_real(self) -> bool {
        self.subscribes(Channel::Real)
    }
    /// An environment actor (numbered, publishes real transitions).
    pub fn is_actor(self) -> bool {
        self.row().numbered && self.publishes(Channel::Real)
    }
    /// Steps an environment: the actors, and the evaluators (which act but publish nothing
    /// real).
    pub fn steps_an_env(self) -> bool {
        matches!(self.wire_role(), Role::Actor | Role::Evaluator)
    }
    /// Pauses at a checkpoint barrier and reports a counter.
    pub const fn pauses(self) -> bool {
        self.row().pauses
    }
}

/// One role process of a run: the `index`-th of its kind (0 for a role that is not
/// numbered). A gateway stands in for such slots on the head and runs them on a worker.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Slot {
    /// What it does.
    pub kind: RoleKind,
    /// Its index within its kind.
    pub index: u16,
}

impl Slot {
    /// The `index`-th role of `kind`.
    pub const fn new(kind: RoleKind, index: u16) -> Self {
        Self { kind, index }
    }
    /// Its name: process, log and checkpoint file (`actor-3`, `evaluator`).
    pub fn name(self) -> String {
        self.kind.name(self.index)
    }
    /// Whether reports and control messages of producer (`role`, `index`) are its.
    pub fn is(self, role: Role, index: u16) -> bool {
        self.kind.wire_role() == role && self.index == index
    }
}

impl fmt::Display for Slot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_in_kind_order_and_numbered_roles_are_the_actors() {
        for (i, row) in ROLES.iter().enumerate() {
            assert_eq!(row.kind as usize, i, "{row:?}");
            assert_eq!(row.kind.row().kind, row.kind);
        }
        let numbered: Vec<RoleKind> = RoleKind::ALL.into_iter().filter(|k| k.is_actor()).collect();
        assert_eq!(
            numbered,
            [
                RoleKind::Actor,
                RoleKind::PlanningActor,
                RoleKind::LatentActor
            ]
        );
        assert_eq!(RoleKind::Actor.name(3), "actor-3");
        assert_eq!(RoleKind::PlanningEvaluator.name(0), "evaluator");
        assert_eq!(RoleKind::RolloutGenerator.name(0), "rollout-generator");
    }

    #[test]
    fn every_binary_and_flag_set_names_one_role() {
        for kind in RoleKind::ALL {
            let found = RoleKind::of_binary(kind.binary(), kind.binary_flags());
            assert_eq!(found, Some(kind));
        }
        assert_eq!(
            RoleKind::of_binary("mbpo-actor", &["--plan", "--eval"]),
            Some(RoleKind::PlanningEvaluator)
        );
        assert_eq!(RoleKind::of_binary("mbpo", &[]), None);
    }

    #[test]
    fn every_published_channel_has_a_subscriber_and_roles_round_trip() {
        for row in &ROLES {
            for ch in row.publishes.iter().filter(|c| **c != Channel::Stats) {
                assert!(
                    ROLES.iter().any(|r| r.subscribes.contains(ch)),
                    "{ch:?} of {:?}",
                    row.kind
                );
            }
        }
        for r in Role::ALL {
            assert_eq!(Role::from_u16(r as u16), Some(r));
        }
        assert_eq!(Role::from_u16(9), None);
    }
}
