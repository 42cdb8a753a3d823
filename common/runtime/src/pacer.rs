//! Stepping on a clock ([`Pacer`]): a paced actor's steps start on absolute deadlines of the
//! monotonic clock, `start + k · period`, so waiting never accumulates drift. A step that starts
//! after its deadline is counted as missed, and the next deadline is the first one of the grid
//! after it (no burst of catch-up steps, as a robot would not want one). No allocation, lock or
//! log on the way: the counts are read after the run.

use std::time::Duration;

/// Deadlines every `period`, and what happened at them.
#[derive(Debug, Clone)]
pub struct Pacer {
    period_ns: u64,
    /// The next deadline (monotonic ns); `None` before the first step.
    next: Option<u64>,
    /// Deadlines a step started after.
    pub missed: u64,
    /// Steps paced.
    pub steps: u64,
    /// The latest start after a deadline, ns.
    pub worst_late_ns: u64,
    /// Rests outside the grid ([`Pacer::rest`]).
    pub rests: u64,
}

impl Pacer {
    /// `hz` steps a second; `None` for 0 (unpaced).
    pub fn new(hz: f64) -> Option<Self> {
        (hz > 0.0).then(|| Self {
            period_ns: (1e9 / hz).round().max(1.0) as u64,
            next: None,
            missed: 0,
            steps: 0,
            worst_late_ns: 0,
            rests: 0,
        })
    }
    /// The time between deadlines.
    pub fn period(&self) -> Duration {
        Duration::from_nanos(self.period_ns)
    }
    /// A rest the pacer did not ask for ended (e.g. waiting for weights between episodes):
    /// counted, and the next step starts a new grid, so the wait is not a missed deadline.
    pub fn rest(&mut self) {
        self.next = None;
        self.rests += 1;
    }
    /// Sleep until the next deadline (the first step starts at once and sets the grid).
    pub fn wait(&mut self) {
        let now = monotonic_ns();
        let deadline = *self.next.get_or_insert(now);
        if now <= deadline {
            sleep_until(deadline);
        } else {
            self.missed += 1;
            self.worst_late_ns = self.worst_late_ns.max(now - deadline);
        }
        // The next deadline on the grid after this step's start.
        let start = now.max(deadline);
        let behind = (start - deadline) / self.period_ns;
        self.next = Some(deadline + (behind + 1) * self.period_ns);
        self.steps += 1;
    }
}

/// CLOCK_MONOTONIC in ns.
fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleep until `deadline` (CLOCK_MONOTONIC ns), an absolute time: no drift from wake-up delays.
fn sleep_until(deadline: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline % 1_000_000_000) as libc::c_long,
    };
    // EINTR (a signal) ends the sleep early: sleep again until the deadline itself.
    // SAFETY: clock_nanosleep reads the timespec; the remainder pointer may be null with
    // TIMER_ABSTIME.
    while unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &ts,
            std::ptr::null_mut(),
        )
    } == libc::EINTR
    {}
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steps start on the grid (never before a deadline: a lower bound, robust on a busy
    /// machine); a step started late is counted and the grid moves on without a burst.
    #[test]
    fn steps_start_on_absolute_deadlines_and_late_ones_are_counted() {
        let mut p = Pacer::new(200.0).unwrap();
        assert_eq!(p.period(), Duration::from_millis(5));
        let first = monotonic_ns();
        for _ in 0..10 {
            p.wait();
        }
        // Ten starts: the first at once, nine deadlines later.
        assert!(monotonic_ns() - first >= 9 * 5_000_000);
        let before = p.missed;
        // Overrun two periods and a half: the next start is late, and counted.
        std::thread::sleep(Duration::from_micros(12_500));
        p.wait();
        assert_eq!(p.missed, before + 1);
        assert!(p.worst_late_ns >= 5_000_000, "{}", p.worst_late_ns);
        // The next deadline is on the grid after that start, not a burst of missed ones.
        let t = monotonic_ns();
        p.wait();
        let waited = monotonic_ns() - t;
        assert!(
            waited <= 5_000_000 + 2_000_000 || p.missed > before + 1,
            "{waited}"
        );
        assert_eq!(p.steps, 12);
        // A rest (waiting for weights) is counted as one, not as a missed deadline.
        let missed = p.missed;
        std::thread::sleep(Duration::from_millis(12));
        p.rest();
        p.wait();
        assert_eq!((p.missed, p.rests), (missed, 1));
        assert!(Pacer::new(0.0).is_none());
    }
}
