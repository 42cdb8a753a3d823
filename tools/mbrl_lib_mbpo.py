"""Time mbrl-lib's MBPO (PyPI `mbrl`, facebookresearch/mbrl-lib) on this machine, as a
same-machine speed baseline for our MBPO: on Pendulum-v1 (deploy/configs/pendulum.toml) or, at
MuJoCo scale, on Hopper-v5 (deploy/configs/hopper.toml).

    .venv-torch/bin/python -m pip install --no-deps -r tools/requirements-mbrl.txt
    .venv-torch/bin/python tools/mbrl_lib_mbpo.py --task pendulum --steps 1400 --threads 1 --seed 0
    -> {"framework": "mbrl-lib", "mbrl": "0.2.0", "torch": "...", "threads": 1,
        "median_seconds_per_env_step": ..., "mean_seconds_per_env_step": ..., "env_steps": 1400,
        "warmup": 400, ...}
    # Hopper-v5 also needs MuJoCo's Python package: pip install --no-deps -r tools/requirements-mujoco.txt
    .venv-torch/bin/python tools/mbrl_lib_mbpo.py --task hopper --steps 8000 --threads 2 --seed 0

The run is `mbrl.algorithms.mbpo.train(env, test_env, no_termination, cfg)` unchanged, on the CPU,
with a config built in code with OmegaConf (the Hydra defaults of mbrl/examples/conf are not
used). Nothing in mbrl is edited; the script only wraps a few callables for timing (see
"Measurement") and replaces the model optimizer by one with per-layer weight decay (see below).

Measurement
-----------
A gymnasium wrapper around the training env records a timestamp at every `env.step` call (the
warm-up steps included), so the time between two consecutive calls is everything the loop did
for one real step: the env step, model training + model rollouts when due, and the G SAC updates.
mbrl-lib trains the model right after the env step that completes a multiple of
`freq_train_model` loop steps, in the same iteration; our trainer does it at the start of the
step after (step 401, 651, ...). So mbrl-lib's step s is matched with our step s + 1: the
measured steps are the N - W steps from mbrl-lib's step W (whose iteration holds the first model
training) to N - 1, the same number of steps and model trainings as ours measures (W + 1 .. N).
Evaluation (mbrl's `evaluate`, wrapped) is subtracted, as ours does not time its evaluations.
mbrl's own saving of the model and replay buffer after every model training (into a temporary
directory) is library behaviour and stays in the figure. The per-step times are grouped into
consecutive windows of --window steps; the reported median is the median of the windows' mean
seconds per step, the mean is total measured time / measured steps (model training amortised
in both). `median_single_step_seconds` is the median of the individual per-step times, the
statistic our trainer prints as median_seconds_per_env_step (it leaves model trainings out).

Config mapping (deploy/configs/pendulum.toml -> mbrl-lib cfg)
---------------------------------------------------------------
env = "Pendulum-v1"             gymnasium.make("Pendulum-v1") (TimeLimit 200) for env and test_env;
                                termination_fn = mbrl.env.termination_fns.no_termination
seed = 0                        cfg.seed = --seed (env, action space, numpy, torch seeded with it)
steps                           --steps (total real env steps, warm-up included);
                                cfg.overrides.num_steps = steps - initial_exploration_steps,
                                which must be a multiple of 250 (mbrl runs whole epochs)
eval.every = 250                mbrl evaluates once per epoch (epoch_length = 250): same
eval.episodes = 5               cfg.algorithm.num_eval_episodes = 5 (timed separately, excluded)
mbpo.init_random_steps = 400    see "Warm-up" below (model first trained on 400 real steps)
mbpo.epoch_length = 250         cfg.overrides.epoch_length = 250
mbpo.model_train_freq = 250     cfg.overrides.freq_train_model = 250
mbpo.rollouts_per_step = 400    cfg.overrides.effective_model_rollouts_per_step = 400
                                (mbrl branches 400 * 250 = 100k rollouts per model training)
mbpo.rollout_schedule           cfg.overrides.rollout_schedule = [1, 15, 1, 1] (k = 1)
mbpo.retain_epochs = 1          cfg.overrides.num_epochs_to_retain_sac_buffer = 1
                                (model buffer capacity k * 100k * 1 = 100k)
mbpo.real_ratio = 0.05          cfg.algorithm.real_data_ratio = 0.05 (see differences)
mbpo.updates_per_step = 20      cfg.overrides.num_sac_updates_per_step = 20,
                                sac_updates_every_steps = 1
mbpo.replay_capacity = 1e6      cfg.algorithm.dataset_size = 1_000_000 (without it mbrl sizes
                                the real buffer to num_steps, smaller than warm-up + num_steps)
sac.gamma/tau                   sac_gamma = 0.99, sac_tau = 0.005, sac_target_update_interval = 1
sac.actor/critic/alpha_lr 1e-3  sac_lr = 1e-3 (mbrl's SAC has one lr for all three optimizers)
sac.batch_size = 256            sac_batch_size = 256
sac.hidden = [256, 256]         sac_hidden_size = 256 (pranz24 SAC: 2 hidden layers, Gaussian
                                policy, twin Q)
sac.init_alpha = 1.0            sac_alpha = 1.0; log_alpha starts at 0 (alpha = 1) in mbrl's SAC
sac.autotune_alpha = true       sac_automatic_entropy_tuning = true, sac_target_entropy = -1
sac.threads = 1                 --threads: torch.set_num_threads (also OMP/OpenBLAS/MKL env vars);
                                OMP_WAIT_POLICY defaults to PASSIVE (see main())
model.members = 7               dynamics_model.ensemble_size = 7 (mbrl.models.GaussianMLP)
model.elites = 5                overrides.num_elites = 5 (random_model propagation over elites)
model.hidden = [200]*4          num_layers = 4, hid_size = 200, SiLU (swish) activations
model.weight_decay (per layer)  Adam param groups: layer i's weight gets weight_decay[i]
                                (coupled L2 = gradient of wd/2 * |W|^2, as MBPO's l2_loss),
                                biases and logvar bounds 0; mbrl's ModelTrainer only takes one
                                value, so the script subclasses it (mbrl.models.ModelTrainer is
                                replaced by the subclass before train() runs)
model.lr = 1e-3                 overrides.model_lr = 1e-3
model.batch_size = 256          overrides.model_batch_size = 256
model.holdout_ratio = 0.2       overrides.validation_ratio = 0.2
model.max_holdout = 5000        no mbrl equivalent; 0.2 * n < 5000 for n < 25000 real steps,
                                so it does not bind in these runs
model.improvement_threshold     overrides.improvement_threshold = 0.01
model.max_epochs_since_update   overrides.patience = 20 (num_epochs_train_model = None)
model.learn_logvar_bounds       dynamics_model.learn_logvar_bounds = true
(normalization, delta targets)  algorithm.normalize = true (double precision),
                                target_is_delta = true, learned_rewards = true
checkpoint.*                    none (mbrl saves model + buffer after each model training and
                                sac.pth on each new best eval, into a temp dir)
device                          cfg.device = "cpu"

Warm-up
-------
mbrl-lib's loop counts its steps from 0 after `initial_exploration_steps` and first trains the
model after loop step freq_train_model (250), not right after the warm-up. With
initial_exploration_steps = 400 (as in the packaged configs) the first 249 policy steps would run
without a model and with (almost) no SAC updates, and every later model training would see 249
more samples than ours. By default the script therefore uses initial_exploration_steps =
init_random_steps - freq_train_model = 150 uniform-random steps followed by 250 policy steps
without a model (mbrl's real-env policy acts with the mean action; a few SAC updates on real data
happen when rng < real_ratio and the real buffer holds >= 256), so the model is first trained on
400 real steps, after real step 400, and then every 250 steps, as in ours. --literal-warmup uses
initial_exploration_steps = 400 instead (first training after real step 650; measurement then
starts there and "warmup" reports 650).

Differences that could not be matched (they change what is learned, not the amount of work,
except where noted)
- real_ratio: mbrl draws the whole SAC batch from the real buffer with probability 0.05 per
  update (otherwise from the model buffer); ours mixes 5 % real samples into every batch.
- mbrl-lib's real-env steps use the SAC mean action (step_env_and_add_to_buffer is called with no
  agent kwargs, so sample=False); ours samples from the policy. Model rollouts sample actions in
  both.
- mbrl-lib resets the real env at the start of every epoch (every 250 steps), so episodes are
  200 + 50 steps long alternately; ours runs full 200-step episodes.
- Model training: mbrl trains each member on a bootstrap resample of the training split
  (BootstrapIterator, sampling with replacement) and evaluates the holdout every epoch; ours is
  MBPO's scheme. Number of epochs is set by a patience rule in both (epochs without > 1 %
  relative improvement of any member), so the amount of work is data-dependent in both; mbrl's
  stops one epoch sooner (`>= patience` where MBPO's is `> max_epochs_since_update`) and, when
  any member improves, lowers every member's best score to min(best, score), not only the
  improved members', so it tends to stop earlier (Hopper, 12 trainings: 665 epochs against 921).
- Eval episodes use mbrl's test_env and the deterministic (mean) policy, excluded from timing.

Hopper-v5 (--task hopper, deploy/configs/hopper.toml): as above, except
env = "Hopper-v5"               gymnasium.make("Hopper-v5") on MuJoCo 3.17.0 (the library ours
                                links, tools/requirements-mujoco.txt); termination_fn =
                                mbrl.env.termination_fns.hopper (MBPO's rule, abs() bug fixed)
mbpo.init_random_steps = 5000   initial_exploration_steps = 4750 (see Warm-up): first model
                                training after real step 5000, ours at the start of step 5001
mbpo.epoch_length = 1000        mbrl's epoch_length stays 250 (= freq_train_model), so that a
                                run is 4750 + a multiple of 250 steps; the rollout schedule's
                                epochs are scaled by 4 to match: [80, 600, 1, 15] mbrl epochs is
                                ours [20, 150, 1, 15] (k = 1 to real step 20k in both). mbrl
                                therefore resets the real env every 250 steps (Hopper's episodes
                                are shorter than that early on) and evaluates every 250 steps
                                (excluded from timing)
sac.*_lr = 3e-4                 sac_lr = 3e-4; sac_target_entropy = -1; action space Box(-1, 1, (3,))
model.max_epochs_since_update   overrides.patience = 5
eval.episodes = 1               cfg.algorithm.num_eval_episodes = 1
model.max_holdout = 5000        binds only above 25,000 real steps; runs here are shorter
"""

import argparse
import contextlib
import json
import os
import statistics
import sys
import tempfile
import time

# Per task: what differs between deploy/configs/pendulum.toml and deploy/configs/hopper.toml
# (the docstring maps each value). mbrl's epoch is always 250 steps (`freq`), so rollout
# schedules are given in mbrl epochs.
TASKS = {
    "pendulum": {
        "env": "Pendulum-v1",
        "init_random_steps": 400,
        "termination_fn": "no_termination",
        "action_box": (-2.0, 2.0, 1),
        "rollout_schedule": [1, 15, 1, 1],
        "patience": 20,
        "sac_lr": 1e-3,
        "target_entropy": -1,
        "eval_episodes": 5,
        "default_steps": 1400,
    },
    "hopper": {
        "env": "Hopper-v5",
        "init_random_steps": 5000,
        "termination_fn": "hopper",
        "action_box": (-1.0, 1.0, 3),
        "rollout_schedule": [80, 600, 1, 15],  # ours: [20, 150, 1, 15] epochs of 1000 steps
        "patience": 5,
        "sac_lr": 3e-4,
        "target_entropy": -1,
        "eval_episodes": 1,
        "default_steps": 8000,
    },
}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", choices=sorted(TASKS), default="pendulum")
    p.add_argument("--steps", type=int, help="total real env steps incl. warm-up "
                   "(default: 1400 for pendulum, 8000 for hopper)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", type=int, default=50, help="env steps per timing window")
    p.add_argument("--literal-warmup", action="store_true",
                   help="initial_exploration_steps = the config's init_random_steps (first model "
                   "training 250 steps later: after step 650 on Pendulum)")
    args = p.parse_args()
    task = TASKS[args.task]
    if args.steps is None:
        args.steps = task["default_steps"]

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(args.threads)
    # torch's libgomp threads spin at barriers by default; with another process on one of the
    # two cores, a 7 x (4 x 200) ensemble update at 2 threads took ~400 ms instead of ~40 ms.
    # PASSIVE (sleep at barriers) avoids that; set OMP_WAIT_POLICY yourself to override.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

    import gymnasium as gym
    import numpy as np
    import omegaconf
    import torch

    import mbrl
    import mbrl.algorithms.mbpo as mbpo
    import mbrl.env.termination_fns
    import mbrl.models
    import mbrl.third_party.pytorch_sac_pranz24 as pranz24
    import mbrl.util.common

    torch.set_num_threads(args.threads)

    # ---- deploy/configs/<task>.toml ----
    init_random_steps = task["init_random_steps"]
    freq = 250
    wd = [2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4]
    initial_exploration = init_random_steps if args.literal_warmup else init_random_steps - freq
    first_train = initial_exploration + freq  # mbrl trains after this real step
    # mbrl's loop runs whole epochs (epoch_length = 250 steps) after the exploration steps.
    if args.steps < first_train + freq or (args.steps - initial_exploration) % 250:
        p.error(f"--steps must be {initial_exploration} + a multiple of 250, >= {first_train + freq}")

    cfg = omegaconf.OmegaConf.create({
        "seed": args.seed,
        "device": "cpu",
        "log_frequency_agent": 1000,
        "save_video": False,
        "debug_mode": False,
        "algorithm": {
            "name": "mbpo",
            "normalize": True,
            "normalize_double_precision": True,
            "target_is_delta": True,
            "learned_rewards": True,
            "freq_train_model": freq,
            "real_data_ratio": 0.05,
            "sac_samples_action": True,
            "initial_exploration_steps": initial_exploration,
            "random_initial_explore": True,
            "num_eval_episodes": task["eval_episodes"],
            "dataset_size": 1_000_000,
            "agent": {
                "_target_": "mbrl.third_party.pytorch_sac_pranz24.sac.SAC",
                "num_inputs": "???",
                "action_space": {
                    # The env's action Box; gymnasium 1.x's Box refuses the ListConfig that
                    # complete_agent_cfg would fill in, so it is given as scalars here.
                    "_target_": "gymnasium.spaces.Box",
                    "_convert_": "all",
                    "low": task["action_box"][0],
                    "high": task["action_box"][1],
                    "shape": [task["action_box"][2]],
                },
                "args": {
                    "gamma": 0.99,
                    "tau": 0.005,
                    "alpha": 1.0,
                    "policy": "Gaussian",
                    "target_update_interval": 1,
                    "automatic_entropy_tuning": True,
                    "target_entropy": task["target_entropy"],
                    "hidden_size": 256,
                    "device": "cpu",
                    "lr": task["sac_lr"],
                },
            },
        },
        "dynamics_model": {
            "_target_": "mbrl.models.GaussianMLP",
            # hydra >= 1.1 would instantiate activation_fn_cfg itself; GaussianMLP wants the cfg
            "_recursive_": False,
            "device": "cpu",
            "num_layers": 4,
            "in_size": "???",
            "out_size": "???",
            "ensemble_size": 7,
            "hid_size": 200,
            "deterministic": False,
            "propagation_method": "random_model",
            "learn_logvar_bounds": True,
            "activation_fn_cfg": {"_target_": "torch.nn.SiLU"},
        },
        "overrides": {
            "env": "gymnasium___" + task["env"],
            "num_steps": args.steps - initial_exploration,
            "epoch_length": 250,
            "num_elites": 5,
            "patience": task["patience"],
            "improvement_threshold": 0.01,
            "model_lr": 1e-3,
            "model_wd": 0.0,  # replaced by per-layer groups below
            "model_batch_size": 256,
            "validation_ratio": 0.2,
            "freq_train_model": freq,
            "effective_model_rollouts_per_step": 400,
            "rollout_schedule": task["rollout_schedule"],
            "num_sac_updates_per_step": 20,
            "sac_updates_every_steps": 1,
            "num_epochs_to_retain_sac_buffer": 1,
            "sac_batch_size": 256,
        },
    })

    # ---- timing instrumentation (wrappers only; mbrl's code runs unchanged) ----
    excluded = [0.0]  # seconds spent in evaluation so far
    stamps = []  # per env.step call: perf_counter - excluded
    updates_at = []  # SAC updates made before each env.step call
    counters = {"updates": 0, "fit_s": 0.0, "fits": 0, "train_save_s": 0.0,
                "rollout_s": 0.0, "eval_s": 0.0, "fit_epochs": [],
                "fit_each_s": [], "fit_after_step": []}

    class StepClock(gym.Wrapper):
        def step(self, action):
            stamps.append(time.perf_counter() - excluded[0])
            updates_at.append(counters["updates"])
            n = len(stamps)
            if n % 250 == 0:
                print(f"[clock] real step {n}, {stamps[-1] - stamps[0]:.1f} s since step 1",
                      file=sys.stderr, flush=True)
            return self.env.step(action)

    orig_eval = mbpo.evaluate

    def timed_evaluate(*a, **k):
        t = time.perf_counter()
        r = orig_eval(*a, **k)
        dt = time.perf_counter() - t
        excluded[0] += dt
        counters["eval_s"] += dt
        return r

    mbpo.evaluate = timed_evaluate

    orig_rollout = mbpo.rollout_model_and_populate_sac_buffer

    def timed_rollout(*a, **k):
        t = time.perf_counter()
        r = orig_rollout(*a, **k)
        counters["rollout_s"] += time.perf_counter() - t
        return r

    mbpo.rollout_model_and_populate_sac_buffer = timed_rollout

    orig_train_save = mbrl.util.common.train_model_and_save_model_and_data

    def timed_train_save(*a, **k):
        t = time.perf_counter()
        r = orig_train_save(*a, **k)
        counters["train_save_s"] += time.perf_counter() - t
        return r

    mbrl.util.common.train_model_and_save_model_and_data = timed_train_save

    orig_update = pranz24.SAC.update_parameters

    def counted_update(self, *a, **k):
        counters["updates"] += 1
        return orig_update(self, *a, **k)

    pranz24.SAC.update_parameters = counted_update

    class PerLayerWdTrainer(mbrl.models.ModelTrainer):
        """mbrl's ModelTrainer with MBPO's per-layer weight decay (weights only)."""

        def __init__(self, model, optim_lr=1e-4, weight_decay=0.0, optim_eps=1e-8, logger=None):
            super().__init__(model, optim_lr=optim_lr, weight_decay=0.0,
                             optim_eps=optim_eps, logger=logger)
            net = model.model  # OneDTransitionRewardModel -> GaussianMLP
            layers = [seq[0] for seq in net.hidden_layers] + [net.mean_and_logvar]
            assert len(layers) == len(wd)
            decayed = {id(l.weight) for l in layers}
            groups = [{"params": [l.weight], "weight_decay": w} for l, w in zip(layers, wd)]
            groups.append({"params": [q for q in model.parameters() if id(q) not in decayed],
                           "weight_decay": 0.0})
            self.optimizer = torch.optim.Adam(groups, lr=optim_lr, eps=optim_eps)

        def train(self, *a, **k):
            t = time.perf_counter()
            train_losses, val_scores = super().train(*a, **k)
            counters["fit_s"] += time.perf_counter() - t
            counters["fit_each_s"].append(round(time.perf_counter() - t, 2))
            counters["fit_after_step"].append(len(stamps))
            counters["fits"] += 1
            counters["fit_epochs"].append(len(train_losses))
            return train_losses, val_scores

    mbrl.models.ModelTrainer = PerLayerWdTrainer

    # ---- run ----
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    env = StepClock(gym.make(task["env"]))
    test_env = gym.make(task["env"])
    env.reset(seed=args.seed)
    env.action_space.seed(args.seed)
    test_env.reset(seed=args.seed + 1000)

    termination_fn = getattr(mbrl.env.termination_fns, task["termination_fn"])
    with tempfile.TemporaryDirectory(prefix=f"mbrl_{args.task}_") as work_dir:
        started = time.perf_counter()
        with contextlib.redirect_stdout(sys.stderr):
            best = mbpo.train(env, test_env, termination_fn, cfg,
                              silent=True, work_dir=work_dir)
        wall = time.perf_counter() - started

    assert len(stamps) == args.steps, (len(stamps), args.steps)
    # stamps[i] is the start of real step i + 1; step s lasts stamps[s] - stamps[s - 1].
    # Measured: steps first_train .. steps - 1 (see the docstring).
    durations = [stamps[s] - stamps[s - 1] for s in range(first_train, args.steps)]
    w = args.window
    windows = [sum(durations[i:i + w]) / w for i in range(0, len(durations) - w + 1, w)]
    measured_updates = updates_at[args.steps - 1] - updates_at[first_train - 1]
    print(json.dumps({
        "framework": "mbrl-lib",
        "task": task["env"],
        "mbrl": mbrl.__version__,
        "torch": torch.__version__,
        "threads": args.threads,
        "omp_wait_policy": os.environ["OMP_WAIT_POLICY"],
        "median_seconds_per_env_step": statistics.median(windows),
        "mean_seconds_per_env_step": sum(durations) / len(durations),
        "env_steps": args.steps,
        "warmup": first_train,
        "seed": args.seed,
        "window": w,
        "windows": len(windows),
        "measured_steps": len(durations),
        "median_single_step_seconds": statistics.median(durations),
        "min_window_seconds_per_env_step": min(windows),
        "max_window_seconds_per_env_step": max(windows),
        "sac_updates_per_measured_step": measured_updates / len(durations),
        "model_trainings": counters["fits"],
        "model_trained_after_step": counters["fit_after_step"],
        "model_train_epochs": counters["fit_epochs"],
        "model_fit_seconds_each": counters["fit_each_s"],
        "model_fit_seconds": round(counters["fit_s"], 2),  # incl. the unmeasured last one
        "model_train_and_save_seconds": round(counters["train_save_s"], 2),
        "model_rollout_seconds": round(counters["rollout_s"], 2),
        "eval_seconds_excluded": round(counters["eval_s"], 2),
        "wall_seconds": round(wall, 1),
        "initial_exploration_steps": initial_exploration,
        "best_eval_return": float(best),
    }))


if __name__ == "__main__":
    main()
