//! Sleeping until any attached port has news, a deadline passes, or SIGINT/SIGTERM arrives.
//!
//! A subscriber cannot be attached to an iceoryx2 WaitSet, so every port owns a listener on the
//! event service paired with its channel: publishers notify after each send. The [`Waiter`]
//! sleeps in `epoll` on those listeners (no polling), and after a wake-up consumes every
//! pending notification and does the ports' housekeeping (a weights publisher delivers its
//! current snapshot to subscribers that just connected). Drain the subscribers after
//! [`WaitOutcome::Notified`]; receiving nothing is normal (a notification can cover several
//! samples, or a publisher appeared).
//!
//! ```no_run
//! # use mbpo_wire::*;
//! # fn f(run: &RunIpc) -> Result<(), Box<dyn std::error::Error>> {
//! let node = run.node::<ipc::Service>(Role::Learner, 0)?;
//! let real = TransitionSubscriber::create(&node, Channel::Real, RowLayout::new(3, 1))?;
//! let mut buffer = mbpo_core::ReplayBuffer::new(3, 1, 1_000_000);
//! let mut waiter = Waiter::new()?;
//! waiter.attach(&real);
//! loop {
//!     match waiter.wait(std::time::Duration::from_millis(500))? {
//!         WaitOutcome::Terminate => break,
//!         WaitOutcome::Notified | WaitOutcome::TimedOut => {}
//!     }
//!     real.drain_into(&mut buffer)?; // ports take &self, so they stay usable while attached
//! }
//! # Ok(()) }
//! ```

use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::{CallbackProgression, SynchronousMultiplexing, WaitSet, WaitSetBuilder};
use iceoryx2::service::Service;
use iceoryx2::waitset::WaitSetRunResult;

use crate::error::{WaitError, WaiterCreateError};
use crate::messages::{MsgPublisher, MsgSubscriber, WireMessage};
use crate::transitions::{TransitionPublisher, TransitionSubscriber};
use crate::weights::{WeightsPublisher, WeightsSubscriber};

mod sealed {
    pub trait Sealed {}
}

/// A port a [`Waiter`] can sleep on: every subscriber (wakes on data) and every publisher
/// (wakes when a subscriber connects).
pub trait Wakeable<S: Service>: sealed::Sealed {
    #[doc(hidden)]
    fn wake_listener(&self) -> &Listener<S>;
    /// Consume the port's pending wake-ups (and act on them); `true` when there were any.
    #[doc(hidden)]
    fn on_wake(&self) -> bool;
}

macro_rules! wakeable {
    ($ty:ty, [$($gen:tt)*], |$s:ident| $listener:expr, |$w:ident| $wake:expr) => {
        impl<$($gen)*> sealed::Sealed for $ty {}
        impl<$($gen)*> Wakeable<S> for $ty {
            fn wake_listener(&self) -> &Listener<S> {
                let $s = self;
                $listener
            }
            fn on_wake(&self) -> bool {
                let $w = self;
                $wake
            }
        }
    };
}

wakeable!(TransitionSubscriber<S>, [S: Service], |s| s.side().listener(), |s| {
    let woken = s.side().consume_events();
    s.refresh(false);
    woken
});
wakeable!(WeightsSubscriber<S>, [S: Service], |s| s.side().listener(), |s| {
    let woken = s.side().consume_events();
    s.refresh(false);
    woken
});
wakeable!(MsgSubscriber<T, S>, [T: WireMessage, S: Service], |s| s.side().listener(), |s| {
    let woken = s.side().consume_events();
    s.refresh(false);
    woken
});
wakeable!(TransitionPublisher<S>, [S: Service], |s| s.side().listener(), |s| {
    s.side().poll_acks() > 0
});
wakeable!(MsgPublisher<T, S>, [T: WireMessage, S: Service], |s| s.side().listener(), |s| {
    s.side().poll_acks() > 0
});
wakeable!(WeightsPublisher<S>, [S: Service], |s| s.side().listener(), |s| s.on_wake());

/// Longest uninterrupted sleep: how quickly a SIGINT/SIGTERM delivered to another thread is
/// noticed. Ten wake-ups per second cost a few microseconds of CPU each.
pub const SIGNAL_CHECK: Duration = Duration::from_millis(100);

/// Why [`Waiter::wait`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum WaitOutcome {
    /// At least one attached port was notified (data arrived, or a peer connected).
    Notified,
    /// The timeout or deadline passed without news.
    TimedOut,
    /// SIGINT or SIGTERM was received: finish up and exit.
    Terminate,
}

/// Sleeps until any attached port has news, the timeout passes, or a termination signal comes.
pub struct Waiter<'a, S: Service = iceoryx2::service::ipc::Service> {
    ws: WaitSet<S>,
    ports: Vec<&'a dyn Wakeable<S>>,
}

impl<S: Service> std::fmt::Debug for Waiter<'_, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Waiter")
            .field("ports", &self.ports.len())
            .finish()
    }
}

impl<'a, S: Service> Waiter<'a, S>
where
    Listener<S>: SynchronousMultiplexing,
{
    /// An empty waiter (SIGINT/SIGTERM end waits with [`WaitOutcome::Terminate`]).
    pub fn new() -> Result<Self, WaiterCreateError> {
        let ws = WaitSetBuilder::new()
            .create::<S>()
            .map_err(|e| WaiterCreateError(format!("{e:?}")))?;
        Ok(Self {
            ws,
            ports: Vec::new(),
        })
    }

    /// Also wake on `port`.
    pub fn attach(&mut self, port: &'a dyn Wakeable<S>) -> &mut Self {
        self.ports.push(port);
        self
    }

    /// Number of attached ports.
    pub fn len(&self) -> usize {
        self.ports.len()
    }
    /// True when nothing is attached.
    pub fn is_empty(&self) -> bool {
        self.ports.is_empty()
    }

    /// Sleep for at most `timeout` (`Duration::MAX`: until news or a signal).
    pub fn wait(&self, timeout: Duration) -> Result<WaitOutcome, WaitError> {
        self.wait_until(Instant::now().checked_add(timeout))
    }

    /// Sleep until `deadline` at the latest (`None`: until news or a signal).
    pub fn wait_until(&self, deadline: Option<Instant>) -> Result<WaitOutcome, WaitError> {
        if self.ports.is_empty() {
            return Err(WaitError::NothingAttached);
        }
        if crate::termination_latched() {
            return Ok(WaitOutcome::Terminate);
        }
        // Take what is pending before sleeping. iceoryx2 0.10's event state can be left
        // "notified" with its socket already drained (a notify racing the drain of an earlier
        // one); every later notify then skips the socket write, and epoll would sleep through
        // them to the timeout (the in-process pipeline stalled a second at a time). Draining
        // resets the state, so the next notify writes again.
        let mut news = false;
        for p in &self.ports {
            news |= p.on_wake();
        }
        if news {
            return Ok(WaitOutcome::Notified);
        }
        // Attach for the duration of this call: level-triggered, so nothing is missed between
        // calls, and the Waiter needs no self-referential guards.
        let mut guards = Vec::with_capacity(self.ports.len());
        for p in &self.ports {
            guards.push(
                self.ws
                    .attach_notification(p.wake_listener())
                    .map_err(|e| WaitError::Attach(format!("{e:?}")))?,
            );
        }
        loop {
            // A signal interrupts epoll only in the thread it is delivered to, which in a
            // multi-threaded process may be another one: wake every SIGNAL_CHECK to look.
            let remaining = match deadline {
                Some(d) => d.saturating_duration_since(Instant::now()),
                None => Duration::MAX,
            }
            .min(SIGNAL_CHECK);
            let mut fired = false;
            let r = self
                .ws
                .wait_and_process_once_with_timeout(
                    |_| {
                        fired = true;
                        CallbackProgression::Continue
                    },
                    remaining,
                )
                .map_err(|e| WaitError::WaitSet(format!("{e:?}")))?;
            match r {
                WaitSetRunResult::TerminationRequest => {
                    crate::latch_termination();
                    return Ok(WaitOutcome::Terminate);
                }
                // EINTR: loop; a SIGINT/SIGTERM is reported by the next call.
                WaitSetRunResult::Interrupt => continue,
                _ => {}
            }
            if fired {
                for p in &self.ports {
                    p.on_wake();
                }
                return Ok(WaitOutcome::Notified);
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Ok(WaitOutcome::TimedOut);
            }
        }
    }
}

/// A service type whose listeners a [`Waiter`] can sleep on: `ipc::Service` (processes) and
/// `local::Service` (threads of one process). The bound is a supertrait, so code generic over
/// `S: Transport` needs no further where-clause to wait.
pub trait Transport:
    Service<
    Event: iceoryx2_cal::event::Event<
        iceoryx2_bb_lock_free::mpmc::counting_bit_set::RelocatableCountingBitSet,
        Listener: iceoryx2_bb_posix::file_descriptor_set::SynchronousMultiplexing,
    >,
>
{
}

impl<S> Transport for S where
    S: Service<
        Event: iceoryx2_cal::event::Event<
            iceoryx2_bb_lock_free::mpmc::counting_bit_set::RelocatableCountingBitSet,
            Listener: iceoryx2_bb_posix::file_descriptor_set::SynchronousMultiplexing,
        >,
    >
{
}
