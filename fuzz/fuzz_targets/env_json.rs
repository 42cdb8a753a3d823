//! A run's `env.json` (a Python environment's widths, written by `mbpo run` and sent to every
//! remote worker in the head's `Welcome`), read by `mbpo_runtime::process::Dims::of_run`, which
//! sizes every wire layout (policy, model, transition rows) from it.
//!
//! Input: the file's bytes, for a run of `env = "gym:..."` (MBPO, small networks).
//!
//! A file that is not UTF-8 is skipped: `of_run` then ignores it like a missing one and makes
//! the environment to learn its widths, which for a `gym:` id starts a Python process.
//!
//! Checks: accepted dimensions are the file's `obs_dim` / `act_dim`; a refusal is a typed
//! error, not a panic or an allocation sized by a number in the file.
#![no_main]

use std::path::PathBuf;

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{scratch, write_seeds_if_asked};
use mbpo_runtime::Dims;
use mbpo_train::ExperimentConfig;

fn seeds() -> Vec<Vec<u8>> {
    [
        r#"{"obs_dim": 3, "act_dim": 1}"#,
        r#"{"obs_dim": 17, "act_dim": 6, "name": "HalfCheetah-v5"}"#,
        r#"{"act_dim": 1, "obs_dim": 11}"#,
    ]
    .iter()
    .map(|s| s.as_bytes().to_vec())
    .collect()
}

fn setup() -> (ExperimentConfig, PathBuf) {
    let mut cfg = ExperimentConfig::default();
    cfg.env = "gym:Fuzz-v0".into();
    cfg.algo = mbpo_train::Algo::MBPO;
    cfg.sac.hidden = vec![8, 8];
    cfg.model.members = 3;
    cfg.model.elites = 2;
    cfg.model.hidden = vec![8, 8];
    cfg.model.weight_decay = vec![1e-4; 3];
    let dir = scratch().join("run");
    std::fs::create_dir_all(&dir).unwrap();
    (cfg, dir)
}

thread_local! {
    static SETUP: (ExperimentConfig, PathBuf) = setup();
}

fuzz_target!(
    init: write_seeds_if_asked("env_json", seeds),
    |data: &[u8]| {
        if std::str::from_utf8(data).is_err() {
            return;
        }
        SETUP.with(|(cfg, dir)| {
            std::fs::write(dir.join(mbpo_train::run_dir::ENV_FILE), data).unwrap();
            if let Ok(dims) = Dims::of_run(cfg, dir) {
                let json: serde_json::Value = serde_json::from_slice(data).expect("accepted JSON");
                assert_eq!(json["obs_dim"].as_u64(), Some(dims.obs as u64));
                assert_eq!(json["act_dim"].as_u64(), Some(dims.act as u64));
            }
        });
    }
);
