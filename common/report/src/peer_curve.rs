//! Published learning curves of other methods, read from the CSV files their authors share, to
//! put beside ours in plots, tables and results files (`--peer` of `mbpo plot` and `mbpo bench
//! learning`).
//!
//! Two layouts are read, told apart by the header (column order free, extra columns ignored):
//! * `step, reward, seed`: one method on one task, a row per evaluation of a seed
//!   (nicklashansen/tdmpc2 `results/<method>/<task>.csv`).
//! * `exp_name, env_name, seed, metric, env_step, value`: many methods and tasks in one file
//!   (dojeon-ai/SimbaV2 `results/baseline/*.csv`); the rows of `metric` `avg_return` for the
//!   run's task are read, one curve per `exp_name`. `Hopper-v4` and `Hopper_v4` both name Hopper.
//!
//! A curve's point at env steps `s` is the mean ± std (n − 1) over seeds of each seed's last
//! evaluation at or before `s`, at every `s` where some seed evaluated and every seed had got
//! to (a seed whose run ended earlier does not lend its last value to later points). Such
//! curves are sparse ([`Reading::AtPoints`]).

use crate::paper_curve::{PaperCurve, PaperPoint, Reading};
use crate::PlotError;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The metric read from a file with a `metric` column: SimbaV2's evaluation return.
const METRIC: &str = "avg_return";

/// The task of an env id or a peer file's env name, to match them across versions and
/// spellings: `gym:Walker2d-v5`, `Walker2d-v4` and `Walker2d_v4` are all `walker2d`.
pub(crate) fn task_name(env: &str) -> String {
    let id = env
        .rsplit_once(':')
        .map_or(env, |(_, id)| id)
        .replace('_', "-");
    let name = id.split_once("-v").map_or(id.as_str(), |(name, _)| name);
    name.to_lowercase()
}

/// A `--peer` argument, `FILE` or `LABEL=FILE`, as (label, file).
pub fn split_peer_spec(spec: &str) -> (Option<&str>, &str) {
    match spec.split_once('=') {
        Some((label, file)) => (Some(label), file),
        None => (None, spec),
    }
}

/// The curves of `spec` (`FILE`, or `LABEL=FILE` to name them) for the task of `env` (see
/// [`task_name`]; a file of one task, without an env column, is read whatever `env` is).
pub fn read_peer_curves(spec: &str, env: &str) -> Result<Vec<PaperCurve>, PlotError> {
    let (label, path) = split_peer_spec(spec);
    let (label, path) = (label.map(String::from), PathBuf::from(path));
    let bad = |message: String| PlotError::PeerCurves {
        path: path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&path).map_err(|e| bad(e.to_string()))?;
    let runs = parse_runs(&text, &task_name(env)).map_err(&bad)?;
    // Without a method column the method is the label given, else the file's folder
    // (tdmpc2's results/<method>/<task>.csv).
    let method_of_file = label.clone().unwrap_or_else(|| folder_and_stem(&path));
    let methods = runs.len();
    runs.into_iter()
        .map(|(method, (env_name, seeds))| {
            // A label names the file's one method, or prefixes each of several.
            let name = match (&label, method) {
                (Some(label), Some(method)) if methods > 1 => format!("{label} {method}"),
                (None, Some(method)) => method,
                _ => method_of_file.clone(),
            };
            let env_part = env_name.map_or(String::new(), |e| format!(", {e}"));
            let points = points_over_seeds(&seeds);
            if points.is_empty() {
                return Err(bad(format!(
                    "{name}{env_part}: no env steps every seed reached"
                )));
            }
            Ok(PaperCurve {
                label: format!("{name}{env_part} ({} seeds, mean ± std)", seeds.len()),
                points,
                reading: Reading::AtPoints,
            })
        })
        .collect()
}

/// `tdmpc2/walker-walk` for `.../tdmpc2/walker-walk.csv`.
fn folder_and_stem(path: &Path) -> String {
    let part = |p: Option<&std::ffi::OsStr>| p.map(|s| s.to_string_lossy().into_owned());
    let stem = part(path.file_stem()).unwrap_or_default();
    match part(path.parent().and_then(|p| p.file_name())) {
        Some(folder) => format!("{folder}/{stem}"),
        None => stem,
    }
}

/// A method's evaluations of the task: the env name as the file first spells it, and per seed
/// (env steps, return) in file order.
type MethodRuns = (Option<String>, BTreeMap<String, Vec<(u64, f64)>>);

/// The evaluations by method (`None`: a file of one method, without a method column).
type Runs = BTreeMap<Option<String>, MethodRuns>;

/// The columns of a peer file's header.
struct Columns {
    steps: usize,
    value: usize,
    seed: usize,
    method: Option<usize>,
    env: Option<usize>,
    metric: Option<usize>,
}

impl Columns {
    fn of(header: &str) -> Result<Self, String> {
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        let find = |options: &[&str]| names.iter().position(|n| options.contains(n));
        let required = |options: &[&str]| {
            find(options).ok_or_else(|| {
                format!(
                    "no {} column in the header {header:?}: expected `step,reward,seed` \
                     (tdmpc2's results) or `exp_name,env_name,seed,metric,env_step,value` \
                     (SimbaV2's baselines)",
                    options.join(" or ")
                )
            })
        };
        Ok(Columns {
            steps: required(&["step", "env_step"])?,
            value: required(&["reward", "value"])?,
            seed: required(&["seed"])?,
            method: find(&["exp_name"]),
            env: find(&["env_name"]),
            metric: find(&["metric"]),
        })
    }
}

/// The file's evaluations of `task` (every row when the file has no env column).
fn parse_runs(text: &str, task: &str) -> Result<Runs, String> {
    let mut lines = text.lines().enumerate();
    let (_, header) = lines.next().ok_or("the file is empty")?;
    let cols = Columns::of(header)?;
    let mut runs = Runs::new();
    let mut other_envs = std::collections::BTreeSet::new();
    for (i, line) in lines.filter(|(_, l)| !l.trim().is_empty()) {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let field = |c: usize| {
            fields.get(c).copied().ok_or_else(|| {
                format!(
                    "line {}: {} fields, the header has more",
                    i + 1,
                    fields.len()
                )
            })
        };
        if cols
            .metric
            .map(field)
            .transpose()?
            .is_some_and(|m| m != METRIC)
        {
            continue;
        }
        let env = cols.env.map(field).transpose()?;
        if let Some(env) = env.filter(|e| task_name(e) != task) {
            other_envs.insert(env.to_string());
            continue;
        }
        let number = |c: usize| {
            let f = field(c)?;
            f.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("line {}: {f:?} is not a finite number", i + 1))
        };
        let method = cols.method.map(field).transpose()?.map(String::from);
        let (_, seeds) = runs
            .entry(method)
            .or_insert_with(|| (env.map(String::from), BTreeMap::new()));
        let (steps, value) = (number(cols.steps)?.round() as u64, number(cols.value)?);
        seeds
            .entry(field(cols.seed)?.to_string())
            .or_default()
            .push((steps, value));
    }
    if runs.is_empty() {
        return Err(format!(
            "no rows for the task {task:?} (metric {METRIC} where the file has a metric \
             column); its tasks: {}",
            other_envs.into_iter().collect::<Vec<_>>().join(", ")
        ));
    }
    Ok(runs)
}

/// Mean ± std over seeds at every env-step count some seed evaluated at and every seed got to
/// (each seed's last evaluation at or before it).
fn points_over_seeds(seeds: &BTreeMap<String, Vec<(u64, f64)>>) -> Vec<PaperPoint> {
    let mut seeds: Vec<Vec<(u64, f64)>> = seeds.values().cloned().collect();
    for s in &mut seeds {
        s.sort_by_key(|p| p.0);
    }
    let reached = seeds
        .iter()
        .map(|s| s.last().map_or(0, |p| p.0))
        .min()
        .unwrap_or(0);
    let steps: std::collections::BTreeSet<u64> = seeds
        .iter()
        .flatten()
        .map(|p| p.0)
        .filter(|&s| s <= reached)
        .collect();
    steps
        .into_iter()
        .filter_map(|at| {
            let values: Vec<f64> = seeds
                .iter()
                .map(|s| s.iter().rev().find(|p| p.0 <= at).map(|p| p.1))
                .collect::<Option<_>>()?;
            let n = values.len() as f64;
            let mean = values.iter().sum::<f64>() / n;
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
            Some(PaperPoint {
                env_steps: at,
                mean,
                std: var.sqrt(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("mbpo-peers-{}", std::process::id()));
        let path = dir.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn a_tdmpc2_file_gives_one_curve_over_its_seeds_at_the_steps_all_reached() {
        // Seed 2 has no evaluation at 0 and seed 1 stops at 200k: the curve has 100k and 200k.
        let path = write(
            "dreamerv3/walker-walk.csv",
            "step,reward,seed\n0,48.8,3\n100000,569.4,3\n200000,700,3\n300000,800,3\n\
             100000,651.8,2\n200000,749.4,2\n300000,900,2\n100000,669.2,1\n200000,855.3,1\n",
        );
        let curves = read_peer_curves(path.to_str().unwrap(), "gym:dmc_env:make").unwrap();
        assert_eq!(curves.len(), 1);
        let c = &curves[0];
        assert_eq!(c.label, "dreamerv3/walker-walk (3 seeds, mean ± std)");
        let steps: Vec<u64> = c.points.iter().map(|p| p.env_steps).collect();
        assert_eq!(steps, [100_000, 200_000]);
        let (a, b, d) = (569.4, 651.8, 669.2);
        let mean = (a + b + d) / 3.0;
        let std = (((a - mean) * (a - mean) + (b - mean) * (b - mean) + (d - mean) * (d - mean))
            / 2.0f64)
            .sqrt();
        assert!((c.points[0].mean - mean).abs() < 1e-9 && (c.points[0].std - std).abs() < 1e-9);
        // Sparse: read at a point or just before one, nowhere between.
        assert_eq!(c.at(100_000), Some(c.points[0]));
        assert_eq!(c.at(100_500), Some(c.points[0]));
        assert_eq!(c.at(150_000), None);
        assert_eq!(c.at(50_000), None);
        let named = read_peer_curves(&format!("DreamerV3={}", path.display()), "x").unwrap();
        assert!(
            named[0].label.starts_with("DreamerV3 (3 seeds"),
            "{}",
            named[0].label
        );
    }

    #[test]
    fn a_simbav2_file_gives_a_curve_per_method_of_the_task_in_either_spelling() {
        let path = write(
            "baseline/sac.csv",
            ",exp_name,env_name,seed,metric,env_step,value\n\
             0,sac,Walker2d-v4,0,avg_return,1.0,-5\n\
             1,sac,Walker2d-v4,0,avg_return,99996.0,700\n\
             2,sac,Walker2d_v4,1,avg_return,1.0,-3\n\
             3,sac,Walker2d_v4,1,avg_return,99996.0,600\n\
             4,sac,Walker2d-v4,1,avg_length,99996.0,1000\n\
             5,sac,Hopper-v4,0,avg_return,99996.0,1100\n",
        );
        let curves = read_peer_curves(path.to_str().unwrap(), "Walker2d-v5").unwrap();
        // The two spellings name one task: one curve over both seeds, named as first spelled.
        assert_eq!(curves.len(), 1, "{curves:?}");
        let c = &curves[0];
        assert_eq!(c.label, "sac, Walker2d-v4 (2 seeds, mean ± std)");
        // 99,996 is read as 100k (within 1 %), not as 50k.
        assert_eq!(c.at(100_000).map(|p| p.mean), Some(650.0));
        assert_eq!(c.at(50_000), None);
        // A label names the file's one method.
        let named = read_peer_curves(&format!("SAC={}", path.display()), "Walker2d-v5").unwrap();
        assert_eq!(named[0].label, "SAC, Walker2d-v4 (2 seeds, mean ± std)");
        let err = read_peer_curves(path.to_str().unwrap(), "Ant-v5")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("sac.csv") && err.contains("\"ant\"") && err.contains("Hopper-v4"),
            "{err}"
        );
    }

    #[test]
    fn bad_files_name_the_file_and_what_is_wrong() {
        let path = write("bad/header.csv", "steps,return\n1,2\n");
        let err = read_peer_curves(path.to_str().unwrap(), "x")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("header.csv") && err.contains("no step or env_step column"),
            "{err}"
        );
        for bad in ["abc", "nan", "inf"] {
            let path = write(
                "bad/value.csv",
                &format!("step,reward,seed\n1000,{bad},0\n"),
            );
            let err = read_peer_curves(path.to_str().unwrap(), "x")
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("line 2") && err.contains(&format!("\"{bad}\"")),
                "{err}"
            );
        }
        let err = read_peer_curves("/nonexistent/peer.csv", "x")
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/peer.csv"), "{err}");
        assert_eq!(task_name("gym:Walker2d-v5"), "walker2d");
        assert_eq!(task_name("Walker2d_v4"), "walker2d");
        assert_eq!(task_name("walker-walk"), "walker-walk");
    }
}
