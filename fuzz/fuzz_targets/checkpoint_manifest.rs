//! A checkpoint directory's `COMPLETE` marker (JSON: format version, env steps, files), read by
//! `mbpo_train::checkpoint::latest` when a run resumes or its newest policy is looked up.
//!
//! Checks: a refusal is `CheckpointError::Resume` (or `Io` for a file that is not UTF-8, as
//! `read_to_string` says); an accepted manifest is the file's JSON
//! (serialising it and parsing that gives the same manifest).
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{scratch, write_seeds_if_asked};
use mbpo_train::checkpoint::{self, CheckpointError, Manifest};

fn seeds() -> Vec<Vec<u8>> {
    let m = Manifest {
        format_version: checkpoint::FORMAT_VERSION,
        env_steps: 500,
        files: [
            "learner",
            "model-trainer",
            "rollout-generator",
            "evaluator",
            "actor-0",
            "run-book",
        ]
        .map(String::from)
        .to_vec(),
    };
    vec![
        serde_json::to_vec(&m).unwrap(),
        serde_json::to_vec_pretty(&m).unwrap(),
    ]
}

fn run() -> &'static PathBuf {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let run = scratch().join("manifest-run");
        std::fs::create_dir_all(checkpoint::dir_for(&run, 500)).unwrap();
        run
    })
}

fuzz_target!(
    init: write_seeds_if_asked("checkpoint_manifest", seeds),
    |data: &[u8]| {
        let run = run();
        let marker = checkpoint::dir_for(run, 500).join(checkpoint::COMPLETE);
        std::fs::write(&marker, data).unwrap();
        match checkpoint::latest(run) {
            Ok(Some((dir, m))) => {
                assert_eq!(dir, checkpoint::dir_for(run, 500));
                let back: Manifest = serde_json::from_slice(&serde_json::to_vec(&m).unwrap()).unwrap();
                assert_eq!(back, m);
            }
            Ok(None) => panic!("a complete checkpoint was not found"),
            Err(CheckpointError::Resume(_)) => {}
            Err(CheckpointError::Io { source, .. })
                if source.kind() == std::io::ErrorKind::InvalidData =>
            {
                assert!(std::str::from_utf8(data).is_err())
            }
            Err(e) => panic!("unexpected error {e}"),
        }
    }
);
