//! How a model snapshot ([`ModelWeights`]) crosses shared memory: one flat `[f32]`,
//!
//! ```text
//! [ θ (n_params, ParamLayout order) | normaliser mean (obs+act) | normaliser std (obs+act) | elites (as f32) ]
//! ```
//!
//! The weights header's layout hash is the ensemble's `ParamLayout::hash`; the lengths of the
//! other parts follow from the config (obs+act inputs, `model.elites` elites), so a mismatch in
//! any of them changes the total length and is rejected by the subscriber.

use mbpo_model::{ModelWeights, ProbabilisticEnsemble};

use crate::error::DecodeError;

/// The flat layout of the model snapshots of one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ModelWireLayout {
    /// `ParamLayout::hash` of the ensemble.
    pub layout_hash: u64,
    /// Floats of θ.
    pub n_params: usize,
    /// Model input width (obs + act).
    pub in_dim: usize,
    /// Number of elites.
    pub elites: usize,
    /// Floats of the learned termination rule (params, input mean, input std); 0 without one.
    pub termination: usize,
}

impl ModelWireLayout {
    /// The layout of `model`'s snapshots with `elites` elites.
    pub fn of_model(model: &ProbabilisticEnsemble, elites: usize) -> Self {
        Self {
            layout_hash: model.layout().hash(),
            n_params: model.params().len(),
            in_dim: model.obs_dim() + model.act_dim(),
            elites,
            termination: model.termination().map_or(0, |c| c.wire_len()),
        }
    }
    /// Total floats.
    pub fn len(&self) -> usize {
        self.n_params + 2 * self.in_dim + self.elites + self.termination
    }
    /// Never empty.
    pub fn is_empty(&self) -> bool {
        false
    }
    /// Write `w` into `out` (resized to [`ModelWireLayout::len`]).
    pub fn encode(&self, w: &ModelWeights, out: &mut Vec<f32>) -> Result<(), DecodeError> {
        if w.layout_hash != self.layout_hash
            || w.params.len() != self.n_params
            || w.normalizer.mean.len() != self.in_dim
            || w.normalizer.std.len() != self.in_dim
            || w.elites.len() != self.elites
            || w.termination
                .as_ref()
                .map_or(0, |t| t.params.len() + t.mean.len() + t.std.len())
                != self.termination
        {
            return Err(DecodeError::ModelWeights(format!(
                "layout {self:?}, weights with hash {:#x}, {} params, {} inputs, {} elites",
                w.layout_hash,
                w.params.len(),
                w.normalizer.mean.len(),
                w.elites.len()
            )));
        }
        out.clear();
        out.extend_from_slice(&w.params);
        out.extend_from_slice(&w.normalizer.mean);
        out.extend_from_slice(&w.normalizer.std);
        out.extend(w.elites.iter().map(|&e| e as f32));
        if let Some(t) = &w.termination {
            out.extend_from_slice(&t.params);
            out.extend_from_slice(&t.mean);
            out.extend_from_slice(&t.std);
        }
        Ok(())
    }
    /// θ, normaliser mean, normaliser std, elites (as f32) and the termination rule's floats
    /// of the snapshot `flat`.
    fn parts<'f>(&self, flat: &'f [f32]) -> Result<[&'f [f32]; 5], DecodeError> {
        if flat.len() != self.len() {
            return Err(DecodeError::ModelLength {
                expected: self.len(),
                found: flat.len(),
            });
        }
        let (p, rest) = flat.split_at(self.n_params);
        let (mean, rest) = rest.split_at(self.in_dim);
        let (std, rest) = rest.split_at(self.in_dim);
        let (elites, termination) = rest.split_at(self.elites);
        Ok([p, mean, std, elites, termination])
    }
    /// Load the snapshot `flat` into `model` in place: the one copy a receiver makes out of
    /// shared memory (no intermediate [`ModelWeights`]).
    pub fn load_into(
        &self,
        flat: &[f32],
        model: &mut ProbabilisticEnsemble,
    ) -> Result<(), DecodeError> {
        let [p, mean, std, elites, termination] = self.parts(flat)?;
        // An index is a whole number >= 0 (`as usize` would truncate 1.5, NaN and -3 to members).
        if let Some(e) = elites.iter().find(|e| !(e.fract() == 0.0 && **e >= 0.0)) {
            return Err(DecodeError::ModelWeights(format!(
                "elite index {e} of a snapshot is not a whole number"
            )));
        }
        let elites = elites.iter().map(|&e| e as usize);
        let bad = |e: mbpo_model::ParamsError| DecodeError::ModelWeights(e.to_string());
        model
            .load_parts(self.layout_hash, p, mean, std, elites)
            .map_err(bad)?;
        if let Some(c) = model.termination() {
            // [params | mean | std], the mean and std one value per classifier input.
            let n = c.in_dim();
            if termination.len() != c.wire_len() {
                return Err(DecodeError::ModelWeights(format!(
                    "a snapshot with {} floats of a termination rule, the model's has {}",
                    termination.len(),
                    c.wire_len()
                )));
            }
            let (params, rest) = termination.split_at(termination.len() - 2 * n);
            let (mean, std) = rest.split_at(n);
            model
                .load_termination_parts(params, mean, std)
                .map_err(bad)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::stream;
    use mbpo_model::{InputNormalizer, ModelConfig};

    #[test]
    fn model_weights_round_trip_through_the_flat_layout() {
        let cfg = ModelConfig {
            members: 3,
            elites: 2,
            hidden: vec![8, 8],
            weight_decay: vec![1e-5, 1e-5, 1e-5],
            ..ModelConfig::default()
        };
        let model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "t", 0)).unwrap();
        let l = ModelWireLayout::of_model(&model, 2);
        let w = ModelWeights {
            layout_hash: l.layout_hash,
            params: (0..l.n_params).map(|i| i as f32 * 0.5).collect(),
            normalizer: InputNormalizer {
                mean: vec![1.0, 2.0, 3.0, 4.0],
                std: vec![0.5, 0.25, 2.0, 1.0],
            },
            elites: vec![2, 0],
            termination: None,
        };
        let mut flat = Vec::new();
        l.encode(&w, &mut flat).unwrap();
        assert_eq!(flat.len(), l.len());
        let mut loaded = model.clone();
        l.load_into(&flat, &mut loaded).unwrap();
        assert_eq!(loaded.weights(), w, "loaded in place = the weights encoded");
        let e = l.load_into(&flat[1..], &mut loaded).unwrap_err();
        assert!(e.to_string().contains(&format!("needs {}", l.len())), "{e}");
        let mut bad = w.clone();
        bad.elites.pop();
        assert!(l.encode(&bad, &mut flat).is_err());
    }

    #[test]
    fn a_learned_termination_rule_rides_at_the_end_of_the_snapshot() {
        let cfg = ModelConfig {
            members: 2,
            elites: 1,
            hidden: vec![8, 8],
            weight_decay: vec![1e-5, 1e-5, 1e-5],
            learn_termination: true,
            ..ModelConfig::default()
        };
        let model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "t", 0)).unwrap();
        let l = ModelWireLayout::of_model(&model, 1);
        let rule = model.termination().unwrap();
        assert_eq!(l.termination, rule.wire_len());
        let mut w = model.weights();
        let t = w.termination.as_mut().unwrap();
        t.params
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = i as f32 * 1e-3);
        t.mean = vec![0.5; rule.in_dim()];
        t.std = vec![2.0; rule.in_dim()];
        let mut flat = Vec::new();
        l.encode(&w, &mut flat).unwrap();
        assert_eq!(flat.len(), l.len());
        let mut loaded =
            ProbabilisticEnsemble::new(3, 1, model.config().clone(), &mut stream(1, "t", 0))
                .unwrap();
        l.load_into(&flat, &mut loaded).unwrap();
        assert_eq!(loaded.weights(), w);
        // Weights without the rule do not fit this layout.
        let mut without = w.clone();
        without.termination = None;
        assert!(l.encode(&without, &mut flat).is_err());
    }
}
