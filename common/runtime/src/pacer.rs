//! Stepping on a clock ([`Pacer`]): a paced actor's steps start on absolute deadlines of the
//! monotonic clock, `start + k · period`, so waiting never accumulates drift. A step that starts
//! after its deadline is counted as missed, and the next deadline is the first one of the grid
//! after it (no burst of catch-up steps, as a robot would not want one). Each step's start is
//! read from the clock after the wait, and the error of the interval since the step before,
//! `|interval − period|`, goes into a fixed histogram ([`IntervalErrors`]): what a robot's
//! controller sees of the scheduler. No allocation, lock or log on the way: the counts are read
//! after the run.

use std::time::Duration;

use mbpo_wire::{PacingPart, PACING_PART_BINS};

/// Upper edges of the bins of [`IntervalErrors`], µs (the last bin is open).
pub const INTERVAL_ERROR_EDGES_US: [f64; INTERVAL_ERROR_BINS] = [
    2.0,
    5.0,
    10.0,
    20.0,
    50.0,
    100.0,
    200.0,
    500.0,
    1e3,
    2e3,
    5e3,
    1e4,
    2e4,
    5e4,
    1e5,
    f64::INFINITY,
];

/// Bins of [`IntervalErrors`].
pub const INTERVAL_ERROR_BINS: usize = 16;

/// A histogram of step-interval errors `|interval − period|` (log-spaced bins, fixed size: adding
/// allocates nothing), with the largest error.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct IntervalErrors {
    /// Intervals per bin of [`INTERVAL_ERROR_EDGES_US`].
    pub counts: [u64; INTERVAL_ERROR_BINS],
    /// The largest error, ns.
    pub max_ns: u64,
}

impl IntervalErrors {
    /// Count one interval error of `ns`.
    pub fn add(&mut self, ns: u64) {
        let us = ns as f64 / 1e3;
        let bin = INTERVAL_ERROR_EDGES_US.iter().position(|&e| us < e);
        self.counts[bin.unwrap_or(INTERVAL_ERROR_BINS - 1)] += 1;
        self.max_ns = self.max_ns.max(ns);
    }
    /// Add `other`'s counts (another actor's).
    pub fn merge(&mut self, other: &IntervalErrors) {
        for (c, o) in self.counts.iter_mut().zip(other.counts) {
            *c += o;
        }
        self.max_ns = self.max_ns.max(other.max_ns);
    }
    /// The histogram as the stats records that carry it (bins in parts of
    /// [`PACING_PART_BINS`]).
    pub fn parts(&self) -> impl Iterator<Item = PacingPart> + '_ {
        let max_error_us = (self.max_ns as f64 / 1e3) as f32;
        self.counts
            .chunks(PACING_PART_BINS)
            .enumerate()
            .map(move |(i, chunk)| {
                let mut counts = [0; PACING_PART_BINS];
                counts[..chunk.len()].copy_from_slice(chunk);
                PacingPart {
                    first_bin: (i * PACING_PART_BINS) as u32,
                    counts,
                    max_error_us,
                }
            })
    }
    /// Add an actor's part (the coordinator puts the parts of every actor together).
    pub fn add_part(&mut self, part: &PacingPart) {
        let first = part.first_bin as usize;
        let bins = self.counts.iter_mut().skip(first);
        for (c, n) in bins.zip(part.counts) {
            *c += n;
        }
        let max_ns = (f64::from(part.max_error_us) * 1e3) as u64;
        self.max_ns = self.max_ns.max(max_ns);
    }
    /// The bins as a person reads them: `< 2 us`, ..., `>= 100 ms`, with their counts.
    pub fn labelled(&self) -> Vec<(String, u64)> {
        let text = |us: f64| match us >= 1e3 {
            true => format!("{} ms", us / 1e3),
            false => format!("{us} us"),
        };
        let mut lower = 0.0;
        let bins = self.counts.iter().zip(INTERVAL_ERROR_EDGES_US);
        bins.map(|(&c, upper)| {
            let label = match (lower, upper.is_finite()) {
                (0.0, _) => format!("< {}", text(upper)),
                (_, true) => format!("{}..{}", text(lower), text(upper)),
                (_, false) => format!(">= {}", text(lower)),
            };
            lower = upper;
            (label, c)
        })
        .collect()
    }
    /// Intervals counted.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }
    /// An upper bound of quantile `q` of the errors, µs: the upper edge of the bin that holds
    /// it, or the largest error when that is smaller (always for the open last bin). 0 when
    /// nothing was counted.
    pub fn quantile_us(&self, q: f64) -> f64 {
        let total = self.total();
        if total == 0 {
            return 0.0;
        }
        let rank = ((q * total as f64).ceil() as u64).clamp(1, total);
        let max_us = self.max_ns as f64 / 1e3;
        let mut seen = 0;
        for (count, edge) in self.counts.iter().zip(INTERVAL_ERROR_EDGES_US) {
            seen += count;
            if seen >= rank {
                return edge.min(max_us);
            }
        }
        max_us
    }
}

/// Late steps the pacer keeps for the log (the first ones of a run).
pub const LATE_STEPS_KEPT: usize = 16;

/// A step that started after its deadline, or whose interval since the step before was off by
/// more than a tenth of the period: when (so that it can be set beside the other roles' logs).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LateStep {
    /// The step's number among the paced steps.
    pub step: u64,
    /// When it started, CLOCK_MONOTONIC ns.
    pub at_ns: u64,
    /// Its interval's error, ns.
    pub error_ns: u64,
    /// It started after its deadline (the step before overran).
    pub missed: bool,
}

/// Deadlines every `period`, and what happened at them.
#[derive(Debug, Clone)]
pub struct Pacer {
    period_ns: u64,
    /// The next deadline (monotonic ns); `None` before the first step.
    next: Option<u64>,
    /// When the step before started (monotonic ns); `None` at the start of a grid.
    last_start: Option<u64>,
    /// Errors of the intervals between steps on one grid.
    pub intervals: IntervalErrors,
    /// Deadlines a step started after.
    pub missed: u64,
    /// Steps paced.
    pub steps: u64,
    /// The latest start after a deadline, ns.
    pub worst_late_ns: u64,
    /// Rests outside the grid ([`Pacer::rest`]).
    pub rests: u64,
    /// The first [`LATE_STEPS_KEPT`] late steps (a fixed array: nothing allocates per step).
    late: [LateStep; LATE_STEPS_KEPT],
    /// Late steps seen (those past the array are only counted).
    late_seen: usize,
}

impl Pacer {
    /// `hz` steps a second; `None` for 0 (unpaced).
    pub fn new(hz: f64) -> Option<Self> {
        (hz > 0.0).then(|| Self {
            period_ns: (1e9 / hz).round().max(1.0) as u64,
            next: None,
            last_start: None,
            intervals: IntervalErrors::default(),
            missed: 0,
            steps: 0,
            worst_late_ns: 0,
            rests: 0,
            late: [LateStep::default(); LATE_STEPS_KEPT],
            late_seen: 0,
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
        self.last_start = None;
        self.rests += 1;
    }
    /// Sleep until the next deadline (the first step starts at once and sets the grid).
    pub fn wait(&mut self) {
        let now = monotonic_ns();
        let deadline = *self.next.get_or_insert(now);
        let missed = now > deadline;
        if missed {
            self.missed += 1;
            self.worst_late_ns = self.worst_late_ns.max(now - deadline);
        } else {
            sleep_until(deadline);
        }
        // The next deadline on the grid after this step's start.
        let start = now.max(deadline);
        let behind = (start - deadline) / self.period_ns;
        self.next = Some(deadline + (behind + 1) * self.period_ns);
        self.steps += 1;
        // The step starts now: when the sleep ended (the scheduler's latency included).
        let started = monotonic_ns();
        let last = self.last_start.replace(started);
        let error_ns = last.map_or(0, |last| (started - last).abs_diff(self.period_ns));
        if last.is_some() {
            self.intervals.add(error_ns);
        }
        if missed || error_ns > self.period_ns / 10 {
            self.note_late(LateStep {
                step: self.steps,
                at_ns: started,
                error_ns,
                missed,
            });
        }
    }
    fn note_late(&mut self, late: LateStep) {
        if let Some(slot) = self.late.get_mut(self.late_seen) {
            *slot = late;
        }
        self.late_seen += 1;
    }
    /// The first late steps (at most [`LATE_STEPS_KEPT`]) and how many there were in all.
    pub fn late_steps(&self) -> (&[LateStep], usize) {
        (
            &self.late[..self.late_seen.min(LATE_STEPS_KEPT)],
            self.late_seen,
        )
    }
}

/// `late` in words for the log: each step's number, UTC time of day (as the logs print it) and
/// error, e.g. `step 25001 at 22:31:05.123 (1.97 ms off, missed)`.
pub fn describe_late_steps(late: &[LateStep]) -> String {
    let (mono_now, unix_now) = (monotonic_ns(), unix_ns());
    let words: Vec<String> = late
        .iter()
        .map(|l| {
            let unix = unix_now.saturating_sub(mono_now.saturating_sub(l.at_ns));
            let ms_of_day = unix / 1_000_000 % 86_400_000;
            let (h, m) = (ms_of_day / 3_600_000, ms_of_day / 60_000 % 60);
            let (sec, ms) = (ms_of_day / 1000 % 60, ms_of_day % 1000);
            let missed = if l.missed { ", missed" } else { "" };
            let off = l.error_ns as f64 / 1e6;
            format!(
                "step {} at {h:02}:{m:02}:{sec:02}.{ms:03} ({off:.2} ms off{missed})",
                l.step
            )
        })
        .collect();
    words.join(", ")
}

/// CLOCK_REALTIME in ns since the Unix epoch.
fn unix_ns() -> u64 {
    let since = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH);
    since.map_or(0, |d| d.as_nanos() as u64)
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
        let t0 = monotonic_ns();
        p.wait();
        let t1 = monotonic_ns();
        assert_eq!(p.missed, before + 1);
        assert!(p.worst_late_ns >= 5_000_000, "{}", p.worst_late_ns);
        // The late step is kept with its number and error, and said with its time of day.
        let (late, all) = p.late_steps();
        let missed_step = late.iter().find(|l| l.missed).expect("the overrun is kept");
        assert_eq!(missed_step.step, 11);
        assert!(missed_step.error_ns >= 5_000_000, "{missed_step:?}");
        assert!(all >= 1 && late.len() == all.min(LATE_STEPS_KEPT));
        let words = describe_late_steps(&[*missed_step]);
        assert!(
            words.starts_with("step 11 at ") && words.ends_with("ms off, missed)"),
            "{words}"
        );
        // The next deadline is the grid's first after that start (which was within t0..t1),
        // not one already past (a burst of the missed ones). Read off the pacer, not off a
        // timed wait: how long a sleep overshoots is the machine's (this failed under load at
        // 7.4 ms against a 7 ms bound, 2026-12-06).
        let next = p.next.expect("a grid after the first step");
        assert!(next > t0 && next <= t1 + 5_000_000, "{t0} {next} {t1}");
        p.wait();
        assert_eq!(p.steps, 12);
        // A rest (waiting for weights) is counted as one, not as a missed deadline.
        let missed = p.missed;
        std::thread::sleep(Duration::from_millis(12));
        p.rest();
        p.wait();
        assert_eq!((p.missed, p.rests), (missed, 1));
        assert!(Pacer::new(0.0).is_none());
        // Past the kept ones, late steps are only counted.
        let mut q = Pacer::new(1e6).unwrap();
        for _ in 0..LATE_STEPS_KEPT + 5 {
            q.note_late(LateStep::default());
        }
        assert_eq!(q.late_steps().0.len(), LATE_STEPS_KEPT);
        assert_eq!(q.late_steps().1, LATE_STEPS_KEPT + 5);
        // Every interval on a grid is counted (the rest started a new one).
        assert_eq!(p.intervals.total(), p.steps - 2);
        assert!(
            p.intervals.max_ns >= 5_000_000,
            "the overrun: {:?}",
            p.intervals
        );
    }

    #[test]
    fn interval_errors_fall_into_log_spaced_bins_with_upper_bounds_as_quantiles() {
        let mut h = IntervalErrors::default();
        assert_eq!(h.quantile_us(0.5), 0.0);
        for ns in [1_000, 1_500, 3_000, 40_000] {
            h.add(ns);
        }
        h.add(250_000_000);
        assert_eq!(h.counts[0], 2); // < 2 us
        assert_eq!(h.counts[1], 1); // 2..5 us
        assert_eq!(h.counts[4], 1); // 20..50 us
        assert_eq!(h.counts[INTERVAL_ERROR_BINS - 1], 1); // over 100 ms
        assert_eq!(h.quantile_us(0.4), 2.0);
        assert_eq!(h.quantile_us(0.6), 5.0);
        assert_eq!(h.quantile_us(0.99), 250_000.0);
        let mut other = IntervalErrors::default();
        other.add(7_000);
        h.merge(&other);
        assert_eq!((h.total(), h.counts[2], h.max_ns), (6, 1, 250_000_000));
        // Through the stats records and back, as the coordinator puts actors together.
        let mut back = IntervalErrors::default();
        h.parts().for_each(|p| back.add_part(&p));
        assert_eq!(back, h);
        assert_eq!(h.parts().count(), 3);
        let labels = h.labelled();
        assert_eq!(labels[0], ("< 2 us".to_string(), 2));
        assert_eq!(labels[9].0, "1 ms..2 ms");
        assert_eq!(labels[15], (">= 100 ms".to_string(), 1));
        // A bin's edge above the largest error is not claimed.
        let mut one = IntervalErrors::default();
        one.add(60_000);
        assert_eq!(one.quantile_us(0.5), 60.0);
    }
}
