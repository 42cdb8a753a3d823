//! Writes a run directory the way a resumed run does, for `tools/check_tensorboard.sh`:
//! rows at steps 100..=500, then `RunDir::reopen` after step 300 (as a resume from a checkpoint
//! at step 300 would) and rows at 400..=600 with new values. TensorBoard must show the first
//! run's points up to 300 and the resumed run's from 400 on.
//!
//! Usage: `cargo run -p mbpo-train --example tb_resume_fixture -- <run dir>`

use mbpo_train::run_dir::MetricsRow;
use mbpo_train::{ExperimentConfig, RunDir};
use std::path::PathBuf;

fn row(step: u64, eval_return: f64) -> MetricsRow {
    MetricsRow {
        env_steps: step,
        eval_return,
        alpha: Some(1.0 / step as f64),
        ..Default::default()
    }
}

fn main() -> std::io::Result<()> {
    let dir: PathBuf = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .ok_or_else(|| std::io::Error::other("usage: tb_resume_fixture <run dir>"))?;
    let _ = std::fs::remove_dir_all(&dir);
    {
        let mut first = RunDir::create(&dir, &ExperimentConfig::default())?;
        for step in (100..=500).step_by(100) {
            first.write_metrics(&row(step, -(step as f64)))?;
        }
    }
    // Event file names carry the creation second: make the resumed file sort after the first,
    // as it would after any real restart.
    std::thread::sleep(std::time::Duration::from_millis(1100));
    let mut resumed = RunDir::reopen(&dir, 300)?;
    for step in (400..=600).step_by(100) {
        resumed.write_metrics(&row(step, step as f64))?;
    }
    println!("{}", dir.display());
    Ok(())
}
