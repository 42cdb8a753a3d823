//! Real transitions kept as the world model learns from them: TD-MPC2 trains on subsequences of
//! H + 1 observations, H actions and H rewards from one episode, drawn uniformly. A ring of
//! transitions (obs, act, reward, next obs), each linked to the row that continues its
//! episode; a subsequence starting at row t is valid when t and the H − 1 rows its links lead
//! to are stored.
//!
//! Several actors' rows arrive interleaved, and a row names neither its actor nor its episode,
//! so a row continues the episode whose open tail's next observation it starts from, bit for
//! bit (a tail is open until it is continued, ends or is overwritten); a row that continues
//! none starts an episode. With one actor the links join consecutive rows.

use mbpo_core::rng::{index, Rng};
use serde::{Deserialize, Serialize};

use crate::world_model::Sequences;

/// Attempts to draw a valid start before sampling gives up (a buffer whose episodes are all
/// shorter than H has none).
const MAX_DRAWS: usize = 10_000;

/// Episodes open at once at most (about one per actor; a tail a time limit cut stays open, as
/// a row does not say it was truncated, until newer ones push it out).
const MAX_OPEN: usize = 1024;

/// A row no link leads from.
const NONE: u32 = u32::MAX;

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
    /// Row i has a row continuing its episode (`links.next[i]`). Kept in this layout for
    /// checkpoints written before the links (format 5: one actor, so the next row).
    continued: Vec<bool>,
    /// Row i ended its episode (terminated).
    ended: Vec<bool>,
    len: usize,
    next: usize,
    /// The links; checkpoints carry them beside the buffer ([`EpisodeBuffer::links`]).
    #[serde(skip)]
    links: EpisodeLinks,
}

/// How the rows of an [`EpisodeBuffer`] join into episodes.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EpisodeLinks {
    /// The row continuing row i's episode, or none (`u32::MAX`).
    next: Vec<u32>,
    /// Rows whose episode may go on (not ended, not continued yet), oldest first.
    open: Vec<u32>,
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
            links: EpisodeLinks {
                next: vec![NONE; capacity],
                open: Vec::new(),
            },
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

    /// Episodes (or their stored ends) it holds: rows no stored row links to.
    pub fn episodes(&self) -> usize {
        let oldest = (self.next + self.capacity - self.len) % self.capacity;
        let mut continued = vec![false; self.capacity];
        for k in 0..self.len {
            match self.links.next[(oldest + k) % self.capacity] {
                NONE => {}
                n => continued[n as usize] = true,
            }
        }
        (0..self.len)
            .filter(|k| !continued[(oldest + k) % self.capacity])
            .count()
    }

    /// The links between its rows, for a checkpoint (the buffer's own serialized form keeps
    /// the layout of checkpoints written before them).
    pub fn links(&self) -> &EpisodeLinks {
        &self.links
    }

    /// The buffer of a checkpoint with its links; `None` (a checkpoint written before them, by
    /// one actor): row i is continued by the next row where `continued` says so, and the newest
    /// row is open unless it ended.
    pub fn with_links(mut self, links: Option<EpisodeLinks>) -> Result<Self, String> {
        let cap = self.capacity;
        let links = match links {
            Some(l) => l,
            None => {
                let next = (0..cap)
                    .map(|i| {
                        if self.continued[i] {
                            ((i + 1) % cap) as u32
                        } else {
                            NONE
                        }
                    })
                    .collect();
                let newest = (self.next + cap - 1) % cap;
                let open_newest = self.len > 0 && !self.ended[newest] && !self.continued[newest];
                let open = if open_newest {
                    vec![newest as u32]
                } else {
                    Vec::new()
                };
                EpisodeLinks { next, open }
            }
        };
        let in_ring = |&r: &u32| r == NONE || (r as usize) < cap;
        if links.next.len() != cap
            || !links.next.iter().all(in_ring)
            || !links.open.iter().all(in_ring)
        {
            return Err(format!("its episode links do not fit its {cap} rows"));
        }
        self.links = links;
        Ok(self)
    }

    /// The same transitions in a ring of `capacity` rows (a run extended past its planned
    /// steps keeps more), oldest first from row 0, so a draw of the k-th oldest row picks the
    /// same transition; the newest `capacity` are kept when there are more, with their links.
    pub fn resized(&self, capacity: usize) -> EpisodeBuffer {
        let mut out = EpisodeBuffer::new(self.obs_dim, self.act_dim, capacity);
        let (o, a) = (self.obs_dim, self.act_dim);
        let oldest = (self.next + self.capacity - self.len) % self.capacity;
        let dropped = self.len.saturating_sub(capacity);
        // Ring row -> its row in `out`, for rows kept.
        let moved = |r: u32| -> Option<u32> {
            let k = (r as usize + self.capacity - oldest) % self.capacity;
            (r != NONE && k >= dropped && k < self.len).then(|| (k - dropped) as u32)
        };
        for k in dropped..self.len {
            let r = (oldest + k) % self.capacity;
            let i = k - dropped;
            out.obs[i * o..(i + 1) * o].copy_from_slice(&self.obs[r * o..(r + 1) * o]);
            out.act[i * a..(i + 1) * a].copy_from_slice(&self.act[r * a..(r + 1) * a]);
            out.reward[i] = self.reward[r];
            out.next_obs[i * o..(i + 1) * o].copy_from_slice(&self.next_obs[r * o..(r + 1) * o]);
            out.ended[i] = self.ended[r];
            out.links.next[i] = moved(self.links.next[r]).unwrap_or(NONE);
            out.continued[i] = out.links.next[i] != NONE;
        }
        out.links.open = self.links.open.iter().filter_map(|&r| moved(r)).collect();
        out.len = self.len - dropped;
        out.next = out.len % capacity;
        out
    }

    /// The open tail whose next observation `obs` is, bit for bit (newest first: an actor's
    /// tail is among the newest).
    fn open_tail_of(&self, obs: &[f32]) -> Option<usize> {
        let o = self.obs_dim;
        self.links.open.iter().rposition(|&r| {
            let r = r as usize;
            let next = &self.next_obs[r * o..(r + 1) * o];
            next.iter()
                .zip(obs)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        })
    }

    /// Append a transition; `terminated`: its episode ended (no row continues it). The oldest
    /// is overwritten once the ring is full.
    pub fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        let (o, a, i) = (self.obs_dim, self.act_dim, self.next);
        if self.len == self.capacity {
            // Row i is the oldest: no stored row links to it, and it leaves the open tails.
            self.links.open.retain(|&r| r as usize != i);
        }
        if let Some(k) = self.open_tail_of(obs) {
            let tail = self.links.open.remove(k) as usize;
            self.links.next[tail] = i as u32;
            self.continued[tail] = true;
        }
        self.obs[i * o..(i + 1) * o].copy_from_slice(obs);
        self.act[i * a..(i + 1) * a].copy_from_slice(act);
        self.reward[i] = reward;
        self.next_obs[i * o..(i + 1) * o].copy_from_slice(next_obs);
        self.continued[i] = false;
        self.links.next[i] = NONE;
        self.ended[i] = terminated;
        if !terminated {
            if self.links.open.len() == MAX_OPEN {
                self.links.open.remove(0);
            }
            self.links.open.push(i as u32);
        }
        self.next = (i + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
    }

    /// The row `horizon − 1` links after ring row `row`, if its episode has that many stored.
    fn valid_start(&self, row: usize, horizon: usize) -> bool {
        let mut r = row;
        for _ in 1..horizon {
            match self.links.next[r] {
                NONE => return false,
                n => r = n as usize,
            }
        }
        true
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
            let mut r = row;
            for t in 0..horizon {
                let at = t * b + j;
                out.obs[at * o..(at + 1) * o].copy_from_slice(&self.obs[r * o..(r + 1) * o]);
                out.act[at * a..(at + 1) * a].copy_from_slice(&self.act[r * a..(r + 1) * a]);
                out.reward[at] = self.reward[r];
                if t + 1 < horizon {
                    r = self.links.next[r] as usize;
                }
            }
            let at = horizon * b + j;
            out.obs[at * o..(at + 1) * o].copy_from_slice(&self.next_obs[r * o..(r + 1) * o]);
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
    fn a_row_continues_the_open_episode_it_starts_from_bit_for_bit() {
        let mut buf = EpisodeBuffer::new(1, 1, 10);
        buf.push(&[0.0], &[0.0], 0.0, &[1.0], false);
        buf.push(&[1.0], &[0.0], 0.0, &[2.0], false);
        assert_eq!(buf.links().next[..2], [1, NONE]);
        buf.push(&[5.0], &[0.0], 0.0, &[6.0], true); // a reset: starts an episode, ends it
        buf.push(&[6.0], &[0.0], 0.0, &[7.0], false); // an ended episode is not continued
        buf.push(&[2.0000002], &[0.0], 0.0, &[3.0], false); // bit for bit, or a new episode
        assert_eq!(buf.links().next[..5], [1, NONE, NONE, NONE, NONE]);
        assert_eq!(buf.links().open, [1, 3, 4]);
    }

    /// Three actors' episodes arriving interleaved (rows in turn, episodes of different
    /// lengths) are drawn as if each had arrived alone.
    #[test]
    fn interleaved_episodes_of_several_actors_are_kept_apart() {
        let (h, b) = (3, 256);
        let mut buf = EpisodeBuffer::new(2, 1, 200);
        // Actor k's episode e: observation (10 k + e, step), 6 + k steps, time limit only.
        let mut steps = [0usize; 3];
        let mut episode = [0usize; 3];
        for _ in 0..60 {
            for k in 0..3 {
                let (e, s) = ((10 * k + episode[k]) as f32, steps[k] as f32);
                buf.push(&[e, s], &[s], s, &[e, s + 1.0], false);
                steps[k] += 1;
                if steps[k] == 6 + k {
                    (steps[k], episode[k]) = (0, episode[k] + 1);
                }
            }
        }
        let mut out = sequences(b, h);
        assert!(buf.sample(h, &mut stream(2, "test.replay", 0), &mut out));
        let mut seen = std::collections::BTreeSet::new();
        for j in 0..b {
            let (e, s) = (out.obs[j * 2], out.obs[j * 2 + 1]);
            let k = (e / 10.0).floor() as usize;
            assert!(
                s as usize + h <= 6 + k,
                "actor {k}: starts at {s}, past its episode"
            );
            for t in 0..=h {
                let at = t * b + j;
                assert_eq!(out.obs[at * 2..at * 2 + 2], [e, s + t as f32]);
            }
            seen.insert(k);
        }
        assert_eq!(seen.len(), 3, "every actor's episodes are drawn");
        // 60 rows each: actor 0 has 10 episodes of 6, actor 1 9 of 7 (the last cut), actor 2
        // 8 of 8 (the last cut); the ring holds the newest 180 rows, all of them.
        assert_eq!(buf.episodes(), 10 + 9 + 8);
        // Regrown, the links move with the rows.
        let mut again = sequences(b, h);
        let grown = buf.resized(300);
        assert!(grown.sample(h, &mut stream(2, "test.replay", 0), &mut again));
        assert_eq!(out.obs, again.obs);
    }

    /// A checkpoint written before the links (one actor): `continued` says which rows the next
    /// one continues, and the newest row is open.
    #[test]
    fn a_buffer_without_links_joins_consecutive_rows() {
        let buf = filled(50, 7, 10);
        let mut old = buf.clone();
        old.links = EpisodeLinks::default();
        let restored = old.with_links(None).unwrap();
        assert_eq!(restored.links(), buf.links());
        let mut short = buf.clone();
        short.links.next.pop();
        let err = buf.clone().with_links(Some(short.links)).unwrap_err();
        assert!(err.contains("50 rows"), "{err}");
    }

    #[test]
    fn episodes_shorter_than_the_horizon_give_no_subsequence() {
        let buf = filled(100, 10, 2);
        let mut out = sequences(4, 3);
        assert!(!buf.sample(3, &mut stream(1, "test.replay", 0), &mut out));
        assert!(buf.sample(2, &mut stream(1, "test.replay", 0), &mut sequences(4, 2)));
    }
}
