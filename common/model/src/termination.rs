//! A learned termination rule for model rollouts: P(terminated | s, a, s') by a small MLP
//! trained on the real transitions' `terminated` flags, for environments without a
//! hand-written rule (a user's Python env). MBPO itself (and mbrl-lib's `term_fn`) needs the
//! rule written by hand; this learns it with the dynamics model, from the same D_env.
//!
//! The classifier sees `[s, a, s']` standardised by mean and standard deviation fitted on the
//! training rows, has two SiLU layers of 64 units (smooth, as the ensemble's) and one logit; `done` is `logit > 0`. The loss
//! is the binary cross-entropy with logits, positives weighted by `√(negatives / positives)`: a
//! terminal transition is rare (one per episode at most), and unweighted the classifier leans to
//! "never", which lets rollouts bootstrap through terminal states; the full ratio leans the other
//! way (on 5 % positives: recall 1.0, precision 0.80; the square root: 1.0 and 0.90,
//! `tests/termination.rs`). Training follows the ensemble's recipe: a
//! holdout split, minibatch Adam, early stopping on the holdout loss (patience 5 epochs, after
//! at least 300 steps), the best epoch's weights kept; it continues from the previous
//! training's weights.

use mbpo_core::rng::shuffle;
use mbpo_core::{Batch, Rng};
use mbpo_nn::{Activation, Adam, AdamConfig, AdamState, Init, Mlp, MlpCache};
use serde::{Deserialize, Serialize};

/// Hidden layer widths of the classifier.
pub const HIDDEN: [usize; 2] = [64, 64];
const BATCH: usize = 256;
const MAX_EPOCHS: usize = 100;
/// Gradient steps before early stopping may end a training, and at most.
const MIN_STEPS: usize = 300;
const MAX_STEPS: usize = 10_000;
const PATIENCE: usize = 5;
const HOLDOUT_RATIO: f64 = 0.2;
const MAX_HOLDOUT: usize = 5000;
const LR: f32 = 1e-3;
/// Upper bound of the positive class weight (a handful of positives in a large D_env must not
/// make each one weigh thousands of negatives).
const MAX_POS_WEIGHT: f32 = 100.0;

/// What a checkpoint or a weight broadcast carries of a [`TerminationClassifier`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TerminationWeights {
    /// MLP parameters.
    pub params: Vec<f32>,
    /// Input mean, per `[s, a, s']` column.
    pub mean: Vec<f32>,
    /// Input standard deviation, per column.
    pub std: Vec<f32>,
}

/// One training call: how well the classifier separates terminal transitions on the holdout.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct TerminationReport {
    /// Epochs run (early stopping included).
    pub epochs: usize,
    /// Terminal transitions among the training rows.
    pub positives: usize,
    /// Terminal transitions among the holdout rows.
    pub holdout_positives: usize,
    /// Weighted BCE on the holdout with the kept weights.
    pub holdout_loss: f64,
    /// Of the holdout rows predicted terminal, the share that are (1 when none predicted).
    pub precision: f64,
    /// Of the terminal holdout rows, the share predicted terminal (1 when there are none).
    pub recall: f64,
}

impl std::fmt::Display for TerminationReport {
    /// `learned termination from 466 terminal rows: holdout precision 0.90, recall 1.00 (125
    /// terminal)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "learned termination from {} terminal rows: holdout precision {:.2}, recall {:.2} \
             ({} terminal)",
            self.positives, self.precision, self.recall, self.holdout_positives
        )
    }
}

/// Counts of a classifier's verdicts against the truth.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Confusion {
    /// Predicted terminal, and terminal.
    pub true_positives: usize,
    /// Predicted terminal, not terminal.
    pub false_positives: usize,
    /// Terminal, not predicted.
    pub false_negatives: usize,
    /// Verdicts counted.
    pub total: usize,
}

impl Confusion {
    /// Count one verdict.
    pub fn add(&mut self, predicted: bool, actual: bool) {
        self.total += 1;
        match (predicted, actual) {
            (true, true) => self.true_positives += 1,
            (true, false) => self.false_positives += 1,
            (false, true) => self.false_negatives += 1,
            (false, false) => {}
        }
    }
    /// Of the transitions predicted terminal, the share that are (1 when none predicted).
    pub fn precision(&self) -> f64 {
        share(self.true_positives, self.false_positives)
    }
    /// Of the terminal transitions, the share predicted terminal (1 when there are none).
    pub fn recall(&self) -> f64 {
        share(self.true_positives, self.false_negatives)
    }
    /// Share of verdicts that are right.
    pub fn accuracy(&self) -> f64 {
        let wrong = self.false_positives + self.false_negatives;
        (self.total - wrong) as f64 / self.total.max(1) as f64
    }
}

fn share(hits: usize, misses: usize) -> f64 {
    match hits + misses {
        0 => 1.0,
        n => hits as f64 / n as f64,
    }
}

/// A learned `done(s, a, s')` (see the module docs).
#[derive(Debug, Clone)]
pub struct TerminationClassifier {
    obs_dim: usize,
    act_dim: usize,
    mlp: Mlp,
    params: Vec<f32>,
    mean: Vec<f32>,
    std: Vec<f32>,
    adam: Adam,
    ws: Scratch,
}

/// Scratch memory of training and prediction (not state).
#[derive(Debug, Clone, Default)]
struct Scratch {
    cache: MlpCache,
    x: Vec<f32>,
    d_logit: Vec<f32>,
    grads: Vec<f32>,
}

impl TerminationClassifier {
    /// An untrained classifier for `obs_dim` observations and `act_dim` actions.
    pub fn new(obs_dim: usize, act_dim: usize, rng: &mut Rng) -> Self {
        let in_dim = 2 * obs_dim + act_dim;
        let dims = [in_dim, HIDDEN[0], HIDDEN[1], 1];
        let mlp = Mlp::new(&dims, Activation::Silu, Activation::Identity);
        let mut params = vec![0.0; mlp.num_params()];
        mlp.init(&mut params, Init::TorchDefault, rng);
        let adam = Adam::new(params.len(), AdamConfig::with_lr(LR));
        Self {
            obs_dim,
            act_dim,
            params,
            mean: vec![0.0; in_dim],
            std: vec![1.0; in_dim],
            adam,
            ws: Scratch {
                cache: MlpCache::new(&mlp, BATCH),
                ..Scratch::default()
            },
            mlp,
        }
    }

    /// Input width `2·obs + act`.
    pub fn in_dim(&self) -> usize {
        self.mlp.in_dim()
    }

    /// Floats of [`TerminationClassifier::weights`] on the wire: params, mean, std.
    pub fn wire_len(&self) -> usize {
        self.params.len() + 2 * self.in_dim()
    }

    /// The weights (for rollouts elsewhere and checkpoints).
    pub fn weights(&self) -> TerminationWeights {
        TerminationWeights {
            params: self.params.clone(),
            mean: self.mean.clone(),
            std: self.std.clone(),
        }
    }

    /// Load weights written by [`TerminationClassifier::weights`] of the same shape.
    pub fn load_weights(&mut self, w: &TerminationWeights) -> Result<(), String> {
        self.load_parts(&w.params, &w.mean, &w.std)
    }

    /// Load weights given as their parts (a snapshot read in place).
    pub fn load_parts(&mut self, params: &[f32], mean: &[f32], std: &[f32]) -> Result<(), String> {
        let n = self.in_dim();
        if params.len() != self.params.len() || mean.len() != n || std.len() != n {
            return Err(format!(
                "termination rule weights of {} params and {} inputs, expected {} and {n}",
                params.len(),
                mean.len(),
                self.params.len()
            ));
        }
        self.params.copy_from_slice(params);
        self.mean.copy_from_slice(mean);
        self.std.copy_from_slice(std);
        Ok(())
    }

    /// Adam's moments and step count.
    pub fn adam_state(&self) -> &AdamState {
        self.adam.state()
    }

    /// Continue training with Adam's `state` (of the same parameter count).
    pub fn set_adam_state(&mut self, state: AdamState) -> Result<(), String> {
        let n = self.params.len();
        if state.m.len() != n || state.v.len() != n {
            return Err(format!(
                "termination rule optimiser state has {}/{} moments for {n} parameters",
                state.m.len(),
                state.v.len()
            ));
        }
        self.adam.set_state(state);
        Ok(())
    }

    /// `done` for `n` transitions (row-major `obs`, `act`, `next_obs`), written to `out`.
    pub fn predict(
        &mut self,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) {
        for start in (0..n).step_by(BATCH) {
            let m = BATCH.min(n - start);
            self.fill_inputs(obs, act, next_obs, Rows::Range(start, m));
            let logits = self
                .mlp
                .forward(&self.params, &self.ws.x, m, &mut self.ws.cache);
            for (o, &z) in out[start..start + m].iter_mut().zip(logits) {
                *o = z > 0.0;
            }
        }
    }

    /// Train on `data` (its `terminated` flags), continuing from the current weights.
    pub fn train(&mut self, data: &Batch, rng: &mut Rng) -> TerminationReport {
        let n = data.len;
        if n == 0 {
            return TerminationReport::default();
        }
        let mut order: Vec<u32> = (0..n as u32).collect();
        shuffle(rng, &mut order);
        let n_hold = ((n as f64 * HOLDOUT_RATIO) as usize).min(MAX_HOLDOUT);
        let (holdout, train) = order.split_at(n_hold);
        let mut train = train.to_vec();
        let positive = |i: &u32| data.terminated[*i as usize] > 0.5;
        let positives = train.iter().filter(|i| positive(i)).count();
        let holdout_positives = holdout.iter().filter(|i| positive(i)).count();
        let pos_weight = match positives {
            0 => 1.0,
            p => ((train.len() - p) as f32 / p as f32)
                .sqrt()
                .clamp(1.0, MAX_POS_WEIGHT),
        };
        self.fit_standardisation(data, &train);
        let mut best = (self.loss_on(data, holdout, pos_weight), self.params.clone());
        let (mut epochs, mut since_best, mut steps) = (0, 0, 0);
        loop {
            // Early stopping only after MIN_STEPS: the first D_env of a run is a few hundred
            // rows, one minibatch an epoch.
            let patience_over = since_best >= PATIENCE || epochs >= MAX_EPOCHS;
            if steps >= MAX_STEPS || (steps >= MIN_STEPS && patience_over) || train.is_empty() {
                break;
            }
            shuffle(rng, &mut train);
            for chunk in train.chunks(BATCH) {
                self.loss_and_gradient(data, chunk, pos_weight);
                self.adam.step(&mut self.params, &self.ws.grads);
                steps += 1;
            }
            epochs += 1;
            let loss = self.loss_on(data, holdout, pos_weight);
            // The ensemble's rule: an improvement of more than 1 % counts (an empty holdout
            // trains for MAX_EPOCHS).
            if loss < best.0 * 0.99 || holdout.is_empty() {
                best = (loss, self.params.clone());
                since_best = 0;
            } else {
                since_best += 1;
            }
        }
        self.params = best.1;
        let (precision, recall) = self.precision_recall(data, holdout);
        TerminationReport {
            epochs,
            positives,
            holdout_positives,
            holdout_loss: best.0,
            precision,
            recall,
        }
    }

    /// Weighted BCE (mean over `rows`) and its gradient in the scratch `grads`.
    pub fn loss_and_gradient(&mut self, data: &Batch, rows: &[u32], pos_weight: f32) -> f64 {
        let m = rows.len();
        self.fill_inputs(&data.obs, &data.act, &data.next_obs, Rows::Picked(rows));
        let logits = self
            .mlp
            .forward(&self.params, &self.ws.x, m, &mut self.ws.cache);
        self.ws.d_logit.resize(m, 0.0);
        let mut loss = 0.0f64;
        for (k, &i) in rows.iter().enumerate() {
            let (z, y) = (logits[k], data.terminated[i as usize]);
            let w = if y > 0.5 { pos_weight } else { 1.0 };
            loss += (w * bce_with_logit(z, y)) as f64;
            self.ws.d_logit[k] = w * (mbpo_nn::activation::sigmoid(z) - y) / m as f32;
        }
        self.ws.grads.resize(self.params.len(), 0.0);
        let (x, cache) = (&self.ws.x, &mut self.ws.cache);
        let grads = Some(&mut self.ws.grads[..]);
        self.mlp
            .backward(&self.params, x, cache, &self.ws.d_logit, grads, None);
        loss / m.max(1) as f64
    }

    /// The gradient of the last [`TerminationClassifier::loss_and_gradient`].
    pub fn gradient(&self) -> &[f32] {
        &self.ws.grads
    }

    /// The parameters, mutably (finite-difference checks).
    pub fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    /// Call `f(logit, row)` for each of `rows`, in order.
    fn for_each_logit(&mut self, data: &Batch, rows: &[u32], mut f: impl FnMut(f32, usize)) {
        for chunk in rows.chunks(BATCH) {
            self.fill_inputs(&data.obs, &data.act, &data.next_obs, Rows::Picked(chunk));
            let (x, cache) = (&self.ws.x, &mut self.ws.cache);
            let logits = self.mlp.forward(&self.params, x, chunk.len(), cache);
            for (&z, &i) in logits.iter().zip(chunk) {
                f(z, i as usize);
            }
        }
    }

    fn loss_on(&mut self, data: &Batch, rows: &[u32], pos_weight: f32) -> f64 {
        let mut total = 0.0;
        self.for_each_logit(data, rows, |z, i| {
            let y = data.terminated[i];
            let w = if y > 0.5 { pos_weight } else { 1.0 };
            total += (w * bce_with_logit(z, y)) as f64;
        });
        total / rows.len().max(1) as f64
    }

    fn precision_recall(&mut self, data: &Batch, rows: &[u32]) -> (f64, f64) {
        let mut counts = Confusion::default();
        self.for_each_logit(data, rows, |z, i| {
            counts.add(z > 0.0, data.terminated[i] > 0.5)
        });
        (counts.precision(), counts.recall())
    }

    /// Mean and standard deviation of `[s, a, s']` over `rows` (a constant column keeps 1).
    fn fit_standardisation(&mut self, data: &Batch, rows: &[u32]) {
        let d = self.in_dim();
        let (mut sum, mut sq) = (vec![0.0f64; d], vec![0.0f64; d]);
        for &i in rows {
            for (c, v) in row_values(data, i as usize, self.obs_dim, self.act_dim).enumerate() {
                sum[c] += v as f64;
                sq[c] += v as f64 * v as f64;
            }
        }
        let n = rows.len().max(1) as f64;
        for c in 0..d {
            let mean = sum[c] / n;
            let var = (sq[c] / n - mean * mean).max(0.0);
            self.mean[c] = mean as f32;
            self.std[c] = if var.sqrt() < 1e-6 {
                1.0
            } else {
                var.sqrt() as f32
            };
        }
    }

    /// Standardised `[s, a, s']` rows into the scratch input: rows picked from data-shaped
    /// arrays, or a contiguous range.
    fn fill_inputs(&mut self, obs: &[f32], act: &[f32], next: &[f32], rows: Rows) {
        let (o, a, d) = (self.obs_dim, self.act_dim, self.in_dim());
        self.ws.x.resize(rows.len() * d, 0.0);
        for (k, x) in self.ws.x.chunks_exact_mut(d).enumerate() {
            let i = rows.index(k);
            x[..o].copy_from_slice(&obs[i * o..(i + 1) * o]);
            x[o..o + a].copy_from_slice(&act[i * a..(i + 1) * a]);
            x[o + a..].copy_from_slice(&next[i * o..(i + 1) * o]);
            for ((v, &mu), &s) in x.iter_mut().zip(&self.mean).zip(&self.std) {
                *v = (*v - mu) / s;
            }
        }
    }
}

/// Which rows [`TerminationClassifier::fill_inputs`] takes.
#[derive(Clone, Copy)]
enum Rows<'r> {
    /// The listed row indices.
    Picked(&'r [u32]),
    /// `m` rows from `start`.
    Range(usize, usize),
}

impl Rows<'_> {
    fn len(self) -> usize {
        match self {
            Rows::Picked(rows) => rows.len(),
            Rows::Range(_, m) => m,
        }
    }
    /// The data row of input row `k`.
    fn index(self, k: usize) -> usize {
        match self {
            Rows::Picked(rows) => rows[k] as usize,
            Rows::Range(start, _) => start + k,
        }
    }
}

/// `[s, a, s']` of row `i`.
fn row_values(data: &Batch, i: usize, o: usize, a: usize) -> impl Iterator<Item = f32> + '_ {
    let s = &data.obs[i * o..(i + 1) * o];
    let act = &data.act[i * a..(i + 1) * a];
    let next = &data.next_obs[i * o..(i + 1) * o];
    s.iter().chain(act).chain(next).copied()
}

/// `−[y·log σ(z) + (1 − y)·log(1 − σ(z))]`, stable for any z: `max(z, 0) − y·z + log(1 + e^−|z|)`.
fn bce_with_logit(z: f32, y: f32) -> f32 {
    z.max(0.0) - y * z + (-z.abs()).exp().ln_1p()
}
