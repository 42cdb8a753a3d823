//! An environment whose steps take at least a set wall time ([`SlowEnv`]): a stand-in for a
//! robot or a simulator that runs in real time, so what a pipeline gains over a sequential loop
//! shows without hardware (`[actor] env_step_ms`).

use std::time::{Duration, Instant};

use mbpo_core::Rng;

use crate::{BoxSpace, Env, EnvError, ObsPart, RestorableEnv, Step};

/// `inner`, each of whose steps takes at least `step_time` of wall time. Only the timing
/// changes: observations, rewards, episode ends and random draws are `inner`'s, so a built-in
/// environment stays deterministic under it.
pub struct SlowEnv {
    inner: Box<dyn Env>,
    step_time: Duration,
}

impl SlowEnv {
    /// Wrap `inner` so that a step lasts at least `step_time`.
    pub fn new(inner: Box<dyn Env>, step_time: Duration) -> Self {
        Self { inner, step_time }
    }
}

impl Env for SlowEnv {
    fn id(&self) -> &'static str {
        self.inner.id()
    }
    fn observation_space(&self) -> &BoxSpace {
        self.inner.observation_space()
    }
    fn action_space(&self) -> &BoxSpace {
        self.inner.action_space()
    }
    fn max_episode_steps(&self) -> usize {
        self.inner.max_episode_steps()
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        self.inner.reset(rng, obs)
    }
    fn elapsed_steps(&self) -> usize {
        self.inner.elapsed_steps()
    }
    /// The wrapped step, then a sleep for what is left of `step_time`.
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        let started = Instant::now();
        let step = self.inner.step(action, obs)?;
        if let Some(rest) = self.step_time.checked_sub(started.elapsed()) {
            std::thread::sleep(rest);
        }
        Ok(step)
    }
    fn observation_f64(&self) -> Option<&[f64]> {
        self.inner.observation_f64()
    }
    fn observation_parts(&self) -> &[ObsPart] {
        self.inner.observation_parts()
    }
    fn restorable(&self) -> Option<&dyn RestorableEnv> {
        self.inner.restorable()
    }
    fn restorable_mut(&mut self) -> Option<&mut dyn RestorableEnv> {
        self.inner.restorable_mut()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::stream;

    /// The same observations and rewards as the bare environment, each step no faster than
    /// its set time (a lower bound: a busy machine only makes it slower).
    #[test]
    fn a_slow_env_is_the_same_env_no_faster_than_its_step_time() {
        let step_time = Duration::from_millis(2);
        let mut slow = SlowEnv::new(crate::make("Pendulum-v1").unwrap(), step_time);
        let mut bare = crate::make("Pendulum-v1").unwrap();
        let (mut rng_a, mut rng_b) = (stream(3, "env", 0), stream(3, "env", 0));
        let (mut a, mut b) = ([0.0f32; 3], [0.0f32; 3]);
        slow.reset(&mut rng_a, &mut a).unwrap();
        bare.reset(&mut rng_b, &mut b).unwrap();
        assert_eq!(a, b);
        let started = Instant::now();
        for i in 0..20 {
            let action = [((i % 5) as f32 - 2.0) * 0.7];
            let (sa, sb) = (
                slow.step(&action, &mut a).unwrap(),
                bare.step(&action, &mut b).unwrap(),
            );
            assert_eq!(
                (a, sa.reward.to_bits()),
                (b, sb.reward.to_bits()),
                "step {i}"
            );
        }
        assert!(
            started.elapsed() >= 20 * step_time,
            "{:?}",
            started.elapsed()
        );
        assert_eq!((slow.id(), slow.elapsed_steps()), ("Pendulum-v1", 20));
        assert!(
            slow.restorable().is_some(),
            "the capability of the wrapped env"
        );
    }
}
