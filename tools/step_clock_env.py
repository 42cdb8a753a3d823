"""A Gymnasium env that records, by its own clock, when each of its steps starts.

For the real-time figures measured on the env's side rather than the actor's: a paced actor
(`actor.control_hz`) says when it meant to step; this says when the env was stepped. Use it as
an entry point of `env = "gym:..."`:

    mbpo run --config deploy/configs/pendulum.toml --control-hz 50 \
        --set 'env="gym:step_clock_env:make"' --set 'gym.path=["<repo>/tools"]' \
        --set 'gym.kwargs={env_id="Pendulum-v1", out="<dir>"}'

Each process's env appends one JSON line per episode to `<out>/steps-<pid>.jsonl`:
`{"process": <its parent's command line>, "steps": [time.monotonic_ns() at each step]}`,
written at the next reset or at close (between episodes, off the paced path). The parent is
the role that steps the env (`mbpo-actor`, with `--eval` for the evaluator).
`tools/step_clock.py <out> --hz 50` reads them.
"""

import json
import os
import time

import gymnasium as gym


def _parent_command_line():
    try:
        with open(f"/proc/{os.getppid()}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return ""


class StepClock(gym.Wrapper):
    """`env` with the start of each step recorded (see the module's docs)."""

    def __init__(self, env, out):
        super().__init__(env)
        os.makedirs(out, exist_ok=True)
        self._path = os.path.join(out, f"steps-{os.getpid()}.jsonl")
        self._process = _parent_command_line()
        self._times = []

    def reset(self, **kwargs):
        self._flush()
        return self.env.reset(**kwargs)

    def step(self, action):
        self._times.append(time.monotonic_ns())
        return self.env.step(action)

    def close(self):
        self._flush()
        return super().close()

    def _flush(self):
        if not self._times:
            return
        line = json.dumps({"process": self._process, "steps": self._times})
        with open(self._path, "a") as f:
            f.write(line + "\n")
        self._times = []


def make(env_id="Pendulum-v1", out="step-clock", **kwargs):
    """Gymnasium's `env_id` (with `kwargs`) that records its step times into `out`."""
    return StepClock(gym.make(env_id, **kwargs), out)
