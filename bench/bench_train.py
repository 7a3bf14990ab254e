"""PPO training throughput: ``train_steps_per_s`` (real LK tracking), ``..._oracle``.

Environment steps per second of wall time while stable-baselines3 PPO trains on
``BranchScan-v0`` with 2 envs in a ``SubprocVecEnv`` (``MultiInputPolicy``, CPU torch with one
thread), at the paper's scan settings (0.275 -> 0.75 m at 2.5 cm/s, paper trees, ground-truth
segmentation) and the default :class:`~branch_gym.training.config.PPOConfig` except a short
rollout (``BENCH_N_STEPS`` per env) so that a PPO update is included within the time budget:
the per-step cost of the update (n_epochs passes over each sample) does not depend on n_steps.
Rollouts (env steps of a fresh policy, whose exploration rotates at almost every step), the
policy's forward passes and the update all count; process start-up and env creation do not.

``train_steps_per_s_trigger_recipe`` is a PPO recipe (docs/results/history.md): the trigger env,
the oracle's fast mode and a policy that starts holding (``first_action_logit_init`` 3), with
rollouts of ``RECIPE_N_STEPS`` per env.

``train_steps_per_s_fast``: the training mode (oracle tracker, pose-only tracking frames) with the
fixed action mix of :mod:`bench.action_mix` (one rotation every 10 steps, whatever
the policy sends), the default rollout length (``PPOConfig.n_steps``, 256 per env),
``FAST_ROLLOUTS`` rollouts and updates, and the rollouts collected in the env processes
(``TrainConfig.worker_rollouts``); the learner's torch threads follow ``train.py``
(:class:`TorchThreadsCallback`: one while the workers step, ``UPDATE_TORCH_THREADS`` in the
update). ``env_steps_per_s_train_trees`` is the single-core rate of the very steps that run
plays: each env's trees (``TreeSeedWrapper``: run seed, rank, episode), the same mix and the same
step count, replayed one env after the other in this process pinned to one core, once before the
training figures and once after (total steps over total time: the machine's speed drifts by up to
~20 % over minutes). ``train_over_env_fast`` (bench/run.py, figures of one run) is the training
rate over twice it (target >= 0.8): the same work on both sides, so what the ratio loses is what
training adds (the update, the wait for the slower worker, the policy's forward passes, pipes).
``train_over_env_fast_mix_seeds`` compares with twice ``env_steps_per_s_mix`` instead (bench_env:
the mix on 8 bench trees, not the training trees, measured minutes apart).
``env_steps_per_s_side_by_side`` runs the two replays at once, one process per core (the sum of
their own rates): ``env_parallel_efficiency`` is it over twice the single-core rate (the machine's
ceiling for the ratio: two processes slow each other by ~15 % on some machines), and
``train_over_side_by_side`` the training rate over it (what training itself loses).
``train_steps_per_s_fast_lockstep`` is the same run with SB3's lockstep collection (a step that
rotates costs ~8x one that does not, and every vector step waits for the slower env), and
``train_steps_per_s_fast_4envs`` the lockstep with 4 env processes on the same cores (more envs
than cores fill the core that would idle). ``train_steps_per_s_fast_orchard_learned`` is the fast
run in the orchard world from pixels (the learned segmenter: how the orchard students train);
``train_fast_clean_over_orchard`` (bench/run.py) the clean rate over it (target <= 1.5).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from bench.action_mix import FixedActionMix
from bench.bench_env import one_core
from branch_gym.training.callbacks import TorchThreadsCallback
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.envs import make_env, make_train_env
from branch_gym.training.train import UPDATE_TORCH_THREADS, new_model

N_ENVS = 2
# Our choice: one rollout of 12 steps per env and one update per tracker keep the whole bench
# under ~1 min: a fresh policy's exploration rotates at almost every step (~1 s of wall time).
BENCH_N_STEPS = 12
ROLLOUTS = 1
SEED = 0
# The shipped model's recipe steps ~10x faster: longer rollouts within the same time budget.
RECIPE_N_STEPS = 64
RECIPE_HOLD_LOGIT = 3.0
FAST_N_STEPS = PPOConfig().n_steps  # the shipped recipe's rollout length
FAST_STEPS = FAST_N_STEPS * N_ENVS  # steps of one rollout of the fast figures
# Our choice: 4 rollouts and updates (~20 scans, ~1 min): one rollout holds ~5 scans per env, and
# how long the slower env's scans take varies by ~20 % from one rollout to the next.
FAST_ROLLOUTS = 4
REPLAY_STEPS_PER_ENV = FAST_STEPS // N_ENVS * FAST_ROLLOUTS  # what each env plays in that run


def _fast_config(
    n_envs: int = N_ENVS, worker_rollouts: bool = True, world: str = "clean", segmenter: str = "gt"
) -> TrainConfig:
    """The run of the fast figures: ``FAST_ROLLOUTS`` rollouts of ``FAST_STEPS`` steps."""
    ppo = PPOConfig(n_steps=FAST_STEPS // n_envs)
    return TrainConfig(
        timesteps=ppo.n_steps * n_envs * FAST_ROLLOUTS, n_envs=n_envs, seed=SEED,
        tracker="oracle", eval_every=0, ppo=ppo, render_tracking_frames=False, normalize=False,
        worker_rollouts=worker_rollouts, world=world, segmenter=segmenter,
    )  # fmt: skip


def _replay_s(rank: int, core: int | None = None) -> float:
    """Seconds env ``rank`` of the fast run takes to play its steps alone (resets included).

    The env (:func:`branch_gym.training.envs.make_env`: its trees, the fixed mix) plays
    ``REPLAY_STEPS_PER_ENV`` steps from its first reset, resetting at episode ends as a
    training env does; the mix ignores the action sent. Its creation is not timed (as in the
    training figure).

    Args:
        rank: The env's index in the run.
        core: Pin this process to this CPU (a side-by-side replay's own process), or None.
    """
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    config = replace(_fast_config(), worker_rollouts=False)
    env = make_env(config, rank, FixedActionMix)
    action = np.zeros(env.action_space.shape, env.action_space.dtype)
    start = time.perf_counter()
    env.reset()
    for _ in range(REPLAY_STEPS_PER_ENV):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    elapsed_s = time.perf_counter() - start
    env.close()
    return elapsed_s


def env_steps_per_s_train_trees() -> float:
    """Single-core env steps per second of the steps :func:`train_steps_per_s_fast` plays.

    The run's envs replayed one after the other in this process, pinned to one core.
    """
    import torch

    threads = torch.get_num_threads()
    try:
        with one_core():
            elapsed_s = sum(_replay_s(rank) for rank in range(N_ENVS))
    finally:
        torch.set_num_threads(threads)  # make_env sets the worker's thread count
    return N_ENVS * REPLAY_STEPS_PER_ENV / elapsed_s


def env_steps_per_s_side_by_side() -> float:
    """The same replays run at once, one process per core: the sum of their own rates.

    Two such processes slow each other on some machines (shared caches and memory bandwidth:
    ~15 % each on one of ours, none on another): the ceiling that machine puts on
    ``train_over_env_fast`` whatever the training does. NaN with fewer than 2 cores.
    """
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if len(cores) < N_ENVS:
        return float("nan")
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(N_ENVS, mp_context=context) as pool:
        seconds = list(pool.map(_replay_s, range(N_ENVS), cores[:N_ENVS]))
    return sum(REPLAY_STEPS_PER_ENV / s for s in seconds)


def train_steps_per_s_fast(
    n_envs: int = N_ENVS, worker_rollouts: bool = True, world: str = "clean", segmenter: str = "gt"
) -> float:
    """Env steps per second of ``PPO.learn`` (training mode, fixed action mix, ``FAST_ROLLOUTS``).

    Args:
        n_envs: Env processes.
        worker_rollouts: Rollouts collected in the env processes (``TrainConfig``); False is
            SB3's lockstep.
        world: "clean" or "orchard".
        segmenter: The envs' segmenter ("learned": from pixels).
    """
    import torch

    threads = torch.get_num_threads()
    config = _fast_config(n_envs, worker_rollouts, world, segmenter)
    steps = config.timesteps
    venv = make_train_env(config, wrapper=FixedActionMix)
    try:
        model = new_model(config, venv)
        callback = TorchThreadsCallback(1, UPDATE_TORCH_THREADS)
        start = time.perf_counter()
        model.learn(total_timesteps=steps, callback=callback)
        elapsed = time.perf_counter() - start
    finally:
        venv.close()
        torch.set_num_threads(threads)
    return model.num_timesteps / elapsed


def _train_steps_per_s(tracker: str, n_steps: int = BENCH_N_STEPS, **recipe: object) -> float:
    """Env steps per second of ``PPO.learn`` with 2 envs and the given tracker."""
    import torch

    torch.set_num_threads(1)
    hold_logit = float(recipe.pop("first_action_logit_init", 0.0))
    ppo = PPOConfig(
        n_steps=n_steps, batch_size=n_steps * N_ENVS, first_action_logit_init=hold_logit
    )
    steps = n_steps * N_ENVS * ROLLOUTS
    config = TrainConfig(
        timesteps=steps, n_envs=N_ENVS, seed=SEED, tracker=tracker, eval_every=0, ppo=ppo,
        **recipe,
    )  # fmt: skip
    venv = make_train_env(config)
    try:
        model = new_model(config, venv)  # applies the hold logit of config.ppo
        start = time.perf_counter()
        model.learn(total_timesteps=steps)
        elapsed = time.perf_counter() - start
    finally:
        venv.close()
    return model.num_timesteps / elapsed


def run() -> dict[str, float]:
    replay_before = env_steps_per_s_train_trees()
    fast = train_steps_per_s_fast()
    lockstep = train_steps_per_s_fast(worker_rollouts=False)
    replay_after = env_steps_per_s_train_trees()
    return {
        # Total steps over total time of the two replays (the same step count each).
        "env_steps_per_s_train_trees": 2.0 / (1.0 / replay_before + 1.0 / replay_after),
        "env_steps_per_s_side_by_side": env_steps_per_s_side_by_side(),
        "train_steps_per_s_fast": fast,
        "train_steps_per_s_fast_lockstep": lockstep,
        "train_steps_per_s_fast_4envs": train_steps_per_s_fast(n_envs=4, worker_rollouts=False),
        "train_steps_per_s_fast_orchard_learned": train_steps_per_s_fast(
            world="orchard", segmenter="learned"
        ),
        "train_steps_per_s": _train_steps_per_s("lk"),
        "train_steps_per_s_oracle": _train_steps_per_s("oracle"),
        "train_steps_per_s_trigger_recipe": _train_steps_per_s(
            "oracle",
            n_steps=RECIPE_N_STEPS,
            env_id="BranchScanTrigger-v0",
            render_tracking_frames=False,
            first_action_logit_init=RECIPE_HOLD_LOGIT,
        ),
    }
