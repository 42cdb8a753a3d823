//! Learning-curve and loss plots from run directories.
//!
//! Runs are grouped by their directory name without the seed suffix (`mbpo-Pendulum-v1-s3` ->
//! `mbpo-Pendulum-v1`). For each group a panel shows the mean over seeds at each evaluation
//! point as a line and the min..max band as a shaded area. A group's colour is its index in
//! the sorted list of all groups, so it is the same in every panel and every file of one call.
//!
//! * [`plot_runs`]: one column (default `eval_return`) against env steps.
//! * [`plot_losses`]: the training diagnostics ([`LOSS_PANELS`]: critic loss, actor loss, α,
//!   model holdout MSE; for TD-MPC2 runs [`WORLD_MODEL_LOSS_PANELS`]), one panel each, one
//!   shared legend.
//! * [`plot_histogram`]: a histogram as bars (a paced run's step-interval errors).
//! * [`learning_table`]: the eval returns as a markdown table, seed by seed, with the median and
//!   published curves (the paper's, [`mbpo_paper_curve`]; peers', [`read_peer_curves`]) at the
//!   same env steps.
#![warn(missing_docs)]

mod histogram;
mod paper_curve;
mod peer_curve;
mod reference_plot;
mod table;

pub use histogram::{plot_histogram, Bar};
pub use paper_curve::{mbpo_paper_curve, PaperCurve, PaperPoint, Reading};
pub use peer_curve::{read_peer_curves, split_peer_spec};
pub use table::learning_table;

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
    /// A peer's curves file cannot be read (`--peer`).
    #[error("peer curves {path}: {message}")]
    PeerCurves {
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
    let text = std::fs::read_to_string(&path).map_err(|e| {
        err(if e.kind() == std::io::ErrorKind::NotFound {
            "no such file: every run directory given must contain the metrics.csv a training run writes".into()
        } else {
            e.to_string()
        })
    })?;
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

/// The group a run belongs to: its directory name without a trailing `-s<seed>` or
/// `-s<seed>-<n>` (the n-th run of that seed in the same place, see `mbpo train --out`).
pub fn group_name(run: &Path) -> String {
    let name = run
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| run.display().to_string());
    let number = |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_digit());
    match name.rsplit_once("-s") {
        Some((head, tail)) => match tail.split_once('-') {
            None if number(tail) => head.to_string(),
            Some((seed, n)) if number(seed) && number(n) => head.to_string(),
            _ => name,
        },
        None => name,
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

/// One group's aggregated curve of one column.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupCurve {
    /// The group name ([`group_name`]).
    pub name: String,
    /// Runs (seeds) in the group.
    pub seeds: usize,
    /// Mean, min and max at every step all of the group's runs have a value for (empty if the
    /// column has no values, e.g. the model's MSE of a SAC run).
    pub points: Vec<BandPoint>,
}

/// The runs of each group, in group-name order. A group is one [`group_name`] in one directory:
/// `results/runs/mbpo-Hopper-v5-s2` and `results/clip-real-box/runs/mbpo-Hopper-v5-s2` are two
/// experiments, not two seeds of one. When the runs come from more than one directory, each
/// group's name says which (`results/clip-real-box/runs/mbpo-Hopper-v5`).
pub(crate) fn group_runs(runs: &[PathBuf]) -> BTreeMap<String, Vec<PathBuf>> {
    let parent = |run: &PathBuf| run.parent().map(Path::to_path_buf).unwrap_or_default();
    let one_directory = runs.windows(2).all(|w| parent(&w[0]) == parent(&w[1]));
    let mut groups: BTreeMap<String, Vec<PathBuf>> = BTreeMap::new();
    for run in runs {
        let name = if one_directory {
            group_name(run)
        } else {
            parent(run).join(group_name(run)).display().to_string()
        };
        groups.entry(name).or_default().push(run.clone());
    }
    groups
}

/// `column` of every group of `runs`, in group-name order (the colour order).
pub fn group_curves(runs: &[PathBuf], column: &str) -> Result<Vec<GroupCurve>, PlotError> {
    group_runs(runs)
        .into_iter()
        .map(|(name, dirs)| {
            let curves = dirs
                .iter()
                .map(|d| read_curve(d, column))
                .collect::<Result<Vec<_>, _>>()?;
            Ok(GroupCurve {
                name,
                seeds: curves.len(),
                points: aggregate(&curves),
            })
        })
        .collect()
}

/// What a plot contains.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotReport {
    /// The file written.
    pub out: PathBuf,
    /// (group, seeds) in colour order.
    pub groups: Vec<(String, usize)>,
    /// Panels that had at least one point, by column.
    pub panels_with_data: Vec<String>,
}

/// How a panel's y axis is scaled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    /// Linear.
    Linear,
    /// log10 when every value is positive (losses and α span decades), else linear.
    Log,
}

/// One panel: a `metrics.csv` column, its title and scale.
#[derive(Debug, Clone, Copy)]
pub struct Panel {
    /// The column.
    pub column: &'static str,
    /// Panel title.
    pub title: &'static str,
    /// Y scale.
    pub scale: Scale,
}

/// The loss panels of [`plot_losses`], in reading order (2 x 2).
pub const LOSS_PANELS: [Panel; 4] = [
    Panel {
        column: "critic_loss",
        title: "critic loss (last update)",
        scale: Scale::Log,
    },
    Panel {
        column: "actor_loss",
        title: "actor loss (last update)",
        scale: Scale::Linear,
    },
    Panel {
        column: "alpha",
        title: "temperature alpha",
        scale: Scale::Log,
    },
    Panel {
        column: "model_holdout_mse",
        title: "model holdout MSE (elites)",
        scale: Scale::Log,
    },
];

/// The loss panels of [`plot_losses`] when a run has TD-MPC2's world-model losses: its Q heads'
/// and policy prior's losses sit in the critic and actor columns.
pub const WORLD_MODEL_LOSS_PANELS: [Panel; 4] = [
    Panel {
        column: "critic_loss",
        title: "value loss: Q heads' two-hot CE (last update)",
        scale: Scale::Log,
    },
    Panel {
        column: "actor_loss",
        title: "policy prior loss (last update)",
        scale: Scale::Linear,
    },
    Panel {
        column: "consistency_loss",
        title: "latent consistency loss (last update)",
        scale: Scale::Log,
    },
    Panel {
        column: "reward_loss",
        title: "reward loss: two-hot CE (last update)",
        scale: Scale::Log,
    },
];

/// [`WORLD_MODEL_LOSS_PANELS`] when any of `runs` has a consistency loss, else [`LOSS_PANELS`]
/// (runs written before that column existed have none).
fn loss_panels(runs: &[PathBuf]) -> &'static [Panel; 4] {
    let world_model = runs
        .iter()
        .any(|r| read_curve(r, "consistency_loss").is_ok_and(|c| !c.points.is_empty()));
    match world_model {
        true => &WORLD_MODEL_LOSS_PANELS,
        false => &LOSS_PANELS,
    }
}

/// `<dir>/<stem>-<suffix>.png` next to `out` (e.g. `curves.png` -> `curves-losses.png`).
pub fn companion_path(out: &Path, suffix: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "plot".into());
    out.with_file_name(format!("{stem}-{suffix}.png"))
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

fn color(i: usize) -> RGBAColor {
    Palette99::pick(i).to_rgba()
}

/// A number for an axis label with about 3 significant digits (`1.5k`, `0.0123`, `2e-5`).
fn sig(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if a >= 1e4 {
        let k = v / 1e3;
        if k.fract().abs() < 1e-9 {
            format!("{k:.0}k")
        } else {
            format!("{k:.1}k")
        }
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1e-3 {
        let decimals = (2 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{v:.0e}")
    }
}

/// Tick positions (bold, light) for the y range `lo..hi` in plot space: round 1-2-5 steps on a
/// linear axis; 1-2-5 (or decades, or 1..9) times powers of ten on a log10 axis, whose plot
/// space is log10 of the value. Bold ticks carry labels, light ticks only grid lines.
pub fn y_ticks(lo: f64, hi: f64, log: bool) -> (Vec<f64>, Vec<f64>) {
    if log {
        let in_range = |mults: &[f64]| -> Vec<f64> {
            let mut v = Vec::new();
            for k in lo.floor() as i32..=hi.ceil() as i32 {
                for m in mults {
                    let p = m.log10() + f64::from(k);
                    if (lo..=hi).contains(&p) {
                        v.push(p);
                    }
                }
            }
            v
        };
        let all: Vec<f64> = (1..10).map(f64::from).collect();
        for mults in [&[1.0][..], &[1.0, 2.0, 5.0][..], &all[..]] {
            let mut bold = in_range(mults);
            if bold.len() >= 3 {
                // Very wide ranges: every n-th decade, at most ~10 labels.
                let every = bold.len().div_ceil(10);
                bold = bold.into_iter().step_by(every).collect();
                let light = if mults.len() < 9 {
                    in_range(&all)
                } else {
                    vec![]
                };
                return (bold, light);
            }
        }
        // Less than a few 1..9 multiples in range: round steps in log space.
    }
    // The smallest 1-2-5 step that gives at most 10 intervals.
    let raw = ((hi - lo) / 10.0).max(f64::MIN_POSITIVE);
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let ticks = |step: f64| -> Vec<f64> {
        let first = (lo / step).ceil() as i64;
        let last = (hi / step).floor() as i64;
        (first..=last).map(|i| i as f64 * step).collect()
    };
    (ticks(step), ticks(step / 5.0))
}

/// A linear f64 axis whose tick marks are given ([`y_ticks`]) instead of chosen by plotters.
struct TickedAxis {
    lo: f64,
    hi: f64,
    bold: Vec<f64>,
    light: Vec<f64>,
}

impl Ranged for TickedAxis {
    type FormatOption = plotters::coord::ranged1d::DefaultFormatting;
    type ValueType = f64;

    fn map(&self, v: &f64, limit: (i32, i32)) -> i32 {
        let f = (v - self.lo) / (self.hi - self.lo).max(f64::MIN_POSITIVE);
        limit.0 + (f * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<H: plotters::coord::ranged1d::KeyPointHint>(&self, hint: H) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            self.light.clone()
        } else {
            self.bold.clone()
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.lo..self.hi
    }
}

/// The chart of one panel: env steps against a ticked (maybe log) y axis.
pub(crate) type PanelChart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, TickedAxis>,
>;

/// Draw one panel of `curves` into `area`; `legend_inside` puts the legend in the plot. The
/// `references` (published curves) are drawn dashed with their ± std over the env steps the
/// runs cover ([`reference_plot`]).
fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    curves: &[GroupCurve],
    title: &str,
    y_desc: &str,
    scale: Scale,
    legend_inside: bool,
    references: &[PaperCurve],
) -> Result<(), String> {
    let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
    let series: Vec<(usize, &GroupCurve)> = curves
        .iter()
        .enumerate()
        .filter(|(_, c)| !c.points.is_empty())
        .collect();
    if series.is_empty() {
        return draw_empty_panel(area, title);
    }
    let log = scale == Scale::Log
        && series
            .iter()
            .all(|(_, c)| c.points.iter().all(|p| p.2 > 0.0 && p.1 > 0.0));
    let tf = |y: f64| if log { y.log10() } else { y };
    let (x0, x1, lo, hi, reference_points) = panel_range(&series, references, log);
    let y_desc = match log {
        true => format!("{y_desc} (log scale)"),
        false => y_desc.to_string(),
    };
    let (bold, light) = y_ticks(lo, hi, log);
    let y_axis = TickedAxis {
        lo,
        hi,
        bold,
        light,
    };
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 22))
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(76)
        .build_cartesian_2d(x0..x1.max(x0 + 1.0), y_axis)
        .map_err(e)?;
    let y_fmt = |y: &f64| if log { sig(10f64.powf(*y)) } else { sig(*y) };
    chart
        .configure_mesh()
        .x_desc("env steps")
        .x_label_formatter(&|x| sig(*x))
        .y_label_formatter(&y_fmt)
        .y_desc(y_desc)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 16))
        .draw()
        .map_err(e)?;
    for &(i, c) in &series {
        draw_runs(&mut chart, i, c, &tf, legend_inside)?;
    }
    reference_plot::draw_references(&mut chart, &reference_points, log, legend_inside)?;
    if legend_inside {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 15))
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

/// A panel with its title and "no data in any run".
fn draw_empty_panel(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    title: &str,
) -> Result<(), String> {
    let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
    let (w, h) = area.dim_in_pixel();
    area.draw(&Text::new(
        title.to_string(),
        (w as i32 / 2 - 120, 12),
        ("sans-serif", 20).into_font(),
    ))
    .map_err(e)?;
    area.draw(&Text::new(
        "no data in any run".to_string(),
        (w as i32 / 2 - 80, h as i32 / 2),
        ("sans-serif", 16)
            .into_font()
            .color(&RGBColor(110, 110, 110)),
    ))
    .map_err(e)?;
    Ok(())
}

/// The panel's x range and padded y range (in the axis's units: log10 on a log scale), and
/// each reference's points within the x range.
fn panel_range<'r>(
    series: &[(usize, &GroupCurve)],
    references: &'r [PaperCurve],
    log: bool,
) -> (f64, f64, f64, f64, Vec<reference_plot::ReferencePoints<'r>>) {
    let tf = |y: f64| if log { y.log10() } else { y };
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (_, c) in series {
        for &(x, _, lo, hi) in &c.points {
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(tf(lo)), y1.max(tf(hi)));
        }
    }
    let reference_points: Vec<_> = references
        .iter()
        .map(|r| (r, reference_plot::within(r, x0, x1)))
        .collect();
    // The references' ± std where the scale can show it (a log scale shows the mean only).
    let spread = |std: f64| if log { 0.0 } else { std };
    for &(_, mean, std) in reference_points.iter().flat_map(|(_, p)| p) {
        let s = spread(std);
        (y0, y1) = (y0.min(tf(mean - s)), y1.max(tf(mean + s)));
    }
    let pad = ((y1 - y0) * 0.05).max(if log { 0.05 } else { 1e-6 });
    (x0, x1, y0 - pad, y1 + pad, reference_points)
}

/// One group of runs: its min..max band and mean line, in colour `i`.
fn draw_runs(
    chart: &mut PanelChart<'_, '_>,
    i: usize,
    c: &GroupCurve,
    tf: &dyn Fn(f64) -> f64,
    legend_inside: bool,
) -> Result<(), String> {
    let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
    let col = color(i);
    let band: Vec<(f64, f64)> = c
        .points
        .iter()
        .map(|p| (p.0, tf(p.3)))
        .chain(c.points.iter().rev().map(|p| (p.0, tf(p.2))))
        .collect();
    chart
        .draw_series(std::iter::once(Polygon::new(band, col.mix(0.18).filled())))
        .map_err(e)?;
    let line = chart
        .draw_series(LineSeries::new(
            c.points.iter().map(|p| (p.0, tf(p.1))),
            col.stroke_width(3),
        ))
        .map_err(e)?;
    if legend_inside {
        line.label(legend_text(c))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col.stroke_width(3)));
    }
    Ok(())
}

fn legend_text(c: &GroupCurve) -> String {
    format!(
        "{} (mean, min..max over {} seed{})",
        c.name,
        c.seeds,
        if c.seeds == 1 { "" } else { "s" }
    )
}

fn report(out: &Path, curves: &[GroupCurve], panels: &[(&str, &[GroupCurve])]) -> PlotReport {
    PlotReport {
        out: out.to_path_buf(),
        groups: curves.iter().map(|c| (c.name.clone(), c.seeds)).collect(),
        panels_with_data: panels
            .iter()
            .filter(|(_, cs)| cs.iter().any(|c| !c.points.is_empty()))
            .map(|(col, _)| col.to_string())
            .collect(),
    }
}

/// Plot `column` (e.g. `eval_return`) of `runs`, grouped by [`group_name`] and directory, to a
/// PNG, with published `references` (e.g. [`mbpo_paper_curve`], [`read_peer_curves`]) dashed
/// next to them.
pub fn plot_runs(
    runs: &[PathBuf],
    column: &str,
    title: &str,
    out: &Path,
    references: &[PaperCurve],
) -> Result<PlotReport, PlotError> {
    let curves = group_curves(runs, column)?;
    if curves.iter().all(|c| c.points.is_empty()) {
        return Err(PlotError::Empty);
    }
    register_font();
    let draw_err = |message: String| PlotError::Draw {
        path: out.to_path_buf(),
        message,
    };
    let root = BitMapBackend::new(out, (960, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(e.to_string()))?;
    draw_panel(
        &root,
        &curves,
        title,
        column,
        Scale::Linear,
        true,
        references,
    )
    .map_err(draw_err)?;
    root.present().map_err(|e| draw_err(e.to_string()))?;
    Ok(report(out, &curves, &[(column, &curves)]))
}

/// [`plot_losses`], or `None` when no run has any of the loss panels' values (an MPC run has
/// none; a TD-MPC2 run written before 2026-12-06 neither): nothing to draw is not an error.
pub fn plot_losses_if_any(
    runs: &[PathBuf],
    title: &str,
    out: &Path,
) -> Result<Option<PlotReport>, PlotError> {
    match plot_losses(runs, title, out) {
        Ok(report) => Ok(Some(report)),
        Err(PlotError::Empty) => Ok(None),
        Err(e) => Err(e),
    }
}

/// Plot the loss panels of `runs` ([`LOSS_PANELS`], or [`WORLD_MODEL_LOSS_PANELS`] for
/// TD-MPC2; 2 x 2 panels, one legend on top) to a PNG. A panel no run has values for (the
/// model's MSE of SAC runs) says so instead of failing.
pub fn plot_losses(runs: &[PathBuf], title: &str, out: &Path) -> Result<PlotReport, PlotError> {
    let panels = loss_panels(runs)
        .iter()
        .map(|p| Ok((p, group_curves(runs, p.column)?)))
        .collect::<Result<Vec<_>, PlotError>>()?;
    if panels
        .iter()
        .all(|(_, cs)| cs.iter().all(|c| c.points.is_empty()))
    {
        return Err(PlotError::Empty);
    }
    let groups = &panels[0].1;
    register_font();
    let draw_err = |message: String| PlotError::Draw {
        path: out.to_path_buf(),
        message,
    };
    let de = |e: plotters::drawing::DrawingAreaErrorKind<_>| draw_err(e.to_string());
    let legend_rows = groups.len().div_ceil(2) as u32;
    let root = BitMapBackend::new(out, (1400, 980 + 26 * legend_rows)).into_drawing_area();
    root.fill(&WHITE).map_err(de)?;
    let (top, grid) = root.split_vertically(44 + 26 * legend_rows);
    top.draw(&Text::new(
        title.to_string(),
        (16, 8),
        ("sans-serif", 26).into_font(),
    ))
    .map_err(de)?;
    for (i, c) in groups.iter().enumerate() {
        let (x, y) = (24 + 690 * (i as i32 % 2), 46 + 26 * (i as i32 / 2));
        top.draw(&PathElement::new(
            vec![(x, y), (x + 28, y)],
            color(i).stroke_width(4),
        ))
        .map_err(de)?;
        top.draw(&Text::new(
            legend_text(c),
            (x + 38, y - 9),
            ("sans-serif", 17).into_font(),
        ))
        .map_err(de)?;
    }
    for (area, (panel, curves)) in grid.split_evenly((2, 2)).iter().zip(&panels) {
        draw_panel(
            area,
            curves,
            panel.title,
            panel.column,
            panel.scale,
            false,
            &[],
        )
        .map_err(draw_err)?;
    }
    root.present().map_err(de)?;
    let with_data: Vec<(&str, &[GroupCurve])> = panels
        .iter()
        .map(|(p, cs)| (p.column, cs.as_slice()))
        .collect();
    Ok(report(out, groups, &with_data))
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
        // The second run of seed 3 in the default place groups with the first.
        assert_eq!(
            group_name(Path::new("runs/mbpo-Pendulum-v1-s3-2")),
            "mbpo-Pendulum-v1"
        );
        assert_eq!(group_name(Path::new("runs/a-s3-x")), "a-s3-x");
    }

    #[test]
    fn runs_of_one_name_in_two_directories_are_two_groups() {
        let runs: Vec<PathBuf> = [
            "results/runs/mbpo-Hopper-v5-s1",
            "results/runs/mbpo-Hopper-v5-s2",
            "results/clip-real-box/runs/mbpo-Hopper-v5-s2",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        let groups = group_runs(&runs);
        let sizes: Vec<(&str, usize)> = groups.iter().map(|(n, r)| (n.as_str(), r.len())).collect();
        assert_eq!(
            sizes,
            [
                ("results/clip-real-box/runs/mbpo-Hopper-v5", 1),
                ("results/runs/mbpo-Hopper-v5", 2)
            ]
        );
        // One directory: the short names, as before.
        let one = group_runs(&runs[..2]);
        assert_eq!(one.keys().collect::<Vec<_>>(), ["mbpo-Hopper-v5"]);
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
    fn the_reference_is_drawn_over_the_runs_steps_with_interpolated_ends() {
        let r = paper_curve::test_curve(&[(0, 0.0), (2000, 200.0), (3000, 100.0), (10_000, 800.0)]);
        assert_eq!(
            reference_plot::within(&r, 1000.0, 4000.0),
            vec![
                (1000.0, 100.0, 10.0),
                (2000.0, 200.0, 20.0),
                (3000.0, 100.0, 10.0),
                (4000.0, 200.0, 20.0)
            ]
        );
        // Runs beyond the curve: it ends where its points do.
        assert_eq!(
            reference_plot::within(&r, 3000.0, 20_000.0),
            vec![(3000.0, 100.0, 10.0), (10_000.0, 800.0, 80.0)]
        );
        let dir = std::env::temp_dir().join(format!("mbpo-plot-ref-{}", std::process::id()));
        let runs = vec![write_run(&dir, "mbpo-Hopper-v5-s0", &[100.0, 900.0, 400.0])];
        let out = dir.join("curves.png");
        // With a sparse peer curve too: drawn at its points within the runs' steps only.
        let sparse = PaperCurve {
            reading: Reading::AtPoints,
            ..paper_curve::test_curve(&[(0, 0.0), (2000, 300.0), (100_000, 900.0)])
        };
        assert_eq!(
            reference_plot::within(&sparse, 1000.0, 3000.0),
            vec![(2000.0, 300.0, 30.0)]
        );
        plot_runs(&runs, "eval_return", "test", &out, &[r, sparse]).unwrap();
        assert!(std::fs::metadata(&out).unwrap().len() > 1000);
        std::fs::remove_dir_all(&dir).unwrap();
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
        let r = plot_runs(&runs, "eval_return", "test", &out, &[]).unwrap();
        assert_eq!(
            r.groups,
            vec![("mbpo-P".to_string(), 1), ("sac-P".to_string(), 2)]
        );
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(bytes.len() > 5000, "a real picture, not an empty canvas");
        let err = plot_runs(&runs, "critic_loss", "t", &out, &[])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("critic_loss") && err.contains("metrics.csv"),
            "{err}"
        );
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A run with every loss column; `mse` empty like a SAC run's when `None`.
    fn write_loss_run(dir: &Path, name: &str, scale: f64, mse: Option<f64>) -> PathBuf {
        let run = dir.join(name);
        std::fs::create_dir_all(&run).unwrap();
        let mut text =
            String::from("env_steps,eval_return,critic_loss,actor_loss,alpha,model_holdout_mse\n");
        // The first row is before any update: losses empty, as the trainers write it.
        text += "100,-1500,,,1,\n";
        for i in 2..=20u32 {
            let t = f64::from(i);
            let m = mse.map(|m| format!("{}", m / t)).unwrap_or_default();
            text += &format!(
                "{},{},{},{},{},{m}\n",
                i * 100,
                -1500.0 + 60.0 * t,
                scale * 50.0 / t,
                -scale * 3.0 * t,
                0.9f64.powf(t * 3.0)
            );
        }
        std::fs::write(run.join("metrics.csv"), text).unwrap();
        run
    }

    #[test]
    fn loss_panels_share_groups_and_tolerate_a_column_without_values() {
        let dir = std::env::temp_dir().join(format!("mbpo-plot-loss-{}", std::process::id()));
        let runs = vec![
            write_loss_run(&dir, "sac-P-s0", 1.0, None),
            write_loss_run(&dir, "sac-P-s1", 1.3, None),
            write_loss_run(&dir, "mbpo-P-s0", 2.0, Some(0.5)),
            write_loss_run(&dir, "mbpo-P-s1", 2.5, Some(0.4)),
            write_loss_run(&dir, "mbpo-P-s2", 3.0, Some(0.3)),
        ];
        let out = companion_path(&dir.join("curves.png"), "losses");
        assert_eq!(out, dir.join("curves-losses.png"));
        let r = plot_losses(&runs, "losses", &out).unwrap();
        assert_eq!(
            r.groups,
            vec![("mbpo-P".to_string(), 3), ("sac-P".to_string(), 2)]
        );
        assert_eq!(
            r.panels_with_data,
            vec!["critic_loss", "actor_loss", "alpha", "model_holdout_mse"]
        );
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(
            bytes.len() > 20_000,
            "four drawn panels, not a blank canvas"
        );

        // SAC alone: the model panel has no data and says so; the rest is drawn.
        let sac_only = dir.join("sac-losses.png");
        let r = plot_losses(&runs[..2], "losses", &sac_only).unwrap();
        assert_eq!(r.groups, vec![("sac-P".to_string(), 2)]);
        assert_eq!(
            r.panels_with_data,
            vec!["critic_loss", "actor_loss", "alpha"]
        );
        assert!(sac_only.exists());

        // The band is the spread over seeds: critic loss at step 200 is 50/2 * {2, 2.5, 3}.
        let mbpo = &group_curves(&runs, "critic_loss").unwrap()[0];
        assert_eq!(mbpo.points[0], (200.0, 25.0 * 2.5, 50.0, 75.0));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_world_model_run_gets_its_own_loss_panels() {
        let dir = std::env::temp_dir().join(format!("mbpo-plot-wm-{}", std::process::id()));
        let old_sac = write_loss_run(&dir, "sac-P-s0", 1.0, None);
        // A SAC run of this version has the world model's columns, empty.
        let sac = write_loss_run(&dir, "sac-P-s1", 1.0, None);
        let text = std::fs::read_to_string(sac.join("metrics.csv")).unwrap();
        let mut lines = text.lines();
        let mut with_columns = format!("{},consistency_loss,reward_loss\n", lines.next().unwrap());
        for line in lines {
            with_columns += &format!("{line},,\n");
        }
        std::fs::write(sac.join("metrics.csv"), with_columns).unwrap();
        let tdmpc = dir.join("tdmpc-P-s0");
        std::fs::create_dir_all(&tdmpc).unwrap();
        let mut text = String::from(
            "env_steps,eval_return,critic_loss,actor_loss,alpha,consistency_loss,reward_loss\n100,-1500,,,,,\n",
        );
        for i in 2..=20u32 {
            let t = f64::from(i);
            text += &format!(
                "{},-1000,{},{},,{},{}\n",
                i * 100,
                5.0 / t,
                -t,
                1.0 / t,
                2.0 / t
            );
        }
        std::fs::write(tdmpc.join("metrics.csv"), text).unwrap();
        let out = dir.join("wm-losses.png");
        let r = plot_losses(&[sac.clone(), tdmpc], "losses", &out).unwrap();
        assert_eq!(
            r.panels_with_data,
            vec![
                "critic_loss",
                "actor_loss",
                "consistency_loss",
                "reward_loss"
            ]
        );
        // SAC alone, written before the column or after it (empty): SAC's panels.
        for runs in [vec![old_sac.clone()], vec![old_sac, sac]] {
            let r = plot_losses(&runs, "losses", &out).unwrap();
            assert_eq!(
                r.panels_with_data,
                vec!["critic_loss", "actor_loss", "alpha"]
            );
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn plot_errors_name_the_run_and_the_problem() {
        let dir = std::env::temp_dir().join(format!("mbpo-plot-err-{}", std::process::id()));
        let good = write_loss_run(&dir, "sac-P-s0", 1.0, None);
        let empty = dir.join("not-a-run");
        std::fs::create_dir_all(&empty).unwrap();
        let out = dir.join("x.png");
        for err in [
            plot_runs(
                &[good.clone(), empty.clone()],
                "eval_return",
                "t",
                &out,
                &[],
            )
            .unwrap_err(),
            plot_losses(&[good.clone(), empty.clone()], "t", &out).unwrap_err(),
        ] {
            let msg = err.to_string();
            assert!(
                msg.contains("not-a-run/metrics.csv") && msg.contains("no such file"),
                "{msg}"
            );
        }
        // An old metrics.csv without a loss column.
        let old = dir.join("old-s0");
        std::fs::create_dir_all(&old).unwrap();
        std::fs::write(old.join("metrics.csv"), "env_steps,eval_return\n100,-1\n").unwrap();
        let msg = plot_losses(std::slice::from_ref(&old), "t", &out)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("old-s0/metrics.csv") && msg.contains("no column `critic_loss`"),
            "{msg}"
        );
        // Columns present but never filled: nothing to plot.
        std::fs::write(
            old.join("metrics.csv"),
            "env_steps,critic_loss,actor_loss,alpha,model_holdout_mse\n100,,,,\n",
        )
        .unwrap();
        assert!(matches!(
            plot_losses(std::slice::from_ref(&old), "t", &out).unwrap_err(),
            PlotError::Empty
        ));
        assert!(!out.exists(), "no file is written when the plot fails");
        // ... which `mbpo plot` and a run's own report take as no loss panels (TD-MPC2, MPC).
        assert!(plot_losses_if_any(&[old], "t", &out).unwrap().is_none());
        assert!(!out.exists());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn y_ticks_are_round_numbers() {
        let near = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9)
        };
        // Linear: -1850..10 in steps of 200 (raw step 186 -> 200), light ticks every 40.
        let (bold, light) = y_ticks(-1850.0, 10.0, false);
        let want: Vec<f64> = (-9..=0).map(|i| f64::from(i) * 200.0).collect();
        assert!(near(&bold, &want), "{bold:?}");
        assert_eq!(light.len(), 47); // -1840, -1800, ..., 0
        let (bold, _) = y_ticks(-3.0, 252.0, false);
        assert!(
            near(&bold, &[0.0, 50.0, 100.0, 150.0, 200.0, 250.0]),
            "{bold:?}"
        );
        // Log over 0.08..40 (plot space log10): 1-2-5 values, labelled as such.
        let (bold, light) = y_ticks(0.08f64.log10(), 40f64.log10(), true);
        let labels: Vec<String> = bold.iter().map(|v| sig(10f64.powf(*v))).collect();
        assert_eq!(labels, ["0.1", "1", "10"]);
        assert!(light.len() > 20, "1..9 sub-ticks: {light:?}");
        // Within one decade: 1-2-5 multiples.
        let (bold, _) = y_ticks(0.15f64.log10(), 1.1f64.log10(), true);
        let labels: Vec<String> = bold.iter().map(|v| sig(10f64.powf(*v))).collect();
        assert_eq!(labels, ["0.2", "0.5", "1"]);
        // Twenty decades: at most ten labels.
        let (bold, _) = y_ticks(-10.0, 10.0, true);
        assert!(bold.len() <= 11 && bold.len() >= 5, "{bold:?}");
        // A sliver of a decade falls back to round steps in log space.
        let (bold, _) = y_ticks(0.031f64.log10(), 0.034f64.log10(), true);
        assert!(bold.len() >= 3, "{bold:?}");
    }

    #[test]
    fn axis_labels_keep_three_significant_digits() {
        let cases = [
            (0.0, "0"),
            (20000.0, "20k"),
            (12500.0, "12.5k"),
            (1500.0, "1500"),
            (-150.0, "-150"),
            (12.34, "12.3"),
            (1.0, "1"),
            (0.25, "0.25"),
            (0.012345, "0.0123"),
            (0.00002, "2e-5"),
        ];
        for (v, want) in cases {
            assert_eq!(sig(v), want, "{v}");
        }
    }
}
