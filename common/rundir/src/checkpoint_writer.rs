//! Writing a checkpoint while the training goes on.
//!
//! A checkpoint of MBPO at Hopper 100k is about 400 MB (the learner's file is the model
//! buffer): encoding, checksumming, writing and `fsync`ing it held the training loop about 2.5 s.
//! Only the encoding (about 0.45 s) needs the loop's state, so the loop encodes the files
//! ([`CheckpointFiles`]) and a [`BackgroundWriter`] writes them on its own thread while the next
//! steps run. The write and the kernel's write-back still take CPU beside the training (with a
//! checkpoint every 100 steps, an SAC update took 2.8 ms instead of 2.45), so the net gain is about
//! 1.2 s per checkpoint at 100k, not the whole 2 s (results/measurements.md, "Checkpoints
//! written beside the training", 2026-11-27, commit ae824eb).
//!
//! What a crash can see does not change: a checkpoint directory is resumable only once every
//! file is on disk and `COMPLETE` is written after them, and older checkpoints are pruned only
//! after that, so a crash part-way falls back to the previous complete checkpoint, as with a
//! synchronous write. At most one checkpoint is in flight (the next one waits for it), which
//! bounds the memory to one encoded checkpoint; a write that failed is reported by the next
//! [`BackgroundWriter::submit`] or by [`BackgroundWriter::wait`], which a run calls before it
//! reports itself done or stopped.

use crate::checkpoint::{self, CheckpointError, EncodedFile};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::thread::JoinHandle;

/// The encoded files of one checkpoint directory, to be written with its `COMPLETE` marker.
pub struct CheckpointFiles {
    dir: PathBuf,
    env_steps: u64,
    files: Vec<EncodedFile>,
}

impl CheckpointFiles {
    /// An empty checkpoint after `env_steps` steps, to go to `dir`.
    pub fn new(dir: &Path, env_steps: u64) -> Self {
        Self {
            dir: dir.to_path_buf(),
            env_steps,
            files: Vec::new(),
        }
    }

    /// Encode `value` as the file `name` of `kind`.
    pub fn add<T: Serialize>(
        &mut self,
        name: &str,
        kind: &str,
        value: &T,
    ) -> Result<(), CheckpointError> {
        self.files
            .push(EncodedFile::encode(&self.dir.join(name), kind, value)?);
        Ok(())
    }

    /// The checkpoint's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Bytes of all its files.
    pub fn bytes(&self) -> usize {
        self.files.iter().map(EncodedFile::bytes).sum()
    }

    /// Write every file (checksummed, synced, renamed into place), then `COMPLETE`.
    pub fn write(self) -> Result<(), CheckpointError> {
        std::fs::create_dir_all(&self.dir).map_err(|source| CheckpointError::Io {
            path: self.dir.clone(),
            source,
        })?;
        let names: Vec<String> = self.files.iter().map(file_name).collect();
        for file in self.files {
            file.write()?;
        }
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        checkpoint::mark_complete(&self.dir, self.env_steps, &names)
    }
}

/// The name of `file` in its checkpoint directory (what `COMPLETE` lists).
fn file_name(file: &EncodedFile) -> String {
    let name = file
        .path()
        .file_name()
        .expect("a file in the checkpoint directory");
    name.to_string_lossy().into_owned()
}

/// Runs one checkpoint write at a time on its own thread.
#[derive(Default)]
pub struct BackgroundWriter {
    in_flight: Option<(PathBuf, JoinHandle<Result<(), CheckpointError>>)>,
}

impl BackgroundWriter {
    /// Write `files`, then run `after` (e.g. prune older checkpoints), on the writer's thread.
    /// Waits for the checkpoint in flight first and returns its error, if it failed.
    pub fn submit(
        &mut self,
        files: CheckpointFiles,
        after: impl FnOnce() -> Result<(), CheckpointError> + Send + 'static,
    ) -> Result<(), CheckpointError> {
        self.wait()?;
        let dir = files.dir().to_path_buf();
        let job = move || files.write().and_then(|()| after());
        let handle = std::thread::Builder::new()
            .name("checkpoint-writer".into())
            .spawn(job)
            .map_err(|source| CheckpointError::Io {
                path: dir.clone(),
                source,
            })?;
        self.in_flight = Some((dir, handle));
        Ok(())
    }

    /// Wait until the checkpoint in flight (if any) is on disk; its error, if it failed.
    pub fn wait(&mut self) -> Result<(), CheckpointError> {
        let Some((dir, handle)) = self.in_flight.take() else {
            return Ok(());
        };
        handle.join().unwrap_or_else(|_| {
            Err(CheckpointError::Resume(format!(
                "checkpoint {}: its writer thread panicked (see the log); the previous \
                 checkpoint is the newest complete one",
                dir.display()
            )))
        })
    }
}

impl Drop for BackgroundWriter {
    /// A run that ends with an error still finishes its checkpoint in flight.
    fn drop(&mut self) {
        if let Err(e) = self.wait() {
            tracing::error!("{e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::tests::tmp;

    fn files(run: &Path, steps: u64) -> CheckpointFiles {
        let mut files = CheckpointFiles::new(&checkpoint::dir_for(run, steps), steps);
        files
            .add("a", "a-kind", &(steps, vec![1.5f32; 1000]))
            .unwrap();
        files.add("b", "b-kind", &format!("b at {steps}")).unwrap();
        files
    }

    #[test]
    fn written_in_the_background_equals_written_in_place() {
        let run = tmp("writer-equal");
        let mut writer = BackgroundWriter::default();
        writer.submit(files(&run, 100), || Ok(())).unwrap();
        writer.wait().unwrap();
        let background = checkpoint::dir_for(&run, 100);
        let (dir, manifest) = checkpoint::latest(&run).unwrap().unwrap();
        assert_eq!(
            (dir, manifest.files),
            (background.clone(), vec!["a".into(), "b".into()])
        );
        let (steps, v): (u64, Vec<f32>) =
            checkpoint::read(&background.join("a"), "a-kind").unwrap();
        assert_eq!((steps, v.len(), v[999]), (100, 1000, 1.5));

        // The same state through the synchronous path gives the same bytes.
        let direct = run.join("direct");
        checkpoint::write(&direct, "a-kind", &(100u64, vec![1.5f32; 1000])).unwrap();
        assert_eq!(
            std::fs::read(&direct).unwrap(),
            std::fs::read(background.join("a")).unwrap()
        );
        std::fs::remove_dir_all(run).unwrap();
    }

    #[test]
    fn one_checkpoint_in_flight_and_pruning_after_it() {
        let run = tmp("writer-prune");
        let mut writer = BackgroundWriter::default();
        for steps in [100, 200, 300] {
            let prune_run = run.clone();
            writer
                .submit(files(&run, steps), move || {
                    checkpoint::prune(&prune_run, 1, 0)
                })
                .unwrap();
        }
        writer.wait().unwrap();
        let left: Vec<_> = std::fs::read_dir(checkpoint::root(&run))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert_eq!(left, ["0000000300"]);
        std::fs::remove_dir_all(run).unwrap();
    }

    #[test]
    fn a_failed_write_is_reported_by_the_next_call_and_leaves_no_complete_marker() {
        let run = tmp("writer-fail");
        let mut writer = BackgroundWriter::default();
        // A directory where the file `a` should go: its rename fails.
        let dir = checkpoint::dir_for(&run, 100);
        std::fs::create_dir_all(dir.join("a").join("in-the-way")).unwrap();
        writer.submit(files(&run, 100), || Ok(())).unwrap();
        let err = writer
            .submit(files(&run, 200), || Ok(()))
            .unwrap_err()
            .to_string();
        assert!(err.contains(&dir.join("a").display().to_string()), "{err}");
        assert!(!dir.join(checkpoint::COMPLETE).exists());
        // The next checkpoint was not submitted; nothing is in flight.
        writer.wait().unwrap();
        assert!(checkpoint::latest(&run).unwrap().is_none());
        std::fs::remove_dir_all(run).unwrap();
    }
}
