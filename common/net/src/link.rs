//! The reliable stream's bookkeeping, free of any I/O so it is tested on its own.
//!
//! Go-back-N over Zenoh: within one Zenoh session messages arrive in order and at most once,
//! but a dropped TCP connection loses what was in flight. So the sender keeps every message
//! until the receiver acknowledges it ([`Outbox`]); when acknowledgements stop for
//! [`RESEND_AFTER`] while some are outstanding, it sends them all again from the oldest. The
//! receiver ([`Inbox`]) hands on exactly the next number it expects and drops any other (a copy
//! sent again, or one after a gap, which comes again after the resend), so every message is
//! handed on once and in order. The window bounds the memory held, and a full window stops the
//! sender: that is how a slow consumer on the head slows an actor on a worker.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Resend the outstanding messages when no acknowledgement came for this long.
pub const RESEND_AFTER: Duration = Duration::from_millis(500);

/// The sender's side: numbers messages, keeps them until acknowledged.
#[derive(Debug)]
pub struct Outbox {
    next_seq: u64,
    /// `(seq, encoded envelope)`, oldest first.
    unacked: VecDeque<(u64, Vec<u8>)>,
    unacked_bytes: usize,
    window_messages: usize,
    window_bytes: usize,
    last_progress: Instant,
    resent: u64,
}

impl Outbox {
    /// An empty outbox holding at most `window_messages` messages or `window_bytes` bytes
    /// (always at least one message, however large).
    pub fn new(window_messages: usize, window_bytes: usize) -> Self {
        Self {
            next_seq: 0,
            unacked: VecDeque::new(),
            unacked_bytes: 0,
            window_messages: window_messages.max(1),
            window_bytes,
            last_progress: Instant::now(),
            resent: 0,
        }
    }

    /// The number the next message gets.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// True when a message of `bytes` must wait for acknowledgements first.
    pub fn is_full(&self, bytes: usize) -> bool {
        !self.unacked.is_empty()
            && (self.unacked.len() >= self.window_messages
                || self.unacked_bytes + bytes > self.window_bytes)
    }

    /// Keep the encoded message `encode(seq)` under the next number; returns that number and
    /// the bytes to send now.
    pub fn push(&mut self, encode: impl FnOnce(u64) -> Vec<u8>) -> (u64, &[u8]) {
        let seq = self.next_seq;
        self.next_seq += 1;
        let bytes = encode(seq);
        if self.unacked.is_empty() {
            self.last_progress = Instant::now();
        }
        self.unacked_bytes += bytes.len();
        self.unacked.push_back((seq, bytes));
        (seq, &self.unacked.back().expect("just pushed").1)
    }

    /// The peer has every message before `next`: forget them. Returns how many were freed.
    pub fn ack(&mut self, next: u64) -> usize {
        let mut freed = 0;
        while let Some((seq, bytes)) = self.unacked.front() {
            if *seq >= next {
                break;
            }
            self.unacked_bytes -= bytes.len();
            self.unacked.pop_front();
            freed += 1;
        }
        if freed > 0 {
            self.last_progress = Instant::now();
        }
        freed
    }

    /// Messages sent but not acknowledged.
    pub fn outstanding(&self) -> usize {
        self.unacked.len()
    }

    /// When acknowledgements have stalled for [`RESEND_AFTER`]: every outstanding message, oldest
    /// first, to be sent again (and the stall clock restarted). Otherwise nothing.
    pub fn due_for_resend(&mut self, now: Instant) -> impl Iterator<Item = &[u8]> {
        let due =
            !self.unacked.is_empty() && now.duration_since(self.last_progress) >= RESEND_AFTER;
        if due {
            self.last_progress = now;
            self.resent += self.unacked.len() as u64;
        }
        self.unacked
            .iter()
            .take(if due { usize::MAX } else { 0 })
            .map(|(_, b)| b.as_slice())
    }

    /// Messages sent more than once so far.
    pub fn resent(&self) -> u64 {
        self.resent
    }
}

/// What the receiver does with message `seq`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accept {
    /// The next one: hand it on, then acknowledge.
    Deliver,
    /// Had it already (a resend): drop it, acknowledge again.
    Duplicate,
    /// A later one (one before it was lost): drop it; it comes again after the resend.
    Early,
}

/// The receiver's side: which number comes next.
#[derive(Debug, Default, Clone)]
pub struct Inbox {
    next: u64,
    duplicates: u64,
    early: u64,
}

impl Inbox {
    /// What to do with message `seq`; [`Accept::Deliver`] advances the stream.
    pub fn accept(&mut self, seq: u64) -> Accept {
        if seq == self.next {
            self.next += 1;
            Accept::Deliver
        } else if seq < self.next {
            self.duplicates += 1;
            Accept::Duplicate
        } else {
            self.early += 1;
            Accept::Early
        }
    }
    /// The next number expected (what an acknowledgement says).
    pub fn next(&self) -> u64 {
        self.next
    }
    /// Copies received again and dropped.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }
    /// Messages received after a gap and dropped.
    pub fn early(&self) -> u64 {
        self.early
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(seq: u64) -> Vec<u8> {
        seq.to_le_bytes().to_vec()
    }

    #[test]
    fn acknowledged_messages_are_freed_and_the_window_bounds_the_rest() {
        let mut out = Outbox::new(3, 1 << 20);
        for i in 0..3 {
            assert!(!out.is_full(8));
            assert_eq!(out.push(msg).0, i);
        }
        assert!(out.is_full(8));
        assert_eq!(out.ack(2), 2);
        assert_eq!(out.outstanding(), 1);
        assert!(!out.is_full(8));
        assert_eq!(out.ack(1), 0, "an old acknowledgement frees nothing");
        let mut small = Outbox::new(100, 20);
        small.push(|_| vec![0; 15]);
        assert!(small.is_full(10), "bytes bound the window too");
        small.ack(1);
        assert!(!small.is_full(1000), "one message always fits");
    }

    #[test]
    fn a_stalled_stream_is_sent_again_from_the_oldest_unacknowledged() {
        let mut out = Outbox::new(10, 1 << 20);
        for _ in 0..4 {
            out.push(msg);
        }
        out.ack(1);
        let t0 = Instant::now();
        assert_eq!(out.due_for_resend(t0).count(), 0, "not yet");
        let later = t0 + RESEND_AFTER * 2;
        let again: Vec<Vec<u8>> = out.due_for_resend(later).map(|b| b.to_vec()).collect();
        assert_eq!(again, vec![msg(1), msg(2), msg(3)]);
        assert_eq!(out.resent(), 3);
        assert_eq!(out.due_for_resend(later).count(), 0, "the clock restarted");
    }

    /// A lossy, duplicating link between an Outbox and an Inbox delivers every message once,
    /// in order.
    #[test]
    fn every_message_arrives_once_in_order_over_a_lossy_link() {
        let mut out = Outbox::new(8, 1 << 20);
        let mut inbox = Inbox::default();
        let mut delivered = Vec::new();
        let mut now = Instant::now();
        let mut rng = 0x1234_5678_u64;
        let mut coin = |p: u64| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng % 100 < p
        };
        let total = 500u64;
        let mut produced = 0u64;
        for _round in 0..100_000 {
            if delivered.len() as u64 == total {
                break;
            }
            let mut wire: Vec<Vec<u8>> = Vec::new();
            while produced < total && !out.is_full(8) {
                wire.push(out.push(msg).1.to_vec());
                produced += 1;
            }
            now += RESEND_AFTER / 4;
            wire.extend(out.due_for_resend(now).map(|b| b.to_vec()));
            let mut acks = Vec::new();
            for m in wire {
                if coin(20) {
                    continue; // lost
                }
                let copies = if coin(10) { 2 } else { 1 };
                for _ in 0..copies {
                    let seq = u64::from_le_bytes(m[..8].try_into().unwrap());
                    if inbox.accept(seq) == Accept::Deliver {
                        delivered.push(seq);
                    }
                    acks.push(inbox.next());
                }
            }
            for a in acks {
                if !coin(20) {
                    out.ack(a);
                }
            }
        }
        assert_eq!(delivered, (0..total).collect::<Vec<_>>());
        assert!(
            inbox.duplicates() > 0 && out.resent() > 0,
            "the link was lossy"
        );
    }
}
