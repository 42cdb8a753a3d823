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

// The channels and roles are the role table's (`mbpo_core::roles`), which every crate asks;
// what they are called in shared memory is this crate's.
pub use mbpo_core::roles::{Channel, Role};

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
