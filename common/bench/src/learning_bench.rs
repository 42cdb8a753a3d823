//! Learning benchmarks: one config over several seeds, summarised into one results file.
//!
//! `results/learning-<env>.json` holds one entry per algorithm (SAC, MBPO, ...), each with
//! every seed's evaluation curve, final return and env steps to reach the task's target return
//! ([`ExperimentConfig::target_return`]: −200 for Pendulum, Gymnasium's `reward_threshold` for
//! the MuJoCo tasks), so sample efficiency is compared in one place. Seeds run in parallel
//! threads; when more than one runs at once, each gets one core (`model.threads` and
//! `sac.threads` are set to 1, whatever the config says), and each run is deterministic, so
//! parallelism does not change any result.
//!
//! Fixed env-step budgets (e.g. the MBPO paper's "return at 20k and 50k steps") are read off
//! the curves: at each budget, the last evaluation at or before it and the wall-clock seconds
//! the run had spent by then ([`BudgetPoint`], [`BudgetSummary`]).

use mbpo_core::stats::{median, RECENT_EVALUATIONS};
use mbpo_train::config::{Algo, ExperimentConfig};
use mbpo_train::error::TrainError;
use mbpo_train::run_dir::{env_steps_to_target, read_eval_curve, read_metric_curve, Summary};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One seed's outcome.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct SeedResult {
    /// Run seed.
    pub seed: u64,
    /// Evaluation curve: (env steps, return).
    pub curve: Vec<(u64, f64)>,
    /// Last evaluation return.
    pub final_return: f64,
    /// First evaluation point with return ≥ the entry's `target_return` (read off the curve, so
    /// a run reused from an older build gets the same figure). Files written before targets
    /// were per task call it `env_steps_to_minus_200`.
    #[serde(alias = "env_steps_to_minus_200")]
    pub env_steps_to_target: Option<u64>,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
    /// Eval return and wall-clock at each requested env-step budget.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub at_budgets: Vec<BudgetPoint>,
    /// The run directory.
    pub run_dir: PathBuf,
}

/// One seed at one env-step budget.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BudgetPoint {
    /// The budget (real env steps).
    pub env_steps: u64,
    /// Return of the last evaluation at or before the budget (`None`: the run never got there).
    pub eval_return: Option<f64>,
    /// Env steps of that evaluation.
    pub evaluated_at: Option<u64>,
    /// Wall-clock seconds of the run at that evaluation.
    pub wall_seconds: Option<f64>,
    /// Mean return of the last [`RECENT_EVALUATIONS`] evaluations at or before the budget
    /// (fewer if the run has fewer): the mean of several says more about the policy of that
    /// time than one evaluation. Files written before this counted 5, not 10.
    #[serde(default)]
    pub recent_mean_return: Option<f64>,
}

/// All seeds at one env-step budget.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BudgetSummary {
    /// The budget (real env steps).
    pub env_steps: u64,
    /// Seeds whose run reached an evaluation at the budget.
    pub seeds_reached: usize,
    /// Median over those seeds of the eval return (`None` if none did).
    pub median_eval_return: Option<f64>,
    /// Mean over those seeds of the eval return.
    pub mean_eval_return: Option<f64>,
    /// Median over those seeds of the wall-clock seconds to get there.
    pub median_wall_seconds: Option<f64>,
    /// Median over those seeds of [`BudgetPoint::recent_mean_return`].
    #[serde(default)]
    pub median_recent_mean_return: Option<f64>,
    /// How many evaluations each seed's [`BudgetPoint::recent_mean_return`] averaged
    /// ([`RECENT_EVALUATIONS`]), so a results file says which mean it holds.
    #[serde(default = "recent_evaluations_before_the_field")]
    pub recent_evaluations: usize,
}

/// Results files written before [`BudgetSummary::recent_evaluations`] averaged the last 5.
fn recent_evaluations_before_the_field() -> usize {
    5
}

/// The last row with env steps ≤ `budget` of a curve sorted by env steps.
fn at_or_before(curve: &[(u64, f64)], budget: u64) -> Option<(u64, f64)> {
    curve.iter().rev().find(|(s, _)| *s <= budget).copied()
}

/// Each budget's eval return and wall-clock, from a run's eval and wall-clock curves. A budget
/// counts as reached only if the run evaluated at the budget itself or later (so a run that
/// stopped early does not report its last return for a budget it never spent).
pub fn budget_points(
    eval: &[(u64, f64)],
    wall: &[(u64, f64)],
    budgets: &[u64],
) -> Vec<BudgetPoint> {
    let last = eval.last().map_or(0, |(s, _)| *s);
    budgets
        .iter()
        .map(|&b| {
            let hit = (last >= b).then(|| at_or_before(eval, b)).flatten();
            let upto = eval.partition_point(|(s, _)| *s <= b);
            let recent = &eval[upto.saturating_sub(RECENT_EVALUATIONS)..upto];
            BudgetPoint {
                env_steps: b,
                eval_return: hit.map(|(_, r)| r),
                evaluated_at: hit.map(|(s, _)| s),
                wall_seconds: hit.and_then(|(s, _)| at_or_before(wall, s).map(|(_, w)| w)),
                recent_mean_return: hit
                    .map(|_| recent.iter().map(|(_, r)| r).sum::<f64>() / recent.len() as f64),
            }
        })
        .collect()
}

/// Summaries over seeds, one per budget.
pub fn summarize_budgets(seeds: &[SeedResult], budgets: &[u64]) -> Vec<BudgetSummary> {
    budgets
        .iter()
        .enumerate()
        .map(|(i, &b)| {
            let points: Vec<&BudgetPoint> = seeds
                .iter()
                .filter_map(|s| s.at_budgets.get(i))
                .filter(|p| p.eval_return.is_some())
                .collect();
            let returns: Vec<f64> = points.iter().filter_map(|p| p.eval_return).collect();
            let mut walls: Vec<f64> = points.iter().filter_map(|p| p.wall_seconds).collect();
            let mut recent: Vec<f64> = points.iter().filter_map(|p| p.recent_mean_return).collect();
            BudgetSummary {
                env_steps: b,
                seeds_reached: returns.len(),
                median_eval_return: median(&mut returns.clone()),
                mean_eval_return: (!returns.is_empty())
                    .then(|| returns.iter().sum::<f64>() / returns.len() as f64),
                median_wall_seconds: median(&mut walls),
                median_recent_mean_return: median(&mut recent),
                recent_evaluations: RECENT_EVALUATIONS,
            }
        })
        .collect()
}

/// One algorithm's results over seeds.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct AlgoResult {
    /// The config file used.
    pub config: String,
    /// Env steps per run.
    pub steps: u64,
    /// Median over seeds of the final return.
    pub median_final_return: f64,
    /// The eval return counted as solving the task (`null`: the task has none). Entries
    /// written before targets were per task lack it: their target was −200.
    #[serde(default = "minus_200")]
    pub target_return: Option<f64>,
    /// Median over seeds of env steps to reach `target_return` (a seed that never did counts as
    /// +∞; `None` when more than half never did).
    #[serde(alias = "median_env_steps_to_minus_200")]
    pub median_env_steps_to_target: Option<u64>,
    /// Eval return and wall-clock at the requested env-step budgets, over seeds.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub budgets: Vec<BudgetSummary>,
    /// Per-seed results.
    pub seeds: Vec<SeedResult>,
    /// Published curves to compare with: the MBPO authors', peers' given with `--peer`
    /// ([`crate::published`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub published: Vec<crate::published::PublishedCurve>,
}

/// The target of entries written before targets were per task.
fn minus_200() -> Option<f64> {
    Some(-200.0)
}

/// Median env steps to a target over seeds, a seed that never reached it counting as +∞
/// ([`median`]; `None` when the median is +∞, i.e. half the seeds or more never did).
fn median_steps(values: &[Option<u64>]) -> Option<u64> {
    let mut v: Vec<f64> = values
        .iter()
        .map(|x| x.map_or(f64::INFINITY, |s| s as f64))
        .collect();
    median(&mut v)
        .filter(|m| m.is_finite())
        .map(|m| m.round() as u64)
}

/// The entries of a results file (none if it does not exist yet).
fn read_results(file: &Path) -> Result<BTreeMap<String, AlgoResult>, TrainError> {
    let text = match std::fs::read_to_string(file) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(BTreeMap::new()),
        Err(e) => return Err(TrainError::Config(format!("{}: {e}", file.display()))),
    };
    serde_json::from_str(&text).map_err(|e| {
        TrainError::Config(format!(
            "{}: not a learning-benchmark results file ({e}); move it away or pass another --out",
            file.display()
        ))
    })
}

/// Run `cfg` for `seeds` on `threads` threads, with run directories under `out/runs/`, and
/// merge the algorithm's entry into `out/learning-<env>.json`. Returns that entry.
pub fn learning_benchmark(
    cfg: &ExperimentConfig,
    config_name: &str,
    seeds: &[u64],
    threads: usize,
    out: &Path,
    train: fn(&ExperimentConfig, &Path) -> Result<Summary, TrainError>,
) -> Result<AlgoResult, TrainError> {
    learning_benchmark_at(cfg, config_name, seeds, threads, out, train, &[])
}

/// `cfg` for seeds run `parallel` at once: one core each (a config's threads are for one run
/// alone on the machine; more threads than cores would only make the seeds wait on each other).
fn one_core_per_seed(cfg: &ExperimentConfig, parallel: usize) -> ExperimentConfig {
    let mut cfg = cfg.clone();
    if parallel > 1 && (cfg.model.threads > 1 || cfg.sac.threads > 1) {
        tracing::info!(
            "{parallel} seeds run at once, one core each: model.threads {} -> 1, sac.threads {} -> 1",
            cfg.model.threads,
            cfg.sac.threads
        );
        cfg.model.threads = 1;
        cfg.sac.threads = 1;
    }
    cfg
}

/// The name of `cfg`'s entry in its results file and of its run directories' prefix: the
/// algorithm's, per planner for MPC (mpc-cem, mpc-mppi, ...), so each keeps its own results.
pub fn entry_name(cfg: &ExperimentConfig) -> String {
    match cfg.algo {
        Algo::MPC => format!("mpc-{}", cfg.mpc.planner.kind.name()),
        other => other.name().to_string(),
    }
}

/// Run `cfg` for `seeds` on `threads` threads, with run directories under `out/runs/`, and
/// return each seed's result, in seed order; no results file is written. What
/// `mbpo bench learning --only-seeds` runs: seeds of one benchmark shared out between processes
/// (`deploy/learning_mujoco.sh`'s lanes), whose file a run over all seeds writes afterwards
/// (it reuses the completed runs).
pub fn run_seeds(
    cfg: &ExperimentConfig,
    seeds: &[u64],
    threads: usize,
    out: &Path,
    train: fn(&ExperimentConfig, &Path) -> Result<Summary, TrainError>,
    budgets: &[u64],
) -> Result<Vec<SeedResult>, TrainError> {
    let algo = entry_name(cfg);
    let target = cfg.target_return();
    let cfg = &one_core_per_seed(cfg, threads);
    let queue = std::sync::Mutex::new(seeds.to_vec());
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            s.spawn(|| loop {
                let Some(seed) = queue.lock().unwrap().pop() else {
                    break;
                };
                let mut c = cfg.clone();
                c.seed = seed;
                let dir = out
                    .join("runs")
                    .join(format!("{algo}-{}-s{seed}", cfg.env_file_name()));
                let r = train(&c, &dir).and_then(|summary| {
                    let metrics = dir.join("metrics.csv");
                    let curve = read_eval_curve(&metrics)?;
                    let wall = read_metric_curve(&metrics, "wall_seconds")?;
                    Ok(SeedResult {
                        seed,
                        at_budgets: budget_points(&curve, &wall, budgets),
                        env_steps_to_target: env_steps_to_target(&curve, target),
                        curve,
                        final_return: summary.final_eval_return,
                        wall_seconds: summary.wall_seconds,
                        run_dir: dir,
                    })
                });
                results.lock().unwrap().push(r);
            });
        }
    });
    let mut per_seed = results
        .into_inner()
        .unwrap()
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    per_seed.sort_by_key(|r| r.seed);
    Ok(per_seed)
}

/// [`learning_benchmark`] that also reports eval return and wall-clock at env-step `budgets`.
pub fn learning_benchmark_at(
    cfg: &ExperimentConfig,
    config_name: &str,
    seeds: &[u64],
    threads: usize,
    out: &Path,
    train: fn(&ExperimentConfig, &Path) -> Result<Summary, TrainError>,
    budgets: &[u64],
) -> Result<AlgoResult, TrainError> {
    let algo = entry_name(cfg);
    let target = cfg.target_return();
    let file = out.join(format!("learning-{}.json", cfg.env_file_name()));
    // A results file that cannot be merged into must stop the benchmark before hours of work,
    // not be found unreadable at the end.
    read_results(&file)?;
    let per_seed = run_seeds(cfg, seeds, threads, out, train, budgets)?;
    let mut finals: Vec<f64> = per_seed.iter().map(|r| r.final_return).collect();
    let entry = AlgoResult {
        config: config_name.to_string(),
        steps: cfg.steps,
        median_final_return: median(&mut finals).expect("a benchmark runs at least one seed"),
        target_return: target,
        median_env_steps_to_target: median_steps(
            &per_seed
                .iter()
                .map(|r| r.env_steps_to_target)
                .collect::<Vec<_>>(),
        ),
        budgets: summarize_budgets(&per_seed, budgets),
        seeds: per_seed,
        published: Vec::new(),
    };
    // Read again just before writing: another benchmark (another algorithm on this task) may
    // have written its entry while these seeds ran.
    let mut all = read_results(&file)?;
    // The published curves stay until `attach_published` sets them again.
    let mut entry = entry;
    entry.published = all.remove(&algo).map(|e| e.published).unwrap_or_default();
    all.insert(algo, entry.clone());
    write_results(&file, &all)?;
    Ok(entry)
}

/// Set the published curves of `cfg`'s entry in its results file under `out` (written by the
/// benchmark just run; [`crate::published::curves_for`]); returns them.
pub fn attach_published(
    out: &Path,
    cfg: &ExperimentConfig,
    peers: &[(String, mbpo_report::PaperCurve)],
    budgets: &[u64],
) -> Result<Vec<crate::published::PublishedCurve>, TrainError> {
    let file = out.join(format!("learning-{}.json", cfg.env_file_name()));
    let mut all = read_results(&file)?;
    let key = entry_name(cfg);
    let entry = all.get_mut(&key).ok_or_else(|| {
        TrainError::Config(format!(
            "{}: no entry {key:?} to attach published curves to",
            file.display()
        ))
    })?;
    let earlier = std::mem::take(&mut entry.published);
    entry.published = crate::published::curves_for(cfg, peers, budgets, earlier);
    let published = entry.published.clone();
    write_results(&file, &all)?;
    Ok(published)
}

/// Write a results file's entries, atomically (a reader never sees half a file).
fn write_results(file: &Path, all: &BTreeMap<String, AlgoResult>) -> Result<(), TrainError> {
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = file.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string_pretty(all)? + "\n")?;
    std::fs::rename(&tmp, file)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budgets_take_the_last_evaluation_at_or_before_and_its_wall_clock() {
        let eval = [(250, 10.0), (500, 20.0), (750, 30.0), (1000, 40.0)];
        let wall = [(250, 1.0), (500, 2.5), (750, 4.0), (1000, 6.0)];
        let p = budget_points(&eval, &wall, &[500, 600, 1000, 2000]);
        let got: Vec<_> = p
            .iter()
            .map(|b| (b.env_steps, b.eval_return, b.evaluated_at, b.wall_seconds))
            .collect();
        let recent: Vec<_> = p.iter().map(|b| b.recent_mean_return).collect();
        // 500: the mean of 10 and 20; 1000: of all four evaluations (fewer than 10 so far).
        assert_eq!(recent, vec![Some(15.0), Some(15.0), Some(25.0), None]);
        assert_eq!(
            got,
            vec![
                (500, Some(20.0), Some(500), Some(2.5)),
                (600, Some(20.0), Some(500), Some(2.5)),
                (1000, Some(40.0), Some(1000), Some(6.0)),
                // The run stopped at 1000: no return is reported for 2000.
                (2000, None, None, None),
            ]
        );
    }

    #[test]
    fn the_recent_mean_takes_the_last_ten_evaluations_up_to_the_budget() {
        let eval: Vec<(u64, f64)> = (1..=14).map(|k| (100 * k, k as f64)).collect();
        let wall: Vec<(u64, f64)> = eval.clone();
        let p = budget_points(&eval, &wall, &[1200, 1250]);
        // 300..=1200: returns 3..=12, the last ten; 1 and 2 (and 13, 14, after) not counted.
        assert_eq!(p[0].recent_mean_return, Some(7.5));
        assert_eq!(p[1].recent_mean_return, Some(7.5));
        assert_eq!(p[1].eval_return, Some(12.0));
    }

    #[test]
    fn budget_summaries_count_only_seeds_that_got_there() {
        let seed = |s: u64, r: Option<f64>, w: Option<f64>| SeedResult {
            seed: s,
            curve: vec![],
            final_return: 0.0,
            env_steps_to_target: None,
            wall_seconds: 0.0,
            at_budgets: vec![BudgetPoint {
                env_steps: 5000,
                eval_return: r,
                evaluated_at: r.map(|_| 5000),
                wall_seconds: w,
                recent_mean_return: r.map(|r| r / 2.0),
            }],
            run_dir: PathBuf::new(),
        };
        let seeds = [
            seed(0, Some(1000.0), Some(60.0)),
            seed(1, Some(200.0), Some(80.0)),
            seed(2, None, None),
            seed(3, Some(900.0), Some(70.0)),
        ];
        let s = &summarize_budgets(&seeds, &[5000])[0];
        assert_eq!(s.seeds_reached, 3);
        assert_eq!(s.median_eval_return, Some(900.0));
        assert_eq!(s.mean_eval_return, Some(700.0));
        assert_eq!(s.median_wall_seconds, Some(70.0));
        assert_eq!(s.median_recent_mean_return, Some(450.0));
        let none = &summarize_budgets(&seeds[2..3], &[5000])[0];
        assert_eq!((none.seeds_reached, none.median_eval_return), (0, None));
    }

    #[test]
    fn median_treats_never_as_infinity() {
        assert_eq!(median_steps(&[Some(3), Some(1), Some(2)]), Some(2));
        assert_eq!(
            median_steps(&[Some(3), None, Some(1), None, Some(2)]),
            Some(3)
        );
        assert_eq!(median_steps(&[None, None, Some(1)]), None);
    }

    /// A stand-in for a training run: seed s evaluates −1000 + 300·s·k at 100·k env steps.
    fn fake_run(cfg: &ExperimentConfig, dir: &Path) -> Result<Summary, TrainError> {
        let mut run = mbpo_train::run_dir::RunDir::create(dir, cfg)?;
        for k in 1..=4u64 {
            run.write_metrics(&mbpo_train::run_dir::MetricsRow {
                env_steps: 100 * k,
                eval_return: -1000.0 + 300.0 * (cfg.seed * k) as f64,
                wall_seconds: k as f64,
                ..Default::default()
            })?;
        }
        Ok(Summary {
            algo: "sac".into(),
            env: cfg.env.clone(),
            seed: cfg.seed,
            env_steps: 400,
            sac_updates: 0,
            final_eval_return: -1000.0 + 1200.0 * cfg.seed as f64,
            best_eval_return: 0.0,
            target_return: None,
            env_steps_to_target: None,
            policy_sha256: String::new(),
            wall_seconds: 4.0,
            median_seconds_per_env_step: None,
            status: "completed".into(),
            episodes_cut_by_resume: 0,
            episodes_lost_to_env_exit: 0,
        })
    }

    fn temp_out(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("mbpo-lb-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn seeds_run_at_once_get_one_core_each_and_one_seed_at_a_time_keeps_the_configs_threads() {
        fn threads_as_return(cfg: &ExperimentConfig, dir: &Path) -> Result<Summary, TrainError> {
            let mut summary = fake_run(cfg, dir)?;
            summary.final_eval_return = (10 * cfg.model.threads + cfg.sac.threads) as f64;
            Ok(summary)
        }
        let mut cfg = ExperimentConfig {
            algo: Algo::SAC,
            ..Default::default()
        };
        (cfg.model.threads, cfg.sac.threads) = (2, 2);
        let out = temp_out("threads-parallel");
        let r = learning_benchmark(&cfg, "c.toml", &[0, 1], 2, &out, threads_as_return).unwrap();
        assert_eq!(r.median_final_return, 11.0);
        let out2 = temp_out("threads-one");
        let r = learning_benchmark(&cfg, "c.toml", &[0, 1], 1, &out2, threads_as_return).unwrap();
        assert_eq!(r.median_final_return, 22.0);
        for dir in [out, out2] {
            std::fs::remove_dir_all(dir).unwrap();
        }
    }

    #[test]
    fn seeds_run_apart_write_no_results_file_and_their_runs_are_the_benchmark_s() {
        let out = temp_out("only-seeds");
        let cfg = ExperimentConfig {
            algo: Algo::SAC,
            ..Default::default()
        };
        let file = out.join(format!("learning-{}.json", cfg.env_file_name()));
        let some = run_seeds(&cfg, &[2, 0], 1, &out, fake_run, &[]).unwrap();
        assert_eq!(some.iter().map(|r| r.seed).collect::<Vec<_>>(), [0, 2]);
        assert!(
            !file.exists(),
            "a share of the seeds writes no results file"
        );
        for seed in [0, 2] {
            let dir = out.join("runs").join(format!("sac-Pendulum-v1-s{seed}"));
            assert_eq!(some[seed as usize / 2].run_dir, dir);
            assert!(dir.join("metrics.csv").exists());
        }
        let all = learning_benchmark(&cfg, "c.toml", &[0, 1, 2], 1, &out, fake_run).unwrap();
        assert_eq!(all.seeds.len(), 3);
        assert!(file.exists());
        assert_eq!(all.seeds[2].final_return, some[1].final_return);
        std::fs::remove_dir_all(out).unwrap();
    }

    #[test]
    fn steps_to_target_are_read_off_the_curve_at_the_tasks_target() {
        let out = temp_out("target");
        let cfg = ExperimentConfig {
            algo: Algo::SAC,
            ..Default::default()
        };
        assert_eq!(cfg.env, "Pendulum-v1");
        // Pendulum's target is −200: seed 1 gets there at 300 (−100), seed 2 at 200 (200),
        // seed 0 never (−1000 throughout).
        let r = learning_benchmark(&cfg, "c.toml", &[0, 1, 2], 2, &out, fake_run).unwrap();
        assert_eq!(r.target_return, Some(-200.0));
        let got: Vec<_> = r.seeds.iter().map(|s| s.env_steps_to_target).collect();
        assert_eq!(got, vec![None, Some(300), Some(200)]);
        assert_eq!(r.median_env_steps_to_target, Some(300));
        // A config's own target wins over the task's.
        let mut high = cfg.clone();
        high.eval.target_return = Some(500.0);
        let r = learning_benchmark(&high, "c.toml", &[2], 1, &out, fake_run).unwrap();
        assert_eq!(r.target_return, Some(500.0));
        assert_eq!(r.seeds[0].env_steps_to_target, Some(300));
        std::fs::remove_dir_all(out).unwrap();
    }

    #[test]
    fn published_curves_sit_beside_the_entry_and_outlive_a_rerun_without_peers() {
        let out = temp_out("published");
        let peer_file = out.join("tdmpc2").join("pendulum.csv");
        std::fs::create_dir_all(peer_file.parent().unwrap()).unwrap();
        std::fs::write(&peer_file, "step,reward,seed\n0,-1200,1\n200,-900,1\n400,-150,1\n0,-1000,2\n200,-700,2\n400,-170,2\n").unwrap();
        let cfg = ExperimentConfig {
            algo: Algo::SAC,
            ..Default::default()
        };
        let spec = format!("TD-MPC2={}", peer_file.display());
        let peers = crate::published::read_peers(&cfg, &[spec]).unwrap();
        let read = |out: &Path| -> AlgoResult {
            let text = std::fs::read_to_string(out.join("learning-Pendulum-v1.json")).unwrap();
            let all: BTreeMap<String, AlgoResult> = serde_json::from_str(&text).unwrap();
            all["sac"].clone()
        };
        learning_benchmark_at(&cfg, "c.toml", &[0], 1, &out, fake_run, &[200, 300]).unwrap();
        let returned = attach_published(&out, &cfg, &peers, &[200, 300]).unwrap();
        let entry = read(&out);
        // Read back through JSON to the bit (serde_json's float_roundtrip).
        assert_eq!(returned, entry.published);
        assert_eq!(
            entry.published.len(),
            1,
            "SAC on Pendulum: the peer only, no MBPO paper"
        );
        let p = &entry.published[0];
        assert_eq!(p.label, "TD-MPC2 (2 seeds, mean ± std)");
        assert_eq!(p.source, peer_file.display().to_string());
        // Its points up to the run's 400 steps, and at the budgets only where it has a point.
        let at: Vec<_> = p.at_budgets.iter().map(|b| (b.env_steps, b.mean)).collect();
        assert_eq!(at, [(200, -800.0)]);
        assert_eq!(p.points.len(), 3);
        assert!(
            (p.points[1].std - 141.421356).abs() < 1e-5,
            "{:?}",
            p.points[1]
        );
        // A rerun without --peer keeps them.
        learning_benchmark_at(&cfg, "c.toml", &[0, 1], 1, &out, fake_run, &[200]).unwrap();
        attach_published(&out, &cfg, &[], &[200]).unwrap();
        let again = read(&out);
        assert_eq!(again.seeds.len(), 2);
        assert_eq!(again.published, entry.published);
        // An MBPO entry of a task the authors ran gets their curve first.
        let mbpo = ExperimentConfig {
            algo: Algo::MBPO,
            env: "Hopper-v5".into(),
            steps: 60_000,
            ..Default::default()
        };
        let with = crate::published::curves_for(&mbpo, &peers, &[50_000], Vec::new());
        assert_eq!(with[0].source, crate::published::MBPO_AUTHORS_SOURCE);
        assert!(
            (with[0].at_budgets[0].mean - 1699.9).abs() < 0.2,
            "{:?}",
            with[0].at_budgets
        );
        assert!(with[0]
            .points
            .windows(2)
            .all(|w| w[1].env_steps >= w[0].env_steps + 1000));
        assert_eq!(with.len(), 2);
        std::fs::remove_dir_all(out).unwrap();
    }

    #[test]
    fn results_files_from_before_per_task_targets_still_merge() {
        let out = temp_out("old");
        std::fs::create_dir_all(&out).unwrap();
        let old = r#"{"mbpo": {"config": "old.toml", "steps": 400, "median_final_return": -150.0,
            "median_env_steps_to_minus_200": 250, "seeds": [{"seed": 0, "curve": [[250, -150.0]],
            "final_return": -150.0, "env_steps_to_minus_200": 250, "wall_seconds": 9.0,
            "run_dir": "runs/x"}]}}"#;
        std::fs::write(out.join("learning-Pendulum-v1.json"), old).unwrap();
        let cfg = ExperimentConfig {
            algo: Algo::SAC,
            ..Default::default()
        };
        learning_benchmark(&cfg, "c.toml", &[1], 1, &out, fake_run).unwrap();
        let text = std::fs::read_to_string(out.join("learning-Pendulum-v1.json")).unwrap();
        let all: BTreeMap<String, AlgoResult> = serde_json::from_str(&text).unwrap();
        let kept = &all["mbpo"];
        assert_eq!(kept.target_return, Some(-200.0));
        assert_eq!(kept.median_env_steps_to_target, Some(250));
        assert_eq!(kept.seeds[0].env_steps_to_target, Some(250));
        assert_eq!(all["sac"].median_env_steps_to_target, Some(300));
        std::fs::remove_dir_all(out).unwrap();
    }

    #[test]
    fn a_budget_summary_says_how_many_evaluations_its_recent_mean_took() {
        let old = r#"{"env_steps": 50000, "seeds_reached": 3, "median_eval_return": 1.0,
            "mean_eval_return": 1.0, "median_wall_seconds": 9.0, "median_recent_mean_return": 2.0}"#;
        let old: BudgetSummary = serde_json::from_str(old).unwrap();
        assert_eq!(
            old.recent_evaluations, 5,
            "files from before the field averaged 5"
        );
        let eval: Vec<(u64, f64)> = (1..=3).map(|k| (100 * k, k as f64)).collect();
        let seed = SeedResult {
            seed: 0,
            at_budgets: budget_points(&eval, &eval, &[300]),
            curve: eval,
            final_return: 3.0,
            env_steps_to_target: None,
            wall_seconds: 3.0,
            run_dir: PathBuf::new(),
        };
        let new = &summarize_budgets(&[seed], &[300])[0];
        assert_eq!(new.recent_evaluations, RECENT_EVALUATIONS);
        assert_eq!(
            RECENT_EVALUATIONS, 10,
            "issue 23's goal: the mean of the last 10"
        );
    }

    #[test]
    fn an_unreadable_results_file_stops_the_benchmark_before_it_runs() {
        fn must_not_run(_: &ExperimentConfig, _: &Path) -> Result<Summary, TrainError> {
            panic!("the benchmark ran although its results file cannot be merged into");
        }
        let out = temp_out("bad");
        std::fs::create_dir_all(&out).unwrap();
        let file = out.join("learning-Pendulum-v1.json");
        std::fs::write(&file, "{ not json").unwrap();
        let cfg = ExperimentConfig::default();
        let err = learning_benchmark(&cfg, "c.toml", &[0], 1, &out, must_not_run)
            .unwrap_err()
            .to_string();
        assert!(err.contains("learning-Pendulum-v1.json"), "{err}");
        assert!(err.contains("move it away"), "{err}");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "{ not json");
        std::fs::remove_dir_all(out).unwrap();
    }

    #[test]
    fn an_entry_written_while_the_seeds_ran_is_kept() {
        /// A run during which another benchmark finishes and writes its own entry.
        fn run_beside_another(cfg: &ExperimentConfig, dir: &Path) -> Result<Summary, TrainError> {
            let file = dir
                .parent()
                .unwrap()
                .parent()
                .unwrap()
                .join("learning-Pendulum-v1.json");
            let other = r#"{"mbpo": {"config": "mbpo.toml", "steps": 400, "median_final_return": 1.0,
                "target_return": -200.0, "median_env_steps_to_target": null, "seeds": []}}"#;
            let summary = fake_run(cfg, dir)?;
            std::fs::write(file, other).unwrap();
            Ok(summary)
        }
        let out = temp_out("beside");
        let cfg = ExperimentConfig::default();
        learning_benchmark(&cfg, "c.toml", &[1], 1, &out, run_beside_another).unwrap();
        let text = std::fs::read_to_string(out.join("learning-Pendulum-v1.json")).unwrap();
        let all: BTreeMap<String, AlgoResult> = serde_json::from_str(&text).unwrap();
        assert_eq!(all.keys().collect::<Vec<_>>(), ["mbpo", "sac"]);
        assert_eq!(all["mbpo"].config, "mbpo.toml");
        assert_eq!(all["sac"].config, "c.toml");
        std::fs::remove_dir_all(out).unwrap();
    }
}
