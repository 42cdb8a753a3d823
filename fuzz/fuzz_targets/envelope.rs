//! `mbpo_net::protocol::decode`: one Zenoh sample between the gateways of two hosts (bincode of
//! an `Envelope`, at most `MAX_MESSAGE_BYTES`).
//!
//! Checks: a decoded envelope is of this protocol version, and its encoding decodes to an
//! envelope with the same encoding (what a gateway sends on is what it received); a refusal is
//! one of the typed `DecodeError`s.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::write_seeds_if_asked;
use mbpo_net::protocol::{
    decode, encode, Assignment, Body, DecodeError, Envelope, Item, ResumeFiles, WeightsMsg,
    PROTOCOL_VERSION,
};
use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{Mode, RoleKind, Slack};
use mbpo_wire::{
    ControlCommand, ControlMsg, Stats, StatsRecord, TransitionMeta, WeightsCounters, WeightsKind,
};

fn seeds() -> Vec<Vec<u8>> {
    let env = |body| Envelope {
        version: PROTOCOL_VERSION,
        session: 0x1234_5678_9abc,
        body,
    };
    let data = |seq, item| env(Body::Data { seq, item });
    let record: StatsRecord = Stats::from(mbpo_wire::EpisodeEnd {
        env_steps: 200,
        episode_return: -900.0,
        version: 199,
    })
    .record();
    let actor = |i| Slot::new(RoleKind::Actor, i);
    let evaluator = Slot::new(RoleKind::Evaluator, 0);
    let envelopes = vec![
        env(Body::Hello {
            worker: "worker-1".into(),
            actors: 2,
            roles: vec!["evaluator".into()],
        }),
        env(Body::Welcome(Box::new(Assignment {
            run_id: "pendulum-s1".into(),
            attempt: 1,
            slots: vec![actor(1), actor(2), evaluator],
            config_toml: "algo = \"mbpo\"\nenv = \"Pendulum-v1\"\n".into(),
            env_json: Some("{\"obs_dim\": 3, \"act_dim\": 1}".into()),
            run_plan: "{\"format\": 1}".into(),
            mode: Mode::Pipelined,
            actors: 3,
            slack: Slack {
                policy_lag: 2,
                update_buffer: 40,
                model_lag: 25,
            },
            resume: Some(ResumeFiles {
                env_steps: 500,
                files: vec![
                    (actor(1), b"MBPOCKPT".to_vec()),
                    (evaluator, b"MBPOCKPT".to_vec()),
                ],
            }),
        }))),
        env(Body::Refused {
            reason: "no free actor slot".into(),
        }),
        env(Body::Ack { next: 17 }),
        env(Body::Heartbeat {
            next: 17,
            weights: 4,
        }),
        env(Body::Weights(Box::new(WeightsMsg {
            kind: WeightsKind::Policy,
            version: 4,
            counters: WeightsCounters {
                env_steps: 300,
                sac_updates: 2400,
                model_trainings: 1,
            },
            params: vec![0.5, -0.25, 1e-3, 7.0],
            sent_ns: 1_700_000_000_000_000_000,
        }))),
        data(
            0,
            Item::Transitions {
                slot: actor(1),
                actor_seq: 0,
                meta: TransitionMeta {
                    policy_version: 0,
                    model_version: 0,
                    env_steps: 1,
                },
                rows: (0..9).map(|i| i as f32).collect(),
            },
        ),
        data(
            1,
            Item::Stats {
                slot: actor(1),
                record,
            },
        ),
        data(
            2,
            Item::CheckpointFile {
                slot: evaluator,
                env_steps: 500,
                bytes: b"MBPOCKPT\x04\0\0\0".to_vec(),
            },
        ),
        data(
            3,
            Item::SlotFailed {
                slot: actor(2),
                reason: "exit status 1".into(),
            },
        ),
        data(
            4,
            Item::Log {
                slot: evaluator,
                text: "step 10\n".into(),
            },
        ),
        data(5, Item::Bye),
        data(
            6,
            Item::Control {
                slot: actor(1),
                msg: ControlMsg::request(ControlCommand::Checkpoint, 2, 0x0001_0001, 500),
            },
        ),
        data(
            8,
            Item::ControlFrom {
                slot: evaluator,
                msg: ControlMsg::request(ControlCommand::Ack, 400, 0x0004_0000, 400),
            },
        ),
        data(7, Item::Finished),
    ];
    envelopes.iter().map(encode).collect()
}

fuzz_target!(
    init: write_seeds_if_asked("envelope", seeds),
    |data: &[u8]| {
        match decode(data) {
            Ok(e) => {
                assert_eq!(e.version, PROTOCOL_VERSION);
                let bytes = encode(&e);
                let again = decode(&bytes).expect("an encoded envelope decodes");
                assert_eq!(encode(&again), bytes, "an envelope changes through encode/decode");
            }
            Err(DecodeError::TooLarge(n)) => assert_eq!(n, data.len()),
            Err(DecodeError::Trailing(n)) => assert!(n > 0 && n <= data.len()),
            Err(DecodeError::Version { found }) => assert_ne!(found, PROTOCOL_VERSION),
            Err(DecodeError::Malformed(_)) => {}
        }
    }
);
