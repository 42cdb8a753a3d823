//! Standardisation of the model's inputs `[obs, act]`.

use mbpo_core::Batch;
use serde::{Deserialize, Serialize};

/// Per-dimension `(x − mean) / std` of the model input `[obs, act]`.
///
/// Fitted on the training split at every training call (MBPO's `StandardScaler.fit`):
/// population std (NumPy's default `ddof = 0`), and a std below 1e-12 is replaced by 1 so a
/// constant input maps to 0 instead of dividing by zero.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputNormalizer {
    /// Per-dimension mean.
    pub mean: Vec<f32>,
    /// Per-dimension standard deviation (1 where the data's was below 1e-12).
    pub std: Vec<f32>,
}

/// Standard deviations below this are replaced by 1 (`StandardScaler`).
const MIN_STD: f64 = 1e-12;

impl InputNormalizer {
    /// The identity transform on `dim` inputs (mean 0, std 1): the state before the first fit.
    pub fn identity(dim: usize) -> Self {
        Self {
            mean: vec![0.0; dim],
            std: vec![1.0; dim],
        }
    }

    /// Input dimension.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// Fit on the rows `rows` of `data` (two passes in f64: mean, then variance about it).
    /// An empty row set gives the identity.
    pub fn fit(&mut self, data: &Batch, rows: &[u32]) {
        let (o, a) = (data.obs_dim, data.act_dim);
        let dim = o + a;
        *self = Self::identity(dim);
        if rows.is_empty() {
            return;
        }
        let input = |r: usize| {
            data.obs[r * o..(r + 1) * o]
                .iter()
                .chain(&data.act[r * a..(r + 1) * a])
        };
        let n = rows.len() as f64;
        let mut mean = vec![0.0f64; dim];
        for &r in rows {
            mean.iter_mut()
                .zip(input(r as usize))
                .for_each(|(m, &v)| *m += v as f64);
        }
        mean.iter_mut().for_each(|m| *m /= n);
        let mut var = vec![0.0f64; dim];
        for &r in rows {
            for ((s, &v), &m) in var.iter_mut().zip(input(r as usize)).zip(&mean) {
                let d = v as f64 - m;
                *s += d * d;
            }
        }
        self.mean = mean.iter().map(|&m| m as f32).collect();
        self.std = var
            .iter()
            .map(|&s| {
                let std = (s / n).sqrt();
                if std < MIN_STD {
                    1.0
                } else {
                    std as f32
                }
            })
            .collect();
    }

    /// Write the standardised row `[obs, act]` into `out` (`dim` long).
    #[inline]
    pub fn transform_into(&self, obs: &[f32], act: &[f32], out: &mut [f32]) {
        let values = obs.iter().chain(act);
        for (((o, &v), &m), &s) in out.iter_mut().zip(values).zip(&self.mean).zip(&self.std) {
            *o = (v - m) / s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_population_std_and_guards_constant_inputs() {
        // obs = [x, 5], act = [-x]; x in {1, 2, 3, 4}; row 4 (x = 100) is not in the fit.
        let mut b = Batch::new(2, 1, 5);
        for (r, x) in [1.0f32, 2.0, 3.0, 4.0, 100.0].iter().enumerate() {
            b.obs[2 * r] = *x;
            b.obs[2 * r + 1] = 5.0;
            b.act[r] = -x;
        }
        let mut n = InputNormalizer::identity(3);
        n.fit(&b, &[0, 1, 2, 3]);
        assert_eq!(n.mean, vec![2.5, 5.0, -2.5]);
        let std = 1.25f32.sqrt(); // population variance of {1,2,3,4} is 1.25
        assert!((n.std[0] - std).abs() < 1e-7 && (n.std[2] - std).abs() < 1e-7);
        assert_eq!(n.std[1], 1.0, "constant input keeps std 1");
        let mut out = [0.0; 3];
        n.transform_into(&[4.0, 5.0], &[-4.0], &mut out);
        assert!((out[0] - 1.5 / std).abs() < 1e-6);
        assert_eq!(out[1], 0.0);
        assert!((out[2] + 1.5 / std).abs() < 1e-6);
    }
}
