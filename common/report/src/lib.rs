//! Learning-curve plots from run directories.
//!
//! Runs are grouped by their directory name without the seed suffix (`mbpo-Pendulum-v1-s3` ->
//! `mbpo-Pendulum-v1`). For each group the plot shows the mean over seeds at each evaluation
//! point as a line and the min..max band as a shaded area, one colour per group.
#![warn(missing_docs)]

use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Why a plot could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// A run directory has no readable `metrics.csv`.
    #[error("{path}: {message}")]
    Metrics {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Nothing to plot.
    #[error("no runs with metrics to plot (give run directories that contain metrics.csv)")]
    Empty,
    /// Drawing or encoding failed.
    #[error("drawing {path}: {message}")]
    Draw {
        /// The output file.
        path: PathBuf,
        /// The backend's message.
        message: String,
    },
}

/// One run's column over env steps.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    /// The run directory.
    pub run: PathBuf,
    /// (env steps, value) points, in file order.
    pub points: Vec<(f64, f64)>,
}

/// Read `column` against `env_steps` from `<run>/metrics.csv` (empty cells are skipped).
pub fn read_curve(run: &Path, column: &str) -> Result<Curve, PlotError> {
    let path = run.join("metrics.csv");
    let err = |message: String| PlotError::Metrics {
        path: path.clone(),
        message,
    };
    let text = std::fs::read_to_string(&path).map_err(|e| err(e.to_string()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let find = |name: &str| {
        header.iter().position(|h| *h == name).ok_or_else(|| {
            err(format!(
                "no column `{name}` (columns: {})",
                header.join(", ")
            ))
        })
    };
    let (xs, ys) = (find("env_steps")?, find(column)?);
    let points = lines
        .filter_map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            Some((cells.get(xs)?.parse().ok()?, cells.get(ys)?.parse().ok()?))
        })
        .collect();
    Ok(Curve {
        run: run.to_path_buf(),
        points,
    })
}

/// The group a run belongs to: its directory name without a trailing `-s<seed>`.
pub fn group_name(run: &Path) -> String {
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| run.display().to_string());
    match name.rsplit_once("-s") {
        Some((head, seed)) if !seed.is_empty() && seed.chars().all(|c| c.is_ascii_digit()) => {
            head.to_string()
        }
        _ => name,
    }
}

/// (env steps, mean, min, max) at one evaluation point.
pub type BandPoint = (f64, f64, f64, f64);

/// Mean, min and max over the curves at each env-step value present in all of them.
pub fn aggregate(curves: &[Curve]) -> Vec<BandPoint> {
    let mut at: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
    for c in curves {
        for &(x, y) in &c.points {
            at.entry(x as u64).or_default().push(y);
        }
    }
    at.into_iter()
        .filter(|(_, ys)| ys.len() == curves.len())
        .map(|(x, ys)| {
            let mean = ys.iter().sum::<f64>() / ys.len() as f64;
            let lo = ys.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = ys.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            (x as f64, mean, lo, hi)
        })
        .collect()
}

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The embedded font cannot fail to parse; if it did, text would be missing, not wrong.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

/// Plot `column` (e.g. `eval_return`) of `runs`, grouped by [`group_name`], to a PNG.
pub fn plot_runs(runs: &[PathBuf], column: &str, title: &str, out: &Path) -> Result<(), PlotError> {
    let mut groups: BTreeMap<String, Vec<Curve>> = BTreeMap::new();
    for run in runs {
        groups
            .entry(group_name(run))
            .or_default()
            .push(read_curve(run, column)?);
    }
    let series: Vec<(String, usize, Vec<BandPoint>)> = groups
        .into_iter()
        .map(|(g, curves)| (g, curves.len(), aggregate(&curves)))
        .filter(|(_, _, pts)| !pts.is_empty())
        .collect();
    if series.is_empty() {
        return Err(PlotError::Empty);
    }
    register_font();
    let draw_err = |e: String| PlotError::Draw {
        path: out.to_path_buf(),
        message: e,
    };
    let all = series.iter().flat_map(|(_, _, p)| p.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, _, lo, hi) in all {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(lo), y1.max(hi));
    }
    let pad = ((y1 - y0) * 0.05).max(1e-6);
    let root = BitMapBackend::new(out, (960, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(x0..x1.max(x0 + 1.0), (y0 - pad)..(y1 + pad))
        .map_err(|e| draw_err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("env steps")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{y:.0}"))
        .y_desc(column)
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|e| draw_err(e.to_string()))?;
    for (i, (name, n, pts)) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let band: Vec<(f64, f64)> = pts
            .iter()
            .map(|p| (p.0, p.3))
            .chain(pts.iter().rev().map(|p| (p.0, p.2)))
            .collect();
        chart
            .draw_series(std::iter::once(Polygon::new(
                band,
                color.mix(0.18).filled(),
            )))
            .map_err(|e| draw_err(e.to_string()))?;
        chart
            .draw_series(LineSeries::new(
                pts.iter().map(|p| (p.0, p.1)),
                color.stroke_width(3),
            ))
            .map_err(|e| draw_err(e.to_string()))?
            .label(format!(
                "{name} (mean, min..max over {n} seed{})",
                if *n == 1 { "" } else { "s" }
            ))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|e| draw_err(e.to_string()))?;
    root.present().map_err(|e| draw_err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_run(dir: &Path, name: &str, ys: &[f64]) -> PathBuf {
        let run = dir.join(name);
        std::fs::create_dir_all(&run).unwrap();
        let mut text = String::from("env_steps,eval_return,alpha\n");
        for (i, y) in ys.iter().enumerate() {
            text += &format!("{},{y},\n", (i + 1) * 100);
        }
        std::fs::write(run.join("metrics.csv"), text).unwrap();
        run
    }

    #[test]
    fn groups_strip_the_seed_suffix() {
        assert_eq!(
            group_name(Path::new("runs/mbpo-Pendulum-v1-s3")),
            "mbpo-Pendulum-v1"
        );
        assert_eq!(group_name(Path::new("runs/my-sweep")), "my-sweep");
        assert_eq!(group_name(Path::new("runs/a-s")), "a-s");
    }

    #[test]
    fn aggregate_gives_mean_min_max_at_shared_steps() {
        let c = |pts: &[(f64, f64)]| Curve {
            run: PathBuf::new(),
            points: pts.to_vec(),
        };
        let agg = aggregate(&[
            c(&[(1.0, 1.0), (2.0, 4.0)]),
            c(&[(1.0, 3.0), (2.0, 0.0), (3.0, 9.0)]),
        ]);
        assert_eq!(agg, vec![(1.0, 2.0, 1.0, 3.0), (2.0, 2.0, 0.0, 4.0)]);
    }

    #[test]
    fn plots_a_png_and_names_a_missing_column() {
        let dir = std::env::temp_dir().join(format!("mbpo-plot-{}", std::process::id()));
        let runs = vec![
            write_run(&dir, "sac-P-s0", &[-1500.0, -800.0, -200.0]),
            write_run(&dir, "sac-P-s1", &[-1400.0, -600.0, -180.0]),
            write_run(&dir, "mbpo-P-s0", &[-1500.0, -150.0, -140.0]),
        ];
        let out = dir.join("curves.png");
        plot_runs(&runs, "eval_return", "test", &out).unwrap();
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(bytes.len() > 5000, "a real picture, not an empty canvas");
        let err = plot_runs(&runs, "critic_loss", "t", &out)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("critic_loss") && err.contains("metrics.csv"),
            "{err}"
        );
        std::fs::remove_dir_all(dir).unwrap();
    }
}
