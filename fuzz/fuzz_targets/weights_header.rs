//! A weight snapshot as a subscriber receives it (`Policy` / `Model` channels): the
//! `WeightsHeader` and the `[f32]` payload, validated by
//! `mbpo_wire::weights::check_weights_header` (what `WeightsSubscriber::receive_latest` calls),
//! then used as the services use it: a policy's floats copied into the actor's parameters
//! (`set_policy_params`), a model's loaded by `ModelWireLayout::load_into`.
//!
//! Input: `[kind byte | WeightsHeader (80 bytes) | payload]`; the subscriber expects the policy
//! of a small SAC actor (kind byte even) or the snapshot of a small model (odd), run id `fuzz`.
//!
//! Checks: accepted exactly when every header field matches and the payload has the announced
//! length; an accepted policy copies, an accepted model snapshot loads or is a typed error.
#![no_main]

use std::cell::RefCell;

use libfuzzer_sys::fuzz_target;
use mbpo_fuzz::{
    bytes_of, float_bytes, floats, pod, run_hash, small_model, small_policy, write_seeds_if_asked,
};
use mbpo_model::ProbabilisticEnsemble;
use mbpo_wire::weights::check_weights_header;
use mbpo_wire::{ModelWireLayout, WeightsHeader, WeightsKind, SCHEMA_VERSION};

struct Expect {
    policy: (u64, usize),
    model: ProbabilisticEnsemble,
    model_layout: ModelWireLayout,
    params: Vec<f32>,
}

thread_local! {
    static EXPECT: RefCell<Expect> = RefCell::new({
        let model = small_model(true);
        let model_layout = ModelWireLayout::of_model(&model, 2);
        let policy = small_policy();
        Expect { policy, model, model_layout, params: vec![0.0; policy.1] }
    });
}

fn seeds() -> Vec<Vec<u8>> {
    EXPECT.with_borrow(|e| {
        let mut out = Vec::new();
        let header = |kind: WeightsKind, hash, n| WeightsHeader {
            run_hash: run_hash(),
            version: 2,
            layout_hash: hash,
            n_values: n as u64,
            env_steps: 300,
            sac_updates: 2400,
            model_trainings: 1,
            send_time_ns: 1_700_000_000_000_000_000,
            schema_version: SCHEMA_VERSION,
            kind: kind as u32,
            producer_id: 0x0004_0000,
            reserved: 0,
        };
        let (hash, n) = e.policy;
        let mut s = vec![0u8];
        s.extend(bytes_of(&header(WeightsKind::Policy, hash, n)));
        s.extend(float_bytes(
            &(0..n).map(|i| i as f32 * 1e-2).collect::<Vec<_>>(),
        ));
        out.push(s);
        let mut flat = Vec::new();
        e.model_layout
            .encode(&e.model.weights(), &mut flat)
            .unwrap();
        let mut s = vec![1u8];
        s.extend(bytes_of(&header(
            WeightsKind::Model,
            e.model_layout.layout_hash,
            flat.len(),
        )));
        s.extend(float_bytes(&flat));
        out.push(s);
        out
    })
}

fuzz_target!(
    init: write_seeds_if_asked("weights_header", seeds),
    |data: &[u8]| {
        let Some((&k, rest)) = data.split_first() else { return };
        let kind = if k % 2 == 0 { WeightsKind::Policy } else { WeightsKind::Model };
        let (h, rest) = pod::<WeightsHeader>(rest);
        let payload = floats(rest);
        EXPECT.with_borrow_mut(|e| {
            let (hash, n) = match kind {
                WeightsKind::Policy | WeightsKind::WorldModel => e.policy,
                WeightsKind::Model => (e.model_layout.layout_hash, e.model_layout.len()),
            };
            let result = check_weights_header(&h, payload.len(), run_hash(), kind, hash, n);
            let valid = h.schema_version == SCHEMA_VERSION
                && h.run_hash == run_hash()
                && h.kind == kind as u32
                && h.layout_hash == hash
                && h.n_values == n as u64
                && payload.len() == n;
            assert_eq!(result.is_ok(), valid, "{h:?} with {} floats: {result:?}", payload.len());
            if result.is_err() {
                return;
            }
            match kind {
                WeightsKind::Policy | WeightsKind::WorldModel => e.params.copy_from_slice(&payload),
                WeightsKind::Model => {
                    let layout = e.model_layout;
                    // Loads, or a typed error; never a panic.
                    let _ = layout.load_into(&payload, &mut e.model);
                }
            }
        });
    }
);
