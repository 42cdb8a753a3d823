//! The box of the real states seen: per dimension, the smallest and largest value of every
//! state and next state a replay buffer holds.
//!
//! Learned models extrapolate: an imagined next state can leave every range the real system
//! was ever seen in, e.g. Hopper-v5 and Walker2d-v5 clip their joint velocities to [−10, 10] in
//! the observation, and a model trained on those observations still samples next states past
//! ±10 (13-23 % of Walker2d's one-step imagined rows in each of four velocities, `mbpo bench
//! diagnose`, which counts imagined states outside this box). The rollout option
//! `mbpo.clip_imagined_states = "real_box"` clamps them into it.

use crate::ReplayBuffer;

/// Per-dimension `[low, high]` of the real states seen.
#[derive(Debug, Clone, PartialEq)]
pub struct StateBox {
    /// Smallest value per dimension (+∞ for an empty buffer: nothing is inside).
    pub low: Vec<f32>,
    /// Largest value per dimension (−∞ for an empty buffer).
    pub high: Vec<f32>,
}

impl StateBox {
    /// The box of every state and next state `real` holds (NaN values are skipped).
    pub fn of(real: &ReplayBuffer) -> Self {
        let o = real.obs_dim();
        let mut b = Self {
            low: vec![f32::INFINITY; o],
            high: vec![f32::NEG_INFINITY; o],
        };
        for state in real.held_states() {
            for ((low, high), &x) in b.low.iter_mut().zip(&mut b.high).zip(state) {
                *low = low.min(x);
                *high = high.max(x);
            }
        }
        b
    }

    /// Clamp `state` into the box, dimension by dimension (NaN stays NaN, as `f32::clamp`
    /// keeps it), and say whether any value moved. An empty box (no real state yet) leaves
    /// `state` as it is.
    pub fn clip(&self, state: &mut [f32]) -> bool {
        let mut moved = false;
        for ((x, &low), &high) in state.iter_mut().zip(&self.low).zip(&self.high) {
            if low <= high && (*x < low || *x > high) {
                *x = x.clamp(low, high);
                moved = true;
            }
        }
        moved
    }

    /// Add 1 to `counts[j]` for every dimension j in which `state` is outside the box (NaN
    /// counts as outside); returns whether it is outside in any.
    pub fn count_outside(&self, state: &[f32], counts: &mut [usize]) -> bool {
        let mut any = false;
        for (((&x, &low), &high), c) in state.iter().zip(&self.low).zip(&self.high).zip(counts) {
            if !(low <= x && x <= high) {
                *c += 1;
                any = true;
            }
        }
        any
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn buffer(rows: &[([f32; 2], [f32; 2])], capacity: usize) -> ReplayBuffer {
        let mut b = ReplayBuffer::new(2, 1, capacity);
        for (s, s_next) in rows {
            b.push(s, &[0.0], 0.0, s_next, false);
        }
        b
    }

    #[test]
    fn the_box_spans_states_and_next_states_held_and_nothing_overwritten() {
        // The first row is overwritten by the fourth (capacity 3): its -100 and 100 are gone.
        let rows = [
            ([-100.0, 0.0], [0.0, 100.0]),
            ([1.0, -2.0], [2.0, 5.0]),
            ([-1.0, 0.5], [f32::NAN, 3.0]),
            ([0.5, 0.5], [0.0, -3.0]),
        ];
        let b = StateBox::of(&buffer(&rows, 3));
        assert_eq!(b.low, vec![-1.0, -3.0]);
        assert_eq!(b.high, vec![2.0, 5.0]);
    }

    #[test]
    fn clipping_clamps_each_dimension_into_the_box() {
        let b = StateBox::of(&buffer(&[([0.0, -1.0], [2.0, 1.0])], 4));
        let mut s = [3.0, -1.5];
        assert!(b.clip(&mut s));
        assert_eq!(s, [2.0, -1.0]);
        let mut inside = [1.0, 0.25];
        assert!(!b.clip(&mut inside));
        assert_eq!(inside, [1.0, 0.25]);
        let mut nan = [f32::NAN, 7.0];
        assert!(b.clip(&mut nan));
        assert!(nan[0].is_nan() && nan[1] == 1.0, "{nan:?}");
    }

    #[test]
    fn an_empty_box_holds_nothing_and_clips_nothing() {
        let b = StateBox::of(&ReplayBuffer::new(2, 1, 4));
        let mut s = [3.0, -1.5];
        assert!(!b.clip(&mut s));
        assert_eq!(s, [3.0, -1.5]);
        let mut counts = [0; 2];
        assert!(b.count_outside(&[0.0, 0.0], &mut counts));
        assert_eq!(counts, [1, 1]);
    }

    #[test]
    fn the_box_holds_its_corners_and_counts_what_is_outside() {
        let b = StateBox::of(&buffer(&[([0.0, 3.0], [2.0, 9.0])], 4));
        let outside = |s: &[f32]| {
            let mut counts = [0; 2];
            let any = b.count_outside(s, &mut counts);
            (any, counts.to_vec())
        };
        for inside in [[0.0, 3.0], [2.0, 9.0], [1.0, 5.0]] {
            assert_eq!(outside(&inside), (false, vec![0, 0]), "{inside:?}");
        }
        assert_eq!(outside(&[2.1, 4.0]), (true, vec![1, 0]));
        assert_eq!(outside(&[0.0, 2.9]), (true, vec![0, 1]));
        assert_eq!(outside(&[f32::NAN, 9.5]), (true, vec![1, 1]));
    }
}
