"""DeepMind Control Suite tasks as Gymnasium environments, for `env = "gym:dmc_env:make"`.

State observations are the task's observation dict flattened in its own key order (float32),
actions are scaled to [-1, 1], and each step repeats the action `action_repeat` times (2, as
TD-MPC2 and DrQ-v2 do) and sums the rewards. An episode is 1000 control steps of the suite, so
500 steps of this env at the default repeat: one env step here is one step of TD-MPC2's
published curves (their x axis counts agent steps, each two control steps). DMC tasks never
terminate; the time limit truncates them (`[gym] max_episode_steps = 500`).

Needs dm_control (its own venv: `bash deploy/setup_dmc.sh`, then run with
`MBPO_PYTHON=.venv-dmc/bin/python`).
"""

import gymnasium as gym
import numpy as np
from dm_control import suite
from dm_control.suite.wrappers import action_scale

# TD-MPC2's short names for two domains.
DOMAINS = {"cup": "ball_in_cup", "pointmass": "point_mass"}


class DmcEnv(gym.Env):
    """One suite task; `task` as TD-MPC2 names them, e.g. "walker-walk", "cartpole-swingup"."""

    metadata = {"render_modes": []}

    def __init__(self, task="walker-walk", action_repeat=2):
        domain, name = task.replace("-", "_").split("_", 1)
        domain = DOMAINS.get(domain, domain)
        if (domain, name) not in suite.ALL_TASKS:
            known = ", ".join(f"{d}-{t}" for d, t in suite.ALL_TASKS)
            raise ValueError(f"unknown DeepMind Control task {task!r}; known: {known}")
        self._env = action_scale.Wrapper(
            suite.load(domain, name, visualize_reward=False), minimum=-1.0, maximum=1.0
        )
        self._repeat = int(action_repeat)
        width = sum(int(np.prod(v.shape)) for v in self._env.observation_spec().values())
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (width,), np.float32)
        spec = self._env.action_spec()
        self.action_space = gym.spaces.Box(-1.0, 1.0, spec.shape, np.float32)

    @staticmethod
    def _flat(observation):
        return np.concatenate(
            [np.asarray(v, dtype=np.float32).ravel() for v in observation.values()]
        )

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            # The suite draws start states from the task's own RandomState (32-bit seeds).
            self._env.task.random.seed(seed % 2**32)
        return self._flat(self._env.reset().observation), {}

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        reward = 0.0
        for _ in range(self._repeat):
            time_step = self._env.step(action)
            reward += time_step.reward or 0.0
            if time_step.last():
                break
        # The suite's own limit (1000 control steps) truncates; `max_episode_steps` says it first.
        return self._flat(time_step.observation), reward, False, time_step.last(), {}


def make(task="walker-walk", action_repeat=2):
    """The entry point `gym:dmc_env:make` (keyword arguments from `[gym.kwargs]`)."""
    return DmcEnv(task=task, action_repeat=action_repeat)
