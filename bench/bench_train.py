"""PPO training throughput: ``train_steps_per_s`` (real LK tracking), ``..._oracle``.

Environment steps per second of wall time while stable-baselines3 PPO trains on
``BranchScan-v0`` with 2 envs in a ``SubprocVecEnv`` (``MultiInputPolicy``, CPU torch with one
thread), at the paper's scan settings (0.275 -> 0.75 m at 2.5 cm/s, paper trees, ground-truth
segmentation) and the default :class:`~branch_gym.training.config.PPOConfig` except a short
rollout (``BENCH_N_STEPS`` per env) so that a PPO update is included within the time budget:
the per-step cost of the update (n_epochs passes over each sample) does not depend on n_steps.
Rollouts (env steps of a fresh policy, whose exploration rotates at almost every step), the
policy's forward passes and the update all count; process start-up and env creation do not.

``train_steps_per_s_trigger_recipe`` is the recipe of the shipped model (README): the trigger env,
the oracle's fast mode and a policy that starts holding (``first_action_logit_init`` 3), with
rollouts of ``RECIPE_N_STEPS`` per env.

``train_steps_per_s_fast``: the training mode (oracle tracker, pose-only tracking frames) with the
fixed action mix of :mod:`branch_gym.training.action_mix` (one rotation every 10 steps, whatever
the policy sends), the default rollout length (``PPOConfig.n_steps``, 256 per env),
``FAST_ROLLOUTS`` rollouts and updates, and the rollouts collected in the env processes
(``TrainConfig.worker_rollouts``); the learner's torch threads follow ``train.py``
(:class:`TorchThreadsCallback`: one while the workers step, ``UPDATE_TORCH_THREADS`` in the
update). Compare it with twice ``env_steps_per_s_mix`` (bench_env, one core, the same mix):
``train_over_env_fast`` (bench/run.py, both figures of one run) is their ratio (target >= 0.8).
``train_steps_per_s_fast_lockstep`` is the same run with SB3's lockstep collection (a step that
rotates costs ~8x one that does not, and every vector step waits for the slower env), and
``train_steps_per_s_fast_4envs`` the lockstep with 4 env processes on the same cores (more envs
than cores fill the core that would idle).
"""

from __future__ import annotations

import time

from branch_gym.training.action_mix import FixedActionMix
from branch_gym.training.callbacks import TorchThreadsCallback
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.envs import make_train_env
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


def train_steps_per_s_fast(n_envs: int = N_ENVS, worker_rollouts: bool = True) -> float:
    """Env steps per second of ``PPO.learn`` (training mode, fixed action mix, ``FAST_ROLLOUTS``).

    Args:
        n_envs: Env processes.
        worker_rollouts: Rollouts collected in the env processes (``TrainConfig``); False is
            SB3's lockstep.
    """
    import torch

    threads = torch.get_num_threads()
    ppo = PPOConfig(n_steps=FAST_STEPS // n_envs)
    steps = ppo.n_steps * n_envs * FAST_ROLLOUTS
    config = TrainConfig(
        timesteps=steps, n_envs=n_envs, seed=SEED, tracker="oracle", eval_every=0, ppo=ppo,
        render_tracking_frames=False, normalize=False, worker_rollouts=worker_rollouts,
    )  # fmt: skip
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
    return {
        "train_steps_per_s_fast": train_steps_per_s_fast(),
        "train_steps_per_s_fast_lockstep": train_steps_per_s_fast(worker_rollouts=False),
        "train_steps_per_s_fast_4envs": train_steps_per_s_fast(n_envs=4, worker_rollouts=False),
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
