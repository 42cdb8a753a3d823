//! The run directory: `config.toml` (resolved), `metrics.csv`, `tb/` (TensorBoard event
//! files), `summary.json`.
//!
//! `metrics.csv` has one row per evaluation with a fixed set of columns (empty where a column
//! does not apply to the algorithm), so every run can be plotted and compared the same way.
//! Every row is also written as TensorBoard scalars (tags in [`TENSORBOARD_TAGS`], step =
//! env steps), flushed at once, so `tensorboard --logdir runs` shows a run while it trains.

use crate::tensorboard::EventWriter;
use mbpo_config::ExperimentConfig;
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
    "updates_per_sec",
    "consistency_loss",
    "reward_loss",
];

/// The columns added to `metrics.csv` on 2026-12-06 (TD-MPC2's world model). A run written
/// before has every other column, in this order, and none of these: resuming it rewrites its
/// rows with them empty ([`RunDir::reopen`]), so the lanes that span versions continue.
const ADDED_COLUMNS: &[&str] = &["consistency_loss", "reward_loss"];

/// Whether `found` is the header of a run written before [`ADDED_COLUMNS`].
fn is_earlier_header(found: &[&str]) -> bool {
    let earlier = METRIC_COLUMNS.iter().filter(|c| !ADDED_COLUMNS.contains(c));
    found.iter().eq(earlier)
}

/// The TensorBoard tag of each `metrics.csv` column (`env_steps` is the step of every scalar).
pub const TENSORBOARD_TAGS: &[(&str, &str)] = &[
    ("episodes", "train/episodes"),
    ("eval_return", "eval/return"),
    ("train_return", "train/return"),
    ("sac_updates", "sac/updates"),
    ("critic_loss", "sac/critic_loss"),
    ("actor_loss", "sac/actor_loss"),
    ("alpha", "sac/alpha"),
    ("entropy", "sac/entropy"),
    ("q_mean", "sac/q_mean"),
    ("model_holdout_mse", "model/holdout_mse"),
    ("rollout_length", "model/rollout_length"),
    ("model_buffer", "model/buffer"),
    ("wall_seconds", "speed/wall_seconds"),
    ("env_steps_per_sec", "speed/env_steps_per_sec"),
    ("updates_per_sec", "speed/updates_per_sec"),
    ("consistency_loss", "world_model/consistency_loss"),
    ("reward_loss", "world_model/reward_loss"),
];

/// Sub-directory of the run directory that holds the TensorBoard event files.
pub const TENSORBOARD_DIR: &str = "tb";

/// File name of the final policy in a run directory (written by `policy_file` when a run
/// completes).
pub const FINAL_POLICY_FILE: &str = "policy.ckpt";

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
    /// The value function's loss in the last update: SAC's critic MSE, TD-MPC2's Q heads'
    /// two-hot cross-entropy.
    pub critic_loss: Option<f64>,
    /// The policy's loss in the last update: SAC's actor, TD-MPC2's policy prior.
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
    /// SAC updates per second since the last row.
    pub updates_per_sec: f64,
    /// The latent dynamics' consistency loss in the last update (TD-MPC2).
    pub consistency_loss: Option<f64>,
    /// The reward head's two-hot cross-entropy in the last update (TD-MPC2).
    pub reward_loss: Option<f64>,
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
            format!("{:.1}", self.updates_per_sec),
            opt(self.consistency_loss),
            opt(self.reward_loss),
        ]
    }

    /// Every column but `env_steps` as (TensorBoard tag, value), in column order; empty cells
    /// are left out.
    fn scalars(&self) -> Vec<(&'static str, f32)> {
        let values = [
            Some(self.episodes as f64),
            Some(self.eval_return),
            self.train_return,
            Some(self.sac_updates as f64),
            self.critic_loss,
            self.actor_loss,
            self.alpha,
            self.entropy,
            self.q_mean,
            self.model_holdout_mse,
            self.rollout_length,
            self.model_buffer,
            Some(self.wall_seconds),
            Some(self.env_steps_per_sec),
            Some(self.updates_per_sec),
            self.consistency_loss,
            self.reward_loss,
        ];
        TENSORBOARD_TAGS
            .iter()
            .zip(values)
            .filter_map(|(&(_, tag), v)| Some((tag, v? as f32)))
            .collect()
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
    /// The eval return counted as solving the task ([`ExperimentConfig::target_return`]).
    #[serde(default)]
    pub target_return: Option<f64>,
    /// First evaluation point (env steps) with return ≥ `target_return`, if any.
    #[serde(default)]
    pub env_steps_to_target: Option<u64>,
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
    /// Episodes that resumes cut short: an environment that cannot save its state (e.g. a
    /// Python env) starts a new episode when its actor resumes from a checkpoint.
    #[serde(default)]
    pub episodes_cut_by_resume: u64,
    /// Episodes lost because the process hosting the environment (a Python env) exited: the
    /// actor started a new process and a new episode.
    #[serde(default)]
    pub episodes_lost_to_env_exit: u64,
}

fn completed() -> String {
    "completed".into()
}

/// The first evaluation point of `curve` (env steps, return) whose return reaches `target`
/// (never, when there is no target).
pub fn env_steps_to_target(curve: &[(u64, f64)], target: Option<f64>) -> Option<u64> {
    let target = target?;
    curve.iter().find(|&&(_, r)| r >= target).map(|&(s, _)| s)
}

/// SHA-256 of parameters as little-endian f32 bytes, hex.
pub fn policy_sha256(params: &[f32]) -> String {
    let mut h = Sha256::new();
    for p in params {
        h.update(p.to_le_bytes());
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// Remove the TensorBoard event files in `dir` (nothing else; a missing `dir` is fine).
fn remove_event_files(dir: &Path) -> std::io::Result<()> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e),
    };
    for entry in entries {
        let entry = entry?;
        if entry
            .file_name()
            .to_string_lossy()
            .starts_with("events.out.tfevents.")
        {
            std::fs::remove_file(entry.path())?;
        }
    }
    Ok(())
}

/// The file describing a run's environment as the run saw it (`env.json`).
pub const ENV_FILE: &str = "env.json";

/// Write `<dir>/env.json`: the environment's id, spaces, time limit, whether it can save its
/// state, and the parts of a flattened Dict observation (a Python env's), so the run's
/// observation columns can be read back by name.
pub fn write_env_file(dir: &Path, env: &dyn mbpo_envs::Env) -> std::io::Result<()> {
    let finite =
        |v: &[f32]| -> Vec<Option<f32>> { v.iter().map(|&x| x.is_finite().then_some(x)).collect() };
    let text = serde_json::to_string_pretty(&serde_json::json!({
        "id": env.id(),
        "obs_dim": env.obs_dim(),
        "act_dim": env.act_dim(),
        "observation_low": finite(&env.observation_space().low),
        "observation_high": finite(&env.observation_space().high),
        "action_low": env.action_space().low,
        "action_high": env.action_space().high,
        "max_episode_steps": env.max_episode_steps(),
        "restorable": env.restorable().is_some(),
        "observation_parts": env.observation_parts(),
    }))?;
    std::fs::create_dir_all(dir)?;
    std::fs::write(dir.join(ENV_FILE), text + "\n")
}

/// Whether `dir` holds what a run wrote: a `metrics.csv` of ours (its header starts with
/// `env_steps,`) or a complete checkpoint. A directory that merely has a `config.toml` or a
/// `logs/` folder (a project directory, say) does not count.
pub fn holds_a_run(dir: &Path) -> bool {
    let ours = File::open(dir.join("metrics.csv")).is_ok_and(|f| {
        let mut header = String::new();
        std::io::BufRead::read_line(&mut std::io::BufReader::new(f), &mut header).is_ok()
            && header.starts_with("env_steps,")
    });
    ours || crate::checkpoint::latest(dir).is_ok_and(|c| c.is_some())
}

/// Whether `name` is a log file a run writes into `logs/`: `train.log` (`mbpo train`),
/// `supervisor.log` and one per service process (`mbpo run`).
fn is_run_log(name: &str) -> bool {
    let Some(stem) = name.strip_suffix(".log") else {
        return false;
    };
    let numbered = |prefix: &str| {
        stem.strip_prefix(prefix)
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    };
    let role = mbpo_core::roles::ROLES.iter().any(|r| match r.numbered {
        true => numbered(&format!("{}-", r.wire.name())),
        false => stem == r.wire.name(),
    });
    role || stem == "train" || stem == mbpo_core::roles::Role::Supervisor.name()
}

/// Remove what an earlier run wrote into `dir` and a fresh run would not overwrite: its
/// checkpoint directories, its logs in `logs/`, `summary.json` and `policy.ckpt` (nothing else:
/// `--overwrite` must not take a user's files with it). `config.toml`, `metrics.csv` and the
/// TensorBoard files are replaced by [`RunDir::create`].
pub fn remove_earlier_run(dir: &Path) -> std::io::Result<()> {
    let not_found_ok = |r: std::io::Result<()>| match r {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    };
    let checkpoints = crate::checkpoint::root(dir);
    if let Ok(entries) = std::fs::read_dir(&checkpoints) {
        for entry in entries {
            let path = entry?.path();
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            let is_checkpoint =
                name.is_some_and(|n| n.len() == 10 && n.bytes().all(|b| b.is_ascii_digit()));
            if is_checkpoint && path.is_dir() {
                std::fs::remove_dir_all(&path)?;
            }
        }
        let _ = std::fs::remove_dir(&checkpoints); // only when empty
    }
    let logs = dir.join("logs");
    if let Ok(entries) = std::fs::read_dir(&logs) {
        for entry in entries {
            let path = entry?.path();
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            if name.is_some_and(|n| is_run_log(&n)) && path.is_file() {
                std::fs::remove_file(&path)?;
            }
        }
        let _ = std::fs::remove_dir(&logs); // only when empty
    }
    not_found_ok(std::fs::remove_file(dir.join("summary.json")))?;
    not_found_ok(std::fs::remove_file(dir.join(FINAL_POLICY_FILE)))?;
    tracing::info!("--overwrite: removed the earlier run in {}", dir.display());
    Ok(())
}

/// An open run directory.
#[derive(Debug)]
pub struct RunDir {
    path: PathBuf,
    metrics: BufWriter<File>,
    tensorboard: EventWriter,
}

impl RunDir {
    /// Create `path` (and parents) for a fresh run: write the resolved config and the metrics
    /// header, remove the event files of an earlier run in the same directory (as
    /// `metrics.csv` is overwritten, so TensorBoard does not mix two runs), and start a new
    /// event file in `path/tb/` that begins with a session start.
    pub fn create(path: &Path, config: &ExperimentConfig) -> std::io::Result<Self> {
        std::fs::create_dir_all(path)?;
        // An earlier run's final policy would pass for this run's (`mbpo eval`).
        match std::fs::remove_file(path.join(FINAL_POLICY_FILE)) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
            _ => {}
        }
        std::fs::write(path.join("config.toml"), config.to_toml())?;
        let mut metrics = BufWriter::new(File::create(path.join("metrics.csv"))?);
        writeln!(metrics, "{}", METRIC_COLUMNS.join(","))?;
        metrics.flush()?;
        let tb = path.join(TENSORBOARD_DIR);
        remove_event_files(&tb)?;
        let mut tensorboard = EventWriter::create(&tb)?;
        // TensorBoard's server takes a run's first START as its beginning and purges on later
        // ones; without this one, the START of a resume would be taken as the first.
        tensorboard.session_start(0)?;
        Ok(Self {
            path: path.to_path_buf(),
            metrics,
            tensorboard,
        })
    }

    /// Reopen the run directory of a run resumed after env step `resume_step`: keep the
    /// `metrics.csv` rows up to that step (later rows belong to the abandoned continuation of
    /// the checkpoint), append after them, and start a new TensorBoard file that begins with a
    /// restart marker at `resume_step + 1`, so TensorBoard drops the old files' later points.
    /// `config.toml` is left alone.
    pub fn reopen(path: &Path, resume_step: u64) -> std::io::Result<Self> {
        let csv = path.join("metrics.csv");
        let text = std::fs::read_to_string(&csv)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", csv.display())))?;
        let kept = rows_up_to(&csv, &text, resume_step)?;
        let tmp = path.join("metrics.csv.tmp");
        std::fs::write(&tmp, kept)?;
        std::fs::rename(&tmp, &csv)?;
        let metrics = BufWriter::new(File::options().append(true).open(&csv)?);
        let mut tensorboard = EventWriter::create(&path.join(TENSORBOARD_DIR))?;
        tensorboard.session_start(resume_step as i64 + 1)?;
        Ok(Self {
            path: path.to_path_buf(),
            metrics,
            tensorboard,
        })
    }

    /// Reopen the directory of a run resumed from its checkpoint after `env_steps`
    /// ([`RunDir::reopen`]) and rewrite its resolved config (`steps` may have been extended).
    pub fn reopen_with_config(
        path: &Path,
        config: &ExperimentConfig,
        env_steps: u64,
    ) -> std::io::Result<Self> {
        let run = Self::reopen(path, env_steps)?;
        std::fs::write(path.join("config.toml"), config.to_toml())?;
        Ok(run)
    }

    /// The first evaluation of this run at `target`, read off its metrics rows: derived rather
    /// than tracked, so a resumed run counts the rows of every attempt alike.
    pub fn env_steps_to_target(&mut self, target: Option<f64>) -> std::io::Result<Option<u64>> {
        self.metrics.flush()?;
        let curve = read_eval_curve(&self.path.join("metrics.csv"))?;
        Ok(env_steps_to_target(&curve, target))
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The TensorBoard event file this run writes.
    pub fn tensorboard_file(&self) -> &Path {
        self.tensorboard.path()
    }

    /// Append one metrics row to `metrics.csv` and as scalars to the TensorBoard file (both
    /// flushed, so a crash loses nothing written and a live TensorBoard sees the row).
    pub fn write_metrics(&mut self, row: &MetricsRow) -> std::io::Result<()> {
        writeln!(self.metrics, "{}", row.cells().join(","))?;
        self.metrics.flush()?;
        self.tensorboard
            .add_scalars(row.env_steps as i64, &row.scalars())
    }

    /// Write `summary.json` atomically (temporary file, then rename).
    pub fn write_summary(&self, summary: &Summary) -> std::io::Result<()> {
        let tmp = self.path.join("summary.json.tmp");
        std::fs::write(&tmp, serde_json::to_string_pretty(summary)? + "\n")?;
        std::fs::rename(tmp, self.path.join("summary.json"))
    }
}

/// The text of a `metrics.csv` (`path`, for errors) cut after the rows up to `resume_step`,
/// under this version's header: a file of an earlier version ([`is_earlier_header`]) has
/// its cells moved under their columns and the new columns left empty; any other header is
/// refused by name.
fn rows_up_to(path: &Path, text: &str, resume_step: u64) -> std::io::Result<String> {
    let mut lines = text.lines();
    let header = lines.next().unwrap_or_default();
    let want = METRIC_COLUMNS.join(",");
    let found: Vec<&str> = header.split(',').collect();
    let bad = |message: String| {
        let message = format!("{}: {message}", path.display());
        std::io::Error::new(std::io::ErrorKind::InvalidData, message)
    };
    let earlier = is_earlier_header(&found);
    if header != want && !earlier {
        return Err(bad(format!(
            "header does not match this version's columns; expected `{want}`, found `{header}`"
        )));
    }
    // Where each of this version's columns is in the file's rows (None: a new column).
    let source: Vec<Option<usize>> = METRIC_COLUMNS
        .iter()
        .map(|c| found.iter().position(|f| f == c))
        .collect();
    let mut kept = format!("{want}\n");
    for (i, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        // Later rows (or a row cut short by a crash) belong to the abandoned continuation.
        if !cells[0].parse::<u64>().is_ok_and(|s| s <= resume_step) {
            continue;
        }
        if cells.len() != found.len() {
            let n = cells.len();
            return Err(bad(format!(
                "line {}: {n} cells under {} columns",
                i + 2,
                found.len()
            )));
        }
        let moved: Vec<&str> = source.iter().map(|c| c.map_or("", |c| cells[c])).collect();
        kept += &moved.join(",");
        kept.push('\n');
    }
    if earlier {
        tracing::info!("{}: rewritten with this version's columns", path.display());
    }
    Ok(kept)
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
    fn overwrite_removes_only_what_a_run_wrote() {
        let dir = std::env::temp_dir().join(format!("run-dir-overwrite-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // A project directory with a config.toml and a logs/ folder is not a run.
        std::fs::create_dir_all(dir.join("logs")).unwrap();
        std::fs::write(dir.join("config.toml"), "steps = 1\n").unwrap();
        std::fs::write(dir.join("logs/notes.txt"), "mine").unwrap();
        std::fs::write(dir.join("logs/my-tool.log"), "mine").unwrap();
        assert!(!holds_a_run(&dir));

        let run = RunDir::create(&dir, &ExperimentConfig::default()).unwrap();
        drop(run);
        assert!(holds_a_run(&dir), "our metrics.csv makes it a run");
        let ckpt = crate::checkpoint::dir_for(&dir, 500);
        std::fs::create_dir_all(&ckpt).unwrap();
        crate::checkpoint::mark_complete(&ckpt, 500, &[]).unwrap();
        std::fs::write(crate::checkpoint::root(&dir).join("README"), "mine").unwrap();
        std::fs::write(dir.join("logs/train.log"), "old log").unwrap();
        std::fs::write(dir.join("logs/actor-12.log"), "old log").unwrap();
        std::fs::write(dir.join("summary.json"), "{}").unwrap();
        std::fs::write(dir.join(FINAL_POLICY_FILE), "old").unwrap();

        remove_earlier_run(&dir).unwrap();
        assert!(!ckpt.exists() && !dir.join("logs/train.log").exists());
        assert!(!dir.join("logs/actor-12.log").exists());
        assert!(!dir.join("summary.json").exists());
        assert!(!dir.join(FINAL_POLICY_FILE).exists());
        for kept in [
            "logs/notes.txt",
            "logs/my-tool.log",
            "checkpoints/README",
            "config.toml",
        ] {
            assert!(
                dir.join(kept).is_file(),
                "{kept} is not the run's to remove"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

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

    #[test]
    fn every_column_but_the_step_has_a_tensorboard_tag_in_column_order() {
        let columns: Vec<&str> = TENSORBOARD_TAGS.iter().map(|t| t.0).collect();
        assert_eq!(columns, METRIC_COLUMNS[1..]);
        let tags: std::collections::BTreeSet<&str> = TENSORBOARD_TAGS.iter().map(|t| t.1).collect();
        assert_eq!(tags.len(), TENSORBOARD_TAGS.len(), "tags must be unique");
        // A row with every value distinct lands under the right tag.
        let row = MetricsRow {
            env_steps: 1,
            episodes: 2,
            eval_return: 3.0,
            train_return: Some(4.0),
            sac_updates: 5,
            critic_loss: Some(6.0),
            actor_loss: Some(7.0),
            alpha: Some(8.0),
            entropy: Some(9.0),
            q_mean: Some(10.0),
            model_holdout_mse: Some(11.0),
            rollout_length: Some(12.0),
            model_buffer: Some(13.0),
            wall_seconds: 14.0,
            env_steps_per_sec: 15.0,
            updates_per_sec: 16.0,
            consistency_loss: Some(17.0),
            reward_loss: Some(18.0),
        };
        let cells = row.cells();
        assert_eq!(cells.len(), METRIC_COLUMNS.len());
        for ((tag, v), (column, cell)) in row
            .scalars()
            .iter()
            .zip(METRIC_COLUMNS.iter().zip(&cells).skip(1))
        {
            assert_eq!(*v as f64, cell.parse::<f64>().unwrap(), "{column} -> {tag}");
        }
        assert_eq!(row.scalars().len(), TENSORBOARD_TAGS.len());
    }

    fn tb_scalars(dir: &Path) -> Vec<(i64, String, f32)> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir.join(TENSORBOARD_DIR))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        let mut out = Vec::new();
        for f in files {
            for e in crate::tensorboard::read::file(&f).unwrap() {
                if e.session_status.is_some() {
                    out.push((e.step, "START".into(), f32::NAN));
                }
                out.extend(e.scalars.into_iter().map(|(t, v)| (e.step, t, v)));
            }
        }
        out
    }

    #[test]
    fn metrics_rows_land_in_tensorboard_and_a_reopened_run_appends() {
        let dir = std::env::temp_dir().join(format!("mbpo-rundir-tb-{}", std::process::id()));
        let row = |t: u64, ret: f64| MetricsRow {
            env_steps: t,
            eval_return: ret,
            critic_loss: (t > 100).then_some(0.5),
            ..Default::default()
        };
        {
            let mut run = RunDir::create(&dir, &ExperimentConfig::default()).unwrap();
            for t in [100, 200, 300] {
                run.write_metrics(&row(t, -(t as f64))).unwrap();
            }
            // Flushed per row: readable while the run is still open.
            let ret: Vec<(i64, f32)> = tb_scalars(&dir)
                .into_iter()
                .filter(|s| s.1 == "eval/return")
                .map(|s| (s.0, s.2))
                .collect();
            assert_eq!(ret, vec![(100, -100.0), (200, -200.0), (300, -300.0)]);
            let losses = tb_scalars(&dir)
                .into_iter()
                .filter(|s| s.1 == "sac/critic_loss")
                .count();
            assert_eq!(losses, 2, "empty cells are not written as scalars");
        }
        // Resume after step 200 (the row of 300 is dropped, the new 300 appended).
        std::thread::sleep(std::time::Duration::from_millis(5));
        let mut run = RunDir::reopen(&dir, 200).unwrap();
        // Both files start with a session start: the first marks the run's beginning (the
        // TensorBoard server ignores a run's first), the second the restart after step 200.
        run.write_metrics(&row(300, 3.0)).unwrap();
        run.write_metrics(&row(400, 4.0)).unwrap();
        let curve = read_eval_curve(&dir.join("metrics.csv")).unwrap();
        assert_eq!(
            curve,
            vec![(100, -100.0), (200, -200.0), (300, 3.0), (400, 4.0)]
        );
        let all = tb_scalars(&dir);
        let files = std::fs::read_dir(dir.join(TENSORBOARD_DIR))
            .unwrap()
            .count();
        assert_eq!(files, 2, "a resumed run writes a new event file");
        let starts: Vec<usize> = (0..all.len()).filter(|&i| all[i].1 == "START").collect();
        assert_eq!(starts.len(), 2, "{all:?}");
        assert_eq!((starts[0], all[starts[0]].0), (0, 0));
        assert_eq!(all[starts[1]].0, 201);
        assert!(all[starts[1] + 1..].iter().all(|s| s.0 >= 300));
        drop(run);

        // A fresh run in the same directory replaces the old event files, as it does metrics.csv.
        let mut run = RunDir::create(&dir, &ExperimentConfig::default()).unwrap();
        run.write_metrics(&row(100, 7.0)).unwrap();
        let files = std::fs::read_dir(dir.join(TENSORBOARD_DIR))
            .unwrap()
            .count();
        assert_eq!(files, 1);
        let ret: Vec<(i64, f32)> = tb_scalars(&dir)
            .into_iter()
            .filter(|s| s.1 == "eval/return")
            .map(|s| (s.0, s.2))
            .collect();
        assert_eq!(ret, vec![(100, 7.0)]);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn reopen_moves_an_earlier_versions_rows_under_the_new_columns() {
        let dir = std::env::temp_dir().join(format!("mbpo-rundir-v1-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // The header runs were written with until 2026-12-06 (as a resumed run finds it).
        let header = "env_steps,episodes,eval_return,train_return,sac_updates,critic_loss,actor_loss,alpha,entropy,q_mean,model_holdout_mse,rollout_length,model_buffer,wall_seconds,env_steps_per_sec,updates_per_sec";
        let earlier: Vec<&str> = header.split(',').collect();
        // Row i holds the value i*100 + (its column's index) in every cell.
        let row = |i: usize| -> String {
            let cells: Vec<String> = (0..earlier.len())
                .map(|c| (i * 100 + c).to_string())
                .collect();
            cells.join(",")
        };
        let text = format!(
            "{}\n{}\n{}\n{}\n",
            earlier.join(","),
            row(1),
            row(2),
            "300,cut"
        );
        std::fs::write(dir.join("metrics.csv"), text).unwrap();
        let mut run = RunDir::reopen(&dir, 250).unwrap();
        run.write_metrics(&MetricsRow {
            env_steps: 300,
            consistency_loss: Some(0.5),
            ..Default::default()
        })
        .unwrap();
        drop(run);
        let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], METRIC_COLUMNS.join(","));
        assert_eq!(lines.len(), 4, "{text}");
        for (i, line) in lines[1..3].iter().enumerate() {
            let i = i + 1;
            for (column, cell) in METRIC_COLUMNS.iter().zip(line.split(',')) {
                let want = match earlier.iter().position(|c| c == column) {
                    Some(c) => (i * 100 + c).to_string(),
                    None => String::new(),
                };
                assert_eq!(cell, want, "row {i}, {column}");
            }
        }
        assert_eq!(
            read_metric_curve(&dir.join("metrics.csv"), "consistency_loss").unwrap(),
            vec![(300, 0.5)]
        );
        // A kept row with fewer cells than the header is refused by line.
        let text = format!("{}\n{}\n100,1\n", earlier.join(","), row(0));
        std::fs::write(dir.join("metrics.csv"), text).unwrap();
        let err = RunDir::reopen(&dir, 250).unwrap_err().to_string();
        assert!(err.contains("line 3: 2 cells under 16 columns"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn reopen_names_a_foreign_header() {
        let dir = std::env::temp_dir().join(format!("mbpo-rundir-old-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("metrics.csv"), "env_steps,eval_return\n100,-5\n").unwrap();
        let err = RunDir::reopen(&dir, 100).unwrap_err().to_string();
        assert!(
            err.contains("metrics.csv")
                && err.contains("expected")
                && err.contains("found `env_steps,eval_return`"),
            "{err}"
        );
        let err = RunDir::reopen(&dir.join("missing"), 100)
            .unwrap_err()
            .to_string();
        assert!(err.contains("missing/metrics.csv"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
