//! The MBPO paper's own learning curves, to put next to ours at the same env steps.
//!
//! The authors shared their TensorFlow runs' curves of the paper's Figure 2 (mean and standard
//! deviation over seeds, one deterministic evaluation episode per 1000-step epoch) as pickles;
//! `deploy/paper_curves.py` turns them into `data/mbpo-authors-curves.csv`, embedded here, and
//! says where the pickles are. The authors ran the v2 tasks on MuJoCo 1.5 (Ant as
//! AntTruncatedObs-v2, without contact forces, like our Ant-v5 config); ours are v5 on
//! MuJoCo 3, whose simulator and task details differ, so the comparison is of shape and level,
//! not to the unit.

/// The authors' curves: `task,source,env_steps,mean,std` after `#` comment lines.
const AUTHORS_CURVES: &str = include_str!("../data/mbpo-authors-curves.csv");

/// One point of a reference curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperPoint {
    /// Real env steps.
    pub env_steps: u64,
    /// Mean eval return over the authors' seeds.
    pub mean: f64,
    /// Standard deviation over the authors' seeds.
    pub std: f64,
}

/// A published learning curve to compare ours with: eval return at env steps (the MBPO
/// authors' own, or a peer method's read by [`crate::read_peer_curves`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PaperCurve {
    /// What the curve is, for legends and tables.
    pub label: String,
    /// The points, sorted by env steps.
    pub points: Vec<PaperPoint>,
    /// How the curve is read between its points.
    pub reading: Reading,
}

/// How a [`PaperCurve`] is read at env steps between its points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reading {
    /// Linearly between neighbouring points: a dense curve (the MBPO authors' has one point
    /// per 1000-step epoch).
    Interpolate,
    /// Only at a point, or one at most 1 % of the env steps before: a sparse curve (TD-MPC2's
    /// published ones have a point per 100k env steps; SAC's in the SimbaV2 collection one per
    /// 16,666, so "at 100k" is its point at 99,996). Between points such a curve says nothing:
    /// a straight line from 0 to 100k would be a figure nobody measured.
    AtPoints,
}

impl PaperCurve {
    /// The curve at `env_steps` (see [`Reading`]); `None` where it says nothing: outside its
    /// points, or between sparse points.
    pub fn at(&self, env_steps: u64) -> Option<PaperPoint> {
        if self.reading == Reading::AtPoints {
            let before = self.points.partition_point(|p| p.env_steps <= env_steps);
            let p = *self.points.get(before.checked_sub(1)?)?;
            return (p.env_steps >= env_steps - env_steps / 100).then_some(p);
        }
        let after = self.points.partition_point(|p| p.env_steps < env_steps);
        let p1 = *self.points.get(after)?;
        if p1.env_steps == env_steps {
            return Some(p1);
        }
        let p0 = *self.points.get(after.checked_sub(1)?)?;
        let t = (env_steps - p0.env_steps) as f64 / (p1.env_steps - p0.env_steps) as f64;
        Some(PaperPoint {
            env_steps,
            mean: p0.mean + t * (p1.mean - p0.mean),
            std: p0.std + t * (p1.std - p0.std),
        })
    }
}

/// The rows of `csv` for `task`: (source task name, point). A malformed row names its line.
fn parse_task(csv: &str, task: &str) -> Result<(String, Vec<PaperPoint>), String> {
    let mut source = String::new();
    let mut points = Vec::new();
    let rows = csv.lines().enumerate().filter(|(_, l)| !l.starts_with('#'));
    for (i, line) in rows.skip(1) {
        let bad = || format!("mbpo-authors-curves.csv line {}: {line:?}", i + 1);
        let fields: Vec<&str> = line.split(',').collect();
        let [name, src, steps, mean, std] = fields[..] else {
            return Err(bad() + ": expected task,source,env_steps,mean,std");
        };
        if name != task {
            continue;
        }
        source = src.to_string();
        points.push(PaperPoint {
            env_steps: steps.parse().map_err(|_| bad())?,
            mean: mean.parse().map_err(|_| bad())?,
            std: std.parse().map_err(|_| bad())?,
        });
    }
    if !points.windows(2).all(|w| w[0].env_steps < w[1].env_steps) {
        return Err(format!("{task}: env steps not increasing"));
    }
    Ok((source, points))
}

/// The paper's MBPO curve for `env` (a task id such as `Hopper-v5`, or with a prefix such as
/// Gymnasium's `gym:Hopper-v5`), if the authors' data has that task.
pub fn mbpo_paper_curve(env: &str) -> Option<PaperCurve> {
    let task = env.rsplit_once(':').map_or(env, |(_, task)| task);
    let name = task.split_once("-v").map(|(name, _)| name)?;
    let (source, points) = parse_task(AUTHORS_CURVES, name)
        .unwrap_or_else(|e| panic!("the embedded curves are checked by the tests: {e}"));
    (!points.is_empty()).then(|| PaperCurve {
        label: format!("MBPO paper, {source} (authors' runs, mean ± std)"),
        points,
        reading: Reading::Interpolate,
    })
}

/// A curve of `(env steps, mean)` points with a std of a tenth of the mean, for tests.
#[cfg(test)]
pub(crate) fn test_curve(points: &[(u64, f64)]) -> PaperCurve {
    PaperCurve {
        label: "paper".into(),
        points: points
            .iter()
            .map(|&(env_steps, mean)| PaperPoint {
                env_steps,
                mean,
                std: mean / 10.0,
            })
            .collect(),
        reading: Reading::Interpolate,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_authors_data_gives_the_four_tasks_at_the_papers_values() {
        // Mean and std at 50k and 100k, as the pickles give them (read with numpy, interpolated).
        let cases = [
            ("Hopper-v5", "Hopper-v2", 1699.9, 799.1, 3315.1),
            ("gym:Walker2d-v5", "Walker2d-v2", 835.7, 475.6, 3475.5),
            ("HalfCheetah-v5", "HalfCheetah-v2", 7948.2, 590.8, 9563.2),
            ("Ant-v5", "AntTruncatedObs-v2", 781.8, 229.2, 1455.8),
        ];
        for (env, source, mean_50k, std_50k, mean_100k) in cases {
            let curve = mbpo_paper_curve(env).unwrap();
            assert!(curve.label.contains(source), "{}", curve.label);
            let at = curve.at(50_000).unwrap();
            assert!((at.mean - mean_50k).abs() < 0.2, "{env}: {at:?}");
            assert!((at.std - std_50k).abs() < 0.2, "{env}: {at:?}");
            assert!(
                (curve.at(100_000).unwrap().mean - mean_100k).abs() < 0.2,
                "{env}"
            );
        }
    }

    #[test]
    fn the_curve_is_read_at_its_points_and_between_them_only() {
        let hopper = mbpo_paper_curve("Hopper-v5").unwrap();
        let (first, last) = (hopper.points[0], *hopper.points.last().unwrap());
        assert_eq!((first.env_steps, last.env_steps), (6019, 125_019));
        assert_eq!(hopper.at(6019), Some(first));
        assert_eq!(hopper.at(6018), None);
        assert_eq!(hopper.at(125_020), None);
        // Halfway between 49,019 (1590.6 ± 786.2) and 50,019 (1702.0 ± 799.4).
        let mid = hopper.at(49_519).unwrap();
        assert!((mid.mean - (1590.6 + 1702.0) / 2.0).abs() < 1e-9, "{mid:?}");
        assert!((mid.std - (786.2 + 799.4) / 2.0).abs() < 1e-9, "{mid:?}");
    }

    #[test]
    fn tasks_without_data_have_no_curve_and_bad_rows_are_named() {
        for env in [
            "Pendulum-v1",
            "InvertedPendulum-v5",
            "Humanoid-v5",
            "Hopper",
        ] {
            assert_eq!(mbpo_paper_curve(env), None, "{env}");
        }
        let csv = "# c\ntask,source,env_steps,mean,std\nHopper,H,1000,1.0\n";
        let err = parse_task(csv, "Hopper").unwrap_err();
        assert!(
            err.contains("line 3") && err.contains("expected task,source"),
            "{err}"
        );
        let csv = "task,source,env_steps,mean,std\nHopper,H,2000,1,0\nHopper,H,1000,1,0\n";
        assert!(parse_task(csv, "Hopper")
            .unwrap_err()
            .contains("not increasing"));
    }
}
