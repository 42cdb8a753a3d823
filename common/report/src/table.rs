//! Learning curves as a markdown table, for the README and issue notes: each run's eval return
//! at every `every` env steps, the mean of its last [`RECENT_EVALUATIONS`] evaluations (one
//! evaluation swings widely; a collapse shows in the mean) and its best, then the median over
//! the group's runs and the published curves (the paper's, peers') at the same env steps.

use crate::{group_name, group_runs, read_curve, PaperCurve, PlotError};
use mbpo_core::stats::{median, RECENT_EVALUATIONS};
use std::path::{Path, PathBuf};

/// `12000` -> `12k`; other step counts as they are.
fn steps_label(steps: u64) -> String {
    if steps.is_multiple_of(1000) {
        format!("{}k", steps / 1000)
    } else {
        steps.to_string()
    }
}

/// `seed 2` for a run directory named `<group>-s2` (`seed 2-1` for `<group>-s2-1`, see
/// [`group_name`]), else the directory's name.
fn run_label(run: &Path) -> String {
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| run.display().to_string());
    match name
        .strip_prefix(group_name(run).as_str())
        .and_then(|rest| rest.strip_prefix("-s"))
    {
        Some(seed) => format!("seed {seed}"),
        None => name,
    }
}

/// One run's row: its eval return at each column's env steps (`None`: the run has not got
/// there), the mean of its last evaluations with their span, and its best with where.
struct Row {
    label: String,
    at: Vec<Option<f64>>,
    last: Option<(f64, u64, u64)>,
    best: Option<(f64, u64)>,
}

impl Row {
    fn new(run: &Path, points: &[(f64, f64)], columns: &[u64]) -> Self {
        let last_step = points.last().map_or(0, |p| p.0 as u64);
        let at = columns
            .iter()
            .map(|&c| {
                (last_step >= c)
                    .then(|| points.iter().rev().find(|p| p.0 as u64 <= c).map(|p| p.1))
                    .flatten()
            })
            .collect();
        let tail = &points[points.len().saturating_sub(RECENT_EVALUATIONS)..];
        let last = (!tail.is_empty()).then(|| {
            let mean = tail.iter().map(|p| p.1).sum::<f64>() / tail.len() as f64;
            (mean, tail[0].0 as u64, last_step)
        });
        let best = points
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|p| (p.1, p.0 as u64));
        Row {
            label: run_label(run),
            at,
            last,
            best,
        }
    }
}

/// The median over `rows` of one column, with "(n of m)" when not every run has a value.
fn median_cell(mut values: Vec<f64>, rows: usize) -> String {
    let n = values.len();
    match median(&mut values) {
        None => String::new(),
        Some(m) if n == rows => format!("{m:.0}"),
        Some(m) => format!("{m:.0} ({n} of {rows})"),
    }
}

/// One group's table.
fn group_table(rows: &[Row], columns: &[u64], references: &[PaperCurve]) -> String {
    let mut header = vec!["env steps".to_string()];
    header.extend(columns.iter().map(|&c| steps_label(c)));
    header.push(format!("mean of last {RECENT_EVALUATIONS}"));
    header.push("best".into());
    let line = |cells: Vec<String>| format!("| {} |\n", cells.join(" | "));
    let mut out = line(header.clone());
    out += &line(vec!["---".into(); header.len()]);
    for r in rows {
        let mut cells = vec![r.label.clone()];
        cells.extend(
            r.at.iter()
                .map(|v| v.map_or(String::new(), |v| format!("{v:.0}"))),
        );
        cells.push(r.last.map_or(String::new(), |(mean, from, to)| {
            format!("{mean:.0} ({}-{})", steps_label(from), steps_label(to))
        }));
        cells.push(r.best.map_or(String::new(), |(best, at)| {
            format!("{best:.0} ({})", steps_label(at))
        }));
        out += &line(cells);
    }
    if rows.len() > 1 {
        let median_of = |value: &dyn Fn(&Row) -> Option<f64>| {
            median_cell(rows.iter().filter_map(value).collect(), rows.len())
        };
        let mut cells = vec!["median".to_string()];
        cells.extend((0..columns.len()).map(|i| median_of(&|r| r.at[i])));
        cells.push(median_of(&|r| r.last.map(|l| l.0)));
        cells.push(median_of(&|r| r.best.map(|b| b.0)));
        out += &line(cells);
    }
    for reference in references {
        let mut cells = vec![reference.label.to_string()];
        cells.extend(columns.iter().map(|&c| {
            reference
                .at(c)
                .map_or(String::new(), |p| format!("{:.0} ± {:.0}", p.mean, p.std))
        }));
        cells.extend([String::new(), String::new()]);
        out += &line(cells);
    }
    out
}

/// The eval returns of `runs` as markdown, one table per group (see [`crate::group_curves`]),
/// with columns every `every` env steps up to the furthest run, and a row of each of the
/// `references` (published curves; a sparse one has values only at its own points).
pub fn learning_table(
    runs: &[PathBuf],
    every: u64,
    references: &[PaperCurve],
) -> Result<String, PlotError> {
    let every = every.max(1);
    let groups = group_runs(runs);
    let mut out = String::new();
    for (name, dirs) in &groups {
        let curves = dirs
            .iter()
            .map(|d| read_curve(d, "eval_return"))
            .collect::<Result<Vec<_>, _>>()?;
        let furthest = curves
            .iter()
            .filter_map(|c| c.points.last())
            .map(|p| p.0 as u64)
            .max()
            .unwrap_or(0);
        let columns: Vec<u64> = (1..=furthest / every).map(|i| i * every).collect();
        let rows: Vec<Row> = curves
            .iter()
            .map(|c| Row::new(&c.run, &c.points, &columns))
            .collect();
        if groups.len() > 1 {
            out += &format!("**{name}**\n\n");
        }
        out += &group_table(&rows, &columns, references);
        out += "\n";
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_run(dir: &Path, name: &str, returns: &[f64]) -> PathBuf {
        let run = dir.join(name);
        std::fs::create_dir_all(&run).unwrap();
        let mut csv = "env_steps,eval_return\n".to_string();
        for (i, r) in returns.iter().enumerate() {
            csv += &format!("{},{r}\n", 1000 * (i + 1));
        }
        std::fs::write(run.join("metrics.csv"), csv).unwrap();
        run
    }

    #[test]
    fn a_table_has_each_seed_the_median_and_the_paper_at_the_same_steps() {
        let dir = std::env::temp_dir().join(format!("mbpo-table-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // Seed 2 stopped at 3000 steps: no value at 4k, and the median says of how many.
        let runs = vec![
            write_run(&dir, "mbpo-Hopper-v5-s0", &[10.0, 20.0, 30.0, 40.0]),
            write_run(&dir, "mbpo-Hopper-v5-s1", &[100.0, 300.0, 200.0, 400.0]),
            write_run(&dir, "mbpo-Hopper-v5-s2", &[50.0, 60.0, 70.0]),
        ];
        let paper = crate::paper_curve::test_curve(&[(1000, 5.0), (3000, 25.0)]);
        let peer = PaperCurve {
            label: "peer".into(),
            reading: crate::Reading::AtPoints,
            ..crate::paper_curve::test_curve(&[(1000, 5.0), (3990, 30.0)])
        };
        let table = learning_table(&runs, 2000, &[paper, peer]).unwrap();
        let expected = "\
| env steps | 2k | 4k | mean of last 10 | best |
| --- | --- | --- | --- | --- |
| seed 0 | 20 | 40 | 25 (1k-4k) | 40 (4k) |
| seed 1 | 300 | 400 | 250 (1k-4k) | 400 (4k) |
| seed 2 | 60 |  | 60 (1k-3k) | 70 (3k) |
| median | 60 | 220 (2 of 3) | 60 | 70 |
| paper | 15 ± 2 |  |  |  |
| peer |  | 30 ± 3 |  |  |

";
        assert_eq!(table, expected);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_mean_of_last_takes_the_last_ten_evaluations_and_groups_get_headings() {
        let dir = std::env::temp_dir().join(format!("mbpo-table-last-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // Twelve evaluations 1..=12: the last ten are 3..=12, mean 7.5.
        let returns: Vec<f64> = (1..=12).map(f64::from).collect();
        let runs = vec![
            write_run(&dir.join("a"), "sac-Pendulum-v1-s0", &returns),
            write_run(&dir.join("b"), "sac-Pendulum-v1-s0", &returns),
        ];
        let table = learning_table(&runs, 6000, &[]).unwrap();
        assert!(
            table.contains("| seed 0 | 6 | 12 | 8 (3k-12k) | 12 (12k) |"),
            "{table}"
        );
        // Two directories: two groups, each named, neither with a median row.
        assert_eq!(table.matches("**").count(), 4, "{table}");
        assert!(!table.contains("median"), "{table}");
        // The n-th run of a seed in one place keeps its number.
        assert_eq!(run_label(Path::new("x/mbpo-Hopper-v5-s3-2")), "seed 3-2");
        assert_eq!(run_label(Path::new("x/my-run")), "my-run");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
