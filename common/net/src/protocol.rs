//! What the gateways of a run say to each other over Zenoh: one [`Envelope`] per Zenoh sample.
//!
//! Two kinds of traffic:
//! * the **reliable stream** ([`Body::Data`] carrying an [`Item`]), one per direction and worker
//!   session: numbered 0, 1, 2, ..., acknowledged cumulatively ([`Body::Ack`]), sent again from
//!   the oldest unacknowledged one when acknowledgements stop ([`crate::link`]). Transitions,
//!   reports, control commands and checkpoint files go here: nothing accepted is lost or doubled,
//!   also when the link drops;
//! * **latest values** ([`Body::Weights`], [`Body::Heartbeat`], [`Body::Hello`] and its answers):
//!   a newer one replaces an older one, so they are simply sent again when the peer's heartbeat
//!   shows it missed one.
//!
//! Decoding never trusts a length: [`decode`] refuses a message over [`MAX_MESSAGE_BYTES`]
//! before bincode reads it, and bincode's limit on the bytes its collections claim grows with the
//! message (at most 16 times its size, 64 KiB for small ones): bincode allocates a claimed
//! length before reading it, so a few bytes must not claim hundreds of megabytes.

use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{Mode, Slack};
use mbpo_wire::{ControlMsg, StatsRecord, TransitionMeta, WeightsCounters, WeightsKind};
use serde::{Deserialize, Serialize};

/// Version of this protocol; a peer speaking another one is refused by name.
pub const PROTOCOL_VERSION: u32 = 2;

/// Largest message accepted (a weight snapshot of a large model, or a checkpoint file).
pub const MAX_MESSAGE_BYTES: usize = 512 << 20;

/// One Zenoh sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// [`PROTOCOL_VERSION`] of the writer.
    pub version: u32,
    /// The sender's session: a random id drawn when its gateway started. A new id means the
    /// peer restarted and everything it had not acknowledged is gone.
    pub session: u64,
    /// What it says.
    pub body: Body,
}

/// The messages.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Body {
    /// Worker -> head, repeated until answered: "I can run `actors` actors and the roles
    /// named `roles`".
    Hello {
        /// The worker's name (its host name unless given), for logs and the summary.
        worker: String,
        /// Actors it offers to run.
        actors: u16,
        /// Roles besides actors it offers to run, by process name (`evaluator`).
        roles: Vec<String>,
    },
    /// Head -> worker: the slots it runs and everything needed to run them.
    Welcome(Box<Assignment>),
    /// Head -> worker: not admitted (the reason says why and what to do).
    Refused {
        /// For the worker's log and exit message.
        reason: String,
    },
    /// One message of the reliable stream.
    Data {
        /// Its number in the stream (0, 1, 2, ...).
        seq: u64,
        /// The message.
        item: Item,
    },
    /// Every message of the peer's stream before `next` arrived and was handed on.
    Ack {
        /// The next number expected.
        next: u64,
    },
    /// Liveness, sent twice a second each way; also carries what the sender has seen.
    Heartbeat {
        /// Like [`Body::Ack`]: the next number expected of the peer's stream.
        next: u64,
        /// Newest weight version received (worker), so the head sends a newer one again.
        weights: u64,
    },
    /// Head -> worker: the newest weight snapshot (latest value, not in the stream).
    Weights(Box<WeightsMsg>),
}

/// A weight snapshot: the actors' policy (MBPO) or model (MPC).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WeightsMsg {
    /// Policy or model.
    pub kind: WeightsKind,
    /// Its version.
    pub version: u64,
    /// The counters it was published with.
    pub counters: WeightsCounters,
    /// Its flat parameters.
    pub params: Vec<f32>,
    /// When its publisher (the learner) sent it, ns since the Unix epoch: the worker measures
    /// the weights' latency from it (meaningful when the hosts' clocks agree).
    pub sent_ns: u64,
}

/// What a worker runs: its slots of the run's roles, with the run's config and arguments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Assignment {
    /// The head's run id (names only; each host has its own iceoryx2 run).
    pub run_id: String,
    /// The head's attempt of the pipeline (a restart from a checkpoint is a new attempt).
    pub attempt: u64,
    /// The role processes (slots) this worker runs.
    pub slots: Vec<Slot>,
    /// The run's `config.toml`, verbatim.
    pub config_toml: String,
    /// The run's `env.json` (a Python env's widths), if it has one.
    pub env_json: Option<String>,
    /// The run's `run-plan.json`: the sizes of what crosses shared memory, resolved once by
    /// the head's launcher (the worker makes no env or model to learn them).
    pub run_plan: String,
    /// Hand-off mode.
    pub mode: Mode,
    /// Actors in the run, local and remote.
    pub actors: u16,
    /// The pipelined mode's slack.
    pub slack: Slack,
    /// The checkpoint the slots continue from, if the attempt resumes one.
    pub resume: Option<ResumeFiles>,
}

/// A checkpoint's files for the slots of one worker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResumeFiles {
    /// The checkpoint's step T.
    pub env_steps: u64,
    /// `(slot, file bytes)`.
    pub files: Vec<(Slot, Vec<u8>)>,
}

/// A message of the reliable stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Item {
    /// Worker -> head: one batch of real transitions of actor `slot`.
    Transitions {
        /// The actor.
        slot: Slot,
        /// The actor's own sequence number of the batch (checked end to end by the head).
        actor_seq: u64,
        /// Versions and counters of the batch.
        meta: TransitionMeta,
        /// The rows, `[obs, act, reward, next_obs, terminated]` each.
        rows: Vec<f32>,
    },
    /// Worker -> head: a report of `slot` for the coordinator.
    Stats {
        /// The role.
        slot: Slot,
        /// The report.
        record: StatsRecord,
    },
    /// Worker -> head, before the report that it was written: `slot`'s file of checkpoint
    /// `env_steps`, to be written into the head's run directory.
    CheckpointFile {
        /// The role.
        slot: Slot,
        /// The checkpoint's step T.
        env_steps: u64,
        /// The file, as the actor wrote it (kind, version and SHA-256 inside).
        bytes: Vec<u8>,
    },
    /// Worker -> head: `slot`'s process ended without being told to.
    SlotFailed {
        /// The role.
        slot: Slot,
        /// Exit status and the tail of its log.
        reason: String,
    },
    /// Worker -> head: lines of a role's log, to be appended to the head's
    /// `logs/<worker>/<slot>.log`.
    Log {
        /// The role.
        slot: Slot,
        /// The text.
        text: String,
    },
    /// Worker -> head: a control message `slot` published (the evaluator's acknowledgement
    /// of an eval point in lockstep), to be published on the head as `slot`'s.
    ControlFrom {
        /// The role.
        slot: Slot,
        /// The message.
        msg: ControlMsg,
    },
    /// Worker -> head, its last message: every role of the worker has exited after the head's
    /// [`Item::Finished`], and its logs are sent.
    Bye,
    /// Head -> worker: a control command for `slot`.
    Control {
        /// The role.
        slot: Slot,
        /// The command.
        msg: ControlMsg,
    },
    /// Head -> worker: the run is over; stop and exit.
    Finished,
}

/// Why bytes are not an [`Envelope`].
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// Longer than [`MAX_MESSAGE_BYTES`].
    #[error("a message of {0} bytes is over the limit of {MAX_MESSAGE_BYTES}")]
    TooLarge(usize),
    /// Not bincode of an envelope.
    #[error("not a message of the mbpo gateway protocol: {0}")]
    Malformed(String),
    /// Bytes left after the envelope.
    #[error("{0} bytes after the end of the message")]
    Trailing(usize),
    /// Another protocol version.
    #[error("the peer speaks protocol version {found}, this build {PROTOCOL_VERSION}: run the same mbpo version on every host")]
    Version {
        /// The peer's.
        found: u32,
    },
}

fn config() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<MAX_MESSAGE_BYTES>()
}

/// `bytes` decoded with at most `LIMIT` bytes claimed by collections.
fn decode_claiming<const LIMIT: usize>(
    bytes: &[u8],
) -> Result<(Envelope, usize), bincode::error::DecodeError> {
    bincode::serde::decode_from_slice(bytes, bincode::config::standard().with_limit::<LIMIT>())
}

/// The bytes of `envelope`.
pub fn encode(envelope: &Envelope) -> Vec<u8> {
    // Every field is plain data: encoding cannot fail.
    bincode::serde::encode_to_vec(envelope, config()).expect("an envelope always encodes")
}

/// The envelope in `bytes`, or why not.
pub fn decode(bytes: &[u8]) -> Result<Envelope, DecodeError> {
    if bytes.len() > MAX_MESSAGE_BYTES {
        return Err(DecodeError::TooLarge(bytes.len()));
    }
    // A claim counts the decoded size (a u64 of one encoded byte claims 8): 16 times the
    // message's size class leaves room for any real message.
    let decoded = match bytes.len() {
        n if n <= 4 << 10 => decode_claiming::<{ 64 << 10 }>(bytes),
        n if n <= 64 << 10 => decode_claiming::<{ 1 << 20 }>(bytes),
        n if n <= 1 << 20 => decode_claiming::<{ 16 << 20 }>(bytes),
        _ => decode_claiming::<MAX_MESSAGE_BYTES>(bytes),
    };
    let (envelope, used) = decoded.map_err(|e| DecodeError::Malformed(e.to_string()))?;
    if used != bytes.len() {
        return Err(DecodeError::Trailing(bytes.len() - used));
    }
    if envelope.version != PROTOCOL_VERSION {
        return Err(DecodeError::Version {
            found: envelope.version,
        });
    }
    Ok(envelope)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Envelope {
        Envelope {
            version: PROTOCOL_VERSION,
            session: 7,
            body: Body::Data {
                seq: 3,
                item: Item::Transitions {
                    slot: Slot::new(mbpo_runtime::RoleKind::Actor, 1),
                    actor_seq: 9,
                    meta: TransitionMeta {
                        policy_version: 4,
                        model_version: 0,
                        env_steps: 12,
                    },
                    rows: vec![1.0, -2.0, 3.5],
                },
            },
        }
    }

    #[test]
    fn envelopes_round_trip() {
        let e = sample();
        assert_eq!(decode(&encode(&e)).unwrap(), e);
    }

    #[test]
    fn other_versions_truncations_and_trailing_bytes_are_refused() {
        let mut e = sample();
        e.version = 99;
        assert!(matches!(
            decode(&encode(&e)),
            Err(DecodeError::Version { found: 99 })
        ));
        let bytes = encode(&sample());
        for cut in 0..bytes.len() {
            assert!(decode(&bytes[..cut]).is_err(), "a prefix of {cut} bytes");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(matches!(decode(&longer), Err(DecodeError::Trailing(1))));
    }

    #[test]
    fn a_small_message_cannot_claim_a_large_allocation() {
        let log = |len: usize| Envelope {
            version: PROTOCOL_VERSION,
            session: 1,
            body: Body::Data {
                seq: 0,
                item: Item::Log {
                    slot: Slot::new(mbpo_runtime::RoleKind::Evaluator, 0),
                    text: "x".repeat(len),
                },
            },
        };
        // A whole 200 KiB log decodes; its first 2 KiB claim 200 KiB (bincode allocates a
        // string's claimed length before reading it), over a small message's 64 KiB, and are
        // refused before the 200 KiB are allocated.
        let bytes = encode(&log(200 << 10));
        assert_eq!(decode(&bytes).unwrap(), log(200 << 10));
        match decode(&bytes[..2 << 10]) {
            Err(DecodeError::Malformed(why)) => assert!(why.contains("Limit"), "{why}"),
            other => panic!("{other:?}"),
        }
        // Real messages of every size class decode.
        for rows in [10, 1000, 100_000, 1_000_000] {
            let mut e = sample();
            if let Body::Data {
                item: Item::Transitions { rows: r, .. },
                ..
            } = &mut e.body
            {
                *r = vec![0.5; rows];
            }
            assert_eq!(decode(&encode(&e)).unwrap(), e);
        }
    }

    #[test]
    fn a_huge_length_is_refused_without_allocating_it() {
        // Data, seq 0, Transitions, slot 0, actor_seq 0, meta, then a row count of 2^60.
        let mut bytes = encode(&sample());
        let n = bytes.len();
        // The rows' length prefix is the 13th byte from the end (3 f32 + its own byte).
        bytes.truncate(n - 13);
        bytes.push(253); // bincode varint: u64 follows
        bytes.extend_from_slice(&(1u64 << 60).to_le_bytes());
        assert!(matches!(decode(&bytes), Err(DecodeError::Malformed(_))));
    }
}
