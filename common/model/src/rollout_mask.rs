//! Masked model rollouts, after M2AC (Pan, He, Tu, Liu, "Trust the Model When It Is
//! Confident: Masked Model-based Actor-Critic", NeurIPS 2020): at each rollout step only the
//! fraction of live transitions the ensemble is most sure of is stored and rolled on; the
//! rest are dropped and their rollouts end, so long rollouts do not feed SAC the states where
//! the model has left what it learned.
//!
//! M2AC scores a transition by a one-vs-rest KL between the members' Gaussians; here the score
//! is the variance over the elites of their mean predictions of `[reward, next_obs]`, summed
//! over dimensions -- the ensemble's epistemic spread, without densities. M2AC's reward penalty
//! is not applied. Not in MBPO: `mbpo.rollout_keep_fraction` (1 by default) turns it on.

use crate::error::PredictError;
use crate::model::{MaskBuffers, ProbabilisticEnsemble};

impl ProbabilisticEnsemble {
    /// The elites' disagreement on each of `n` transitions (`obs`, `act` row-major) into
    /// `out`: Σ_d Var_e μ_{e,d}, the variance over the elites e of their mean predictions,
    /// summed over the dimensions d of `[reward, next_obs]`.
    pub fn elite_disagreement(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        out: &mut [f32],
    ) -> Result<(), PredictError> {
        let mut bufs = std::mem::take(&mut self.ws.mask);
        let done = self.disagreement_into(obs, act, n, &mut bufs);
        if done.is_ok() {
            out[..n].copy_from_slice(&bufs.disagreement[..n]);
        }
        self.ws.mask = bufs;
        done
    }

    /// Mark in `b.keep` the ⌈fraction · n⌉ (at least one) of the `n` live transitions the
    /// elites disagree on least (ties: the earlier row; a NaN score ranks last); returns how
    /// many are kept.
    pub(crate) fn keep_mask(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        fraction: f64,
        b: &mut MaskBuffers,
    ) -> Result<usize, PredictError> {
        if n == 0 {
            return Ok(0);
        }
        self.disagreement_into(obs, act, n, b)?;
        let kept = ((fraction * n as f64).ceil() as usize).clamp(1, n);
        b.order.clear();
        b.order.extend(0..n as u32);
        let score = &b.disagreement;
        b.order.sort_unstable_by(|&i, &j| {
            let (si, sj) = (score[i as usize], score[j as usize]);
            si.total_cmp(&sj).then(i.cmp(&j))
        });
        b.keep.clear();
        b.keep.resize(n, false);
        for &i in &b.order[..kept] {
            b.keep[i as usize] = true;
        }
        Ok(kept)
    }

    /// [`ProbabilisticEnsemble::elite_disagreement`] into `b.disagreement`: one mean
    /// prediction per elite over all `n` rows, the moments summed in f64.
    fn disagreement_into(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        b: &mut MaskBuffers,
    ) -> Result<(), PredictError> {
        let d = 1 + self.obs_dim();
        b.members.resize(n, 0);
        b.mean.resize(n * d, 0.0);
        b.logvar.resize(n * d, 0.0);
        b.sum.clear();
        b.sum.resize(n * d, 0.0);
        b.sum_sq.clear();
        b.sum_sq.resize(n * d, 0.0);
        let elites = self.elites().len();
        for e in 0..elites {
            let member = self.elites()[e];
            b.members[..n].fill(member);
            let (mean, logvar) = (&mut b.mean[..n * d], &mut b.logvar[..n * d]);
            self.predict_gaussian(obs, act, n, &b.members[..n], mean, logvar)?;
            for ((s, q), &m) in b.sum.iter_mut().zip(b.sum_sq.iter_mut()).zip(&b.mean) {
                let m = f64::from(m);
                *s += m;
                *q += m * m;
            }
        }
        let k = elites as f64;
        b.disagreement.resize(n, 0.0);
        let rows = b.sum.chunks_exact(d).zip(b.sum_sq.chunks_exact(d));
        for (out, (sum, sum_sq)) in b.disagreement.iter_mut().zip(rows) {
            let var = sum.iter().zip(sum_sq).map(|(&s, &q)| {
                let mean = s / k;
                (q / k - mean * mean).max(0.0)
            });
            *out = var.sum::<f64>() as f32;
        }
        Ok(())
    }
}
