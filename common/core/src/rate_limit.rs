//! Reverb-style rate limiting: hold a ratio between a producer's and a consumer's progress.
//!
//! A pipelined MBPO changes the algorithm if its ratios drift with the speed of each process:
//! SAC updates per real env step (G), model rollouts per env step (M), how stale the actors'
//! policy and the rollouts' model may be. Each ratio is a [`RateLimiter`] between two counters,
//! `inserts` (producer) and `samples` (consumer), exactly as in DeepMind Reverb's
//! `SampleToInsertRatio` limiter:
//!
//! ```text
//! diff = (inserts − warmup) · samples_per_insert − samples
//! a producer may insert     iff  inserts < warmup  or  diff + samples_per_insert ≤ max_diff
//! a consumer may sample     iff  inserts ≥ warmup  and  diff − 1 ≥ min_diff
//! ```
//!
//! The first `warmup` inserts owe no samples (MBPO's uniform-random steps before learning
//! starts), which is Reverb's offset of `min_size_to_sample · samples_per_insert`.
//!
//! Whichever side is faster waits. `lockstep` is the zero-slack buffer `[0, G]`: after every
//! insert exactly G samples happen before the next insert, which is the sequential algorithm.
//! `pipelined` widens the buffer so both sides run concurrently, within a bounded drift.
//!
//! ```
//! use mbpo_core::rate_limit::RateLimiter;
//! let g = RateLimiter::lockstep(20.0, 0);
//! assert!(g.can_insert(0, 0) && !g.can_sample(0, 0));
//! assert!(!g.can_insert(1, 0) && g.can_sample(1, 0));   // 20 updates are owed
//! assert!(g.can_insert(1, 20) && !g.can_sample(1, 20));  // paid: the next env step may go
//! ```

/// A sample-to-insert ratio with an error buffer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLimiter {
    /// Target consumer steps per producer step.
    pub samples_per_insert: f64,
    /// Producer steps that owe no consumer steps (the consumer starts after them).
    pub warmup: u64,
    /// Lower edge of the allowed `diff` window.
    pub min_diff: f64,
    /// Upper edge of the allowed `diff` window.
    pub max_diff: f64,
}

impl RateLimiter {
    /// Zero slack: exactly `samples_per_insert` consumer steps between producer steps.
    pub fn lockstep(samples_per_insert: f64, warmup: u64) -> Self {
        Self {
            samples_per_insert,
            warmup,
            min_diff: 0.0,
            max_diff: samples_per_insert,
        }
    }

    /// A window of `error_buffer` consumer steps on each side of the target ratio.
    pub fn pipelined(samples_per_insert: f64, warmup: u64, error_buffer: f64) -> Self {
        Self {
            samples_per_insert,
            warmup,
            min_diff: -error_buffer,
            max_diff: samples_per_insert + error_buffer,
        }
    }

    fn diff(&self, inserts: u64, samples: u64) -> f64 {
        (inserts as f64 - self.warmup as f64) * self.samples_per_insert - samples as f64
    }

    /// May the producer make its next step?
    pub fn can_insert(&self, inserts: u64, samples: u64) -> bool {
        inserts < self.warmup
            || self.diff(inserts, samples) + self.samples_per_insert <= self.max_diff + 1e-9
    }

    /// May the consumer make its next step?
    pub fn can_sample(&self, inserts: u64, samples: u64) -> bool {
        inserts >= self.warmup && self.diff(inserts, samples) - 1.0 >= self.min_diff - 1e-9
    }

    /// How many consumer steps are allowed right now.
    pub fn samples_allowed(&self, inserts: u64, samples: u64) -> u64 {
        if inserts < self.warmup {
            return 0;
        }
        (self.diff(inserts, samples) - self.min_diff + 1e-9)
            .floor()
            .max(0.0) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Simulate a producer and a consumer with speeds `p` and `c` steps per tick; return the
    /// extreme diffs seen.
    fn simulate(l: &RateLimiter, p: u64, c: u64, ticks: u64) -> (f64, f64, u64, u64) {
        let (mut ins, mut smp) = (0u64, 0u64);
        let (mut lo, mut hi) = (f64::MAX, f64::MIN);
        for _ in 0..ticks {
            for _ in 0..p {
                if l.can_insert(ins, smp) {
                    ins += 1;
                }
            }
            for _ in 0..c {
                if l.can_sample(ins, smp) {
                    smp += 1;
                }
            }
            if ins >= l.warmup {
                let d = (ins - l.warmup) as f64 * l.samples_per_insert - smp as f64;
                lo = lo.min(d);
                hi = hi.max(d);
            }
        }
        (lo, hi, ins, smp)
    }

    #[test]
    fn lockstep_holds_the_exact_ratio_whatever_the_speeds() {
        let l = RateLimiter::lockstep(20.0, 3);
        for (p, c) in [(1, 1), (100, 1), (1, 1000), (7, 13)] {
            let (lo, hi, ins, smp) = simulate(&l, p, c, 5000);
            assert!(lo >= 0.0 && hi <= 20.0, "p={p} c={c}: diff in [{lo}, {hi}]");
            let owed = (ins - 3) * 20;
            assert!(smp <= owed && smp + 20 >= owed, "p={p} c={c}: {ins} {smp}");
        }
    }

    #[test]
    fn pipelined_stays_within_its_buffer_and_lets_both_sides_move() {
        let l = RateLimiter::pipelined(20.0, 10, 60.0);
        for (p, c) in [(1, 1), (100, 1), (1, 1000)] {
            let (lo, hi, ins, smp) = simulate(&l, p, c, 5000);
            assert!(
                lo >= -60.0 && hi <= 80.0,
                "p={p} c={c}: diff in [{lo}, {hi}]"
            );
            assert!(ins > 10 && smp > 0);
        }
    }

    #[test]
    fn consumer_waits_for_the_warmup_and_producer_is_free_during_it() {
        let l = RateLimiter::lockstep(20.0, 5);
        assert!(!l.can_sample(4, 0) && l.can_insert(4, 0));
        // Insert #6 (the first after warm-up) owes 20 samples before insert #7.
        assert!(l.can_insert(5, 0));
        assert!(!l.can_sample(5, 0) && l.can_sample(6, 0));
        assert!(!l.can_insert(6, 19) && l.can_insert(6, 20));
        assert_eq!(l.samples_allowed(6, 0), 20);
        assert_eq!(
            RateLimiter::pipelined(1.0, 5, 100.0).samples_allowed(6, 0),
            101
        );
    }
}
