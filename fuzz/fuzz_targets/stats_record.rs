//! `mbpo_wire::Stats::decode`: a `StatsRecord` as another process left it on the stats channel
//! (every byte of the 88-byte record chosen by the fuzzer).
//!
//! Checks beyond "no panic": a known kind decodes and an unknown one is
//! `DecodeError::UnknownStatsKind` naming it; a decoded report's own record decodes to the same
//! report (the record <-> report mapping is one mapping).
#![no_main]

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{bytes_of, pod, write_seeds_if_asked};
use mbpo_wire::error::DecodeError;
use mbpo_wire::{
    BarrierReport, Done, EnvFailed, EpisodeEnd, EvalResult, LearnerRow, ModelTrained,
    ModelTraining, PacingPart, Progress, RolloutBranch, Stats, StatsKind, StatsRecord,
};

fn seeds() -> Vec<Vec<u8>> {
    let reports: Vec<Stats> = vec![
        EpisodeEnd {
            env_steps: 200,
            episode_return: -1234.5,
            version: 199,
        }
        .into(),
        EvalResult {
            env_steps: 1000,
            policy_version: 999,
            model_version: 4,
            mean_return: -150.0,
            episodes: 5,
        }
        .into(),
        LearnerRow {
            env_steps: 400,
            sac_updates: 4000,
            critic_loss: 1.5,
            actor_loss: -3.0,
            alpha: 0.2,
            entropy: -1.0,
            q_mean: 12.0,
            consistency_loss: 0.25,
            reward_loss: 0.5,
            rollout_length: 3,
            model_buffer: 100_000,
            model_version: 2,
        }
        .into(),
        ModelTrained {
            rows: 300,
            version: 3,
            holdout_mse: 0.01,
            epochs: 40,
            seconds: 2.5,
        }
        .into(),
        ModelTraining {
            env_steps: 651,
            version: 2,
            epoch: 318,
            holdout_mse: 0.0025,
            seconds: 10.5,
        }
        .into(),
        RolloutBranch {
            env_steps: 299,
            model_version: 3,
            policy_version: 298,
            rows: 400,
            length: 1,
            seconds: 0.1,
        }
        .into(),
        Progress {
            env_steps: 10,
            sac_updates: 80,
            model_version: 1,
            policy_version: 9,
        }
        .into(),
        Done {
            real: 1000,
            lost: 0,
            work: 9000,
            median_step_seconds: 0.01,
            slack_min: 0.0,
            slack_max: 2.0,
            slack_mean: 1.0,
            ipc_seconds: 0.5,
            wall_seconds: 30.0,
            episodes_cut: 0,
            episodes_lost: 1,
            real_spilled: 3,
            missed_deadlines: 2,
            rests: 1,
        }
        .into(),
        BarrierReport::Paused(300).into(),
        BarrierReport::Written(300).into(),
        EnvFailed { env_steps: 77 }.into(),
        PacingPart {
            first_bin: 6,
            counts: [900, 80, 7, 1, 0, 2],
            max_error_us: 11722.8,
        }
        .into(),
    ];
    reports.iter().map(|s| bytes_of(&s.record())).collect()
}

fuzz_target!(
    init: write_seeds_if_asked("stats_record", seeds),
    |data: &[u8]| {
        let (r, _) = pod::<StatsRecord>(data);
        match Stats::decode(&r) {
            Ok(s) => {
                assert!(StatsKind::from_u32(r.kind).is_some(), "kind {} decoded", r.kind);
                let again = Stats::decode(&s.record())
                    .expect("the record of a decoded report decodes");
                // Debug, not ==: NaN fields are the same NaN either way.
                assert_eq!(format!("{again:?}"), format!("{s:?}"), "record {r:?}");
            }
            Err(DecodeError::UnknownStatsKind(k)) => {
                assert_eq!(k, r.kind);
                assert!(StatsKind::from_u32(k).is_none(), "known kind {k} refused");
            }
            Err(e) => panic!("a stats record refused with {e:?}"),
        }
    }
);
