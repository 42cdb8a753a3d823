//! The MBPO paper's own learning curves, to put next to ours at the same env steps.
//!
//! The authors shared their TensorFlow runs' curves (mean over seeds) as pickles behind a Drive
//! link that is not reachable from here; Xingyu-Lin/mbpo_pytorch plots them as
//! `results/hopper.png` and `results/walker2d.png` (`make_plot.py`: `data['y']`, the line in
//! colour #1f77b4). The points below were read off those PNGs: at each env step, the mean row of
//! the line's pixels in the columns around it, mapped through the axes' gridlines. One pixel is
//! about 16 (Hopper) and 17 (Walker2d) in return, so read them as ±25. The authors ran the v2
//! tasks on MuJoCo 1.5; ours are v5 on MuJoCo 3, whose simulator and task details differ, so
//! the comparison is of shape and level, not to the unit. HalfCheetah and Ant have no such
//! plot; they have no curve here.

/// A reference learning curve: eval return at env steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperCurve {
    /// What the curve is, for legends and tables.
    pub label: &'static str,
    /// (env steps, eval return), sorted by env steps.
    pub points: &'static [(u64, f64)],
}

impl PaperCurve {
    /// The curve's return at `env_steps`, linearly interpolated between the read-off points;
    /// `None` outside them (the curve says nothing there).
    pub fn at(&self, env_steps: u64) -> Option<f64> {
        let after = self.points.partition_point(|(s, _)| *s < env_steps);
        let &(s1, r1) = self.points.get(after)?;
        if s1 == env_steps {
            return Some(r1);
        }
        let &(s0, r0) = self.points.get(after.checked_sub(1)?)?;
        let t = (env_steps - s0) as f64 / (s1 - s0) as f64;
        Some(r0 + t * (r1 - r0))
    }
}

/// Hopper-v2, the authors' TF runs, every 5000 env steps from 10k (the line starts at 5.5k).
const HOPPER: &[(u64, f64)] = &[
    (10_000, 356.0),
    (15_000, 482.0),
    (20_000, 552.0),
    (25_000, 608.0),
    (30_000, 713.0),
    (35_000, 785.0),
    (40_000, 921.0),
    (45_000, 1301.0),
    (50_000, 1753.0),
    (55_000, 2242.0),
    (60_000, 2666.0),
    (65_000, 2942.0),
    (70_000, 3102.0),
    (75_000, 3052.0),
    (80_000, 3131.0),
    (85_000, 3259.0),
    (90_000, 3215.0),
    (95_000, 3223.0),
    (100_000, 3331.0),
    (105_000, 3359.0),
    (110_000, 3339.0),
    (115_000, 3409.0),
    (120_000, 3371.0),
];

/// Walker2d-v2, the authors' TF runs, every 5000 env steps (15k is hidden under the PyTorch
/// port's line in the plot).
const WALKER2D: &[(u64, f64)] = &[
    (5_000, 103.0),
    (10_000, 247.0),
    (20_000, 416.0),
    (25_000, 445.0),
    (30_000, 472.0),
    (35_000, 559.0),
    (40_000, 626.0),
    (45_000, 729.0),
    (50_000, 862.0),
    (55_000, 1112.0),
    (60_000, 1572.0),
    (65_000, 1926.0),
    (70_000, 2023.0),
    (75_000, 1952.0),
    (80_000, 2349.0),
    (85_000, 2943.0),
    (90_000, 3162.0),
    (95_000, 3298.0),
    (100_000, 3493.0),
    (105_000, 3668.0),
    (110_000, 3575.0),
    (115_000, 3476.0),
    (120_000, 3572.0),
    (125_000, 3550.0),
    (130_000, 3278.0),
    (135_000, 2978.0),
    (140_000, 3313.0),
    (145_000, 3949.0),
    (150_000, 4052.0),
    (155_000, 3786.0),
    (160_000, 3939.0),
    (165_000, 4052.0),
    (170_000, 3694.0),
    (175_000, 3606.0),
    (180_000, 4026.0),
    (185_000, 4255.0),
    (190_000, 4186.0),
    (195_000, 3961.0),
    (200_000, 4102.0),
    (205_000, 4122.0),
    (210_000, 3956.0),
    (215_000, 4178.0),
    (220_000, 4364.0),
    (225_000, 4249.0),
    (230_000, 4239.0),
    (235_000, 4524.0),
    (240_000, 4655.0),
    (245_000, 4600.0),
    (250_000, 4501.0),
    (255_000, 4498.0),
    (260_000, 4230.0),
    (265_000, 4211.0),
    (270_000, 4507.0),
    (275_000, 4857.0),
    (280_000, 4789.0),
    (285_000, 4712.0),
    (290_000, 4702.0),
    (295_000, 4798.0),
    (300_000, 4908.0),
];

/// The paper's MBPO curve for `env` (a task id such as `Hopper-v5`, or with a prefix such as
/// Gymnasium's `gym:Hopper-v5`), if the authors' data was plotted for it.
pub fn mbpo_paper_curve(env: &str) -> Option<PaperCurve> {
    let task = env.rsplit_once(':').map_or(env, |(_, task)| task);
    let (label, points) = match task.split_once("-v").map(|(name, _)| name)? {
        "Hopper" => ("MBPO paper, Hopper-v2 (authors' runs, mean)", HOPPER),
        "Walker2d" => ("MBPO paper, Walker2d-v2 (authors' runs, mean)", WALKER2D),
        _ => return None,
    };
    Some(PaperCurve { label, points })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_curve_is_read_at_its_points_and_between_them_only() {
        let hopper = mbpo_paper_curve("Hopper-v5").unwrap();
        assert_eq!(hopper.at(50_000), Some(1753.0));
        assert_eq!(hopper.at(52_500), Some((1753.0 + 2242.0) / 2.0));
        assert_eq!(hopper.at(9_999), None);
        assert_eq!(hopper.at(120_001), None);
        assert_eq!(hopper.at(120_000), Some(3371.0));
        // Walker2d has no point at 15k: halfway between 10k and 20k.
        let walker = mbpo_paper_curve("gym:Walker2d-v5").unwrap();
        assert_eq!(walker.at(15_000), Some((247.0 + 416.0) / 2.0));
    }

    #[test]
    fn only_the_plotted_tasks_have_a_curve() {
        for env in ["HalfCheetah-v5", "Ant-v5", "Pendulum-v1", "Hopper"] {
            assert_eq!(mbpo_paper_curve(env), None, "{env}");
        }
        for points in [HOPPER, WALKER2D] {
            assert!(points.windows(2).all(|w| w[0].0 < w[1].0));
        }
    }
}
