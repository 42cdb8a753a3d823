//! Training: bootstrap resampling, minibatch Adam epochs, holdout early stopping and elites,
//! as MBPO's `BNN.train` (`mbpo/models/bnn.py`) does it.
//!
//! One training call on N transitions:
//!
//! 1. **Holdout split** ([`ModelConfig::holdout_size`]): a random permutation; the first
//!    `min(int(0.2·N), 5000)` rows are the holdout, the rest the training split.
//! 2. **Normaliser**: mean/std of the training split's inputs ([`crate::InputNormalizer`]).
//! 3. **Bootstrap** ([`BootstrapIndices`]): each member draws N_train row indices *with
//!    replacement*, once per call. Each epoch shuffles every member's vector and walks it in
//!    minibatches. (Redrawing the indices every iteration instead makes every member see the same
//!    distribution of data, and the ensemble collapses; mbrl-lib PR #61.)
//! 4. **Epoch**: for each minibatch, every member's Gaussian NLL gradient on its own rows, then
//!    one Adam step on all parameters (the L2 decay enters through Adam).
//! 5. **Early stopping** ([`EarlyStopping`]): after each epoch, each member's holdout MSE; a
//!    member improving by more than 1 % relative to its best is snapshotted; training stops once
//!    more than 5 epochs in a row improved no member (or at the optional epoch / time caps).
//! 6. **Restore and elites** ([`select_elites`]): every member goes back to its snapshot and the
//!    elites are the K members with the lowest holdout MSE.
//!
//! Weights, Adam's moments and the bounds carry over from one call to the next (MBPO never resets
//! the model); snapshots restore member weights only, as `_set_state` does.

use crate::error::TrainError;
use crate::model::{standardize, ProbabilisticEnsemble, Workspace};
use crate::parallel::{adam_step, holdout_mse, members_loss_and_grads};
use mbpo_core::rng::{index, shuffle};
use mbpo_core::{Batch, Rng};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Best holdout MSE before the first epoch (`_start_train`: `(None, 1e10)`).
const INITIAL_BEST: f32 = 1e10;

/// What one training call did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    /// Transitions in the training split.
    pub n_train: usize,
    /// Transitions in the holdout.
    pub n_holdout: usize,
    /// Epochs run.
    pub epochs: usize,
    /// Adam steps taken.
    pub gradient_steps: usize,
    /// Per epoch, each member's mean training loss (Gaussian NLL terms, no decay or bound term).
    pub train_loss: Vec<Vec<f32>>,
    /// Per epoch, each member's holdout MSE of the mean (before any restore).
    pub holdout_mse: Vec<Vec<f32>>,
    /// Per member, the epoch whose weights were restored (None: never improved, kept as is).
    pub best_epoch: Vec<Option<usize>>,
    /// Per member, the holdout MSE of the restored weights (its snapshot epoch's).
    pub final_holdout_mse: Vec<f32>,
    /// The new elites, best first.
    pub elites: Vec<usize>,
    /// Why training stopped.
    pub stop: StopReason,
    /// Wall-clock seconds of the call.
    pub seconds: f64,
    /// Of those, seconds computing the holdout MSE after each epoch.
    pub holdout_seconds: f64,
    /// The learned termination rule's training, when the model has one.
    pub termination: Option<crate::TerminationReport>,
}

impl TrainReport {
    /// The report with its wall-clock fields zeroed: what two runs of the same training share.
    pub fn without_timings(mut self) -> Self {
        self.seconds = 0.0;
        self.holdout_seconds = 0.0;
        self
    }

    /// Mean holdout MSE of the elites (the `model_holdout_mse` metrics column), summed in
    /// elite order: every command computes it here, so their rows agree bit for bit.
    pub fn elite_holdout_mse(&self) -> f64 {
        elite_mean(&self.final_holdout_mse, &self.elites)
    }
}

/// Mean of `mse` over `elites`, summed in elite order.
fn elite_mean(mse: &[f32], elites: &[usize]) -> f64 {
    elites.iter().map(|&e| mse[e] as f64).sum::<f64>() / elites.len().max(1) as f64
}

/// Each member's holdout MSE after step 6's restore, from the MSEs recorded per epoch: its
/// snapshot epoch's, or its last epoch's when it never improved (kept as is). At least one
/// epoch is recorded.
fn restored_holdout_mse(best_epoch: &[Option<usize>], holdout_mse: &[Vec<f32>]) -> Vec<f32> {
    let last = holdout_mse.len() - 1;
    best_epoch
        .iter()
        .enumerate()
        .map(|(e, best)| holdout_mse[best.unwrap_or(last)][e])
        .collect()
}

/// The elite holdout MSE ([`TrainReport::elite_holdout_mse`]) that `report`'s training would
/// have ended with had `model.max_epochs` stopped it after `cap` epochs: MBPO's snapshot rule
/// ([`EarlyStopping`], `threshold` = `model.improvement_threshold`) replayed on the recorded
/// holdout MSEs of the first `cap` epochs, then the restore and the elites as a training does
/// them. Exact, not an estimate: up to its cap a capped training takes the same steps as an
/// uncapped one (`tests/training.rs`). What `mbpo bench breakdown` reports an epoch cap would
/// cost in model quality, against what it saves in epochs. NaN for a cap of 0.
pub fn elite_holdout_mse_if_capped(
    report: &TrainReport,
    cap: usize,
    elites: usize,
    threshold: f32,
) -> f64 {
    let epochs = &report.holdout_mse[..cap.min(report.epochs)];
    let Some(last) = epochs.last() else {
        return f64::NAN;
    };
    let members = last.len();
    let mut stopper = EarlyStopping::new(members, usize::MAX, threshold);
    let mut improved = vec![false; members];
    for mse in epochs {
        stopper.update(mse, &mut improved);
    }
    let restored = restored_holdout_mse(stopper.best_epoch(), epochs);
    elite_mean(&restored, &select_elites(&restored, elites))
}

/// Why a training call ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StopReason {
    /// More than `max_epochs_since_update` epochs without an improving member.
    NoImprovement,
    /// `max_epochs` reached.
    MaxEpochs,
    /// `max_train_seconds` exceeded.
    TimeLimit,
}

/// Each member's bootstrap resample of the training split: N_train indices drawn uniformly
/// with replacement, once per training call (member-major storage).
#[derive(Debug, Clone, PartialEq)]
pub struct BootstrapIndices {
    n: usize,
    idx: Vec<u32>,
}

impl BootstrapIndices {
    /// Draw `members` vectors of `n` indices in `0..n`, with replacement (`np.random.randint`).
    pub fn draw(members: usize, n: usize, rng: &mut Rng) -> Self {
        let mut b = Self { n, idx: Vec::new() };
        b.redraw(members, n, rng);
        b
    }

    /// [`BootstrapIndices::draw`] into the existing storage.
    pub fn redraw(&mut self, members: usize, n: usize, rng: &mut Rng) {
        self.n = n;
        self.idx.resize(members * n, 0);
        self.idx.iter_mut().for_each(|i| *i = index(rng, n) as u32);
    }

    /// Permute each member's vector independently (`shuffle_rows`, once per epoch): the same
    /// resample, visited in a new order.
    pub fn shuffle_rows(&mut self, rng: &mut Rng) {
        if self.n > 0 {
            self.idx
                .chunks_exact_mut(self.n)
                .for_each(|row| shuffle(rng, row));
        }
    }

    /// Member e's indices, in the current epoch's order.
    pub fn member(&self, e: usize) -> &[u32] {
        &self.idx[e * self.n..(e + 1) * self.n]
    }
}

/// MBPO's `_save_best`: per-member best holdout MSE and the patience counter.
#[derive(Debug, Clone, PartialEq)]
pub struct EarlyStopping {
    best: Vec<f32>,
    best_epoch: Vec<Option<usize>>,
    epochs_since_update: usize,
    max_epochs_since_update: usize,
    threshold: f32,
    epoch: usize,
}

impl EarlyStopping {
    /// Fresh state for a training call (every best at 1e10).
    pub fn new(members: usize, max_epochs_since_update: usize, threshold: f32) -> Self {
        Self {
            best: vec![INITIAL_BEST; members],
            best_epoch: vec![None; members],
            epochs_since_update: 0,
            max_epochs_since_update,
            threshold,
            epoch: 0,
        }
    }

    /// Record one epoch's holdout MSEs. Sets `improved[e]` for each member whose MSE beat its
    /// best by more than the threshold, relative (`(best − mse)/best > 0.01`; the caller
    /// snapshots those), and returns true when training should stop: more than
    /// `max_epochs_since_update` epochs in a row without any improvement.
    pub fn update(&mut self, holdout_mse: &[f32], improved: &mut [bool]) -> bool {
        let mut any = false;
        for (e, &mse) in holdout_mse.iter().enumerate() {
            let best = self.best[e];
            // NaN compares false: a diverged member never counts as improving.
            improved[e] = (best - mse) / best > self.threshold;
            if improved[e] {
                self.best[e] = mse;
                self.best_epoch[e] = Some(self.epoch);
                any = true;
            }
        }
        self.epoch += 1;
        if any {
            self.epochs_since_update = 0;
        } else {
            self.epochs_since_update += 1;
        }
        self.epochs_since_update > self.max_epochs_since_update
    }

    /// Epoch of each member's snapshot.
    pub fn best_epoch(&self) -> &[Option<usize>] {
        &self.best_epoch
    }
}

/// The `k` members with the lowest holdout MSE, best first (ties by index; NaN ranks last).
pub fn select_elites(mse: &[f32], k: usize) -> Vec<usize> {
    let key = |e: usize| {
        if mse[e].is_nan() {
            f32::INFINITY
        } else {
            mse[e]
        }
    };
    let mut order: Vec<usize> = (0..mse.len()).collect();
    order.sort_by(|&a, &b| key(a).total_cmp(&key(b)).then(a.cmp(&b)));
    order.truncate(k);
    order
}

/// The standardised holdout split of one training call.
struct Holdout {
    /// Inputs, `rows x in`.
    x: Vec<f32>,
    /// Targets, `rows x out`.
    t: Vec<f32>,
    /// Rows held out.
    rows: usize,
}

/// What the epochs of one training call carry from one to the next.
struct Epochs {
    stopper: EarlyStopping,
    /// Each member's weights at its best holdout MSE so far.
    snapshot: Vec<f32>,
    improved: Vec<bool>,
    mse: Vec<f32>,
    epoch_loss: Vec<f64>,
}

impl TrainReport {
    /// The report of a call on `n_train` + `n_holdout` rows before its first epoch.
    fn empty(n_train: usize, n_holdout: usize, members: usize) -> Self {
        Self {
            n_train,
            n_holdout,
            epochs: 0,
            gradient_steps: 0,
            train_loss: Vec::new(),
            holdout_mse: Vec::new(),
            best_epoch: vec![None; members],
            final_holdout_mse: Vec::new(),
            elites: Vec::new(),
            stop: StopReason::NoImprovement,
            seconds: 0.0,
            holdout_seconds: 0.0,
            termination: None,
        }
    }
}

/// Where a training call stands after an epoch (what a progress line shows of it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpochProgress {
    /// Epochs done in this call.
    pub epoch: usize,
    /// The members' mean holdout MSE after this epoch.
    pub holdout_mse: f32,
    /// Seconds since the call began.
    pub seconds: f64,
}

impl ProbabilisticEnsemble {
    /// Fit the ensemble to `data` (all transitions collected so far), continuing from the
    /// current weights; see the module docs for the procedure. Draws the holdout permutation,
    /// the bootstrap indices and the per-epoch shuffles from `rng`.
    pub fn train(&mut self, data: &Batch, rng: &mut Rng) -> Result<TrainReport, TrainError> {
        let report = self.train_watched(data, rng, |_| false)?;
        Ok(report.expect("a training that is never asked to stop completes"))
    }

    /// [`Self::train`], showing `after_epoch` where the call stands after each epoch that does
    /// not end it (for a progress line: a training can take minutes on a large D_env); when it
    /// returns true (a user's Ctrl-C), the call gives up and returns `None`. The ensemble and
    /// `rng` are then part-way: restore a checkpoint taken before the call.
    pub fn train_watched(
        &mut self,
        data: &Batch,
        rng: &mut Rng,
        mut after_epoch: impl FnMut(&EpochProgress) -> bool,
    ) -> Result<Option<TrainReport>, TrainError> {
        // Subnormals flushed, as every job of the pool (mbpo_nn::subnormal says why).
        let _flush = mbpo_nn::FlushSubnormals::new();
        let start = Instant::now();
        self.check_training_data(data)?;
        let cfg = self.config.clone();
        let members = cfg.members;
        // 1-2. Holdout split, normaliser, standardised inputs and targets.
        let holdout = self.split_and_standardize(data, rng);
        let n_train = data.len - holdout.rows;
        // 3. Bootstrap resamples, drawn once for the whole call.
        let mut boot = BootstrapIndices::draw(members, n_train, rng);
        let mut epochs = Epochs {
            stopper: EarlyStopping::new(
                members,
                cfg.max_epochs_since_update,
                cfg.improvement_threshold,
            ),
            snapshot: vec![0.0f32; self.net.num_net_params()],
            improved: vec![false; members],
            mse: vec![0.0f32; members],
            epoch_loss: vec![0.0f64; members],
        };
        let mut report = TrainReport::empty(n_train, holdout.rows, members);
        self.ws.grads.resize(self.theta.len(), 0.0);
        self.ws
            .threads
            .ensure(cfg.threads, &self.net, cfg.batch_size);
        loop {
            let stop = self.epoch(&mut boot, &holdout, &mut epochs, &mut report, rng);
            let limit = match () {
                _ if stop => Some(StopReason::NoImprovement),
                _ if cfg.max_epochs.is_some_and(|m| report.epochs >= m) => {
                    Some(StopReason::MaxEpochs)
                }
                _ if cfg
                    .max_train_seconds
                    .is_some_and(|s| start.elapsed().as_secs_f64() > s) =>
                {
                    Some(StopReason::TimeLimit)
                }
                _ => None,
            };
            if let Some(reason) = limit {
                report.stop = reason;
                break;
            }
            let progress = EpochProgress {
                epoch: report.epochs,
                holdout_mse: epochs.mse.iter().sum::<f32>() / members as f32,
                seconds: start.elapsed().as_secs_f64(),
            };
            if after_epoch(&progress) {
                return Ok(None);
            }
        }
        self.restore_best(&epochs, &mut report);
        // The learned termination rule, on the same data, after the ensemble's draws.
        if let Some(c) = self.termination.as_mut() {
            report.termination = Some(c.train(data, rng));
        }
        report.seconds = start.elapsed().as_secs_f64();
        Ok(Some(report))
    }

    /// Steps 1 and 2: the holdout split (a permutation from `rng`), the normaliser fitted on
    /// the training split, then both splits standardised (the training split into the
    /// workspace).
    fn split_and_standardize(&mut self, data: &Batch, rng: &mut Rng) -> Holdout {
        let n = data.len;
        let n_hold = self.config.holdout_size(n);
        let mut perm: Vec<u32> = (0..n as u32).collect();
        shuffle(rng, &mut perm);
        let (hold_rows, train_rows) = perm.split_at(n_hold);
        self.normalizer.fit(data, train_rows);
        let mut x = Vec::new();
        let mut t = Vec::new();
        standardize(&self.normalizer, data, hold_rows, &mut x, &mut t);
        let Workspace { x_all, t_all, .. } = &mut self.ws;
        standardize(&self.normalizer, data, train_rows, x_all, t_all);
        Holdout { x, t, rows: n_hold }
    }

    /// Steps 4 and 5: one epoch of minibatch steps over every member's bootstrap vector, then
    /// the holdout MSE, the snapshots of the members that improved, patience. `true`: no
    /// member improved for long enough (early stopping).
    fn epoch(
        &mut self,
        boot: &mut BootstrapIndices,
        holdout: &Holdout,
        e: &mut Epochs,
        report: &mut TrainReport,
        rng: &mut Rng,
    ) -> bool {
        let (n_train, batch) = (report.n_train, self.config.batch_size);
        e.epoch_loss.fill(0.0);
        let mut b0 = 0;
        while b0 < n_train {
            let rows = batch.min(n_train - b0);
            self.train_step(boot, b0, rows, &mut e.epoch_loss);
            report.gradient_steps += 1;
            b0 += rows;
        }
        boot.shuffle_rows(rng);
        let holdout_start = Instant::now();
        holdout_mse(
            &mut self.ws.threads,
            &self.net,
            &self.theta,
            &holdout.x,
            &holdout.t,
            holdout.rows,
            &mut e.mse,
        );
        report.holdout_seconds += holdout_start.elapsed().as_secs_f64();
        let stop = e.stopper.update(&e.mse, &mut e.improved);
        for m in (0..e.mse.len()).filter(|&m| e.improved[m]) {
            let r = self.net.ensemble().member_range(m);
            e.snapshot[r.clone()].copy_from_slice(&self.theta[r]);
        }
        report.epochs += 1;
        let per_row = |&l: &f64| (l / n_train as f64) as f32;
        report
            .train_loss
            .push(e.epoch_loss.iter().map(per_row).collect());
        report.holdout_mse.push(e.mse.clone());
        stop
    }

    /// Step 6: restore every member's best weights and pick the elites. MBPO re-evaluates the
    /// holdout here; the MSE depends only on the member's weights (not on the shared bounds)
    /// and the evaluation is deterministic, so a restored member's MSE is exactly the one
    /// recorded at its snapshot epoch, and a member never snapshotted keeps its last one.
    fn restore_best(&mut self, e: &Epochs, report: &mut TrainReport) {
        report.best_epoch = e.stopper.best_epoch().to_vec();
        for (m, best) in report.best_epoch.iter().enumerate() {
            if best.is_some() {
                let r = self.net.ensemble().member_range(m);
                self.theta[r.clone()].copy_from_slice(&e.snapshot[r]);
            }
        }
        let mse = restored_holdout_mse(&report.best_epoch, &report.holdout_mse);
        self.elites = select_elites(&mse, self.config.elites);
        report.final_holdout_mse = mse;
        report.elites = self.elites.clone();
    }

    /// One Adam step: every member's loss gradient on rows `b0..b0 + rows` of its bootstrap
    /// vector, the bound regulariser, then the update; members and Adam run on
    /// `config.threads` threads (`parallel.rs`). Adds `loss·rows` per member to `loss`.
    fn train_step(&mut self, boot: &BootstrapIndices, b0: usize, rows: usize, loss: &mut [f64]) {
        let Workspace {
            threads,
            grads,
            x_all,
            t_all,
            ..
        } = &mut self.ws;
        members_loss_and_grads(
            threads,
            &self.net,
            &self.theta,
            x_all,
            t_all,
            |e| &boot.member(e)[b0..b0 + rows],
            grads,
            loss,
        );
        let mut g = std::mem::take(&mut self.ws.grads);
        self.finish_bound_grads(&mut g);
        adam_step(&mut self.ws.threads, &mut self.adam, &mut self.theta, &g);
        self.ws.grads = g;
    }

    fn check_training_data(&self, data: &Batch) -> Result<(), TrainError> {
        let (o, a) = (self.obs_dim, self.act_dim);
        if (data.obs_dim, data.act_dim) != (o, a) {
            return Err(TrainError::Dims {
                obs_dim: o,
                act_dim: a,
                found_obs: data.obs_dim,
                found_act: data.act_dim,
            });
        }
        let n = data.len;
        let fields: [(&'static str, &[f32], usize); 4] = [
            ("obs", &data.obs, o),
            ("act", &data.act, a),
            ("reward", &data.reward, 1),
            ("next_obs", &data.next_obs, o),
        ];
        for (field, values, width) in fields {
            if values.len() < n * width {
                return Err(TrainError::Ragged {
                    field,
                    found: values.len(),
                    expected: n * width,
                    len: n,
                });
            }
            if let Some(pos) = values[..n * width].iter().position(|v| !v.is_finite()) {
                return Err(TrainError::NonFinite {
                    row: pos / width,
                    field,
                });
            }
        }
        if !self.config.can_train_on(n) {
            return Err(TrainError::TooFewTransitions {
                found: n,
                required: self.config.min_training_transitions(),
                ratio: self.config.holdout_ratio,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::members_mse;
    use mbpo_core::stream;

    #[test]
    fn bootstrap_is_drawn_once_and_only_reordered_each_epoch() {
        let mut rng = stream(1, "boot", 0);
        let mut b = BootstrapIndices::draw(3, 500, &mut rng);
        let sorted = |b: &BootstrapIndices, e| {
            let mut v = b.member(e).to_vec();
            v.sort_unstable();
            v
        };
        let before: Vec<Vec<u32>> = (0..3).map(|e| sorted(&b, e)).collect();
        // With replacement: some index repeats, some is missing (P(no repeat) is astronomically small).
        let distinct = |v: &Vec<u32>| {
            let mut d = v.clone();
            d.dedup();
            d.len()
        };
        assert!(distinct(&before[0]) < 500);
        assert_ne!(before[0], before[1], "members resample independently");
        let first_order = b.member(0).to_vec();
        for _ in 0..3 {
            b.shuffle_rows(&mut rng);
            for (e, want) in before.iter().enumerate() {
                assert_eq!(&sorted(&b, e), want, "epoch shuffles keep each resample");
            }
        }
        assert_ne!(b.member(0), &first_order[..], "…but change the order");
    }

    #[test]
    fn early_stopping_follows_save_best() {
        let mut s = EarlyStopping::new(2, 5, 0.01);
        let mut imp = [false; 2];
        assert!(!s.update(&[1.0, 2.0], &mut imp));
        assert_eq!(imp, [true, true]);
        // 0.5 % better: not an improvement; member 1 improves by 10 %.
        assert!(!s.update(&[0.995, 1.8], &mut imp));
        assert_eq!(imp, [false, true]);
        // Six flat epochs: the counter reaches 6 > 5 on the sixth and training stops.
        for i in 0..6 {
            let stop = s.update(&[0.999, 1.79], &mut imp);
            assert_eq!(imp, [false, false]);
            assert_eq!(stop, i == 5, "epoch {i}");
        }
        assert_eq!(s.best_epoch(), &[Some(0), Some(1)]);
        // A NaN never improves.
        let mut s = EarlyStopping::new(1, 5, 0.01);
        s.update(&[f32::NAN], &mut imp[..1]);
        assert!(!imp[0]);
    }

    #[test]
    fn recorded_snapshot_mse_is_the_restored_weights_mse() {
        // Long enough that members are restored to earlier epochs; then evaluate the restored
        // weights on the same holdout (replaying the permutation from a clone of the stream).
        use crate::ModelConfig;
        let data = crate::bench::synthetic_transitions(600, 3);
        let cfg = ModelConfig {
            members: 3,
            elites: 2,
            hidden: vec![16, 16],
            weight_decay: vec![1e-4; 3],
            lr: 3e-3,
            max_epochs: Some(25),
            ..ModelConfig::default()
        };
        let mut rng = stream(4, "restore", 0);
        let mut model = ProbabilisticEnsemble::new(17, 6, cfg, &mut rng).unwrap();
        let replay = rng.clone();
        let report = model.train(&data, &mut rng).unwrap();
        let last = report.epochs - 1;
        assert!(
            report
                .best_epoch
                .iter()
                .any(|b| b.is_some_and(|b| b < last)),
            "some member must be restored to an earlier epoch: {:?}",
            report.best_epoch
        );
        let mut replay = replay;
        let mut perm: Vec<u32> = (0..data.len as u32).collect();
        shuffle(&mut replay, &mut perm);
        let hold = &perm[..report.n_holdout];
        let (mut x, mut t) = (Vec::new(), Vec::new());
        standardize(&model.normalizer, &data, hold, &mut x, &mut t);
        let mut mse = vec![0.0; 3];
        members_mse(
            &model.net,
            &model.theta,
            &x,
            &t,
            hold.len(),
            &mut model.ws.infer,
            &mut mse,
        );
        assert_eq!(mse, report.final_holdout_mse);
    }

    #[test]
    fn elites_are_the_lowest_mse_best_first() {
        assert_eq!(
            select_elites(&[0.3, 0.1, f32::NAN, 0.2, 0.1], 3),
            vec![1, 4, 3]
        );
        assert_eq!(select_elites(&[f32::NAN, 1.0], 2), vec![1, 0]);
    }
}
