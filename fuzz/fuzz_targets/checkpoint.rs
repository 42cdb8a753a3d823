//! Checkpoint files (`mbpo_train::checkpoint::read` / `verify`), for every kind of file a
//! checkpoint directory or a run holds, decoded into the type its reader asks for: the roles'
//! (`run_files`), the run book, the launcher's (`SupervisorCheckpoint`), the final policy
//! (`policy.ckpt`) and `mbpo train`'s SAC state (through `checkpointed_actor_params`).
//!
//! Input: `[selector byte | bytes]`. The selector's low bits pick the kind; with its high bit
//! clear the bytes are the whole file (header, checksum and all), with it set they are the
//! payload, put behind a valid header and SHA-256 (what a buggy or forged writer could produce:
//! the fuzzer cannot find a SHA-256 by itself). The reader reads a file, so the input is
//! written to a file on tmpfs first.
//!
//! Checks: `verify` accepts exactly the files whose header and checksum `read` accepts (a
//! `read` refusal after a passed `verify` is a `Decode` error); a decoded value encodes and
//! decodes back to the same encoding.
#![no_main]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{scratch, write_seeds_if_asked};
use mbpo_runtime::barrier;
use mbpo_runtime::coordinator::checkpoints::SupervisorCheckpoint;
use mbpo_train::checkpoint::{self, CheckpointError, FORMAT_VERSION};
use mbpo_train::policy_file::FinalPolicy;
use mbpo_train::run_files::{
    kind, ActorCheckpoint, EvaluatorCheckpoint, LearnerCheckpoint, ModelTrainerCheckpoint,
    PlanningActorCheckpoint, PlanningEvaluatorCheckpoint, RolloutCheckpoint, RunBook,
};
use mbpo_train::ExperimentConfig;
use serde::de::DeserializeOwned;
use serde::Serialize;
use sha2::{Digest, Sha256};

/// `mbpo train`'s SAC checkpoint kind (crate-private in `sac_checkpoint`; checked at start-up by
/// `sac_kind_is_right`).
const SAC_KIND: &str = "mbpo.sac-trainer";

/// Kinds, in selector order.
fn kinds() -> &'static [&'static str; 11] {
    static KINDS: OnceLock<[&'static str; 11]> = OnceLock::new();
    KINDS.get_or_init(|| {
        [
            kind::ACTOR,
            kind::EVALUATOR,
            kind::MODEL_TRAINER,
            kind::ROLLOUT,
            kind::LEARNER,
            kind::PLANNING_ACTOR,
            kind::PLANNING_EVALUATOR,
            kind::RUN_BOOK,
            barrier::kind::SUPERVISOR,
            final_policy_kind(),
            SAC_KIND,
        ]
    })
}

/// The kind in the header of a checkpoint file.
fn kind_of(file: &[u8]) -> String {
    let n = u16::from_le_bytes([file[12], file[13]]) as usize;
    String::from_utf8(file[14..14 + n].to_vec()).unwrap()
}

/// The final policy's kind, as `write_final_policy` writes it (the constant is private).
fn final_policy_kind() -> &'static str {
    let run = scratch().join("final-kind");
    std::fs::create_dir_all(&run).unwrap();
    mbpo_train::policy_file::write_final_policy(&run, 1, &[0.5]).unwrap();
    let file = std::fs::read(run.join(mbpo_train::policy_file::FINAL_POLICY_FILE)).unwrap();
    Box::leak(kind_of(&file).into_boxed_str())
}

/// A checkpoint file of `kind` around `payload`, as `checkpoint::write` lays it out.
fn file_with(kind: &str, payload: &[u8]) -> Vec<u8> {
    let mut b = Vec::with_capacity(payload.len() + 64 + kind.len());
    b.extend_from_slice(b"MBPOCKPT");
    b.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    b.extend_from_slice(&(kind.len() as u16).to_le_bytes());
    b.extend_from_slice(kind.as_bytes());
    b.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    b.extend_from_slice(&Sha256::digest(payload));
    b.extend_from_slice(payload);
    b
}

/// The payload of a checkpoint file (after the header and checksum).
fn payload_of(file: &[u8]) -> &[u8] {
    let n = u16::from_le_bytes([file[12], file[13]]) as usize;
    &file[14 + n + 8 + 32..]
}

fn config(algo: &str) -> ExperimentConfig {
    let set: Vec<String> = [
        &format!("algo={algo}") as &str,
        "env=Pendulum-v1",
        "steps=40",
        "sac.hidden=[8]",
        "sac.batch_size=4",
        "model.members=2",
        "model.elites=1",
        "model.hidden=[8]",
        "model.weight_decay=[1e-4, 1e-4]",
        "model.batch_size=4",
        "mbpo.init_random_steps=10",
        "mbpo.model_train_freq=10",
        "mbpo.rollouts_per_step=4",
        "mbpo.replay_capacity=64",
        "sac_loop.replay_capacity=64",
        "eval.every=20",
        "eval.episodes=1",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    ExperimentConfig::resolve(None, &set).expect("the seed config is valid")
}

/// Real files of every kind but `mbpo train`'s SAC state: the checkpoint `Mbpo` writes after a
/// few warm-up steps, an MPC run's planning roles, the launcher's file and a final policy.
fn seeds() -> Vec<Vec<u8>> {
    let dir = scratch().join("seed-checkpoint");
    let cfg = config("mbpo");
    let mut mbpo = mbpo_train::Mbpo::new(&cfg).unwrap();
    for _ in 0..6 {
        mbpo.warm_up_step().unwrap();
    }
    let evaluator = mbpo_train::eval::Evaluator::new(&cfg).unwrap();
    let mut book = RunBook::start();
    book.wrote_row(20, -1200.0, 3.5, 0);
    book.episodes.push((200, -1500.0));
    book.models.insert(1, 0.02);
    let files = mbpo.encode_checkpoint(&dir, 6, &evaluator, &book).unwrap();
    files.write().unwrap();
    let mpc = config("mpc");
    let actor = mbpo_train::mpc_roles::PlanningActorRole::new(&mpc, 0).unwrap();
    let eval = mbpo_train::mpc_roles::PlanningEvaluator::new(&mpc).unwrap();
    checkpoint::write(
        &dir.join("planning-actor"),
        kind::PLANNING_ACTOR,
        &PlanningActorCheckpoint {
            role: actor.checkpoint(),
            steps: 0,
        },
    )
    .unwrap();
    checkpoint::write(
        &dir.join("planning-evaluator"),
        kind::PLANNING_EVALUATOR,
        &PlanningEvaluatorCheckpoint {
            role: eval.checkpoint(),
            evals: 0,
            env_steps: 0,
        },
    )
    .unwrap();
    let sup = SupervisorCheckpoint {
        mode: mbpo_runtime::Mode::Pipelined,
        actors: 3,
        slack: mbpo_runtime::Slack {
            policy_lag: 2,
            update_buffer: 40,
            model_lag: 25,
        },
    };
    checkpoint::write(&dir.join("supervisor"), barrier::kind::SUPERVISOR, &sup).unwrap();
    mbpo_train::policy_file::write_final_policy(&dir, 6, &[0.5, -0.5, 1.0]).unwrap();
    let names = [
        "actor-0",
        "evaluator",
        "model-trainer",
        "rollout-generator",
        "learner",
        "planning-actor",
        "planning-evaluator",
        "run-book",
        "supervisor",
        mbpo_train::policy_file::FINAL_POLICY_FILE,
    ];
    let mut out = Vec::new();
    for (i, name) in names.iter().enumerate() {
        let file = std::fs::read(dir.join(name)).unwrap();
        assert_eq!(kind_of(&file), kinds()[i], "{name}");
        assert_eq!(
            file_with(kinds()[i], payload_of(&file)),
            file,
            "the header layout"
        );
        let mut s = vec![i as u8];
        s.extend_from_slice(&file);
        out.push(s.clone());
        // The same file with a header whose payload length lies (too long by one, or near
        // u64::MAX: `at + len` must not overflow).
        let at = 1 + 14 + kinds()[i].len();
        let len = payload_of(&file).len() as u64;
        for lie in [len + 1, 1 << 63, u64::MAX - 16, u64::MAX] {
            let mut t = s.clone();
            t[at..at + 8].copy_from_slice(&lie.to_le_bytes());
            out.push(t);
        }
        let mut s = vec![i as u8 | 0x80];
        s.extend_from_slice(payload_of(&file));
        out.push(s);
    }
    let _ = std::fs::remove_dir_all(dir);
    out
}

/// Read `path` as a `T` of `kind`, comparing with `verify`; a value must survive encode/decode.
fn check<T: Serialize + DeserializeOwned>(path: &Path, kind: &str) {
    let verified = checkpoint::verify(path, kind);
    match checkpoint::read::<T>(path, kind) {
        Ok(v) => {
            assert!(verified.is_ok(), "read accepts what verify refuses");
            let cfg = bincode::config::standard();
            let a = bincode::serde::encode_to_vec(&v, cfg).unwrap();
            let (w, used): (T, usize) = bincode::serde::decode_from_slice(&a, cfg)
                .expect("a decoded value's encoding decodes");
            assert_eq!(used, a.len());
            assert_eq!(bincode::serde::encode_to_vec(&w, cfg).unwrap(), a);
        }
        Err(CheckpointError::Decode { .. }) => {
            assert!(
                verified.is_ok(),
                "verify and read refuse for different reasons"
            )
        }
        Err(e) => {
            let v = verified.expect_err("verify accepts what read refuses by its header");
            assert_eq!(v.to_string(), e.to_string());
        }
    }
}

/// The SAC trainer's state type is private: read it through its public reader.
fn check_sac(dir: &Path) {
    let _ = mbpo_train::sac_checkpoint::checkpointed_actor_params(dir);
}

/// `SAC_KIND` is the kind `mbpo train` uses: a file of that kind with a payload that is no
/// SAC state is refused for its content, not its kind.
fn sac_kind_is_right(dir: &Path) {
    let path = dir.join(mbpo_train::sac_checkpoint::SAC_CHECKPOINT_FILE);
    std::fs::write(&path, file_with(SAC_KIND, &[0xff; 4])).unwrap();
    let err = mbpo_train::sac_checkpoint::checkpointed_actor_params(dir).unwrap_err();
    assert!(err.to_string().contains("cannot decode"), "{err}");
}

fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = scratch().join("checkpoint");
        std::fs::create_dir_all(&d).unwrap();
        sac_kind_is_right(&d);
        d
    })
}

fuzz_target!(
    init: write_seeds_if_asked("checkpoint", seeds),
    |data: &[u8]| {
        let Some((&sel, rest)) = data.split_first() else { return };
        let which = (sel & 0x7f) as usize % kinds().len();
        let kind = kinds()[which];
        let bytes = match sel & 0x80 {
            0 => rest.to_vec(),
            _ => file_with(kind, rest),
        };
        let dir = dir();
        let path = match which {
            10 => dir.join(mbpo_train::sac_checkpoint::SAC_CHECKPOINT_FILE),
            _ => dir.join("file"),
        };
        std::fs::write(&path, &bytes).unwrap();
        match which {
            0 => check::<ActorCheckpoint>(&path, kind),
            1 => check::<EvaluatorCheckpoint>(&path, kind),
            2 => check::<ModelTrainerCheckpoint>(&path, kind),
            3 => check::<RolloutCheckpoint>(&path, kind),
            4 => check::<LearnerCheckpoint>(&path, kind),
            5 => check::<PlanningActorCheckpoint>(&path, kind),
            6 => check::<PlanningEvaluatorCheckpoint>(&path, kind),
            7 => check::<RunBook>(&path, kind),
            8 => check::<SupervisorCheckpoint>(&path, kind),
            9 => check::<FinalPolicy>(&path, kind),
            _ => check_sac(dir),
        }
    }
);
