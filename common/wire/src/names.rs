//! Service names, roles and producer ids: the one place that says what a run's services are called.
//!
//! Every service of a run lives under `mbpo/<run-id>/`:
//!
//! | [`Channel`] | service name | pattern | payload | delivery |
//! |---|---|---|---|---|
//! | `Real` | `mbpo/<run>/real` | pub-sub + event | `[f32]` rows, [`TransitionHeader`](crate::TransitionHeader) | reliable (never dropped) |
//! | `Imagined` | `mbpo/<run>/imagined` | pub-sub + event | `[f32]` rows, [`TransitionHeader`](crate::TransitionHeader) | reliable |
//! | `Policy` | `mbpo/<run>/policy` | pub-sub + event | `[f32]` params, [`WeightsHeader`](crate::WeightsHeader) | latest value |
//! | `Model` | `mbpo/<run>/model` | pub-sub + event | `[f32]` params, [`WeightsHeader`](crate::WeightsHeader) | latest value |
//! | `Stats` | `mbpo/<run>/stats` | pub-sub + event | [`StatsRecord`](crate::StatsRecord), [`MsgHeader`](crate::MsgHeader) | reliable |
//! | `Control` | `mbpo/<run>/control` | pub-sub + event | [`ControlMsg`](crate::ControlMsg), [`MsgHeader`](crate::MsgHeader) | reliable |
//!
//! Each publisher additionally owns a small event service `<service>/attach/<publisher-id>` on
//! which subscribers confirm that they are connected (see [`crate::reliable`]).

use std::fmt;

/// Version of everything this crate puts in shared memory. Bump it whenever a header, a payload
/// type or a row layout changes; receivers reject other versions.
pub const SCHEMA_VERSION: u32 = 1;

/// Longest accepted run id (bytes). Service names must stay well under iceoryx2's limits.
pub const MAX_RUN_ID_LEN: usize = 64;

/// The services of a run.
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
    /// Reports (`crate::stats::Stats`), everyone -> coordinator.
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

/// The role of a process in the pipeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
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
    /// The role with numeric value `v`.
    pub fn from_u16(v: u16) -> Option<Role> {
        Some(match v {
            0 => Role::Supervisor,
            1 => Role::Actor,
            2 => Role::ModelTrainer,
            3 => Role::RolloutGenerator,
            4 => Role::Learner,
            5 => Role::Evaluator,
            15 => Role::Tool,
            _ => return None,
        })
    }

    /// Lower-case name used in node names and logs.
    pub fn name(self) -> &'static str {
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

/// Who produced a message: `(role, index)` packed into a `u32` as `role << 16 | index`.
///
/// Sequence numbers are tracked per producer id, so ids must be unique among the live publishers
/// of one channel (actor 0, actor 1, ...). A restarted process reuses its id; receivers notice the
/// new publisher port and start a new sequence.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub struct ProducerId(pub u32);

impl ProducerId {
    /// The producer `index` of `role`.
    pub fn new(role: Role, index: u16) -> Self {
        ProducerId(((role as u32) << 16) | index as u32)
    }
    /// The role, if the id was built by [`ProducerId::new`].
    pub fn role(self) -> Option<Role> {
        Role::from_u16((self.0 >> 16) as u16)
    }
    /// The index within the role.
    pub fn index(self) -> u16 {
        (self.0 & 0xffff) as u16
    }
}

impl fmt::Display for ProducerId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.role() {
            Some(r) => write!(f, "{}-{}", r.name(), self.index()),
            None => write!(f, "producer-{:#x}", self.0),
        }
    }
}

/// Name of the per-publisher attach event service (see [`crate::reliable`]).
pub(crate) fn attach_service_name(service: &str, publisher_id: u128) -> String {
    format!("{service}/attach/{publisher_id:032x}")
}

/// True when `run_id` is usable in service names, node names and paths.
pub(crate) fn valid_run_id(run_id: &str) -> bool {
    !run_id.is_empty()
        && run_id.len() <= MAX_RUN_ID_LEN
        && run_id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_' || b == b'.')
        && !run_id.starts_with('.')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn service_names_and_tags_are_stable() {
        assert_eq!(Channel::Real.service_name("r1"), "mbpo/r1/real");
        assert_eq!(Channel::Control.service_name("x"), "mbpo/x/control");
        for c in Channel::ALL {
            assert_eq!(Channel::from_tag(c.tag()), Some(c));
        }
    }

    #[test]
    fn producer_ids_pack_role_and_index() {
        let p = ProducerId::new(Role::Actor, 3);
        assert_eq!(p.role(), Some(Role::Actor));
        assert_eq!(p.index(), 3);
        assert_eq!(p.to_string(), "actor-3");
    }

    #[test]
    fn run_ids_are_checked() {
        assert!(valid_run_id("pendulum-seed1_2024.01"));
        assert!(!valid_run_id(""));
        assert!(!valid_run_id("a/b"));
        assert!(!valid_run_id(".hidden"));
        assert!(!valid_run_id(&"x".repeat(65)));
    }
}
