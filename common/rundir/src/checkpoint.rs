//! Checkpoint files and checkpoint directories.
//!
//! A run checkpoints into `<run>/checkpoints/<env steps, 10 digits>/`, one file per role
//! (`actor-0`, `model-trainer`, `rollout-generator`, `learner`, `evaluator`), the run's book
//! and, written last, `COMPLETE` (JSON: env steps and the files); `mbpo_train::run_files` defines
//! them, the same for `mbpo train` and `mbpo run` (MBPO, MPC). Only a directory with `COMPLETE` is
//! ever resumed from, so a crash while checkpointing falls back to the previous one.
//!
//! Each file is
//!
//! ```text
//! "MBPOCKPT" | format version u32 | kind length u16 | kind | payload length u64 | SHA-256(payload) | payload
//! ```
//!
//! (little-endian; the payload is bincode of the role's state), written to a temporary file,
//! flushed to disk and renamed, so a reader sees the old file or the new one, never half of one.
//! Reading checks the magic, the version, the kind, the length and the checksum, and says which
//! failed.

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::io::Write;
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"MBPOCKPT";

/// Version of the file layout and of the role states inside; bump on any change to either
/// (2: actors keep the environment's resume state, e.g. MuJoCo's solver warm start; 3: an
/// actor's episode in progress is optional, for environments that cannot save their state, and
/// the role files are one format for both commands, `run_files`; 4: an actor counts the episodes
/// lost to an environment process that exited; 5: the learner's file may store D_model as the
/// branches that made it, a field after all others, `mbpo_train::d_model_branches`; 6: TD-MPC2's
/// world-model learner keeps how its buffer's rows join into episodes, so that several actors'
/// rows can interleave, a field after all others).
pub const FORMAT_VERSION: u32 = 6;

/// The oldest format this build still reads: every file of format 4 or 5 is its format-6
/// payload but for a last field of the learner's (format 4) or the world-model learner's
/// (format 4 and 5), absent ([`upgraded_payload`]).
const OLDEST_READABLE: u32 = 4;

/// A payload of format `version` as this build's format reads it.
fn upgraded_payload<'a>(version: u32, kind: &str, payload: &'a [u8]) -> std::borrow::Cow<'a, [u8]> {
    // `d_model_branches: None` (4 -> 5), `episode_links: None` (5 -> 6): bincode writes `None`
    // as one zero byte.
    let absent_last_field = (version == 4 && kind == kind::LEARNER)
        || (version <= 5 && kind == kind::WORLD_MODEL_LEARNER);
    if absent_last_field {
        let mut upgraded = payload.to_vec();
        upgraded.push(0);
        return upgraded.into();
    }
    payload.into()
}

/// Kinds of the role files of a checkpoint (the `kind` field of a file's header; the files
/// themselves are `run_files`' types). They live here because the format's history is per kind
/// (`upgraded_payload`).
pub mod kind {
    use mbpo_core::roles::RoleKind;
    /// `run_files::ActorCheckpoint`.
    pub const ACTOR: &str = RoleKind::Actor.checkpoint_kind();
    /// `run_files::EvaluatorCheckpoint`.
    pub const EVALUATOR: &str = RoleKind::Evaluator.checkpoint_kind();
    /// `run_files::ModelTrainerCheckpoint`.
    pub const MODEL_TRAINER: &str = RoleKind::ModelTrainer.checkpoint_kind();
    /// `run_files::RolloutCheckpoint`.
    pub const ROLLOUT: &str = RoleKind::RolloutGenerator.checkpoint_kind();
    /// `run_files::LearnerCheckpoint`.
    pub const LEARNER: &str = RoleKind::Learner.checkpoint_kind();
    /// `run_files::PlanningActorCheckpoint` (MPC runs).
    pub const PLANNING_ACTOR: &str = RoleKind::PlanningActor.checkpoint_kind();
    /// `run_files::PlanningEvaluatorCheckpoint` (MPC runs).
    pub const PLANNING_EVALUATOR: &str = RoleKind::PlanningEvaluator.checkpoint_kind();
    /// `run_files::WorldModelLearnerCheckpoint` (TD-MPC2 runs).
    pub const WORLD_MODEL_LEARNER: &str = RoleKind::WorldModelLearner.checkpoint_kind();
    /// `run_files::LatentActorCheckpoint` (TD-MPC2 runs).
    pub const LATENT_ACTOR: &str = RoleKind::LatentActor.checkpoint_kind();
    /// `run_files::LatentEvaluatorCheckpoint` (TD-MPC2 runs).
    pub const LATENT_EVALUATOR: &str = RoleKind::LatentEvaluator.checkpoint_kind();
    /// `run_files::RunBook`.
    pub const RUN_BOOK: &str = "mbpo.run-book";
}

/// Name of the marker that makes a checkpoint directory resumable.
pub const COMPLETE: &str = "COMPLETE";

/// Why a checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading or writing failed.
    #[error("checkpoint {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file does not start with the checkpoint magic.
    #[error("checkpoint {path}: not a checkpoint file (no MBPOCKPT header)")]
    NotACheckpoint {
        /// The file.
        path: PathBuf,
    },
    /// Written by another format version.
    #[error("checkpoint {path}: format version {found}, this build reads versions {oldest} to {supported}; resume it with the build that wrote it", oldest = OLDEST_READABLE)]
    Version {
        /// The file.
        path: PathBuf,
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// Holds another role's state.
    #[error("checkpoint {path}: holds `{found}`, expected `{expected}`")]
    Kind {
        /// The file.
        path: PathBuf,
        /// Kind in the file.
        found: String,
        /// Kind asked for.
        expected: String,
    },
    /// Shorter than its header says.
    #[error("checkpoint {path}: truncated: {found} bytes, expected {expected}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Bytes the header promises.
        expected: u64,
        /// Bytes present.
        found: u64,
    },
    /// The payload's checksum does not match.
    #[error("checkpoint {path}: corrupted: SHA-256 of the payload does not match its header")]
    Corrupt {
        /// The file.
        path: PathBuf,
    },
    /// The payload does not decode into the expected state.
    #[error("checkpoint {path}: cannot decode `{kind}`: {message}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// Kind asked for.
        kind: String,
        /// bincode's message.
        message: String,
    },
    /// A checkpoint directory that cannot be resumed.
    #[error("{0}")]
    Resume(String),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Write `value` as a checkpoint of `kind` to `path`, atomically.
pub fn write<T: Serialize>(path: &Path, kind: &str, value: &T) -> Result<(), CheckpointError> {
    EncodedFile::encode(path, kind, value)?.write()
}

/// A checkpoint file encoded in memory, header and payload in one buffer, its checksum not yet
/// computed. Encoding is the snapshot of a role's state and must happen where the state is
/// consistent (the training loop); [`EncodedFile::write`] (checksum, write, `fsync`) does not
/// touch the state, so [`crate::checkpoint_writer`] runs it on another thread.
pub struct EncodedFile {
    path: PathBuf,
    bytes: Vec<u8>,
    payload_start: usize,
}

impl EncodedFile {
    /// Encode `value` as a checkpoint of `kind` to go to `path`. The payload is encoded straight
    /// after the header, so a large state (a pipeline learner's 360 MB model buffer at Hopper 100k) is
    /// never copied whole.
    pub fn encode<T: Serialize>(
        path: &Path,
        kind: &str,
        value: &T,
    ) -> Result<Self, CheckpointError> {
        let mut bytes = Vec::new();
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        bytes.extend_from_slice(&(kind.len() as u16).to_le_bytes());
        bytes.extend_from_slice(kind.as_bytes());
        // Payload length and SHA-256, filled in below and in `write`.
        bytes.extend_from_slice(&[0; 8 + 32]);
        let payload_start = bytes.len();
        bincode::serde::encode_into_std_write(value, &mut bytes, bincode::config::standard())
            .map_err(|e| CheckpointError::Decode {
                path: path.to_path_buf(),
                kind: kind.to_string(),
                message: e.to_string(),
            })?;
        let len = (bytes.len() - payload_start) as u64;
        bytes[payload_start - 40..payload_start - 32].copy_from_slice(&len.to_le_bytes());
        Ok(Self {
            path: path.to_path_buf(),
            bytes,
            payload_start,
        })
    }

    /// Where the file goes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes of the whole file.
    pub fn bytes(&self) -> usize {
        self.bytes.len()
    }

    /// Checksum the payload and write the file atomically ([`write_atomically`]).
    pub fn write(mut self) -> Result<(), CheckpointError> {
        let sum = Sha256::digest(&self.bytes[self.payload_start..]);
        self.bytes[self.payload_start - 32..self.payload_start].copy_from_slice(&sum);
        write_atomically(&self.path, &self.bytes)
    }
}

/// Write `bytes` to `path` through a temporary file, synced, then renamed over `path`. On
/// failure (a full disk, ...) the temporary file is removed and the error names `path`, whose
/// directory names the checkpoint's step; an earlier file at `path` is left as it was.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), CheckpointError> {
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    let written = std::fs::File::create(&tmp).and_then(|mut file| {
        file.write_all(bytes)?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)
    });
    if let Err(source) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_err(path)(source));
    }
    if let Some(dir) = path.parent() {
        // Make the rename itself durable.
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
    }
    Ok(())
}

/// Check a checkpoint file of `kind` at `path` (every header field and the checksum) without
/// decoding it: the supervisor checks every role file before it starts a resumed pipeline.
pub fn verify(path: &Path, kind: &str) -> Result<(), CheckpointError> {
    checked_payload(path, kind).map(|_| ())
}

/// Read a checkpoint of `kind` from `path`, checking every header field and the checksum.
pub fn read<T: DeserializeOwned>(path: &Path, kind: &str) -> Result<T, CheckpointError> {
    let (bytes, range, version) = checked_payload(path, kind)?;
    let payload = upgraded_payload(version, kind, &bytes[range]);
    let p = || path.to_path_buf();
    let (value, _) = bincode::serde::decode_from_slice(&payload, bincode::config::standard())
        .map_err(|e| CheckpointError::Decode {
            path: p(),
            kind: kind.to_string(),
            message: e.to_string(),
        })?;
    Ok(value)
}

/// The file's bytes, the range of its payload and its format version, after every check.
fn checked_payload(
    path: &Path,
    kind: &str,
) -> Result<(Vec<u8>, std::ops::Range<usize>, u32), CheckpointError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let p = || path.to_path_buf();
    let truncated = |expected: usize| CheckpointError::Truncated {
        path: p(),
        expected: expected as u64,
        found: bytes.len() as u64,
    };
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(if bytes.len() < 8 && MAGIC.starts_with(&bytes) {
            truncated(8)
        } else {
            CheckpointError::NotACheckpoint { path: p() }
        });
    }
    let mut at: usize = 8;
    let mut take = |n: usize| -> Result<&[u8], CheckpointError> {
        // Saturating: a length near u64::MAX in a damaged header must not overflow.
        let end = at.saturating_add(n);
        let s = bytes.get(at..end).ok_or_else(|| truncated(end))?;
        at = end;
        Ok(s)
    };
    let version = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes"));
    if !(OLDEST_READABLE..=FORMAT_VERSION).contains(&version) {
        return Err(CheckpointError::Version {
            path: p(),
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let kind_len = u16::from_le_bytes(take(2)?.try_into().expect("2 bytes")) as usize;
    let found_kind = String::from_utf8_lossy(take(kind_len)?).into_owned();
    if found_kind != kind {
        return Err(CheckpointError::Kind {
            path: p(),
            found: found_kind,
            expected: kind.to_string(),
        });
    }
    let len = u64::from_le_bytes(take(8)?.try_into().expect("8 bytes")) as usize;
    let sum: [u8; 32] = take(32)?.try_into().expect("32 bytes");
    let payload = take(len)?;
    if Sha256::digest(payload).as_slice() != sum {
        return Err(CheckpointError::Corrupt { path: p() });
    }
    let end = at;
    Ok((bytes, end - len..end, version))
}

/// The `COMPLETE` marker of a checkpoint directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Format version of the files.
    pub format_version: u32,
    /// Real env steps every role had completed.
    pub env_steps: u64,
    /// The role files of this checkpoint.
    pub files: Vec<String>,
}

/// `<run>/checkpoints`.
pub fn root(run: &Path) -> PathBuf {
    run.join("checkpoints")
}

/// The directory of the checkpoint taken after `env_steps` steps.
pub fn dir_for(run: &Path, env_steps: u64) -> PathBuf {
    root(run).join(format!("{env_steps:010}"))
}

/// The env steps a checkpoint directory was taken at (its name), if it is one.
fn steps_of(dir: &Path) -> Option<u64> {
    dir.file_name()?.to_str()?.parse().ok()
}

/// The env steps of `run`'s complete checkpoints, oldest first (none without a checkpoint root).
pub fn complete_steps(run: &Path) -> Vec<u64> {
    let mut steps: Vec<u64> = std::fs::read_dir(root(run))
        .into_iter()
        .flatten()
        .filter_map(|e| {
            let dir = e.ok()?.path();
            dir.join(COMPLETE).is_file().then(|| steps_of(&dir))?
        })
        .collect();
    steps.sort_unstable();
    steps
}

/// Mark `dir` complete (after every role file in `files` is written).
pub fn mark_complete(dir: &Path, env_steps: u64, files: &[&str]) -> Result<(), CheckpointError> {
    for f in files {
        let path = dir.join(f);
        if !path.is_file() {
            return Err(CheckpointError::Resume(format!(
                "checkpoint {}: role file {f} is missing",
                dir.display()
            )));
        }
    }
    let manifest = Manifest {
        format_version: FORMAT_VERSION,
        env_steps,
        files: files.iter().map(|f| f.to_string()).collect(),
    };
    let text = serde_json::to_string_pretty(&manifest).expect("manifest serialises") + "\n";
    write_atomically(&dir.join(COMPLETE), text.as_bytes())
}

/// The newest complete checkpoint of a run: its directory and manifest. `None` when the run has
/// none; incomplete directories (a crash while checkpointing) are skipped.
pub fn latest(run: &Path) -> Result<Option<(PathBuf, Manifest)>, CheckpointError> {
    let root = root(run);
    let entries = match std::fs::read_dir(&root) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io_err(&root)(e)),
    };
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join(COMPLETE).is_file())
        .collect();
    dirs.sort();
    let Some(dir) = dirs.pop() else {
        return Ok(None);
    };
    let marker = dir.join(COMPLETE);
    let text = std::fs::read_to_string(&marker).map_err(io_err(&marker))?;
    let manifest: Manifest = serde_json::from_str(&text)
        .map_err(|e| CheckpointError::Resume(format!("checkpoint {}: {e}", marker.display())))?;
    Ok(Some((dir, manifest)))
}

/// Delete all but the newest `keep` complete checkpoints (and any incomplete older ones); a
/// complete one taken at a multiple of `keep_every` env steps (when not 0) is kept as well.
pub fn prune(run: &Path, keep: usize, keep_every: u64) -> Result<(), CheckpointError> {
    let root = root(run);
    let Ok(entries) = std::fs::read_dir(&root) else {
        return Ok(());
    };
    let mut dirs: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    dirs.sort();
    let complete: Vec<&PathBuf> = dirs.iter().filter(|d| d.join(COMPLETE).is_file()).collect();
    let Some(oldest_kept) = complete.len().checked_sub(keep.max(1)).map(|i| complete[i]) else {
        return Ok(());
    };
    let milestone = |d: &Path| {
        keep_every > 0
            && d.join(COMPLETE).is_file()
            && steps_of(d).is_some_and(|steps| steps.is_multiple_of(keep_every))
    };
    for d in dirs.iter().filter(|d| *d < oldest_kept && !milestone(d)) {
        std::fs::remove_dir_all(d).map_err(io_err(d))?;
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A fresh scratch directory for one test (also `checkpoint_writer`'s tests).
    pub(crate) fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("mbpo-ckpt-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn round_trip_and_every_damage_is_named() {
        let dir = tmp("damage");
        let path = dir.join("x.ckpt");
        let value = (vec![1.5f32, -2.0], 7u64, Some("s".to_string()));
        write(&path, "test-state", &value).unwrap();
        let back: (Vec<f32>, u64, Option<String>) = read(&path, "test-state").unwrap();
        assert_eq!(back, value);
        let good = std::fs::read(&path).unwrap();

        let err = read::<u64>(&path, "learner").unwrap_err().to_string();
        assert!(
            err.contains("holds `test-state`, expected `learner`"),
            "{err}"
        );

        for cut in [3, 20, good.len() - 1] {
            std::fs::write(&path, &good[..cut]).unwrap();
            let err = read::<(Vec<f32>, u64, Option<String>)>(&path, "test-state").unwrap_err();
            assert!(
                matches!(err, CheckpointError::Truncated { .. }),
                "cut {cut}: {err}"
            );
        }
        let mut flipped = good.clone();
        *flipped.last_mut().unwrap() ^= 1;
        std::fs::write(&path, &flipped).unwrap();
        let err = read::<(Vec<f32>, u64, Option<String>)>(&path, "test-state").unwrap_err();
        assert!(err.to_string().contains("corrupted"), "{err}");

        let mut other_version = good.clone();
        other_version[8] = 99;
        std::fs::write(&path, &other_version).unwrap();
        let err = read::<u64>(&path, "test-state").unwrap_err().to_string();
        assert!(err.contains("format version 99"), "{err}");

        std::fs::write(&path, b"{\"json\": true}").unwrap();
        let err = read::<u64>(&path, "test-state").unwrap_err().to_string();
        assert!(err.contains("not a checkpoint"), "{err}");

        // A valid file of another shape: decodes fail cleanly.
        write(&path, "test-state", &1u8).unwrap();
        let err = read::<(Vec<f32>, u64, String)>(&path, "test-state").unwrap_err();
        assert!(matches!(err, CheckpointError::Decode { .. }), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A learner file of format 4 (lanes of long runs started by the build before) reads as
    /// format 5 without D_model's branches, a world-model learner's of format 4 or 5 without
    /// its episode links; another role's older file reads as it is, and format 3 is refused by
    /// name.
    #[test]
    fn older_files_read_with_the_learners_new_fields_absent() {
        use super::kind::{LEARNER, ROLLOUT, WORLD_MODEL_LEARNER};
        let dir = tmp("format-4");
        let path = dir.join("learner");
        let as_format = |version: u32, kind: &str, value: &(u64, Vec<f32>)| {
            let mut file = EncodedFile::encode(&path, kind, value).unwrap();
            file.bytes[8..12].copy_from_slice(&version.to_le_bytes());
            file.write().unwrap();
        };
        let before = (7u64, vec![1.5f32, -2.0]);
        as_format(4, LEARNER, &before);
        let now: (u64, Vec<f32>, Option<u32>) = read(&path, LEARNER).unwrap();
        assert_eq!(now, (7, vec![1.5, -2.0], None));
        as_format(5, LEARNER, &before);
        assert!(read::<(u64, Vec<f32>, Option<u32>)>(&path, LEARNER).is_err());
        for version in [4, 5] {
            as_format(version, WORLD_MODEL_LEARNER, &before);
            let now: (u64, Vec<f32>, Option<u32>) = read(&path, WORLD_MODEL_LEARNER).unwrap();
            assert_eq!(now, (7, vec![1.5, -2.0], None));
        }
        as_format(6, WORLD_MODEL_LEARNER, &before);
        assert!(read::<(u64, Vec<f32>, Option<u32>)>(&path, WORLD_MODEL_LEARNER).is_err());
        as_format(4, ROLLOUT, &before);
        assert_eq!(read::<(u64, Vec<f32>)>(&path, ROLLOUT).unwrap(), before);
        as_format(3, ROLLOUT, &before);
        let err = read::<(u64, Vec<f32>)>(&path, ROLLOUT)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("format version 3, this build reads versions 4 to 6"),
            "{err}"
        );
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_failed_write_names_the_file_and_leaves_no_temporary_file() {
        let dir = tmp("failed-write");
        // A directory where the file should go: the rename over it fails after the write.
        let path = dir.join("learner");
        std::fs::create_dir_all(path.join("in-the-way")).unwrap();
        let err = write(&path, "test-state", &1u64).unwrap_err().to_string();
        assert!(err.contains(&path.display().to_string()), "{err}");
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert_eq!(left, ["learner"], "a temporary file was left behind");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn latest_skips_incomplete_and_prune_keeps_the_newest() {
        let run = tmp("latest");
        assert!(latest(&run).unwrap().is_none());
        for steps in [100, 200, 300] {
            let d = dir_for(&run, steps);
            std::fs::create_dir_all(&d).unwrap();
            write(&d.join("a.ckpt"), "a", &steps).unwrap();
            mark_complete(&d, steps, &["a.ckpt"]).unwrap();
        }
        // A crash while writing step 400: no COMPLETE marker.
        let d = dir_for(&run, 400);
        std::fs::create_dir_all(&d).unwrap();
        write(&d.join("a.ckpt"), "a", &400u64).unwrap();
        let (dir, manifest) = latest(&run).unwrap().unwrap();
        assert_eq!((dir, manifest.env_steps), (dir_for(&run, 300), 300));
        let err = mark_complete(&d, 400, &["a.ckpt", "b.ckpt"]).unwrap_err();
        assert!(err.to_string().contains("b.ckpt is missing"), "{err}");

        let left = || {
            let mut left: Vec<_> = std::fs::read_dir(root(&run))
                .unwrap()
                .map(|e| e.unwrap().file_name().into_string().unwrap())
                .collect();
            left.sort();
            left
        };
        prune(&run, 2, 0).unwrap();
        assert_eq!(left(), ["0000000200", "0000000300", "0000000400"]);
        // With keep_every, older complete checkpoints at its multiples stay.
        for steps in [500, 600] {
            let d = dir_for(&run, steps);
            std::fs::create_dir_all(&d).unwrap();
            write(&d.join("a.ckpt"), "a", &steps).unwrap();
            mark_complete(&d, steps, &["a.ckpt"]).unwrap();
        }
        prune(&run, 1, 200).unwrap();
        assert_eq!(left(), ["0000000200", "0000000600"]);
        std::fs::remove_dir_all(run).unwrap();
    }
}
