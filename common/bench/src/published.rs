//! Published learning curves kept beside a benchmark's own results (`published` of an entry of
//! `learning-<env>.json`): the MBPO authors' curve for an MBPO run of a task they ran, and peer
//! methods' curves given with `mbpo bench learning --peer` (read by
//! [`mbpo_report::read_peer_curves`]). Each is stored as mean ± std over its seeds at its points
//! up to the run's length and at the benchmark's budgets, with the file it came from, so the
//! results file says what ours stands beside without anyone opening the peers' files.

use mbpo_report::{PaperCurve, PlotError, Reading};
use mbpo_train::config::{Algo, ExperimentConfig};
use serde::{Deserialize, Serialize};

/// Where the MBPO authors' curve comes from (embedded in the build).
pub const MBPO_AUTHORS_SOURCE: &str = "common/report/data/mbpo-authors-curves.csv";

/// One published curve beside an entry.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct PublishedCurve {
    /// What the curve is (method, task, seeds).
    pub label: String,
    /// The file it was read from.
    pub source: String,
    /// Its value at each of the benchmark's budgets where it has one (a sparse curve only at or
    /// just before its own points, [`mbpo_report::Reading`]).
    pub at_budgets: Vec<PublishedPoint>,
    /// Its points up to the run's length (a dense curve: one per 1000 env steps at most).
    pub points: Vec<PublishedPoint>,
}

/// Mean ± std over a published curve's seeds at some env steps.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct PublishedPoint {
    /// Env steps (of the curve's point, for `at_budgets` the budget).
    pub env_steps: u64,
    /// Mean over the curve's seeds.
    pub mean: f64,
    /// Standard deviation over the curve's seeds.
    pub std: f64,
}

/// The peers' curves of `peers` (`[LABEL=]FILE`) for `cfg`'s task, read before a benchmark
/// starts so a bad file stops it before hours of work.
pub fn read_peers(
    cfg: &ExperimentConfig,
    peers: &[String],
) -> Result<Vec<(String, PaperCurve)>, PlotError> {
    let mut curves = Vec::new();
    for spec in peers {
        let (_, source) = mbpo_report::split_peer_spec(spec);
        for curve in mbpo_report::read_peer_curves(spec, &cfg.env)? {
            curves.push((source.to_string(), curve));
        }
    }
    Ok(curves)
}

/// An entry's published curves: the MBPO authors' (recomputed), then `peers` when some are
/// given, else the peers' curves of `earlier` (the entry's so far: a rerun without `--peer`
/// keeps them).
pub fn curves_for(
    cfg: &ExperimentConfig,
    peers: &[(String, PaperCurve)],
    budgets: &[u64],
    earlier: Vec<PublishedCurve>,
) -> Vec<PublishedCurve> {
    let authors = (cfg.algo == Algo::MBPO)
        .then(|| mbpo_report::mbpo_paper_curve(&cfg.env))
        .flatten()
        .map(|c| summarize(MBPO_AUTHORS_SOURCE, &c, cfg.steps, budgets));
    let kept: Vec<PublishedCurve> = match peers.is_empty() {
        true => earlier
            .into_iter()
            .filter(|c| c.source != MBPO_AUTHORS_SOURCE)
            .collect(),
        false => peers
            .iter()
            .map(|(source, c)| summarize(source, c, cfg.steps, budgets))
            .collect(),
    };
    authors.into_iter().chain(kept).collect()
}

/// `curve` at `budgets` and its points up to `steps` (a dense curve thinned to one point per
/// 1000 env steps; a sparse one whole).
fn summarize(source: &str, curve: &PaperCurve, steps: u64, budgets: &[u64]) -> PublishedCurve {
    let point = |env_steps: u64, p: mbpo_report::PaperPoint| PublishedPoint {
        env_steps,
        mean: p.mean,
        std: p.std,
    };
    let mut last_kept = None;
    let points = curve
        .points
        .iter()
        .filter(|p| p.env_steps <= steps)
        .filter(|p| {
            let keep = curve.reading == Reading::AtPoints
                || last_kept.is_none_or(|k: u64| p.env_steps >= k + 1000);
            if keep {
                last_kept = Some(p.env_steps);
            }
            keep
        })
        .map(|&p| point(p.env_steps, p))
        .collect();
    PublishedCurve {
        label: curve.label.clone(),
        source: source.to_string(),
        at_budgets: budgets
            .iter()
            .filter_map(|&b| Some(point(b, curve.at(b)?)))
            .collect(),
        points,
    }
}
