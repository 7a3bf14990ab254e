"""RLlib PPO on the branch scanning env, with several env runners (Ray actors) sampling at once.

Needs RLlib, which pins its own gymnasium (``ray[rllib]`` 2.60 requires gymnasium 1.2.2, the
project's ``.venv`` has 1.4.0): install it into a separate virtual environment, see
docs/integrations/ray.md::

    python -m venv ~/venv-rllib && ~/venv-rllib/bin/pip install torch==2.13.0
    ~/venv-rllib/bin/pip install -e ".[rllib]"
    ~/venv-rllib/bin/python examples/rllib_ppo.py --env-runners 2 --iterations 3 --seed 0

One line per training iteration: env steps sampled so far, the mean return of the episodes that
ended, and the learner's losses. The observation is ``BranchScanFlat-v0``'s flat vector (RLlib's
default MLP); scans use the depth-oracle tracker in its fast mode and end at 0.4 m by default
(~18 steps an episode). ``--address`` trains on a Ray cluster whose nodes have this project
installed.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

ENV_NAME = "branch_scan_flat"  # RLlib's name for the env creator below
# Fast episodes: exact tracks from the rendered depth, rendering only the frames the modeler
# runs on (the oracle's fast mode), ending just above the 0.275 m start height.
FAST_ENV = {"tracker": "oracle", "end_height_m": 0.4, "render_tracking_frames": False}
# A small run's PPO settings (our choice): a batch of 128 env steps (~7 episodes), minibatches
# of 64, RLlib's default learning rate and epochs scaled down; the MLP of torch_ppo.py.
TRAIN_BATCH_STEPS = 128
MINIBATCH_SIZE = 64
NUM_EPOCHS = 4
LEARNING_RATE = 3e-4
HIDDEN = (64, 64)
# How long the driver waits for an env runner's samples (RLlib's default: 60 s). RLlib's initial
# action std is 1: most actions rotate by the full 45 deg, and a rotation costs simulation, so a
# step takes 0.3-0.75 s and a runner's 64 steps can take longer than the default.
SAMPLE_TIMEOUT_S = 600.0


def make_env(env_config: dict[str, Any]) -> Any:
    """RLlib's env creator: ``BranchScanFlat-v0`` with ``env_config`` as its keywords."""
    import gymnasium

    import branch_gym

    return gymnasium.make(branch_gym.FLAT_ENV_ID, **env_config)


def build_config(env_config: dict[str, Any], env_runners: int, seed: int) -> Any:
    """The PPO configuration (RLlib's new API stack: RLModule, Learner, EnvRunner)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=env_config)
        .env_runners(
            num_env_runners=env_runners,
            num_envs_per_env_runner=1,
            sample_timeout_s=SAMPLE_TIMEOUT_S,
        )
        .training(
            train_batch_size_per_learner=TRAIN_BATCH_STEPS,
            minibatch_size=MINIBATCH_SIZE,
            num_epochs=NUM_EPOCHS,
            lr=LEARNING_RATE,
        )
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=list(HIDDEN)))
        .debugging(seed=seed)
    )


def _get(result: dict, *keys: str) -> float:
    """A nested result entry, NaN when RLlib did not report it this iteration."""
    for key in keys:
        if not isinstance(result, dict) or key not in result:
            return math.nan
        result = result[key]
    return float(result)


def main(argv: list[str] | None = None) -> list[float]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--env-runners", type=int, default=2, help="sampling actors (default 2)")
    parser.add_argument("--iterations", type=int, default=3, help="training iterations")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tracker", default=FAST_ENV["tracker"], choices=("lk", "oracle"))
    parser.add_argument("--end-height", type=float, default=FAST_ENV["end_height_m"])
    parser.add_argument("--address", help="Ray cluster address; default: a local instance")
    args = parser.parse_args(argv)

    import ray
    from ray.tune.registry import register_env

    if args.address:
        ray.init(address=args.address)
    else:  # env runners + the learner in this process, one CPU each
        ray.init(address="local", num_cpus=args.env_runners + 1, include_dashboard=False)
    register_env(ENV_NAME, make_env)
    env_config = {
        "tracker": args.tracker,
        "end_height_m": args.end_height,
        "render_tracking_frames": args.tracker == "lk",  # fast mode: oracle tracks only
    }
    algo = build_config(env_config, args.env_runners, args.seed).build_algo()
    print(
        f"RLlib {ray.__version__} PPO on BranchScanFlat-v0 {env_config}, "
        f"{args.env_runners} env runners"
    )
    returns = []
    try:
        for _ in range(args.iterations):
            result = algo.train()
            learner = ("learners", "default_policy")
            returns.append(_get(result, "env_runners", "episode_return_mean"))
            print(
                f"iteration {result['training_iteration']:3d}  "
                f"steps {_get(result, 'num_env_steps_sampled_lifetime'):6.0f}  "
                f"episodes {_get(result, 'env_runners', 'num_episodes'):3.0f}  "
                f"return {returns[-1]:7.3f}  "
                f"policy {_get(result, *learner, 'policy_loss'):+.4f}  "
                f"value {_get(result, *learner, 'vf_loss'):.4f}  "
                f"entropy {_get(result, *learner, 'entropy'):.3f}",
                flush=True,
            )
    finally:
        algo.stop()
        ray.shutdown()
    return returns


if __name__ == "__main__":
    main()
