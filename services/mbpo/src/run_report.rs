//! What a run leaves a person to look at when it ends (`mbpo run`, `mbpo train`): its learning
//! curve and training losses plotted into the run directory, and where they and the
//! TensorBoard files are, said last.

use std::path::{Path, PathBuf};

/// The learning curve's file in a run directory (`mbpo plot` writes the same for many runs).
pub const CURVE: &str = "learning.png";

/// Plot the run in `out` (`learning.png`, `learning-losses.png`) and log where its results
/// are. A plot that cannot be drawn (no evaluation yet) is a warning: the run's own outcome
/// stands.
pub fn plot_and_point(out: &Path) {
    let runs = [out.to_path_buf()];
    let curve = out.join(CURVE);
    let losses = mbpo_report::companion_path(&curve, "losses");
    let title = out
        .file_name()
        .map_or_else(|| out.display().to_string(), |n| n.to_string_lossy().into());
    let references = Vec::from_iter(mbpo_paper_curve_of(&runs));
    let plotted = mbpo_report::plot_runs(&runs, "eval_return", &title, &curve, &references)
        .and_then(|_| {
            let title = format!("{title}: training losses");
            mbpo_report::plot_losses_if_any(&runs, &title, &losses)
        });
    match plotted {
        Ok(Some(_)) => tracing::info!(
            "learning curve: {}; losses: {}",
            curve.display(),
            losses.display()
        ),
        Ok(None) => tracing::info!("learning curve: {}", curve.display()),
        Err(e) => tracing::warn!("no plot of {}: {e}", out.display()),
    }
    if let Some(pacing) = plot_pacing(out) {
        tracing::info!(
            "step-interval errors of the paced actors: {}",
            pacing.display()
        );
    }
    tracing::info!(
        "metrics: {}; summary: {}; TensorBoard: tensorboard --logdir {}",
        out.join("metrics.csv").display(),
        out.join("summary.json").display(),
        out.join("tb").display()
    );
}

/// The MBPO paper's curve for `runs` when every one is an MBPO run of the same task that has
/// one (read from each run's `config.toml`; a run without a readable config gets none).
pub fn mbpo_paper_curve_of(runs: &[PathBuf]) -> Option<mbpo_report::PaperCurve> {
    let mut envs = runs.iter().map(|run| {
        let cfg = mbpo_train::ExperimentConfig::load(&run.join("config.toml")).ok()?;
        (cfg.algo == mbpo_train::Algo::MBPO).then_some(cfg.env)
    });
    let first = envs.next()??;
    envs.all(|env| env.as_deref() == Some(first.as_str()))
        .then(|| mbpo_report::mbpo_paper_curve(&first))
        .flatten()
}

/// The published curves to draw beside `runs`: the MBPO paper's where it applies
/// ([`mbpo_paper_curve_of`]), then those of each `--peer` file for the runs' task (read from the
/// first run's `config.toml`).
pub fn references_of(
    runs: &[PathBuf],
    peers: &[String],
) -> Result<Vec<mbpo_report::PaperCurve>, mbpo_report::PlotError> {
    let env = runs
        .first()
        .and_then(|run| mbpo_train::ExperimentConfig::load(&run.join("config.toml")).ok())
        .map_or_else(String::new, |cfg| cfg.env);
    let mut references = Vec::from_iter(mbpo_paper_curve_of(runs));
    for peer in peers {
        references.extend(mbpo_report::read_peer_curves(peer, &env)?);
    }
    Ok(references)
}

/// A paced run's histogram of step-interval errors (`summary.json`'s `pacing`) drawn to
/// `pacing.png`; `None` for an unpaced run (or a plot that could not be drawn: a warning).
fn plot_pacing(out: &Path) -> Option<PathBuf> {
    let text = std::fs::read_to_string(out.join("summary.json")).ok()?;
    let summary: serde_json::Value = serde_json::from_str(&text).ok()?;
    let p = summary.get("pacing")?;
    // A bin `a..b` is drawn as `< b`: short enough to stand under its bar.
    let bars = p["histogram"].as_array()?.iter().map(|b| {
        let bin = b["bin"].as_str()?;
        Some(mbpo_report::Bar {
            label: bin
                .split_once("..")
                .map_or(bin.into(), |(_, hi)| format!("< {hi}")),
            count: b["steps"].as_u64()?,
        })
    });
    let bars = bars.collect::<Option<Vec<_>>>()?;
    let e = &p["interval_error_us"];
    let us = |v: &serde_json::Value| {
        let v = v.as_f64().unwrap_or(0.0);
        match v >= 1e3 {
            true => format!("{:.1} ms", v / 1e3),
            false => format!("{v:.0} us"),
        }
    };
    let title = format!(
        "step-interval error at {} Hz: p50 <= {}, p99 <= {}, max {}",
        p["control_hz"],
        us(&e["p50"]),
        us(&e["p99"]),
        us(&e["max"])
    );
    let path = out.join(PACING);
    match mbpo_report::plot_histogram(&bars, &title, "|interval - period|", &path) {
        Ok(()) => Some(path),
        Err(e) => {
            tracing::warn!("no plot of the step intervals: {e}");
            None
        }
    }
}

/// The paced actors' histogram of step-interval errors in a run directory.
pub const PACING: &str = "pacing.png";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_paced_run_gets_its_histogram_drawn_and_an_unpaced_one_none() {
        let dir = std::env::temp_dir().join(format!("mbpo-pacing-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("summary.json"), r#"{"status": "completed"}"#).unwrap();
        assert_eq!(plot_pacing(&dir), None);
        let mut errors = mbpo_runtime::pacer::IntervalErrors::default();
        for ns in [1_000, 3_000, 3_500, 800_000, 12_000_000] {
            errors.add(ns);
        }
        let histogram: Vec<serde_json::Value> = errors
            .labelled()
            .into_iter()
            .map(|(bin, steps)| serde_json::json!({"bin": bin, "steps": steps}))
            .collect();
        let summary = serde_json::json!({"pacing": {
            "control_hz": 50.0, "missed_deadlines": 0,
            "interval_error_us": {"p50": 5.0, "p99": 20000.0, "max": 12000.0},
            "histogram": histogram,
        }});
        std::fs::write(dir.join("summary.json"), summary.to_string()).unwrap();
        let png = plot_pacing(&dir).expect("drawn");
        assert!(std::fs::metadata(&png).unwrap().len() > 1000);
        if let Ok(keep) = std::env::var("MBPO_KEEP_PLOT") {
            std::fs::copy(&png, keep).unwrap();
        }
        std::fs::remove_dir_all(dir).unwrap();
    }
}
