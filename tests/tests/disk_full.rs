//! A full disk during a checkpoint: the run stops with an error that names the checkpoint's
//! step and file, leaves no temporary file, and the previous complete checkpoint still
//! resumes to the uninterrupted run's end. The disk is a small tmpfs the test mounts (as
//! root, as CI runs); where mounting is not allowed the test says so and checks nothing.

use std::path::{Path, PathBuf};
use std::process::Command;

use mbpo_integration_tests::*;
use mbpo_train::{checkpoint, train_mbpo, train_mbpo_with, RunOptions};

/// A tmpfs mounted at a directory of its own, unmounted when dropped.
struct SmallDisk(PathBuf);

impl SmallDisk {
    /// Mount `kib` KiB of tmpfs at `dir`; `None` where this process may not mount.
    fn mount(dir: &Path, kib: u64) -> Option<Self> {
        std::fs::create_dir_all(dir).unwrap();
        let status = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={kib}k"), "tmpfs"])
            .arg(dir)
            .status()
            .ok()?;
        status.success().then(|| Self(dir.to_path_buf()))
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// Every file below `dir` whose name marks a temporary checkpoint file.
fn temporary_files(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            found.extend(temporary_files(&path));
        } else if path.to_string_lossy().contains(".tmp-") {
            found.push(path);
        }
    }
    found
}

#[test]
fn a_full_disk_during_a_checkpoint_names_it_and_keeps_the_previous_one_resumable() {
    let mut cfg = tiny_config(400);
    cfg.checkpoint.every = 100;
    let dir = scratch("disk-full");
    // Checkpoints of this run take about 340, 350, 560 and 740 KiB (D_env grows): with two
    // kept, the third no longer fits in 1100 KiB.
    let Some(disk) = SmallDisk::mount(&dir.join("disk"), 1100) else {
        eprintln!("SKIPPED: cannot mount a tmpfs here (not root?); CI runs this test as root");
        return;
    };
    let run = disk.0.join("run");
    let err = train_mbpo(&cfg, &run).unwrap_err().to_string();
    assert!(
        err.contains("No space left on device") && err.contains("/checkpoints/0000000300/"),
        "{err}"
    );
    assert_eq!(temporary_files(&run), Vec::<PathBuf>::new());
    let (newest, manifest) = checkpoint::latest(&run).unwrap().unwrap();
    assert_eq!(manifest.env_steps, 200, "{}", newest.display());

    // Moved to a disk with room, the run resumes from 200 and ends as an uninterrupted one.
    let moved = dir.join("moved");
    copy_dir(&run, &moved);
    drop(disk);
    let resume = RunOptions {
        resume: true,
        ..Default::default()
    };
    let resumed = train_mbpo_with(&cfg, &moved, resume).unwrap();
    let uninterrupted = train_mbpo(&cfg, &dir.join("uninterrupted")).unwrap();
    assert_eq!(resumed.policy_sha256, uninterrupted.policy_sha256);
    assert_eq!(
        metrics_without_timing(&moved),
        metrics_without_timing(&dir.join("uninterrupted"))
    );
    let _ = std::fs::remove_dir_all(dir);
}
