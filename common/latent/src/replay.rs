//! Real transitions kept as the world model learns from them: TD-MPC2 trains on subsequences of
//! H + 1 observations, H actions and H rewards from one episode, drawn uniformly. A ring of
//! transitions (obs, act, reward, next obs) with a flag saying whether the next row continues
//! the same episode; a subsequence starting at row t is valid when rows t..t+H−1 are stored,
//! each but the last continued by the next, and none but the last ends its episode.

use mbpo_core::rng::{index, Rng};
use serde::{Deserialize, Serialize};

use crate::world_model::Sequences;

/// Attempts to draw a valid start before sampling gives up (a buffer whose episodes are all
/// shorter than H has none).
const MAX_DRAWS: usize = 10_000;

/// The transitions, oldest first within a ring of `capacity` rows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeBuffer {
    obs_dim: usize,
    act_dim: usize,
    capacity: usize,
    obs: Vec<f32>,
    act: Vec<f32>,
    reward: Vec<f32>,
    next_obs: Vec<f32>,
    /// Row i + 1 continues row i's episode (written when row i + 1 arrives).
    continued: Vec<bool>,
    /// Row i ended its episode (terminated or truncated).
    ended: Vec<bool>,
    len: usize,
    next: usize,
}

impl EpisodeBuffer {
    /// An empty buffer of `capacity` transitions of `obs_dim` and `act_dim` values.
    pub fn new(obs_dim: usize, act_dim: usize, capacity: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            capacity,
            obs: vec![0.0; capacity * obs_dim],
            act: vec![0.0; capacity * act_dim],
            reward: vec![0.0; capacity],
            next_obs: vec![0.0; capacity * obs_dim],
            continued: vec![false; capacity],
            ended: vec![false; capacity],
            len: 0,
            next: 0,
        }
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Rows it can hold.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether `other` holds rows of the same observation and action widths (a checkpoint's
    /// buffer of this task).
    pub fn same_widths(&self, other: &EpisodeBuffer) -> bool {
        (self.obs_dim, self.act_dim) == (other.obs_dim, other.act_dim)
    }

    /// The same transitions in a ring of `capacity` rows (a run extended past its planned
    /// steps keeps more), oldest first from row 0, so a draw of the k-th oldest row picks the
    /// same transition; the newest `capacity` are kept when there are more.
    pub fn resized(&self, capacity: usize) -> EpisodeBuffer {
        let mut out = EpisodeBuffer::new(self.obs_dim, self.act_dim, capacity);
        let (o, a) = (self.obs_dim, self.act_dim);
        let oldest = (self.next + self.capacity - self.len) % self.capacity;
        for k in self.len.saturating_sub(capacity)..self.len {
            let r = (oldest + k) % self.capacity;
            out.push(
                &self.obs[r * o..(r + 1) * o],
                &self.act[r * a..(r + 1) * a],
                self.reward[r],
                &self.next_obs[r * o..(r + 1) * o],
                self.ended[r],
            );
        }
        out
    }

    /// The newest transition ended its episode (found out when the next one arrives: a row
    /// carries `terminated` but not a time limit's truncation).
    pub fn end_last(&mut self) {
        if self.len > 0 {
            let last = (self.next + self.capacity - 1) % self.capacity;
            self.ended[last] = true;
        }
    }

    /// Whether `obs` continues the newest transition: it is that transition's next
    /// observation, bit for bit, and the transition did not end its episode.
    pub fn continues(&self, obs: &[f32]) -> bool {
        if self.len == 0 {
            return false;
        }
        let (o, last) = (
            self.obs_dim,
            (self.next + self.capacity - 1) % self.capacity,
        );
        let next = &self.next_obs[last * o..(last + 1) * o];
        !self.ended[last]
            && next
                .iter()
                .zip(obs)
                .all(|(a, b)| a.to_bits() == b.to_bits())
    }

    /// Append a transition; `episode_ended`: terminated or truncated (the next one starts a new
    /// episode). The oldest is overwritten once the ring is full.
    pub fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        episode_ended: bool,
    ) {
        let (o, a, i) = (self.obs_dim, self.act_dim, self.next);
        if self.len > 0 {
            let prev = (i + self.capacity - 1) % self.capacity;
            self.continued[prev] = !self.ended[prev];
        }
        self.obs[i * o..(i + 1) * o].copy_from_slice(obs);
        self.act[i * a..(i + 1) * a].copy_from_slice(act);
        self.reward[i] = reward;
        self.next_obs[i * o..(i + 1) * o].copy_from_slice(next_obs);
        self.continued[i] = false;
        self.ended[i] = episode_ended;
        self.next = (i + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
    }

    /// Whether a subsequence of `horizon` transitions starts at ring row `row`.
    fn valid_start(&self, row: usize, horizon: usize) -> bool {
        // Oldest-first position of `row`: the last `horizon - 1` rows cannot start one.
        let oldest = (self.next + self.capacity - self.len) % self.capacity;
        let pos = (row + self.capacity - oldest) % self.capacity;
        pos + horizon <= self.len
            && (0..horizon - 1).all(|k| self.continued[(row + k) % self.capacity])
    }

    /// Fill `out` (its `batch` set) with subsequences of `horizon` transitions drawn uniformly
    /// among the valid starts; false when none was found in a bounded number of draws.
    pub fn sample(&self, horizon: usize, rng: &mut Rng, out: &mut Sequences) -> bool {
        let (o, a, b) = (self.obs_dim, self.act_dim, out.batch);
        if self.len < horizon {
            return false;
        }
        for j in 0..b {
            let Some(row) = (0..MAX_DRAWS)
                .map(|_| index(rng, self.len))
                .map(|k| (self.next + self.capacity - self.len + k) % self.capacity)
                .find(|&r| self.valid_start(r, horizon))
            else {
                return false;
            };
            for t in 0..horizon {
                let r = (row + t) % self.capacity;
                let at = t * b + j;
                out.obs[at * o..(at + 1) * o].copy_from_slice(&self.obs[r * o..(r + 1) * o]);
                out.act[at * a..(at + 1) * a].copy_from_slice(&self.act[r * a..(r + 1) * a]);
                out.reward[at] = self.reward[r];
            }
            let last = (row + horizon - 1) % self.capacity;
            let at = horizon * b + j;
            out.obs[at * o..(at + 1) * o].copy_from_slice(&self.next_obs[last * o..(last + 1) * o]);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::stream;

    /// Episodes of `len` steps; observation = (episode, step), action = step, reward = step.
    fn filled(capacity: usize, episodes: usize, len: usize) -> EpisodeBuffer {
        let mut buf = EpisodeBuffer::new(2, 1, capacity);
        for e in 0..episodes {
            for s in 0..len {
                let (obs, next) = ([e as f32, s as f32], [e as f32, (s + 1) as f32]);
                buf.push(&obs, &[s as f32], s as f32, &next, s + 1 == len);
            }
        }
        buf
    }

    fn sequences(batch: usize, h: usize) -> Sequences {
        Sequences::zeros(batch, h, 2, 1)
    }

    #[test]
    fn a_subsequence_stays_inside_one_episode_and_ends_with_the_last_next_observation() {
        let (h, b) = (3, 64);
        // A ring of 50 rows over 7 episodes of 10 steps: the oldest 20 were overwritten.
        let buf = filled(50, 7, 10);
        assert_eq!(buf.len(), 50);
        let mut out = sequences(b, h);
        assert!(buf.sample(h, &mut stream(0, "test.replay", 0), &mut out));
        let mut starts = std::collections::BTreeSet::new();
        for j in 0..b {
            let (episode, step) = (out.obs[j * 2], out.obs[j * 2 + 1]);
            assert!(episode >= 2.0, "episode {episode} was overwritten");
            assert!(
                step + h as f32 <= 10.0,
                "starts at step {step}: runs past its episode"
            );
            for t in 0..=h {
                let at = t * b + j;
                assert_eq!(out.obs[at * 2], episode, "one episode throughout");
                assert_eq!(out.obs[at * 2 + 1], step + t as f32);
                if t < h {
                    assert_eq!(out.act[at], step + t as f32);
                    assert_eq!(out.reward[at], step + t as f32);
                }
            }
            starts.insert(step as u32);
        }
        // Every start an episode allows (steps 0..=7) is drawn.
        assert_eq!(
            starts.into_iter().collect::<Vec<_>>(),
            (0..=7).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_resized_buffer_draws_the_same_subsequences_and_keeps_the_newest_rows() {
        // 7 episodes of 10 steps in a ring of 50: wrapped, the oldest row mid-ring.
        let buf = filled(50, 7, 10);
        let mut same = sequences(32, 3);
        let mut bigger = sequences(32, 3);
        assert!(buf.sample(3, &mut stream(3, "test.replay", 0), &mut same));
        let grown = buf.resized(80);
        assert_eq!(grown.len(), 50);
        assert!(grown.sample(3, &mut stream(3, "test.replay", 0), &mut bigger));
        assert_eq!(same.obs, bigger.obs);
        assert_eq!(same.reward, bigger.reward);
        let shrunk = buf.resized(20);
        assert_eq!(shrunk.len(), 20);
        assert_eq!(
            &shrunk.obs[..2],
            &[5.0, 0.0],
            "the newest 20 rows: episodes 5 and 6"
        );
        assert!(shrunk.sample(3, &mut stream(4, "test.replay", 0), &mut same));
    }

    #[test]
    fn a_row_that_does_not_start_from_the_last_next_observation_starts_an_episode() {
        let mut buf = EpisodeBuffer::new(1, 1, 10);
        assert!(!buf.continues(&[0.0]), "nothing to continue");
        buf.push(&[0.0], &[0.0], 0.0, &[1.0], false);
        assert!(buf.continues(&[1.0]));
        assert!(!buf.continues(&[5.0]), "a reset");
        assert!(!buf.continues(&[-0.0f32 + 1.0000001]), "bit for bit");
        buf.end_last();
        assert!(!buf.continues(&[1.0]), "an ended episode is not continued");
    }

    #[test]
    fn episodes_shorter_than_the_horizon_give_no_subsequence() {
        let buf = filled(100, 10, 2);
        let mut out = sequences(4, 3);
        assert!(!buf.sample(3, &mut stream(1, "test.replay", 0), &mut out));
        assert!(buf.sample(2, &mut stream(1, "test.replay", 0), &mut sequences(4, 2)));
    }
}
