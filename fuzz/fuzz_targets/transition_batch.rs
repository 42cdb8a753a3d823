//! A transition batch as a subscriber receives it (`Real` / `Imagined` channels): the
//! `TransitionHeader` and the `[f32]` payload in shared memory, validated by
//! `mbpo_wire::transitions::check_header` (what `TransitionSubscriber::receive` calls), then
//! consumed the way `TransitionBatch` does (`RowLayout::unpack_into`, `push_into` a replay
//! buffer, `split_row`).
//!
//! Input: `[obs_dim byte | act_dim byte | channel byte | TransitionHeader (80 bytes) | payload]`;
//! the subscriber expects `obs_dim` 1..=24, `act_dim` 1..=8 and the channel from the first
//! three bytes, run id `fuzz`.
//!
//! Checks: a batch is accepted exactly when every header field matches (an independent check
//! of each) and the payload is `n_rows` whole rows; an accepted batch unpacks into `n_rows`
//! rows that pack back into the same payload (terminated flags as 0/1).
#![no_main]

use libfuzzer_sys::fuzz_target;
use mbpo_core::{Batch, ReplayBuffer};
use mbpo_fuzz::{bytes_of, float_bytes, floats, pod, run_hash, same_bits, write_seeds_if_asked};
use mbpo_wire::transitions::check_header;
use mbpo_wire::{Channel, RowLayout, TransitionHeader, SCHEMA_VERSION};

fn expectation(data: &[u8]) -> (RowLayout, Channel) {
    let b = |i: usize| data.get(i).copied().unwrap_or(0) as usize;
    let layout = RowLayout::new(1 + b(0) % 24, 1 + b(1) % 8);
    let channel = if b(2) % 2 == 0 {
        Channel::Real
    } else {
        Channel::Imagined
    };
    (layout, channel)
}

fn seeds() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for (o, a, ch, n) in [
        (3u8, 1u8, 0u8, 2u32),
        (17, 6, 1, 1),
        (11, 3, 0, 0),
        (1, 1, 1, 5),
    ] {
        let (layout, channel) = expectation(&[o - 1, a - 1, ch]);
        let h = TransitionHeader {
            run_hash: run_hash(),
            seq: 4,
            policy_version: 3,
            model_version: ch as u64,
            env_steps: 5,
            layout_hash: layout.hash(),
            send_time_ns: 1_700_000_000_000_000_000,
            schema_version: SCHEMA_VERSION,
            producer_id: 0x0001_0000,
            stream: channel.tag(),
            n_rows: n,
            obs_dim: layout.obs_dim as u32,
            act_dim: layout.act_dim as u32,
        };
        let mut rows = vec![0.0f32; n as usize * layout.width()];
        for (i, v) in rows.iter_mut().enumerate() {
            *v = i as f32 * 0.25 - 1.0;
        }
        for r in 0..n as usize {
            rows[r * layout.width() + layout.terminated_offset()] = (r % 2) as f32;
        }
        let mut s = vec![o - 1, a - 1, ch];
        s.extend(bytes_of(&h));
        s.extend(float_bytes(&rows));
        out.push(s);
    }
    out
}

fuzz_target!(
    init: write_seeds_if_asked("transition_batch", seeds),
    |data: &[u8]| {
        let (layout, channel) = expectation(data);
        let (h, rest) = pod::<TransitionHeader>(data.get(3..).unwrap_or(&[]));
        let payload = floats(rest);
        let result = check_header(&h, payload.len(), run_hash(), channel, layout, layout.hash());
        let valid = h.schema_version == SCHEMA_VERSION
            && h.run_hash == run_hash()
            && h.stream == channel.tag()
            && h.obs_dim as usize == layout.obs_dim
            && h.act_dim as usize == layout.act_dim
            && h.layout_hash == layout.hash()
            && h.n_rows as usize * layout.width() == payload.len();
        assert_eq!(result.is_ok(), valid, "{h:?} with {} floats: {result:?}", payload.len());
        if result.is_err() {
            return;
        }
        // Consume it as a subscriber does.
        let n = h.n_rows as usize;
        let w = layout.width();
        let mut batch = Batch::default();
        layout.unpack_into(&payload, &mut batch);
        assert_eq!(batch.len, n);
        let mut buf = ReplayBuffer::new(layout.obs_dim, layout.act_dim, 64);
        layout.push_into(&payload, &mut buf);
        assert_eq!(buf.len(), n.min(64));
        for i in 0..n {
            let r = layout.split_row(&payload[i * w..(i + 1) * w]);
            assert_eq!(r.obs.len(), layout.obs_dim);
            assert_eq!(r.next_obs.len(), layout.obs_dim);
            assert_eq!(r.act.len(), layout.act_dim);
        }
        let mut back = vec![0.0f32; n * w];
        layout.pack(&batch, 0, n, &mut back);
        let mut expected = payload.clone();
        for r in 0..n {
            let t = &mut expected[r * w + layout.terminated_offset()];
            *t = if *t != 0.0 { 1.0 } else { 0.0 };
        }
        assert!(same_bits(&back, &expected), "rows do not pack back");
    }
);
