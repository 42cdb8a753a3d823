//! When things happen in a run, as pure functions of the env step t (1-based): warm-up, model
//! trainings and rollout branches (train points), evaluations, and the SAC updates owed. The
//! sequential trainers and every pipeline role ask this one type, so no rule is written twice.

use crate::config::{Algo, ExperimentConfig};

/// The schedule of one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Schedule {
    /// Uniform-random warm-up steps.
    pub init_random_steps: u64,
    /// Env steps per epoch.
    pub epoch_length: u64,
    /// Model retrain period in env steps.
    pub model_train_freq: u64,
    /// SAC updates per env step after the warm-up (G; 0 for MPC, which has no learner).
    pub updates_per_step: u64,
    /// Evaluate every this many env steps (and after the last one).
    pub eval_every: u64,
    /// Env steps of the run.
    pub steps: u64,
    /// Skip eval points inside the warm-up (MPC: there is no model to plan with yet).
    pub skip_warm_up_evals: bool,
    /// Updates owed at once by the last warm-up step (TD-MPC2: as many as its seed steps).
    pub burst_updates: u64,
}

impl Schedule {
    /// The schedule of a config (MPC's warm-up and retrain period for algo = "mpc").
    pub fn of(cfg: &ExperimentConfig) -> Self {
        if cfg.algo == Algo::TDMPC {
            return Self::of_tdmpc(cfg);
        }
        let mpc = cfg.algo == Algo::MPC;
        let (init_random_steps, epoch_length, model_train_freq) = match mpc {
            true => (
                cfg.mpc.init_random_steps,
                cfg.mpc.model_train_freq,
                cfg.mpc.model_train_freq,
            ),
            false => (
                cfg.mbpo.init_random_steps,
                cfg.mbpo.epoch_length,
                cfg.mbpo.model_train_freq,
            ),
        };
        Self {
            init_random_steps,
            epoch_length,
            model_train_freq,
            updates_per_step: if mpc {
                0
            } else {
                cfg.mbpo.updates_per_step as u64
            },
            eval_every: cfg.eval.every,
            steps: cfg.steps,
            skip_warm_up_evals: mpc,
            burst_updates: 0,
        }
    }
    /// TD-MPC2's: `seed_steps` of warm-up, as many updates at its last step, then
    /// `updates_per_step` per step; no model trainings or rollouts of MBPO's.
    fn of_tdmpc(cfg: &ExperimentConfig) -> Self {
        Self {
            init_random_steps: cfg.tdmpc.seed_steps,
            epoch_length: cfg.steps.max(1),
            model_train_freq: cfg.steps.max(1),
            updates_per_step: cfg.tdmpc.updates_per_step as u64,
            eval_every: cfg.eval.every,
            steps: cfg.steps,
            skip_warm_up_evals: false,
            burst_updates: cfg.tdmpc.seed_steps,
        }
    }
    /// Is step `t` a warm-up step?
    pub fn is_warm_up(&self, t: u64) -> bool {
        t <= self.init_random_steps
    }
    /// `Some(epoch)` when the model is trained and rollouts are branched before step `t`.
    pub fn train_point(&self, t: u64) -> Option<usize> {
        if self.is_warm_up(t) {
            return None;
        }
        let since = t - self.init_random_steps - 1;
        since
            .is_multiple_of(self.model_train_freq)
            .then_some((since / self.epoch_length) as usize)
    }
    /// Number of train points t' ≤ `t`: the model trainings (and imagined batches) that exist
    /// once step `t` is taken.
    pub fn train_points_upto(&self, t: u64) -> u64 {
        if t <= self.init_random_steps {
            0
        } else {
            (t - self.init_random_steps - 1) / self.model_train_freq + 1
        }
    }
    /// The env step of the `n`-th train point (where model version `n` is trained); `None`
    /// for n = 0 or past the run's last train point.
    pub fn nth_train_point(&self, n: u64) -> Option<u64> {
        let t = (n.checked_sub(1)?.checked_mul(self.model_train_freq)?)
            .checked_add(self.init_random_steps + 1)?;
        (t <= self.steps).then_some(t)
    }
    /// Is step `t` an eval point: t a multiple of `eval.every`, or the last step (MPC: not
    /// inside the warm-up)?
    pub fn is_eval_point(&self, t: u64) -> bool {
        let warm_up = self.skip_warm_up_evals && self.is_warm_up(t);
        !warm_up && (t.is_multiple_of(self.eval_every) || t == self.steps)
    }
    /// Every eval point of the run, in order.
    pub fn eval_points(&self) -> impl Iterator<Item = u64> + '_ {
        (1..=self.steps).filter(|&t| self.is_eval_point(t))
    }
    /// The first eval point after step `after` (`None`: none is left).
    pub fn next_eval_point(&self, after: u64) -> Option<u64> {
        let mut t = after;
        while t < self.steps {
            t = ((t / self.eval_every + 1) * self.eval_every).min(self.steps);
            if self.is_eval_point(t) {
                return Some(t);
            }
        }
        None
    }
    /// Eval points ≤ `t` (the evaluations a checkpoint after step `t` holds).
    pub fn eval_points_upto(&self, t: u64) -> u64 {
        (1..=t).filter(|&p| self.is_eval_point(p)).count() as u64
    }
    /// Updates owed once step `t` is consumed: G per step after the warm-up (SAC's; TD-MPC2's
    /// world model's after a burst of `burst_updates` at the warm-up's last step).
    pub fn updates_owed(&self, t: u64) -> u64 {
        let burst = match t >= self.init_random_steps {
            true => self.burst_updates,
            false => 0,
        };
        burst + t.saturating_sub(self.init_random_steps) * self.updates_per_step
    }
    /// The updates owed for step `t` alone: `updates_owed(t) − updates_owed(t − 1)`.
    pub fn updates_at(&self, t: u64) -> u64 {
        self.updates_owed(t) - self.updates_owed(t.saturating_sub(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mpc() -> ExperimentConfig {
        let mut cfg = ExperimentConfig {
            algo: Algo::MPC,
            steps: 1000,
            ..Default::default()
        };
        cfg.mpc.init_random_steps = 100;
        cfg.mpc.model_train_freq = 250;
        cfg.eval.every = 50;
        cfg
    }

    #[test]
    fn train_points_counted_listed_and_numbered_agree() {
        for cfg in [mpc(), ExperimentConfig::default()] {
            let s = Schedule::of(&cfg);
            let points: Vec<u64> = (1..=s.steps)
                .filter(|&t| s.train_point(t).is_some())
                .collect();
            for t in 0..=s.steps {
                let upto = points.iter().filter(|&&p| p <= t).count() as u64;
                assert_eq!(s.train_points_upto(t), upto, "t = {t}");
            }
            for (i, &p) in points.iter().enumerate() {
                assert_eq!(s.nth_train_point(i as u64 + 1), Some(p));
            }
            assert_eq!(s.nth_train_point(0), None, "no model: no train point");
            assert_eq!(s.nth_train_point(points.len() as u64 + 1), None);
        }
        let s = Schedule::of(&mpc());
        let firsts: Vec<_> = (1..=4).map(|n| s.nth_train_point(n).unwrap()).collect();
        // The first model right after the warm-up, then one every 250 steps.
        assert_eq!(firsts, [101, 351, 601, 851]);
    }

    #[test]
    fn eval_points_skip_the_warm_up_only_for_mpc() {
        let s = Schedule::of(&mpc());
        let points: Vec<u64> = s.eval_points().take(3).collect();
        assert_eq!(points, [150, 200, 250]);
        let mut cfg = ExperimentConfig {
            steps: 130,
            ..Default::default()
        };
        cfg.eval.every = 50;
        cfg.mbpo.init_random_steps = 100;
        let s = Schedule::of(&cfg);
        assert_eq!(s.eval_points().collect::<Vec<_>>(), [50, 100, 130]);
        assert_eq!(s.updates_owed(100), 0);
        assert_eq!(s.updates_owed(103), 3 * cfg.mbpo.updates_per_step as u64);
        let mut tdmpc = cfg.clone();
        tdmpc.algo = Algo::TDMPC;
        (tdmpc.tdmpc.seed_steps, tdmpc.tdmpc.updates_per_step) = (50, 2);
        let t = Schedule::of(&tdmpc);
        let at: Vec<u64> = [1, 49, 50, 51, 52].map(|s| t.updates_at(s)).to_vec();
        assert_eq!(
            at,
            [0, 0, 50, 2, 2],
            "the burst at the last seed step, then G"
        );
        assert_eq!(t.updates_owed(52), 54);
    }

    #[test]
    fn the_next_eval_point_is_the_first_listed_after_the_step() {
        let mut last = ExperimentConfig {
            steps: 1003,
            ..Default::default()
        };
        last.eval.every = 7;
        for cfg in [mpc(), ExperimentConfig::default(), last] {
            let s = Schedule::of(&cfg);
            let points: Vec<u64> = s.eval_points().collect();
            for after in 0..=s.steps + 1 {
                let want = points.iter().copied().find(|&p| p > after);
                assert_eq!(s.next_eval_point(after), want, "after {after}");
            }
        }
    }
}
