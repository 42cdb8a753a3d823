"""mbpo's Gymnasium host: one Python environment in this process, driven by one mbpo actor.

The actor (Rust, mbpo_envs::python) starts `python -c <this file> <spec json>` and talks to it
over the child's stdin and stdout, which this script takes over as the protocol pipes: whatever
the environment prints goes to stderr, the actor's log, and never into the protocol.

Every frame has a fixed size, so one read and one write carry a step (little-endian):

  hello     u8 status (0 ok, 1 error) | 7 pad | u64 n | n bytes of JSON (the env's description,
            or {"kind", "message"} of the error)
  request   u8 op (b'r' reset, b's' step, b'q' quit) | u8 has_seed | 6 pad | u64 seed
            | f64[act_dim] action
  response  u8 status (0 ok, 1 exception) | u8 terminated | u8 truncated | 5 pad | f64 reward
            | u64 n | f64[obs_dim] observation | on status 1: n bytes of UTF-8 traceback

With {"termination": "module:function"} in the spec it hosts a termination rule instead:
`function(obs, act, next_obs)` on float32 arrays of n rows returns n booleans.

  request   u64 n (0: quit) | f32[n, obs] obs | f32[n, act] act | f32[n, obs] next_obs
  response  u8 status (0 ok, 1 exception) | 7 pad | u64 m | m bytes: n flags (0/1) or a traceback
"""

import json
import os
import struct
import sys
import traceback

REQUEST_HEAD = 16
RESPONSE_HEAD = 24


class SpecError(Exception):
    """The environment cannot be driven by mbpo; the message names why and the fix."""


def main():
    proto_in = os.fdopen(os.dup(0), "rb", buffering=0)
    proto_out = os.fdopen(os.dup(1), "wb", buffering=0)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.dup2(2, 1)
    spec = json.loads(sys.argv[1])
    if "termination" in spec:
        return serve_termination(spec, proto_in, proto_out)
    try:
        env, describe, flatten = make(spec)
    except SpecError as e:
        return hello(proto_out, 1, {"kind": "spec", "message": str(e)})
    except BaseException as e:  # an import error, a constructor raising, ...
        kind = "import" if isinstance(e, ImportError) else "make"
        return hello(proto_out, 1, {"kind": kind, "message": traceback.format_exc()})
    hello(proto_out, 0, describe)
    serve(env, flatten, len(describe["act_low"]), len(describe["obs_low"]), proto_in, proto_out)


def serve_termination(spec, proto_in, proto_out):
    import numpy as np

    target = spec["termination"]
    try:
        module, _, name = target.partition(":")
        import importlib

        rule = getattr(importlib.import_module(module), name, None)
        if not callable(rule):
            raise SpecError(f"module {module} has no function {name}")
    except SpecError as e:
        return hello(proto_out, 1, {"kind": "spec", "message": str(e)})
    except BaseException as e:
        kind = "import" if isinstance(e, ImportError) else "make"
        return hello(proto_out, 1, {"kind": kind, "message": traceback.format_exc()})
    obs_dim, act_dim = spec["obs_dim"], spec["act_dim"]
    hello(proto_out, 0, {"termination": target})
    while True:
        head = read_exactly(proto_in, 8)
        if head is None:
            return
        (n,) = struct.unpack("<Q", head)
        if n == 0:
            return
        body = read_exactly(proto_in, 4 * n * (2 * obs_dim + act_dim))
        if body is None:
            return
        flat = np.frombuffer(body, dtype="<f4")
        obs = flat[: n * obs_dim].reshape(n, obs_dim)
        act = flat[n * obs_dim : n * (obs_dim + act_dim)].reshape(n, act_dim)
        next_obs = flat[n * (obs_dim + act_dim) :].reshape(n, obs_dim)
        try:
            done = np.asarray(rule(obs, act, next_obs), dtype=bool).reshape(-1)
            if done.shape != (n,):
                raise ValueError(f"{target} returned {done.size} flags for {n} transitions")
            out = done.astype(np.uint8).tobytes()
            proto_out.write(struct.pack("<B7xQ", 0, len(out)) + out)
        except BaseException:
            message = traceback.format_exc().encode()
            proto_out.write(struct.pack("<B7xQ", 1, len(message)) + message)


def read_exactly(stream, size):
    """`size` bytes, or None once the actor is gone."""
    buf = bytearray(size)
    view, got = memoryview(buf), 0
    while got < size:
        n = stream.readinto(view[got:])
        if not n:
            return None
        got += n
    return buf


def hello(out, status, payload):
    body = json.dumps(payload).encode()
    out.write(struct.pack("<B7xQ", status, len(body)) + body)


def finite_or_none(values):
    """JSON has no infinity: an unbounded side is sent as null."""
    return [float(v) if abs(float(v)) != float("inf") else None for v in values]


def make(spec):
    import gymnasium as gym
    import numpy as np

    target, kwargs = spec["env"], spec.get("kwargs") or {}
    steps = spec.get("max_episode_steps")
    entry = entry_point(target)
    if entry is not None:
        env = entry(**kwargs)
        if not isinstance(env, gym.Env):
            raise SpecError(
                f"it made a {type(env).__name__}, not a gymnasium.Env: "
                "point gym: at a gymnasium.Env class or a function returning one"
            )
        if steps is not None:
            env = gym.wrappers.TimeLimit(env, max_episode_steps=steps)
    else:
        extra = {} if steps is None else {"max_episode_steps": steps}
        try:
            env = gym.make(target, **kwargs, **extra)
        except (gym.error.NameNotFound, gym.error.VersionNotFound, gym.error.DeprecatedEnv) as e:
            if ":" not in target:
                raise SpecError(
                    f"Gymnasium has no environment {target}: {e} (the ids it has: "
                    "python -c 'import gymnasium; gymnasium.pprint_registry()'; "
                    "an env of your own: gym:module:Class)"
                ) from None
            module, _, name = target.partition(":")
            raise SpecError(
                f"module {module} has no class or function {name}, and Gymnasium has no env "
                f"registered under that name ({e})"
            ) from None
    limit = steps if steps is not None else getattr(env.spec, "max_episode_steps", None)
    wrapper = env
    while limit is None and isinstance(wrapper, gym.Wrapper):
        # An entry point may return its env inside a TimeLimit of its own.
        if isinstance(wrapper, gym.wrappers.TimeLimit):
            limit = wrapper._max_episode_steps
        wrapper = wrapper.env
    if limit is None:
        raise SpecError(
            "it has no time limit: set `max_episode_steps` in the config's [gym] table"
        )

    act = env.action_space
    if not isinstance(act, gym.spaces.Box):
        raise SpecError(
            f"the action space is {act}, not a Box: MBPO's policy outputs continuous "
            "actions, so the env needs a Box action space (wrap a discrete env in a continuous one)"
        )
    if not np.issubdtype(act.dtype, np.floating):
        raise SpecError(f"the action Box has dtype {act.dtype}; it must be a float type")
    if not (np.all(np.isfinite(act.low)) and np.all(np.isfinite(act.high))):
        raise SpecError(
            f"the action space {act} is unbounded: the policy's actions in [-1, 1] are "
            "rescaled to the bounds, so give finite bounds (e.g. gymnasium.wrappers.ClipAction "
            "over a bounded Box)"
        )

    obs_space = env.observation_space
    layout = []
    if isinstance(obs_space, gym.spaces.Dict):
        for key, sub in obs_space.spaces.items():
            check_float_box(f"observation['{key}']", sub, gym, np)
            layout.append({"key": key, "shape": list(sub.shape)})
        flat_space = gym.spaces.flatten_space(obs_space)

        def flatten(obs):
            return gym.spaces.flatten(obs_space, obs)
    else:
        check_float_box("observation", obs_space, gym, np)
        flat_space = obs_space

        def flatten(obs):
            return np.asarray(obs).reshape(-1)

    describe = {
        "id": target,
        "max_episode_steps": int(limit),
        "obs_low": finite_or_none(np.asarray(flat_space.low, dtype=np.float64).reshape(-1)),
        "obs_high": finite_or_none(np.asarray(flat_space.high, dtype=np.float64).reshape(-1)),
        "act_low": [float(v) for v in np.asarray(act.low, dtype=np.float64).reshape(-1)],
        "act_high": [float(v) for v in np.asarray(act.high, dtype=np.float64).reshape(-1)],
        "act_shape": list(act.shape),
        "obs_layout": layout,
    }
    return env, describe, flatten


def check_float_box(what, space, gym, np):
    if not isinstance(space, gym.spaces.Box):
        raise SpecError(
            f"the {what} space is {space}, not a Box: the dynamics model predicts "
            "real vectors, so observations must be float Boxes (or a Dict of them)"
        )
    if not np.issubdtype(space.dtype, np.floating):
        raise SpecError(
            f"the {what} space {space} has dtype {space.dtype}; the dynamics model "
            "predicts real vectors, so it must be a float type (convert it with a "
            "gymnasium.ObservationWrapper)"
        )


def entry_point(target):
    """`module.path:Name` where the module has an attribute Name: a constructor; else None
    (a registered id, possibly in Gymnasium's own `module:EnvId` form)."""
    if ":" not in target:
        return None
    module, _, name = target.partition(":")
    import importlib

    found = getattr(importlib.import_module(module), name, None)
    return found if callable(found) else None


def serve(env, flatten, act_dim, obs_dim, proto_in, proto_out):
    import numpy as np

    request = bytearray(REQUEST_HEAD + 8 * act_dim)
    request_view = memoryview(request)
    action = np.frombuffer(request, dtype="<f8", offset=REQUEST_HEAD, count=act_dim)
    act_dtype = env.action_space.dtype
    act_shape = env.action_space.shape
    response = bytearray(RESPONSE_HEAD + 8 * obs_dim)
    obs_out = np.frombuffer(response, dtype="<f8", offset=RESPONSE_HEAD, count=obs_dim)
    while True:
        got = 0
        while got < len(request):
            n = proto_in.readinto(request_view[got:])
            if not n:
                return  # the actor is gone
            got += n
        op, has_seed, seed = struct.unpack_from("<BB6xQ", request)
        if op == ord("q"):
            return
        try:
            if op == ord("r"):
                obs, _ = env.reset(seed=seed if has_seed else None)
                reward, terminated, truncated = 0.0, False, False
            else:
                a = action.astype(act_dtype).reshape(act_shape)
                obs, reward, terminated, truncated, _ = env.step(a)
            obs_out[:] = flatten(obs)
        except BaseException:
            message = traceback.format_exc().encode()
            struct.pack_into("<B2B5xdQ", response, 0, 1, 0, 0, 0.0, len(message))
            proto_out.write(bytes(response) + message)
            continue
        struct.pack_into(
            "<B2B5xdQ", response, 0, 0, bool(terminated), bool(truncated), float(reward), 0
        )
        proto_out.write(response)


if __name__ == "__main__":
    main()
