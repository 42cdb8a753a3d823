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
    let reference = mbpo_paper_curve_of(&runs);
    let plotted = mbpo_report::plot_runs(&runs, "eval_return", &title, &curve, reference.as_ref())
        .and_then(|_| {
            let title = format!("{title}: training losses");
            mbpo_report::plot_losses(&runs, &title, &losses)
        });
    match plotted {
        Ok(_) => tracing::info!(
            "learning curve: {}; losses: {}",
            curve.display(),
            losses.display()
        ),
        Err(e) => tracing::warn!("no plot of {}: {e}", out.display()),
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
