//! Experiment configs: the TOML text of `mbpo run --config FILE` / `mbpo train --config FILE`
//! (`ExperimentConfig::resolve`) and of a run directory's `config.toml`, which every service
//! process and every remote worker (it arrives in the head's `Welcome`) loads with
//! `ExperimentConfig::load`. Both parse, then validate every value (and make the environment
//! once to learn its dimensions).
//!
//! The decoders read a file: each input is written to a file on tmpfs first.
//!
//! Checks: `resolve` and `load` agree on whether a config is valid (when it names no
//! `gym.path`, which `resolve` takes relative to the file); an accepted config's resolved copy
//! (`to_toml`, what the run directory keeps) loads again, to the same TOML.
#![no_main]

use std::path::PathBuf;

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{scratch, write_seeds_if_asked};
use mbpo_train::ExperimentConfig;

fn seeds() -> Vec<Vec<u8>> {
    // The example configs are added by tools/fuzz.sh (deploy/configs/*.toml); these add the
    // resolved form of the defaults and of each algorithm.
    ["sac", "mbpo", "mpc"]
        .iter()
        .filter_map(|algo| {
            let cfg = ExperimentConfig::resolve(
                None,
                &[format!("algo={algo}"), "env=Pendulum-v1".into()],
            )
            .ok()?;
            Some(cfg.to_toml().into_bytes())
        })
        .collect()
}

fn files() -> (PathBuf, PathBuf) {
    let dir = scratch().join("config");
    std::fs::create_dir_all(&dir).unwrap();
    (dir.join("config.toml"), dir.join("resolved.toml"))
}

fuzz_target!(
    init: write_seeds_if_asked("config", seeds),
    |data: &[u8]| {
        let (path, resolved) = files();
        std::fs::write(&path, data).unwrap();
        let cli = ExperimentConfig::resolve(Some(&path), &[]);
        let service = ExperimentConfig::load(&path);
        if let Ok(cfg) = &service {
            if cfg.gym.path.is_empty() {
                assert_eq!(
                    cli.is_ok(),
                    true,
                    "`load` accepts what `resolve` refuses: {:?}",
                    cli.as_ref().err()
                );
            }
        }
        if let (Err(e), Ok(cfg)) = (&service, &cli) {
            assert!(
                !cfg.gym.path.is_empty(),
                "`resolve` accepts what `load` refuses: {e}"
            );
        }
        let Ok(cfg) = cli else { return };
        let text = cfg.to_toml();
        std::fs::write(&resolved, &text).unwrap();
        let again = ExperimentConfig::load(&resolved)
            .unwrap_or_else(|e| panic!("the resolved copy of an accepted config is refused: {e}\n{text}"));
        assert_eq!(again.to_toml(), text, "the resolved copy loads as another config");
    }
);
