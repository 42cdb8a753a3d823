//! The run directory: `config.toml` (resolved), `metrics.csv`, `summary.json`.
//!
//! `metrics.csv` has one row per evaluation with a fixed set of columns (empty where a column
//! does not apply to the algorithm), so every run can be plotted and compared the same way.

use crate::config::ExperimentConfig;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Columns of `metrics.csv`, in order.
pub const METRIC_COLUMNS: &[&str] = &[
    "env_steps",
    "episodes",
    "eval_return",
    "train_return",
    "sac_updates",
    "critic_loss",
    "actor_loss",
    "alpha",
    "entropy",
    "q_mean",
    "model_holdout_mse",
    "rollout_length",
    "model_buffer",
    "wall_seconds",
    "env_steps_per_sec",
];

/// One row of `metrics.csv`; `None` prints as an empty cell.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MetricsRow {
    /// Real environment steps so far.
    pub env_steps: u64,
    /// Finished training episodes.
    pub episodes: u64,
    /// Mean deterministic evaluation return.
    pub eval_return: f64,
    /// Return of the last finished training episode.
    pub train_return: Option<f64>,
    /// SAC updates so far.
    pub sac_updates: u64,
    /// Critic loss of the last update.
    pub critic_loss: Option<f64>,
    /// Actor loss of the last update.
    pub actor_loss: Option<f64>,
    /// Temperature α.
    pub alpha: Option<f64>,
    /// Policy entropy estimate.
    pub entropy: Option<f64>,
    /// Mean Q₁ on the last batch.
    pub q_mean: Option<f64>,
    /// Mean elite holdout MSE of the last model training (MBPO).
    pub model_holdout_mse: Option<f64>,
    /// Current rollout length k (MBPO).
    pub rollout_length: Option<f64>,
    /// Transitions in the model buffer (MBPO).
    pub model_buffer: Option<f64>,
    /// Seconds since the run started.
    pub wall_seconds: f64,
    /// Env steps per second since the last row.
    pub env_steps_per_sec: f64,
}

impl MetricsRow {
    fn cells(&self) -> Vec<String> {
        let opt = |v: Option<f64>| v.map(|x| format!("{x}")).unwrap_or_default();
        vec![
            self.env_steps.to_string(),
            self.episodes.to_string(),
            format!("{}", self.eval_return),
            opt(self.train_return),
            self.sac_updates.to_string(),
            opt(self.critic_loss),
            opt(self.actor_loss),
            opt(self.alpha),
            opt(self.entropy),
            opt(self.q_mean),
            opt(self.model_holdout_mse),
            opt(self.rollout_length),
            opt(self.model_buffer),
            format!("{:.3}", self.wall_seconds),
            format!("{:.1}", self.env_steps_per_sec),
        ]
    }
}

/// What a finished run reports (`summary.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Algorithm.
    pub algo: String,
    /// Environment id.
    pub env: String,
    /// Run seed.
    pub seed: u64,
    /// Real env steps taken.
    pub env_steps: u64,
    /// SAC updates performed.
    pub sac_updates: u64,
    /// Last evaluation return.
    pub final_eval_return: f64,
    /// Best evaluation return.
    pub best_eval_return: f64,
    /// First evaluation point (env steps) with return ≥ −200 (Pendulum's "solved" line), if any.
    pub env_steps_to_minus_200: Option<u64>,
    /// SHA-256 of the final policy parameters (flattened, little-endian f32).
    pub policy_sha256: String,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// Median wall-clock seconds per env step after the warm-up (MBPO), if measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub median_seconds_per_env_step: Option<f64>,
    /// `completed`, or `stopped` (a clean stop before `steps`; resume with `--resume`).
    #[serde(default = "completed")]
    pub status: String,
}

fn completed() -> String {
    "completed".into()
}

/// SHA-256 of parameters as little-endian f32 bytes, hex.
pub fn policy_sha256(params: &[f32]) -> String {
    let mut h = Sha256::new();
    for p in params {
        h.update(p.to_le_bytes());
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// An open run directory.
#[derive(Debug)]
pub struct RunDir {
    path: PathBuf,
    metrics: BufWriter<File>,
}

impl RunDir {
    /// Create `path` (and parents), write the resolved config and the metrics header.
    pub fn create(path: &Path, config: &ExperimentConfig) -> std::io::Result<Self> {
        std::fs::create_dir_all(path)?;
        std::fs::write(path.join("config.toml"), config.to_toml())?;
        let mut metrics = BufWriter::new(File::create(path.join("metrics.csv"))?);
        writeln!(metrics, "{}", METRIC_COLUMNS.join(","))?;
        metrics.flush()?;
        Ok(Self {
            path: path.to_path_buf(),
            metrics,
        })
    }

    /// Reopen the directory of a run resumed from its checkpoint after `env_steps`: rows of
    /// `metrics.csv` written after that checkpoint are dropped (the resumed run writes them
    /// again), the resolved config is rewritten (its `steps` may have been extended).
    pub fn resume(path: &Path, config: &ExperimentConfig, env_steps: u64) -> std::io::Result<Self> {
        let metrics_path = path.join("metrics.csv");
        let text = std::fs::read_to_string(&metrics_path)?;
        let mut lines = text.lines();
        let header = lines.next().unwrap_or_default();
        if header != METRIC_COLUMNS.join(",") {
            return Err(std::io::Error::other(format!(
                "{}: header is `{header}`, expected `{}` (written by another version?)",
                metrics_path.display(),
                METRIC_COLUMNS.join(",")
            )));
        }
        let mut kept = format!("{header}\n");
        for line in lines {
            let steps: Option<u64> = line.split(',').next().and_then(|c| c.parse().ok());
            if steps.is_some_and(|s| s <= env_steps) {
                kept.push_str(line);
                kept.push('\n');
            }
        }
        let tmp = path.join("metrics.csv.tmp");
        std::fs::write(&tmp, kept)?;
        std::fs::rename(&tmp, &metrics_path)?;
        std::fs::write(path.join("config.toml"), config.to_toml())?;
        let metrics = BufWriter::new(
            std::fs::OpenOptions::new()
                .append(true)
                .open(&metrics_path)?,
        );
        Ok(Self {
            path: path.to_path_buf(),
            metrics,
        })
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Append one metrics row (flushed, so a crash loses nothing written).
    pub fn write_metrics(&mut self, row: &MetricsRow) -> std::io::Result<()> {
        writeln!(self.metrics, "{}", row.cells().join(","))?;
        self.metrics.flush()
    }

    /// Write `summary.json` atomically (temporary file, then rename).
    pub fn write_summary(&self, summary: &Summary) -> std::io::Result<()> {
        let tmp = self.path.join("summary.json.tmp");
        std::fs::write(&tmp, serde_json::to_string_pretty(summary)? + "\n")?;
        std::fs::rename(tmp, self.path.join("summary.json"))
    }
}

/// Read one column of a `metrics.csv` back as (env_steps, value) pairs (rows where it is empty
/// are skipped).
pub fn read_metric_curve(path: &Path, column: &str) -> std::io::Result<Vec<(u64, f64)>> {
    let text = std::fs::read_to_string(path)?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (Some(s), Some(c)) = (col("env_steps"), col(column)) else {
        return Err(std::io::Error::other(format!(
            "{}: no env_steps/{column} columns",
            path.display()
        )));
    };
    Ok(lines
        .filter_map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            Some((cells.get(s)?.parse().ok()?, cells.get(c)?.parse().ok()?))
        })
        .collect())
}

/// Read a `metrics.csv` back as (env_steps, eval_return) pairs.
pub fn read_eval_curve(path: &Path) -> std::io::Result<Vec<(u64, f64)>> {
    let text = std::fs::read_to_string(path)?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let (Some(s), Some(r)) = (col("env_steps"), col("eval_return")) else {
        return Err(std::io::Error::other(format!(
            "{}: no env_steps/eval_return columns",
            path.display()
        )));
    };
    Ok(lines
        .filter_map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            Some((cells.get(s)?.parse().ok()?, cells.get(r)?.parse().ok()?))
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sha_of_params_is_stable_and_sensitive() {
        let a = policy_sha256(&[1.0, 2.0]);
        assert_eq!(a.len(), 64);
        assert_eq!(a, policy_sha256(&[1.0, 2.0]));
        assert_ne!(a, policy_sha256(&[1.0, 2.0000002]));
        // SHA-256 of the 8 bytes 00 00 80 3f 00 00 00 40 (1.0f32, 2.0f32 little-endian).
        let mut h = Sha256::new();
        h.update([0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0x40]);
        let want: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(a, want);
    }

    #[test]
    fn metrics_round_trip_through_csv() {
        let dir = std::env::temp_dir().join(format!("mbpo-rundir-{}", std::process::id()));
        let mut run = RunDir::create(&dir, &ExperimentConfig::default()).unwrap();
        for i in 1..=3 {
            run.write_metrics(&MetricsRow {
                env_steps: i * 100,
                eval_return: -(i as f64) * 10.5,
                ..Default::default()
            })
            .unwrap();
        }
        let curve = read_eval_curve(&dir.join("metrics.csv")).unwrap();
        assert_eq!(curve, vec![(100, -10.5), (200, -21.0), (300, -31.5)]);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
