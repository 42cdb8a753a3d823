"""Python Gymnasium environments of the test suite (not registered with Gymnasium): the tests
reach them as `gym:mbpo_test_envs:<Name>` with this folder in `gym.path`."""

import os
import time

import gymnasium as gym
import numpy as np


class PendulumAt(gym.Wrapper):
    """Gymnasium's Pendulum-v1 whose every episode starts at the given (theta, thetadot), so
    its transitions can be compared with the built-in Pendulum started at the same state."""

    def __init__(self, theta, thetadot):
        super().__init__(gym.make("Pendulum-v1"))
        self.start = np.array([theta, thetadot], dtype=np.float64)

    def reset(self, *, seed=None, options=None):
        self.env.reset(seed=seed, options=options)
        self.env.unwrapped.state = self.start.copy()
        return self.env.unwrapped._get_obs(), {}


class Drift(gym.Env):
    """A point on a line pushed by the action; reward -x^2. No time limit of its own (the
    config sets one). `raise_at` raises in step at that step of the process's life;
    `exit_at` ends the interpreter there (os._exit), as a crash would; `hang_at` sleeps there
    for two minutes, as a stuck simulator would; `terminate_beyond`
    ends an episode (terminated) once |x| exceeds it."""

    def __init__(self, raise_at=-1, exit_at=-1, exit_marker="", terminate_beyond=None,
                 hang_at=-1):
        self.observation_space = gym.spaces.Box(-5.0, 5.0, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-2.0, 2.0, shape=(1,), dtype=np.float32)
        self.raise_at, self.exit_at, self.exit_marker = raise_at, exit_at, exit_marker
        self.terminate_beyond = terminate_beyond
        self.hang_at = hang_at
        self.steps = 0
        self.x = 0.0
        self.v = 0.0

    def _obs(self):
        return np.array([self.x, self.v], dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1.0, 1.0))
        self.v = 0.0
        return self._obs(), {}

    def step(self, action):
        self.steps += 1
        if self.steps == self.hang_at:
            marker = os.environ.get("MBPO_TEST_HANG_MARKER")
            if marker:
                open(marker, "w").close()  # tells the test the env is stuck now
            time.sleep(120)
        if self.steps == self.raise_at:
            raise RuntimeError(f"Drift: failing on purpose at step {self.steps}")
        if self.steps == self.exit_at and not os.path.exists(self.exit_marker):
            open(self.exit_marker, "w").close()  # exit once per test, not in every new process
            os._exit(3)
        a = float(np.clip(action[0], -2.0, 2.0))
        self.v = float(np.clip(0.9 * self.v + 0.05 * a, -1.0, 1.0))
        self.x = float(np.clip(self.x + self.v, -5.0, 5.0))
        beyond = self.terminate_beyond is not None and abs(self.x) > self.terminate_beyond
        return self._obs(), -self.x * self.x - 0.01 * a * a, beyond, False, {}


class DictObs(gym.Env):
    """A Dict observation (flattened by the bridge in key order)."""

    def __init__(self):
        self.observation_space = gym.spaces.Dict(
            {
                "b": gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float64),
                "a": gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32),
            }
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return {"a": np.array([0.5], np.float32), "b": np.array([0.25, -0.25])}, {}

    def step(self, action):
        return {"a": np.array([float(action[0])], np.float32), "b": np.array([1.0, -1.0])}, 0.0, False, False, {}


class DiscreteActions(gym.Env):
    observation_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
    action_space = gym.spaces.Discrete(3)


class UnboundedActions(gym.Env):
    observation_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
    action_space = gym.spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float32)


class ImageObs(gym.Env):
    observation_space = gym.spaces.Box(0, 255, shape=(4, 4), dtype=np.uint8)
    action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)


def drift_for_orphan_check():
    """A Drift that hangs in its 10th step (it never reads its closed pipe then), under a name
    no other test uses (the orphan test looks for processes whose command line holds it)."""
    return gym.wrappers.TimeLimit(Drift(hang_at=10), max_episode_steps=50)


def beyond_1_2(obs, act, next_obs):
    """Drift(terminate_beyond=1.2)'s rule, batched: `termination = "python:mbpo_test_envs:beyond_1_2"`."""
    return np.abs(next_obs[:, 0]) > 1.2


def broken_rule(obs, act, next_obs):
    raise ValueError("rule broken on purpose")


def wrong_length(obs, act, next_obs):
    return [True]
