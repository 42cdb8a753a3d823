//! A model snapshot (the `Model` channel's payload: θ | normaliser mean | std | elites |
//! termination rule) loaded by `ModelWireLayout::load_into`, the one decoder of model weights
//! that a receiver runs on shared memory.
//!
//! Input: `[variant byte | f32 ...]`: the variant picks a model with or without a learned
//! termination rule (both 3 observations, 1 action, 3 members of [8, 8], 2 elites).
//!
//! Checks: a snapshot of the wrong length is `DecodeError::ModelLength`; a loaded snapshot
//! encodes back (`ModelWireLayout::encode` of the model's weights) to the same floats, bit for
//! bit, and the same elite indices (so nothing was loaded other than what was sent).
#![no_main]

use std::cell::RefCell;

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{float_bytes, floats, same_bits, small_model, write_seeds_if_asked};
use mbpo_model::ProbabilisticEnsemble;
use mbpo_wire::error::DecodeError;
use mbpo_wire::ModelWireLayout;

thread_local! {
    static MODELS: RefCell<Vec<(ProbabilisticEnsemble, ModelWireLayout)>> = RefCell::new(
        [false, true]
            .into_iter()
            .map(|t| {
                let m = small_model(t);
                let l = ModelWireLayout::of_model(&m, 2);
                (m, l)
            })
            .collect(),
    );
}

fn seeds() -> Vec<Vec<u8>> {
    MODELS.with_borrow(|models| {
        let mut out = Vec::new();
        for (v, (m, l)) in models.iter().enumerate() {
            let mut flat = Vec::new();
            l.encode(&m.weights(), &mut flat).unwrap();
            let mut s = vec![v as u8];
            s.extend(float_bytes(&flat));
            out.push(s);
        }
        out
    })
}

fuzz_target!(
    init: write_seeds_if_asked("model_snapshot", seeds),
    |data: &[u8]| {
        let Some((&v, rest)) = data.split_first() else { return };
        let flat = floats(rest);
        MODELS.with_borrow_mut(|models| {
            let (model, layout) = &mut models[v as usize % 2];
            match layout.load_into(&flat, model) {
                Ok(()) => {
                    let mut back = Vec::new();
                    layout
                        .encode(&model.weights(), &mut back)
                        .expect("a loaded model encodes in its own layout");
                    let e = layout.n_params + 2 * layout.in_dim;
                    let (elites_in, elites_out) = (&flat[e..e + layout.elites], &back[e..e + layout.elites]);
                    assert_eq!(elites_in, elites_out, "elite indices loaded as other members");
                    assert!(same_bits(&flat[..e], &back[..e]), "θ or normaliser loaded differently");
                    assert!(same_bits(&flat[e + layout.elites..], &back[e + layout.elites..]), "termination rule loaded differently");
                }
                Err(DecodeError::ModelLength { expected, found }) => {
                    assert_eq!((expected, found), (layout.len(), flat.len()));
                }
                Err(DecodeError::ModelWeights(_)) => assert_eq!(flat.len(), layout.len()),
                Err(e) => panic!("unexpected error {e:?}"),
            }
        });
    }
);
