//! The `[tdmpc]` table: TD-MPC2 (Hansen, Su, Wang, ICLR 2024) on a latent world model
//! (algo = "tdmpc"). Defaults are the paper's (its 1M-parameter preset, which suits a CPU);
//! `size = "5m"` takes the 5M preset, and each width can be set on its own.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// TD-MPC2's model-size presets (its `MODEL_SIZE` table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum TdmpcSize {
    /// About 1M parameters: latent 128, encoder 256, hidden 384, 2 Q heads.
    #[serde(rename = "1m")]
    OneM,
    /// About 5M parameters: latent 512, encoder 256, hidden 512, 5 Q heads.
    #[serde(rename = "5m")]
    FiveM,
}

/// The widths a run's networks have: the preset's, or the config's where it sets one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TdmpcWidths {
    /// Latent width (a multiple of 8, SimNorm's group).
    pub latent: usize,
    /// The encoder's hidden width.
    pub encoder_hidden: usize,
    /// The hidden width of the dynamics, reward, Q and policy networks.
    pub hidden: usize,
    /// Q heads.
    pub q_heads: usize,
}

/// Settings of TD-MPC2 (algo = "tdmpc"): `seed_steps` uniform-random env steps, then as many
/// updates at once; after that one MPPI plan in the latent space and `updates_per_step`
/// updates per env step, each on `batch_size` subsequences of `horizon` steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct TdmpcConfig {
    /// Model-size preset, "1m" or "5m" (the widths below override its parts).
    pub size: TdmpcSize,
    /// Latent width; unset: the preset's. A multiple of 8 (SimNorm's group).
    pub latent: Option<usize>,
    /// The encoder's hidden width; unset: the preset's.
    pub encoder_hidden: Option<usize>,
    /// Hidden width of the dynamics, reward, Q and policy networks; unset: the preset's.
    pub hidden: Option<usize>,
    /// Q heads (at least 2: targets take the minimum of two drawn at random); unset: the
    /// preset's.
    pub q_heads: Option<usize>,
    /// Horizon H of the loss and of planning.
    pub horizon: usize,
    /// Uniform-random env steps before planning; after the last of them the model takes as
    /// many updates at once (TD-MPC2 uses max(1000, 5 episodes)).
    pub seed_steps: u64,
    /// Updates per env step after the seed steps.
    pub updates_per_step: u32,
    /// Subsequences per update.
    pub batch_size: usize,
    /// Adam's learning rate (the encoder's is 0.3 of it).
    pub lr: f32,
    /// γ of the TD targets; unset: TD-MPC2's rule from the task's episode length L,
    /// (L/5 − 1)/(L/5) clipped to [0.95, 0.995].
    pub discount: Option<f32>,
    /// ρ: the loss of step t of the horizon is weighted ρᵗ.
    pub rho: f32,
    /// Weight of the latent consistency loss.
    pub consistency_coef: f32,
    /// Weight of the reward loss.
    pub reward_coef: f32,
    /// Weight of the value loss.
    pub value_coef: f32,
    /// Dropout of the Q heads' first layer while learning (not in the TD targets' heads nor
    /// in planning).
    pub q_dropout: f32,
    /// Real transitions kept (a ring); 0: all of the run's steps.
    pub buffer_capacity: u64,
    /// Planning: MPPI in the latent space.
    pub planner: LatentPlannerConfig,
}

impl Default for TdmpcConfig {
    fn default() -> Self {
        Self {
            size: TdmpcSize::OneM,
            latent: None,
            encoder_hidden: None,
            hidden: None,
            q_heads: None,
            horizon: 3,
            seed_steps: 1000,
            updates_per_step: 1,
            batch_size: 256,
            lr: 3e-4,
            discount: None,
            rho: 0.5,
            consistency_coef: 20.0,
            reward_coef: 0.1,
            value_coef: 0.1,
            q_dropout: 0.01,
            buffer_capacity: 0,
            planner: LatentPlannerConfig::default(),
        }
    }
}

/// MPPI over latent action sequences with the value at the horizon (TD-MPC2's defaults).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct LatentPlannerConfig {
    /// Candidate action sequences per iteration.
    pub samples: usize,
    /// Of them, sequences rolled out by the policy prior.
    pub policy_samples: usize,
    /// The best sequences the sampling distribution moves to.
    pub elites: usize,
    /// Iterations per plan.
    pub iterations: usize,
    /// Lower bound of the sampling σ.
    pub min_std: f32,
    /// Upper bound (and start) of the sampling σ.
    pub max_std: f32,
    /// Temperature of the elites' weights.
    pub temperature: f32,
    /// Wall milliseconds one plan may take (0: no budget): iterations stop before one that
    /// would overrun it (the first always runs; at most `iterations`), so an actor on a clock
    /// plans within its period; the log reports the iterations per plan. A budget makes plans
    /// depend on the machine's speed, so two runs differ.
    pub budget_ms: f64,
    /// Arithmetic of the plan's matrix products: "f32", or "bf16" -- inputs rounded to bf16,
    /// sums in f32, on Intel AMX (Xeon 4th generation and later), where a plan costs about
    /// half (results/RESULTS.md); on a CPU without AMX the plan stays f32 and the log says so.
    /// Plans differ from f32 ones by the rounding; learning is unchanged (the learner is f32).
    pub precision: PlanPrecision,
}

/// The arithmetic of a plan's matrix products (`tdmpc.planner.precision`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum PlanPrecision {
    /// f32 throughout (the paper's).
    #[default]
    F32,
    /// bf16 inputs and f32 sums on AMX where the CPU has it, f32 elsewhere.
    Bf16,
}

impl Default for LatentPlannerConfig {
    fn default() -> Self {
        Self {
            samples: 512,
            policy_samples: 24,
            elites: 64,
            iterations: 6,
            min_std: 0.05,
            max_std: 2.0,
            temperature: 0.5,
            budget_ms: 0.0,
            precision: PlanPrecision::F32,
        }
    }
}

impl LatentPlannerConfig {
    /// The time budget of one plan (`budget_ms`), if any.
    pub fn budget(&self) -> Option<std::time::Duration> {
        (self.budget_ms > 0.0).then(|| std::time::Duration::from_secs_f64(self.budget_ms / 1e3))
    }
}

impl TdmpcConfig {
    /// The networks' widths: the preset's, each replaced where the config sets it.
    pub fn widths(&self) -> TdmpcWidths {
        let preset = match self.size {
            TdmpcSize::OneM => TdmpcWidths {
                latent: 128,
                encoder_hidden: 256,
                hidden: 384,
                q_heads: 2,
            },
            TdmpcSize::FiveM => TdmpcWidths {
                latent: 512,
                encoder_hidden: 256,
                hidden: 512,
                q_heads: 5,
            },
        };
        TdmpcWidths {
            latent: self.latent.unwrap_or(preset.latent),
            encoder_hidden: self.encoder_hidden.unwrap_or(preset.encoder_hidden),
            hidden: self.hidden.unwrap_or(preset.hidden),
            q_heads: self.q_heads.unwrap_or(preset.q_heads),
        }
    }

    /// γ for a task of `episode_length` steps: the config's, or TD-MPC2's rule.
    pub fn discount_for(&self, episode_length: usize) -> f32 {
        self.discount.unwrap_or_else(|| {
            let frac = episode_length as f32 / 5.0;
            ((frac - 1.0) / frac).clamp(0.95, 0.995)
        })
    }

    /// Replay capacity for a run of `steps` env steps.
    pub fn capacity_for(&self, steps: u64) -> usize {
        match self.buffer_capacity {
            0 => steps as usize,
            n => n as usize,
        }
    }

    /// Every value in range: `Err((key under "tdmpc.", expected, found))` names the first
    /// that is not.
    pub fn check(&self) -> Result<(), (String, String, String)> {
        let w = self.widths();
        let p = &self.planner;
        let err = |key: &str, expected: &str, found: String| {
            Err((key.to_string(), expected.to_string(), found))
        };
        if w.latent == 0 || !w.latent.is_multiple_of(8) {
            return err("latent", "a positive multiple of 8", w.latent.to_string());
        }
        if w.q_heads < 2 {
            return err("q_heads", "at least 2", w.q_heads.to_string());
        }
        let positive = [
            ("encoder_hidden", w.encoder_hidden as f64),
            ("hidden", w.hidden as f64),
            ("horizon", self.horizon as f64),
            ("updates_per_step", self.updates_per_step as f64),
            ("batch_size", self.batch_size as f64),
            ("lr", self.lr as f64),
            ("planner.samples", p.samples as f64),
            ("planner.elites", p.elites as f64),
            ("planner.iterations", p.iterations as f64),
            ("planner.min_std", p.min_std as f64),
            ("planner.temperature", p.temperature as f64),
        ];
        if let Some((key, v)) = positive.iter().find(|(_, v)| !(*v > 0.0 && v.is_finite())) {
            return err(key, "a positive number", v.to_string());
        }
        if !(0.0..1.0).contains(&self.q_dropout) {
            return err(
                "q_dropout",
                "a fraction in [0, 1)",
                self.q_dropout.to_string(),
            );
        }
        if !(p.budget_ms >= 0.0 && p.budget_ms.is_finite()) {
            let expected = "0 (no budget) or a positive number of milliseconds";
            return err("planner.budget_ms", expected, p.budget_ms.to_string());
        }
        if let Some(g) = self.discount.filter(|g| !(*g > 0.0 && *g < 1.0)) {
            return err("discount", "a number in (0, 1)", g.to_string());
        }
        if self.seed_steps < self.horizon as u64 {
            let expected = format!("at least tdmpc.horizon ({}): the first updates learn from the seed steps' subsequences", self.horizon);
            return err("seed_steps", &expected, self.seed_steps.to_string());
        }
        if p.max_std < p.min_std {
            let expected = format!("at least planner.min_std ({})", p.min_std);
            return err("planner.max_std", &expected, p.max_std.to_string());
        }
        if p.policy_samples >= p.samples || p.elites > p.samples {
            let expected = format!(
                "fewer policy samples and elites than samples ({})",
                p.samples
            );
            let found = format!("policy_samples {}, elites {}", p.policy_samples, p.elites);
            return err("planner", &expected, found);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_give_the_papers_widths_and_a_set_width_replaces_its_part() {
        let mut c = TdmpcConfig::default();
        assert_eq!(c.widths().latent, 128);
        c.size = TdmpcSize::FiveM;
        c.hidden = Some(64);
        let w = c.widths();
        assert_eq!((w.latent, w.hidden, w.q_heads), (512, 64, 5));
    }

    #[test]
    fn the_discount_follows_the_episode_length_unless_set() {
        let mut c = TdmpcConfig::default();
        assert_eq!(c.discount_for(200), 0.975);
        assert_eq!(c.discount_for(1000), 0.995);
        assert_eq!(c.discount_for(20), 0.95);
        c.discount = Some(0.9);
        assert_eq!(c.discount_for(1000), 0.9);
    }

    #[test]
    fn out_of_range_values_are_named() {
        let mut c = TdmpcConfig {
            latent: Some(12),
            ..Default::default()
        };
        assert_eq!(c.check().unwrap_err().0, "latent");
        c.latent = None;
        c.planner.policy_samples = 600;
        let (key, _, found) = c.check().unwrap_err();
        assert_eq!(
            (key.as_str(), found.as_str()),
            ("planner", "policy_samples 600, elites 64")
        );
        c.planner.policy_samples = 24;
        c.discount = Some(1.0);
        assert_eq!(c.check().unwrap_err().0, "discount");
        assert!(TdmpcConfig::default().check().is_ok());
    }
}
