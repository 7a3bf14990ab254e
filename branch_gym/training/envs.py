"""The training and evaluation environments of a run.

Training: ``n_envs`` copies of the run's env id, each wrapped in :class:`TreeSeedWrapper` (its own
sequence of training trees; inside it :class:`PriceRangeWrapper` with ``train_branch_value_s``)
and SB3's ``Monitor`` (outside it :class:`~branch_gym.training.shaping.ViewShapingWrapper` with
``view_shaping_weight``), in a ``SubprocVecEnv`` when ``n_envs > 1`` (a ``DummyVecEnv`` otherwise),
optionally inside ``VecNormalize``; with ``TrainConfig.worker_rollouts`` each env's outermost
wrapper is :class:`~branch_gym.training.worker_rollouts.PolicyRolloutWorker`. Evaluation: one
plain env in this process, reset on the held-out trees one by one
(:mod:`branch_gym.training.seeds`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import gymnasium as gym
from gymnasium import spaces

from branch_gym.env.layout import VECTOR_KEY
from branch_gym.threads import pin_worker_threads
from branch_gym.training.config import TrainConfig
from branch_gym.training.prices import PriceRangeWrapper
from branch_gym.training.seeds import TreeSeedWrapper
from branch_gym.training.shaping import ViewShapingWrapper
from branch_gym.training.worker_rollouts import PolicyRolloutWorker

DICT_POLICY = "MultiInputPolicy"
FLAT_POLICY = "MlpPolicy"
# sb3-contrib RecurrentPPO's (TrainConfig.recurrent): the same features, then an LSTM.
DICT_LSTM_POLICY = "MultiInputLstmPolicy"
FLAT_LSTM_POLICY = "MlpLstmPolicy"


def make_env(
    config: TrainConfig, rank: int, wrapper: Callable[[gym.Env], gym.Env] | None = None
) -> gym.Env:
    """Training env ``rank``: the env id with the run's settings, its trees, episode stats.

    Args:
        config: The run.
        rank: The env's index in the vector env (its tree sequence).
        wrapper: Applied around the monitored env (e.g. the bench's fixed action mix), inside
            the worker-rollout wrapper when ``config.worker_rollouts``.
    """
    from stable_baselines3.common.monitor import Monitor

    pin_worker_threads()
    env = gym.make(config.env_id, **config.env_kwargs())
    if config.train_branch_value_s is not None:
        env = PriceRangeWrapper(env, config.train_branch_value_s)
    env = Monitor(TreeSeedWrapper(env, config.seed, rank, config.n_envs))
    if config.view_shaping_weight:  # outside the Monitor: the curve's returns are the env's
        env = ViewShapingWrapper(env, config.view_shaping_weight, config.ppo.gamma)
    if wrapper is not None:
        env = wrapper(env)
    return PolicyRolloutWorker(env, rank) if config.worker_rollouts else env


def make_train_env(
    config: TrainConfig,
    normalizer: Any = None,
    wrapper: Callable[[gym.Env], gym.Env] | None = None,
) -> Any:
    """The vectorised training envs (``VecNormalize`` on top when ``config.normalize``).

    Args:
        config: The run.
        normalizer: Saved ``VecNormalize`` statistics to continue from (resume), or None for
            fresh ones.
        wrapper: Applied to every env (:func:`make_env`); picklable for ``SubprocVecEnv``.
    """
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    factories = [
        functools.partial(make_env, config, rank, wrapper) for rank in range(config.n_envs)
    ]
    venv = SubprocVecEnv(factories) if config.n_envs > 1 else DummyVecEnv(factories)
    if not config.normalize:
        return venv
    if normalizer is not None:
        normalizer.set_venv(venv)
        return normalizer
    keys = [VECTOR_KEY] if isinstance(venv.observation_space, spaces.Dict) else None
    return VecNormalize(venv, norm_obs_keys=keys, gamma=config.ppo.gamma)


def make_eval_env(config: TrainConfig) -> gym.Env:
    """The evaluation env: the training settings, in this process, trees chosen per reset."""
    return gym.make(config.env_id, **config.env_kwargs())


def policy_class(observation_space: spaces.Space, recurrent: bool = False) -> str:
    """SB3's policy for an observation space: MultiInputPolicy for Dict, MlpPolicy for a Box.

    Args:
        observation_space: The env's.
        recurrent: RecurrentPPO's LSTM policies instead: MultiInputLstmPolicy, MlpLstmPolicy.
    """
    if isinstance(observation_space, spaces.Dict):
        return DICT_LSTM_POLICY if recurrent else DICT_POLICY
    return FLAT_LSTM_POLICY if recurrent else FLAT_POLICY


def episode_counts(venv: Any) -> list[int]:
    """Episodes started by each training env (their :class:`TreeSeedWrapper` counters)."""
    return [int(n) for n in venv.get_attr("episodes")]


def restore_episode_counts(venv: Any, counts: list[int]) -> None:
    """Continue each training env's tree sequence after ``counts`` episodes (resume).

    Raises:
        ValueError: ``counts`` does not hold one count per env.
    """
    if len(counts) != venv.num_envs:
        raise ValueError(f"episode counts {counts} do not match n_envs={venv.num_envs}")
    for rank, count in enumerate(counts):
        venv.env_method("set_episodes", int(count), indices=[rank])
