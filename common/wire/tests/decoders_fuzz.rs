//! Decoders of bytes another process wrote into shared memory: whatever a stats record or a
//! model snapshot holds, decoding it returns a typed error or a value, never a panic (issue 24
//! item 5). `MBPO_FUZZ_ITERS` sets the iterations (default 20000 in the normal suite).

use mbpo_core::rng::{index, normal_f32, stream, Rng};
use mbpo_model::{ModelConfig, ProbabilisticEnsemble};
use mbpo_wire::{ModelWireLayout, Stats, StatsRecord};

fn iters() -> usize {
    std::env::var("MBPO_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000)
}

/// A float as an adversary would pick it: ordinary, huge, tiny, negative, NaN or infinite.
fn any_f32(rng: &mut Rng) -> f32 {
    match index(rng, 8) {
        0 => f32::NAN,
        1 => f32::INFINITY,
        2 => f32::NEG_INFINITY,
        3 => f32::MAX,
        4 => -1.0,
        5 => index(rng, 64) as f32,
        _ => normal_f32(rng) * 1e3,
    }
}

fn any_u64(rng: &mut Rng) -> u64 {
    match index(rng, 4) {
        0 => u64::MAX,
        1 => index(rng, 16) as u64,
        _ => (index(rng, u32::MAX as usize) as u64) << index(rng, 33),
    }
}

#[test]
fn any_stats_record_decodes_to_a_report_or_a_typed_error() {
    let mut rng = stream(0, "fuzz.stats", 0);
    let (mut ok, mut refused) = (0, 0);
    for _ in 0..iters() {
        let mut r = StatsRecord {
            env_steps: any_u64(&mut rng),
            sac_updates: any_u64(&mut rng),
            model_trainings: any_u64(&mut rng),
            policy_version: any_u64(&mut rng),
            model_version: any_u64(&mut rng),
            value: any_f32(&mut rng) as f64,
            metrics: [0.0; 8],
            kind: match index(&mut rng, 3) {
                0 => index(&mut rng, u32::MAX as usize) as u32,
                _ => index(&mut rng, 12) as u32,
            },
            episode_len: index(&mut rng, u32::MAX as usize) as u32,
        };
        r.metrics.iter_mut().for_each(|m| *m = any_f32(&mut rng));
        match Stats::decode(&r) {
            Ok(_) => ok += 1,
            Err(_) => refused += 1,
        }
    }
    assert!(ok > 0 && refused > 0, "{ok} decoded, {refused} refused");
}

#[test]
fn any_model_snapshot_loads_or_is_refused() {
    let cfg = ModelConfig {
        members: 3,
        elites: 2,
        hidden: vec![8, 8],
        weight_decay: vec![1e-4; 3],
        learn_termination: true,
        ..ModelConfig::default()
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "fuzz.model", 0)).unwrap();
    let layout = ModelWireLayout::of_model(&model, 2);
    let mut rng = stream(0, "fuzz.snapshot", 0);
    let (mut loaded, mut refused) = (0, 0);
    let mut flat = vec![0.0f32; layout.len()];
    for i in 0..iters() / 10 {
        // Mostly the right length (the decoder's own checks), sometimes not.
        let len = match i % 5 {
            0 => index(&mut rng, 2 * layout.len()),
            _ => layout.len(),
        };
        flat.resize(len, 0.0);
        for v in flat.iter_mut() {
            *v = normal_f32(&mut rng);
        }
        // Elites are member indices: whole numbers below `members`, so that without the
        // adversarial floats below a snapshot of the right length can load.
        if len == layout.len() {
            let at = layout.n_params + 2 * layout.in_dim;
            for v in &mut flat[at..at + layout.elites] {
                *v = index(&mut rng, 3) as f32;
            }
        }
        // A few adversarial floats anywhere, elites included (the snapshot's tail).
        for _ in 0..index(&mut rng, 6) {
            if len > 0 {
                let at = match index(&mut rng, 2) {
                    0 => len - 1 - index(&mut rng, len.min(8)),
                    _ => index(&mut rng, len),
                };
                flat[at] = any_f32(&mut rng);
            }
        }
        match layout.load_into(&flat, &mut model) {
            Ok(()) => loaded += 1,
            Err(_) => refused += 1,
        }
    }
    assert!(
        loaded > 0 && refused > 0,
        "{loaded} loaded, {refused} refused"
    );
}
