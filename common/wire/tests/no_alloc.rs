//! The receive path (receive a batch, push it into a replay buffer or copy it into a `Batch`;
//! read the newest weights) allocates nothing once the ports exist except in the periodic
//! re-list of publishers (iceoryx2 builds a two-block snapshot; at most every 50 ms, which a
//! loaded machine reaches within the test's 200 steps), and the send path (a batch, or rows
//! an actor writes in place into a loaned sample) allocates
//! nothing beyond the one small block iceoryx2 0.10 itself allocates per `send()` (measured on
//! a bare iceoryx2 publisher; a WaitSet wake-up also allocates inside iceoryx2).
//!
//! A counting global allocator wraps the system one; this file holds one test so no other test
//! allocates concurrently.

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use std::time::Duration;

use mbpo_core::{Batch, ReplayBuffer, TransitionSink};
use mbpo_wire::*;

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn steady_state_receive_path_does_not_allocate() {
    ignore_libtest_main_thread();
    let run = RunIpc::new(
        &format!("noalloc-{}", std::process::id()),
        "/tmp/mbpo-wire-test",
    )
    .unwrap();
    {
        let actor = run.node::<ipc::Service>(Role::Actor, 0).unwrap();
        let learner = run.node::<ipc::Service>(Role::Learner, 0).unwrap();
        let layout = RowLayout::new(17, 6);
        let tx = TransitionPublisher::create(&actor, Channel::Real, layout, 1000).unwrap();
        let rx = TransitionSubscriber::create(&learner, Channel::Real, layout).unwrap();
        let wp = WeightsPublisher::create(&learner, WeightsKind::Policy, 1, 1000).unwrap();
        let ws = WeightsSubscriber::create(&actor, WeightsKind::Policy, 1, 1000).unwrap();
        tx.wait_for_subscribers(1, Duration::from_secs(5)).unwrap();
        let batch = Batch::new(17, 6, 1000);
        let mut buf = ReplayBuffer::new(17, 6, 10_000);
        let mut out = Batch::new(17, 6, 1000);
        let params = vec![0.25f32; 1000];
        let mut dst = vec![0.0f32; 1000];
        let relists = || rx.publisher_relists() + ws.publisher_relists();
        // (send-side, receive-side) allocations of one step.
        let mut step = |v: u64| {
            let a0 = allocations();
            let meta = TransitionMeta {
                policy_version: v,
                model_version: 0,
                env_steps: v,
            };
            if v.is_multiple_of(2) {
                tx.send_batch(&batch, meta).unwrap();
            } else {
                // An actor's path: rows written in place into the loaned sample.
                let mut loan = tx.loan_rows(1000).unwrap();
                for r in 0..1000 {
                    let (o, a) = (
                        &batch.obs[r * 17..(r + 1) * 17],
                        &batch.act[r * 6..(r + 1) * 6],
                    );
                    loan.push(o, a, 0.5, o, false);
                }
                loan.send(meta).unwrap();
            }
            wp.publish(&params, v, WeightsCounters::default()).unwrap();
            let a1 = allocations();
            let b = rx.receive().unwrap().unwrap();
            b.push_into(&mut buf);
            b.to_batch(&mut out);
            drop(b);
            ws.receive_latest_into(&mut dst).unwrap().unwrap();
            let a2 = allocations();
            (a1 - a0, a2 - a1)
        };
        for v in 1..=20 {
            step(v);
        }
        let (mut send, mut recv) = (0, 0);
        let relists_before = relists();
        for v in 21..=220 {
            let (s, r) = step(v);
            send += s;
            recv += r;
        }
        let relisted = relists() - relists_before;
        // Two blocks per re-list (iceoryx2's publisher snapshot); nothing else.
        assert!(
            recv as u64 <= 2 * relisted,
            "{recv} allocations on the receive path in 200 steps ({relisted} publisher re-lists, \
             which may allocate 2 each)"
        );
        // Two iceoryx2 sends per step, one block each.
        assert!(
            send <= 2 * 200,
            "{send} allocations on the send path in 200 steps"
        );
    }
    run.remove_all::<ipc::Service>().unwrap();
}
