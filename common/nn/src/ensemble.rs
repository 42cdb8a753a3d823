//! A batched ensemble of E independent MLPs of one architecture.
//!
//! The probabilistic dynamics model is 7 such members. Parameters are member-major: member e's
//! whole MLP occupies `params[e·P .. (e+1)·P]`, so snapshotting or restoring one member (holdout
//! early stopping) is one slice copy. Inputs and outputs are `[E, B, ·]`: each member sees its own
//! rows (bootstrap batches when training); [`EnsembleMlp::forward_member`] runs one member on
//! any number of rows (model rollouts, where each sample uses one random elite).

use crate::init::Init;
use crate::layout::ParamLayout;
use crate::mlp::{Mlp, MlpCache};
use mbpo_core::Rng;
use std::ops::Range;

/// E members sharing one MLP architecture.
#[derive(Debug, Clone, PartialEq)]
pub struct EnsembleMlp {
    members: usize,
    mlp: Mlp,
    layout: ParamLayout,
}

impl EnsembleMlp {
    /// `members` copies of `mlp`'s architecture.
    pub fn new(members: usize, mlp: Mlp) -> Self {
        assert!(members > 0, "an ensemble needs at least one member");
        let mut layout = ParamLayout::new();
        for e in 0..members {
            layout.extend_prefixed(&format!("m{e}"), mlp.layout());
        }
        Self {
            members,
            mlp,
            layout,
        }
    }

    /// Number of members E.
    pub fn members(&self) -> usize {
        self.members
    }
    /// The members' architecture.
    pub fn mlp(&self) -> &Mlp {
        &self.mlp
    }
    /// Total parameters (E x per-member).
    pub fn num_params(&self) -> usize {
        self.layout.len()
    }
    /// Names and shapes of all parameters.
    pub fn layout(&self) -> &ParamLayout {
        &self.layout
    }
    /// Range of member `e`'s parameters.
    pub fn member_range(&self, e: usize) -> Range<usize> {
        let p = self.mlp.num_params();
        e * p..(e + 1) * p
    }

    /// Initialise every member (members draw one after the other from `rng`).
    pub fn init(&self, params: &mut [f32], init: Init, rng: &mut Rng) {
        for e in 0..self.members {
            self.mlp.init(&mut params[self.member_range(e)], init, rng);
        }
    }

    /// Forward all members: `x` is `[E, batch, in]`; outputs are read with
    /// [`EnsembleCache::output`].
    pub fn forward(&self, params: &[f32], x: &[f32], batch: usize, cache: &mut EnsembleCache) {
        let n_in = self.mlp.in_dim();
        cache.ensure(self, batch);
        for e in 0..self.members {
            let xe = &x[e * batch * n_in..(e + 1) * batch * n_in];
            self.mlp.forward(
                &params[self.member_range(e)],
                xe,
                batch,
                &mut cache.members[e],
            );
        }
    }

    /// Forward member `e` alone on `batch` rows.
    pub fn forward_member<'c>(
        &self,
        e: usize,
        params: &[f32],
        x: &[f32],
        batch: usize,
        cache: &'c mut MlpCache,
    ) -> &'c [f32] {
        self.mlp
            .forward(&params[self.member_range(e)], x, batch, cache)
    }

    /// Backward all members after [`EnsembleMlp::forward`]: `d_out` is `[E, batch, out]`;
    /// writes `grads` (all members, overwritten) and optionally `d_input` (`[E, batch, in]`).
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        cache: &mut EnsembleCache,
        d_out: &[f32],
        grads: Option<&mut [f32]>,
        mut d_input: Option<&mut [f32]>,
    ) {
        let batch = cache.batch;
        let (n_in, n_out) = (self.mlp.in_dim(), self.mlp.out_dim());
        let mut grads = grads;
        for e in 0..self.members {
            let r = self.member_range(e);
            let xs = e * batch * n_in..(e + 1) * batch * n_in;
            let ys = e * batch * n_out..(e + 1) * batch * n_out;
            self.mlp.backward(
                &params[r.clone()],
                &x[xs.clone()],
                &mut cache.members[e],
                &d_out[ys],
                grads.as_deref_mut().map(|g| &mut g[r]),
                d_input.as_deref_mut().map(|d| &mut d[xs]),
            );
        }
    }
}

/// Per-member caches of an [`EnsembleMlp`].
#[derive(Debug, Clone, Default)]
pub struct EnsembleCache {
    batch: usize,
    members: Vec<MlpCache>,
}

impl EnsembleCache {
    /// A cache for `ens` at `batch` rows per member.
    pub fn new(ens: &EnsembleMlp, batch: usize) -> Self {
        let mut c = Self::default();
        c.ensure(ens, batch);
        c
    }
    /// Output rows (`batch x out`) of member `e` from the last forward pass.
    pub fn output<'c>(&'c self, ens: &EnsembleMlp, e: usize) -> &'c [f32] {
        self.members[e].output(ens.mlp())
    }
    fn ensure(&mut self, ens: &EnsembleMlp, batch: usize) {
        self.batch = batch;
        if self.members.len() != ens.members() {
            self.members = (0..ens.members())
                .map(|_| MlpCache::new(ens.mlp(), batch))
                .collect();
        }
    }
}
