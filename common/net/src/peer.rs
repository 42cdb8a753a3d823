//! One side's view of the other end of a link: the Zenoh publisher towards it, the reliable
//! stream's [`Outbox`] and [`Inbox`], and when it was last heard. Used by both gateways.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use zenoh::qos::CongestionControl;
use zenoh::Wait;

use crate::link::{Accept, Inbox, Outbox};
use crate::protocol::{encode, Body, Envelope, Item, PROTOCOL_VERSION};
use crate::GatewayError;

/// At most this many messages of the reliable stream are unacknowledged per peer.
pub const WINDOW_MESSAGES: usize = 256;
/// At most this many bytes are unacknowledged per peer (beyond one message).
pub const WINDOW_BYTES: usize = 8 << 20;
/// How often heartbeats go out.
pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(200);
/// A receiver acknowledges every this many delivered messages at once; in between the
/// heartbeat carries the acknowledgement (well within the sender's resend timeout). Half the
/// link's messages were acknowledgements of one transition batch each.
pub const ACK_EVERY: u32 = 32;

/// The Zenoh publisher of `session` on `key`: reliable, and blocking when the link is congested
/// rather than dropping.
pub fn publisher(
    session: &zenoh::Session,
    key: String,
) -> Result<Arc<zenoh::pubsub::Publisher<'static>>, GatewayError> {
    session
        .declare_publisher(key.clone())
        .congestion_control(CongestionControl::Block)
        .wait()
        .map(Arc::new)
        .map_err(|e| GatewayError::Zenoh(format!("declaring a publisher on {key}: {e}")))
}

/// The other end of a link.
pub struct Peer {
    /// Our session id (stamped on everything we send).
    pub me: u64,
    /// Its session id.
    pub session: u64,
    /// Its name (a worker's; "head" on a worker).
    pub name: String,
    publisher: Arc<zenoh::pubsub::Publisher<'static>>,
    outbox: Outbox,
    inbox: Inbox,
    /// When anything last arrived from it.
    pub last_heard: Instant,
    /// Its messages delivered since we last told it how far we are.
    unacknowledged: u32,
}

impl Peer {
    /// A peer reached through `publisher`.
    pub fn new(
        me: u64,
        session: u64,
        name: String,
        publisher: Arc<zenoh::pubsub::Publisher<'static>>,
    ) -> Self {
        Self {
            me,
            session,
            name,
            publisher,
            outbox: Outbox::new(WINDOW_MESSAGES, WINDOW_BYTES),
            inbox: Inbox::default(),
            last_heard: Instant::now(),
            unacknowledged: 0,
        }
    }

    /// Send `body` outside the reliable stream (it may be lost; the protocol sends it again).
    pub fn send_now(&self, body: Body) -> Result<(), GatewayError> {
        self.put(encode(&Envelope {
            version: PROTOCOL_VERSION,
            session: self.me,
            body,
        }))
    }

    /// Send encoded bytes as they are (a weight snapshot encoded once for every peer).
    pub fn put(&self, bytes: Vec<u8>) -> Result<(), GatewayError> {
        self.publisher
            .put(bytes)
            .wait()
            .map_err(|e| GatewayError::Zenoh(format!("sending to {}: {e}", self.name)))
    }

    /// True when an item of about `bytes` must wait for acknowledgements.
    pub fn window_full(&self, bytes: usize) -> bool {
        self.outbox.is_full(bytes)
    }

    /// Put `item` into the reliable stream and send it.
    pub fn send_item(&mut self, item: Item) -> Result<u64, GatewayError> {
        let me = self.me;
        let (seq, bytes) = self.outbox.push(|seq| {
            encode(&Envelope {
                version: PROTOCOL_VERSION,
                session: me,
                body: Body::Data { seq, item },
            })
        });
        let bytes = bytes.to_vec();
        self.put(bytes)?;
        Ok(seq)
    }

    /// Send the stream's unacknowledged messages again if acknowledgements stalled.
    pub fn resend_due(&mut self, now: Instant) -> Result<(), GatewayError> {
        let again: Vec<Vec<u8>> = self
            .outbox
            .due_for_resend(now)
            .map(<[u8]>::to_vec)
            .collect();
        if !again.is_empty() {
            tracing::debug!("{}: sending {} message(s) again", self.name, again.len());
        }
        for bytes in again {
            self.put(bytes)?;
        }
        Ok(())
    }

    /// The peer acknowledged everything before `next`.
    pub fn acked(&mut self, next: u64) -> usize {
        self.outbox.ack(next)
    }

    /// Messages not yet acknowledged.
    pub fn outstanding(&self) -> usize {
        self.outbox.outstanding()
    }

    /// Messages sent again so far.
    pub fn resent(&self) -> u64 {
        self.outbox.resent()
    }

    /// What to do with its message `seq`.
    pub fn accept(&mut self, seq: u64) -> Accept {
        self.inbox.accept(seq)
    }

    /// The next number expected of its stream.
    pub fn next_expected(&self) -> u64 {
        self.inbox.next()
    }

    /// Copies of its messages received again (dropped).
    pub fn duplicates(&self) -> u64 {
        self.inbox.duplicates()
    }

    /// Acknowledge its message that `accept` judged: every [`ACK_EVERY`] deliveries, and at
    /// once for a copy or an early message (it is sending again and needs to know how far we
    /// are); the heartbeat acknowledges the rest.
    pub fn acknowledge(&mut self, accept: Accept) -> Result<(), GatewayError> {
        if accept == Accept::Deliver {
            self.unacknowledged += 1;
            if self.unacknowledged < ACK_EVERY {
                return Ok(());
            }
        }
        self.unacknowledged = 0;
        self.send_now(Body::Ack {
            next: self.next_expected(),
        })
    }

    /// A heartbeat saying what we have seen (and so acknowledging it).
    pub fn heartbeat(&mut self, weights: u64) -> Result<(), GatewayError> {
        self.unacknowledged = 0;
        self.send_now(Body::Heartbeat {
            next: self.next_expected(),
            weights,
        })
    }
}

/// Wait on `cv` until `ready(state)` or `stop(state)`; false when stopped.
pub fn wait_until<'a, T>(
    cv: &Condvar,
    mut guard: MutexGuard<'a, T>,
    mut ready: impl FnMut(&mut T) -> bool,
    mut stop: impl FnMut(&T) -> bool,
) -> (MutexGuard<'a, T>, bool) {
    loop {
        if ready(&mut guard) {
            return (guard, true);
        }
        if stop(&guard) {
            return (guard, false);
        }
        guard = cv
            .wait_timeout(guard, Duration::from_millis(100))
            .map(|(g, _)| g)
            .unwrap_or_else(|e| e.into_inner().0);
    }
}

/// Lock `m`, also after a thread panicked holding it (the state is counters and queues).
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}
