//! When a run counts its task as solved and ends early (`eval.stop_when_solved`): one rule for
//! `mbpo train` and `mbpo run`, fed the evaluations in the order of their eval points.

use crate::config::ExperimentConfig;

/// Evaluations in a row at or above the target return.
#[derive(Debug, Clone, PartialEq)]
pub struct SolvedRule {
    target: f64,
    needed: u32,
    streak: u32,
}

impl SolvedRule {
    /// The rule of `cfg`; `None` when the run takes every step (`eval.stop_when_solved = 0`,
    /// or a task without a target return, which validation refuses with the rule on).
    pub fn of(cfg: &ExperimentConfig) -> Option<Self> {
        let needed = cfg.eval.stop_when_solved;
        let target = cfg.target_return()?;
        (needed > 0).then_some(Self {
            target,
            needed,
            streak: 0,
        })
    }

    /// See the next eval point's return; `true` once enough evaluations in a row reached
    /// the target (and for every one after that reaches it too).
    pub fn see(&mut self, eval_return: f64) -> bool {
        self.streak = if eval_return >= self.target {
            self.streak + 1
        } else {
            0
        };
        self.streak >= self.needed
    }

    /// The rule in words, for the log: "eval return >= -200 at 2 evaluations in a row".
    pub fn describe(&self) -> String {
        format!(
            "eval return >= {} at {} evaluation(s) in a row",
            self.target, self.needed
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rule(needed: u32) -> Option<SolvedRule> {
        let mut cfg = ExperimentConfig::default(); // Pendulum-v1: target -200
        cfg.eval.stop_when_solved = needed;
        SolvedRule::of(&cfg)
    }

    #[test]
    fn the_run_is_solved_after_enough_evaluations_in_a_row_at_the_target() {
        assert_eq!(rule(0), None, "0 runs every step");
        let mut r = rule(2).unwrap();
        let seen: Vec<bool> = [-900.0, -150.0, -250.0, -200.0, -120.0, -100.0]
            .iter()
            .map(|&ret| r.see(ret))
            .collect();
        // A miss breaks the streak; the target itself counts as reached.
        assert_eq!(seen, [false, false, false, false, true, true]);
    }

    #[test]
    fn a_task_without_a_target_cannot_stop_when_solved() {
        let mut cfg = ExperimentConfig {
            env: "gym:MyEnv-v0".into(),
            ..Default::default()
        };
        cfg.eval.stop_when_solved = 2;
        let err = cfg.validate("test.toml").unwrap_err().to_string();
        assert!(err.contains("eval.stop_when_solved"), "{err}");
        cfg.eval.target_return = Some(100.0);
        assert!(SolvedRule::of(&cfg).is_some());
    }
}
