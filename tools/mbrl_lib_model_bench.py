"""Time mbrl-lib's dynamics model (PyPI `mbrl` 0.2.0 on PyTorch, CPU) on the two hot paths that
`mbpo bench model-train` and `mbpo bench model-rollout` time in ours, on the same shapes, so the
two can run side by side on one machine (tools/compare_model_bench.sh).

    .venv-torch/bin/python tools/mbrl_lib_model_bench.py --threads 1
    -> {"framework": "mbrl-lib", "threads": 1, "train_call_seconds": ..., "epoch_seconds": ...,
        "rollout_seconds": ..., ...}

The model is MBPO's as mbrl-lib builds it for its MBPO (`mbrl.models.GaussianMLP`: 7 members,
4 hidden layers of 200, SiLU, learned log-variance bounds; wrapped in
`OneDTransitionRewardModel`: normalised inputs, Δobs and reward targets), at HalfCheetah's
dimensions (obs 17, act 6), with MBPO's per-layer weight decay in Adam (lr 1e-3), as
tools/mbrl_lib_mbpo.py sets it up. The data are 10 000 synthetic transitions made by the same
rule as ours (`mbpo_model::bench::synthetic_transitions`: Gaussian observations, uniform actions,
a smooth next state); speed does not depend on what is learnt.

What is timed (the best of --repetitions, after one warm-up call):
- `train_call_seconds`: what mbrl-lib's MBPO does per model training
  (`mbrl.util.common.train_model_and_save_model_and_data` without the saving): the 80/20 split
  and bootstrap iterators, the normaliser fit, then `ModelTrainer.train(num_epochs=1)`, which
  evaluates the holdout once before the epoch and once after it.
- `epoch_seconds`: `train_call_seconds` minus one holdout evaluation (timed alone), i.e. what
  one more epoch of a longer training costs: every minibatch of every member (each member its
  own bootstrap batch of 256) and one holdout evaluation. This is what ours reports as one epoch
  (its holdout pass runs once per epoch).
- `rollout_seconds`: 100 000 one-step rollouts as mbrl's `rollout_model_and_populate_sac_buffer`
  makes them (`ModelEnv.reset` + `ModelEnv.step(sample=True)` with random-model propagation,
  then `add_batch` into a replay buffer), with uniform random actions instead of the SAC agent,
  as ours does.

Threads: torch.set_num_threads(--threads), and OMP/MKL/OpenBLAS variables set to the same.
OMP_WAIT_POLICY is taken from the environment (PASSIVE when unset: libgomp's spinning threads
cost PyTorch 10x when another process holds a core, see tools/mbrl_lib_mbpo.py).
"""

import argparse
import json
import os
import statistics
import time

OBS_DIM, ACT_DIM = 17, 6
WEIGHT_DECAY = [2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4]


def synthetic_transitions(np, n, seed):
    """The rule of ours, in numpy (not the same random numbers; speed does not depend on them)."""
    rng = np.random.default_rng(seed)
    obs = rng.standard_normal((n, OBS_DIM)).astype(np.float32)
    act = rng.uniform(-1.0, 1.0, (n, ACT_DIM)).astype(np.float32)
    j = np.arange(OBS_DIM)
    next_obs = obs + 0.1 * np.sin(obs[:, (j + 1) % OBS_DIM] + act[:, j % ACT_DIM])
    reward = (-0.1 * act * act).sum(axis=1) + obs[:, 0]
    return obs, act, next_obs.astype(np.float32), reward.astype(np.float32)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repetitions", type=int, default=5)
    p.add_argument("--transitions", type=int, default=10_000)
    p.add_argument("--rollouts", type=int, default=100_000)
    args = p.parse_args()

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(args.threads)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

    import gymnasium as gym
    import numpy as np
    import omegaconf
    import torch

    import mbrl
    import mbrl.env.termination_fns
    import mbrl.models
    import mbrl.util.common
    from mbrl.util.replay_buffer import ReplayBuffer

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    net = mbrl.models.GaussianMLP(
        in_size=OBS_DIM + ACT_DIM,
        out_size=OBS_DIM + 1,
        device="cpu",
        num_layers=4,
        ensemble_size=7,
        hid_size=200,
        deterministic=False,
        propagation_method="random_model",
        learn_logvar_bounds=True,
        activation_fn_cfg=omegaconf.OmegaConf.create({"_target_": "torch.nn.SiLU"}),
    )
    model = mbrl.models.OneDTransitionRewardModel(
        net, target_is_delta=True, normalize=True, normalize_double_precision=True,
        learned_rewards=True, num_elites=5,
    )
    trainer = mbrl.models.ModelTrainer(model, optim_lr=1e-3, weight_decay=0.0)
    # MBPO's per-layer weight decay on the weights (as tools/mbrl_lib_mbpo.py).
    layers = [seq[0] for seq in net.hidden_layers] + [net.mean_and_logvar]
    decayed = {id(l.weight) for l in layers}
    groups = [{"params": [l.weight], "weight_decay": w} for l, w in zip(layers, WEIGHT_DECAY)]
    groups.append({"params": [q for q in model.parameters() if id(q) not in decayed],
                   "weight_decay": 0.0})
    trainer.optimizer = torch.optim.Adam(groups, lr=1e-3)

    rng = np.random.default_rng(0)
    data = ReplayBuffer(args.transitions, (OBS_DIM,), (ACT_DIM,), rng=rng)
    obs, act, next_obs, reward = synthetic_transitions(np, args.transitions, 0)
    false = np.zeros(args.transitions, dtype=bool)
    data.add_batch(obs, act, next_obs, reward, false, false)

    def train_call():
        t = time.perf_counter()
        train_it, val_it = mbrl.util.common.get_basic_buffer_iterators(
            data, 256, 0.2, ensemble_size=7, shuffle_each_epoch=True, bootstrap_permutes=False)
        model.update_normalizer(data.get_all())
        trainer.train(train_it, dataset_val=val_it, num_epochs=1, patience=5,
                      improvement_threshold=0.01, silent=True)
        return time.perf_counter() - t, val_it

    def holdout_eval(val_it):
        t = time.perf_counter()
        trainer.evaluate(val_it)
        return time.perf_counter() - t

    class Spaces(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32)

    model_env = mbrl.models.ModelEnv(Spaces(), model, mbrl.env.termination_fns.no_termination,
                                     generator=torch.Generator().manual_seed(0))
    pool = ReplayBuffer(args.rollouts, (OBS_DIM,), (ACT_DIM,), rng=np.random.default_rng(1))
    start_obs = rng.standard_normal((args.rollouts, OBS_DIM)).astype(np.float32)

    def rollout():
        t = time.perf_counter()
        state = model_env.reset(initial_obs_batch=start_obs, return_as_np=True)
        action = rng.uniform(-1.0, 1.0, (args.rollouts, ACT_DIM)).astype(np.float32)
        nxt, rew, done, _ = model_env.step(action, state, sample=True)
        trunc = np.zeros_like(done, dtype=bool)
        pool.add_batch(start_obs, action, nxt, rew[:, 0], done[:, 0], trunc[:, 0])
        return time.perf_counter() - t

    train_call()  # warm-up
    rollout()
    calls, evals, rollouts = [], [], []
    for _ in range(max(1, args.repetitions)):
        seconds, val_it = train_call()
        calls.append(seconds)
        evals.append(holdout_eval(val_it))
        rollouts.append(rollout())
    epochs = [c - e for c, e in zip(calls, evals)]
    print(json.dumps({
        "framework": "mbrl-lib",
        "mbrl": mbrl.__version__,
        "torch": torch.__version__,
        "threads": args.threads,
        "omp_wait_policy": os.environ["OMP_WAIT_POLICY"],
        "transitions": args.transitions,
        "rollouts": args.rollouts,
        "train_call_seconds": min(calls),
        "epoch_seconds": min(epochs),
        "holdout_eval_seconds": statistics.median(evals),
        "rollout_seconds": min(rollouts),
        "train_call_seconds_all": [round(x, 4) for x in calls],
        "rollout_seconds_all": [round(x, 4) for x in rollouts],
    }))


if __name__ == "__main__":
    main()
