//! A run's `run-plan.json` (the sizes of everything that crosses shared memory, resolved once
//! by the launcher and sent to every remote worker in the head's `Welcome`), read by
//! `mbpo_runtime::ResolvedRun::parse`, which every process trusts afterwards.
//!
//! Input: the file's bytes.
//!
//! Checks: an accepted plan has widths in range and no more local actors than actors, and
//! writes back to a plan equal to itself; a refusal is a message, not a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::write_seeds_if_asked;
use mbpo_runtime::ResolvedRun;

fn seeds() -> Vec<Vec<u8>> {
    let plan = r#"{"format": 1, "dims": {"obs": 3, "act": 1, "policy_hash": 9, "policy_len": 50,
        "model": {"layout_hash": 7, "n_params": 100, "in_dim": 4, "elites": 3, "termination": 0}},
        "mode": "pipelined", "actors": 3, "local_actors": 1,
        "slack": {"policy_lag": 2, "update_buffer": 40, "model_lag": 25}}"#;
    vec![plan.as_bytes().to_vec(), b"{}".to_vec()]
}

fuzz_target!(
    init: write_seeds_if_asked("run_plan", seeds),
    |data: &[u8]| {
        let Ok(text) = std::str::from_utf8(data) else {
            return;
        };
        if let Ok(plan) = ResolvedRun::parse(text) {
            let d = plan.dims;
            assert!(d.obs >= 1 && d.obs <= 1 << 16 && d.act >= 1 && d.act <= 1 << 16);
            assert!(plan.local_actors <= plan.actors);
            let again = serde_json::to_string(&plan).unwrap();
            assert_eq!(ResolvedRun::parse(&again), Ok(plan));
        }
    }
);
