//! [`PlannerConfig`]: which planner, and every setting of each, with published defaults.
//!
//! Deserialises from a partial table (missing keys keep their defaults, unknown keys are an
//! error), like the model's and SAC's configs.

use crate::error::PlanError;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// The planning algorithm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum PlannerKind {
    /// Random shooting: the best of N uniform action sequences.
    Random,
    /// Cross-entropy method (PETS' CEM).
    Cem,
    /// Reward-weighted refinement with filtered noise (MPPI as in PDDM).
    Mppi,
    /// Gradient ascent on the action sequence through the model (Adam).
    Grad,
}

impl PlannerKind {
    /// Lower-case name (as in config files).
    pub fn name(self) -> &'static str {
        match self {
            PlannerKind::Random => "random",
            PlannerKind::Cem => "cem",
            PlannerKind::Mppi => "mppi",
            PlannerKind::Grad => "grad",
        }
    }
}

/// Random shooting settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RandomConfig {
    /// Sequences drawn uniformly from the action box per plan.
    pub candidates: usize,
}

impl Default for RandomConfig {
    fn default() -> Self {
        Self { candidates: 2500 }
    }
}

/// CEM settings (Chua et al. 2018, PETS `dmbrl/controllers/MPC.py` and `optimizers/cem.py`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct CemConfig {
    /// Population per iteration (PETS: 500).
    pub candidates: usize,
    /// Elites refitted per iteration (PETS: 50).
    pub elites: usize,
    /// Iterations per plan (PETS: 5).
    pub iterations: usize,
    /// Smoothing: new = alpha·old + (1 − alpha)·refit, for mean and variance (PETS: 0.1).
    pub alpha: f32,
    /// Initial standard deviation in the [−1, 1] box, (high − low)/4 (PETS' initial variance).
    pub init_std: f32,
}

impl Default for CemConfig {
    fn default() -> Self {
        Self {
            candidates: 500,
            elites: 50,
            iterations: 5,
            alpha: 0.1,
            init_std: 0.5,
        }
    }
}

/// MPPI settings (Nagabandi et al. 2019, PDDM §4: reward-weighted mean with filtered noise).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct MppiConfig {
    /// Sampled sequences per iteration (PDDM: 700).
    pub candidates: usize,
    /// Refinement iterations per plan (PDDM: 1).
    pub iterations: usize,
    /// γ: weights are exp(γ·(R − max R)) (PDDM: 10 on its reward scale).
    pub temperature: f32,
    /// β: filtered noise n_t = β·u_t + (1 − β)·n_{t−1} (PDDM: 0.6).
    pub beta: f32,
    /// σ of the raw noise u_t ~ N(0, σ²) in the [−1, 1] box (PDDM: 0.9 of the unit box).
    pub sigma: f32,
}

impl Default for MppiConfig {
    fn default() -> Self {
        Self {
            candidates: 700,
            iterations: 1,
            temperature: 10.0,
            beta: 0.6,
            sigma: 0.9,
        }
    }
}

/// Gradient-planner settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct GradConfig {
    /// Sequences optimised in parallel: the warm-started one plus uniform random restarts.
    pub sequences: usize,
    /// Adam steps per plan.
    pub iterations: usize,
    /// Adam learning rate (in units of the [−1, 1] box per step).
    pub lr: f32,
}

impl Default for GradConfig {
    fn default() -> Self {
        Self {
            sequences: 16,
            iterations: 20,
            lr: 0.1,
        }
    }
}

/// One planner's configuration (`[mpc.planner]` of an experiment file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct PlannerConfig {
    /// Which planner runs.
    pub kind: PlannerKind,
    /// Planning horizon H in env steps (PETS: 30 on its MuJoCo tasks).
    pub horizon: usize,
    /// Particles per action sequence for trajectory sampling; particle p is bound to one
    /// member for the whole horizon (TS∞) (PETS: 20).
    pub particles: usize,
    /// Random shooting.
    pub random: RandomConfig,
    /// CEM.
    pub cem: CemConfig,
    /// MPPI / PDDM.
    pub mppi: MppiConfig,
    /// Gradient planner.
    pub grad: GradConfig,
    /// Wall milliseconds one plan may take (0: no budget). CEM, MPPI and the gradient planner
    /// then stop before an iteration that would overrun it (the first always runs; at most
    /// their `iterations`), so a planning actor on a clock (`actor.control_hz`) meets its
    /// period with as many iterations as fit: set `iterations` high and let the budget decide.
    /// Its log reports the iterations per plan. A budget makes plans depend on the machine's
    /// speed: lockstep refuses it, and two runs differ.
    pub budget_ms: f64,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            kind: PlannerKind::Cem,
            horizon: 30,
            particles: 20,
            random: RandomConfig::default(),
            cem: CemConfig::default(),
            mppi: MppiConfig::default(),
            grad: GradConfig::default(),
            budget_ms: 0.0,
        }
    }
}

impl PlannerConfig {
    /// The time budget of one plan (`budget_ms`), if any.
    pub fn budget(&self) -> Option<std::time::Duration> {
        (self.budget_ms > 0.0).then(|| std::time::Duration::from_secs_f64(self.budget_ms / 1e3))
    }

    /// Check every range (keys are reported relative to the planner table, e.g. `cem.elites`).
    pub fn validate(&self) -> Result<(), PlanError> {
        let bad = |key: &str, expected: &str, found: String| {
            Err(PlanError::Config {
                key: key.into(),
                expected: expected.into(),
                found,
            })
        };
        let positive = [
            ("horizon", self.horizon),
            ("particles", self.particles),
            ("random.candidates", self.random.candidates),
            ("cem.candidates", self.cem.candidates),
            ("cem.iterations", self.cem.iterations),
            ("mppi.candidates", self.mppi.candidates),
            ("mppi.iterations", self.mppi.iterations),
            ("grad.sequences", self.grad.sequences),
            ("grad.iterations", self.grad.iterations),
        ];
        for (key, v) in positive {
            if v == 0 {
                return bad(key, "a positive integer", v.to_string());
            }
        }
        if self.cem.elites == 0 || self.cem.elites > self.cem.candidates {
            return bad(
                "cem.elites",
                &format!("between 1 and cem.candidates = {}", self.cem.candidates),
                self.cem.elites.to_string(),
            );
        }
        let unit = [("cem.alpha", self.cem.alpha), ("mppi.beta", self.mppi.beta)];
        for (key, v) in unit {
            if !(0.0..=1.0).contains(&v) {
                return bad(key, "in [0, 1]", v.to_string());
            }
        }
        if self.mppi.beta == 0.0 {
            return bad(
                "mppi.beta",
                "in (0, 1] (0 would ignore all noise)",
                "0".into(),
            );
        }
        let pos = [
            ("cem.init_std", self.cem.init_std),
            ("mppi.temperature", self.mppi.temperature),
            ("mppi.sigma", self.mppi.sigma),
            ("grad.lr", self.grad.lr),
        ];
        for (key, v) in pos {
            if !(v > 0.0 && v.is_finite()) {
                return bad(key, "a positive number", v.to_string());
            }
        }
        if !(self.budget_ms >= 0.0 && self.budget_ms.is_finite()) {
            return bad(
                "budget_ms",
                "0 (no budget) or a positive number of milliseconds",
                self.budget_ms.to_string(),
            );
        }
        Ok(())
    }

    /// Candidate sequences evaluated per iteration by the configured planner.
    pub fn candidates(&self) -> usize {
        match self.kind {
            PlannerKind::Random => self.random.candidates,
            PlannerKind::Cem => self.cem.candidates,
            PlannerKind::Mppi => self.mppi.candidates,
            PlannerKind::Grad => self.grad.sequences,
        }
    }

    /// Iterations per plan of the configured planner.
    pub fn iterations(&self) -> usize {
        match self.kind {
            PlannerKind::Random => 1,
            PlannerKind::Cem => self.cem.iterations,
            PlannerKind::Mppi => self.mppi.iterations,
            PlannerKind::Grad => self.grad.iterations,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_tables_keep_defaults_and_typos_are_rejected() {
        let c: PlannerConfig =
            toml::from_str("kind = \"mppi\"\nhorizon = 15\n[mppi]\nbeta = 0.5\n").unwrap();
        assert_eq!(
            (c.kind, c.horizon, c.particles),
            (PlannerKind::Mppi, 15, 20)
        );
        assert_eq!((c.mppi.beta, c.mppi.candidates), (0.5, 700));
        c.validate().unwrap();
        let err = toml::from_str::<PlannerConfig>("[cem]\nelite = 3\n").unwrap_err();
        assert!(err.to_string().contains("elite"), "{err}");
    }

    #[test]
    fn bad_ranges_name_the_key() {
        let mut c = PlannerConfig::default();
        c.cem.elites = 600;
        let err = c.validate().unwrap_err().to_string();
        assert!(err.contains("cem.elites") && err.contains("600"), "{err}");
        let mut c = PlannerConfig::default();
        c.mppi.temperature = -1.0;
        assert!(c
            .validate()
            .unwrap_err()
            .to_string()
            .contains("mppi.temperature"));
        let c = PlannerConfig {
            horizon: 0,
            ..PlannerConfig::default()
        };
        assert!(c.validate().unwrap_err().to_string().contains("horizon"));
    }
}
