//! Control messages (`ControlMsg`, supervisor <-> everyone, and head -> worker in the network
//! stream) as a receiver interprets them: `ControlMsg::control_command`, `is_for` and the
//! acknowledgement built from a request.
//!
//! Checks: a command decodes exactly when its number is one of the five known ones and maps
//! back to that number; `is_for` is "broadcast or this producer"; an ack names the request.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{bytes_of, pod, write_seeds_if_asked};
use mbpo_wire::{ControlCommand, ControlMsg, ProducerId, Role, CONTROL_TARGET_ALL};

fn seeds() -> Vec<Vec<u8>> {
    let sup = ProducerId::new(Role::Supervisor, 0);
    let actor = ProducerId::new(Role::Actor, 3);
    let req = ControlMsg::request(ControlCommand::Checkpoint, 7, CONTROL_TARGET_ALL, 500);
    [
        ControlMsg::request(ControlCommand::Stop, 1, actor.0, 0),
        req,
        ControlMsg::request(ControlCommand::Pause, u64::MAX, CONTROL_TARGET_ALL, 0),
        ControlMsg::request(ControlCommand::Resume, 8, CONTROL_TARGET_ALL, 0),
        ControlMsg::ack(&req, 500, 0, sup),
    ]
    .iter()
    .map(bytes_of)
    .collect()
}

fuzz_target!(
    init: write_seeds_if_asked("control_msg", seeds),
    |data: &[u8]| {
        let (m, rest) = pod::<ControlMsg>(data);
        match m.control_command() {
            Some(c) => {
                assert!((1..=5).contains(&m.command));
                assert_eq!(c as u32, m.command);
            }
            None => assert!(!(1..=5).contains(&m.command), "command {} refused", m.command),
        }
        let who = ProducerId(rest.first().map_or(0, |&b| u32::from(b) * 0x0101_0101));
        assert_eq!(m.is_for(who), m.target == CONTROL_TARGET_ALL || m.target == who.0);
        let ack = ControlMsg::ack(&m, 1, 0, ProducerId::new(Role::Supervisor, 0));
        assert_eq!(ack.control_command(), Some(ControlCommand::Ack));
        assert_eq!((ack.request_id, ack.acked_command), (m.request_id, m.command));
    }
);
