"""Worker rollouts: the env processes play whole PPO rollouts under a copy of the policy.

What matters: the rollout buffer the learner fills holds what PPO's lockstep collection would
(each observation with the action taken on it, the env's reward, episode starts, the learner's
own values and log-probabilities, the time-limit bootstrap), reproducibly, and a training run
with it saves, resumes and loads like any PPO run. A toy env (CartPole, cut at a few steps so
that rollouts cross episode ends and time limits) keeps the unit tests fast.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import branch_gym
from agents.ppo import load_policy
from branch_gym.training.checkpoints import read_checkpoint
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.paths import RunPaths
from branch_gym.training.train import train
from branch_gym.training.worker_rollouts import (
    PolicyRolloutWorker,
    RolloutRequest,
    WorkerRolloutPPO,
)

N_ENVS, N_STEPS = 2, 40
MAX_EPISODE_STEPS = 7  # CartPole episodes cut here: time-limit truncations within a rollout
SEED = 5


def _toy_env(rank: int, worker: bool = True) -> gym.Env:
    env = gym.make("CartPole-v1", max_episode_steps=MAX_EPISODE_STEPS)
    return PolicyRolloutWorker(env, rank) if worker else env


def _model(worker: bool = True) -> WorkerRolloutPPO:
    venv = DummyVecEnv([functools.partial(_toy_env, rank, worker) for rank in range(N_ENVS)])
    return WorkerRolloutPPO(
        "MlpPolicy", venv, n_steps=N_STEPS, batch_size=N_STEPS, seed=SEED, device="cpu"
    )


def _collect(model: WorkerRolloutPPO) -> None:
    _, callback = model._setup_learn(N_STEPS * N_ENVS)
    callback.on_training_start(locals(), globals())
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, N_STEPS)


def test_buffer_holds_the_learners_policy_and_the_envs_transitions() -> None:
    model = _model()
    _collect(model)
    buffer = model.rollout_buffer
    obs = torch.as_tensor(buffer.observations.reshape(-1, 4))
    actions = torch.as_tensor(buffer.actions.reshape(-1))
    with torch.no_grad():
        values, log_probs, _ = model.policy.evaluate_actions(obs, actions)
    # The workers' values and log-probabilities are the learner's policy's on the same pairs.
    np.testing.assert_allclose(buffer.values.reshape(-1), values.numpy().ravel(), atol=1e-5)
    np.testing.assert_allclose(buffer.log_probs.reshape(-1), log_probs.numpy(), atol=1e-5)
    # Replaying the buffer's actions in fresh envs (SB3 resets env k with seed + k) gives the
    # buffer's observations, episode starts and rewards, a time limit's with gamma * V(final).
    truncations = 0
    for rank in range(N_ENVS):
        env = _toy_env(rank, worker=False)
        observation, _ = env.reset(seed=SEED + rank)
        done = True  # the first observation starts an episode
        for step in range(N_STEPS):
            assert buffer.episode_starts[step, rank] == done
            np.testing.assert_allclose(buffer.observations[step, rank], observation, atol=1e-6)
            observation, reward, terminated, truncated, _ = env.step(
                int(buffer.actions[step, rank, 0])
            )
            done = terminated or truncated
            if truncated and not terminated:
                truncations += 1
                with torch.no_grad():
                    final = model.policy.predict_values(torch.as_tensor(observation[None]))
                reward += model.gamma * float(final)
            assert buffer.rewards[step, rank] == pytest.approx(reward, abs=1e-5)
            if done:
                observation, _ = env.reset()
    assert truncations >= N_ENVS * (N_STEPS // (MAX_EPISODE_STEPS + 1) - 1)
    assert model.num_timesteps == N_STEPS * N_ENVS
    assert np.isfinite(buffer.advantages).all() and np.abs(buffer.returns).sum() > 0


def test_the_same_seed_gives_the_same_rollout_and_envs_sample_independently() -> None:
    first, second = _model(), _model()
    _collect(first)
    _collect(second)
    np.testing.assert_array_equal(first.rollout_buffer.actions, second.rollout_buffer.actions)
    np.testing.assert_array_equal(first.rollout_buffer.rewards, second.rollout_buffer.rewards)
    actions = first.rollout_buffer.actions[:, :, 0]
    assert not np.array_equal(actions[:, 0], actions[:, 1])  # each rank its own draws


def test_unusable_envs_and_configs_are_refused() -> None:
    plain = _model(worker=False)
    with pytest.raises(ValueError, match="PolicyRolloutWorker"):
        plain.learn(N_STEPS * N_ENVS)
    normalized = _model()
    normalized.set_env(VecNormalize(normalized.env))
    with pytest.raises(ValueError, match="VecNormalize"):
        normalized.learn(N_STEPS * N_ENVS)
    with pytest.raises(ValueError, match="worker_rollouts"):
        TrainConfig(worker_rollouts=True, normalize=True)
    with pytest.raises(ValueError, match="worker_rollouts"):
        TrainConfig(worker_rollouts=True, recurrent=True)
    worker = _toy_env(0)
    request = RolloutRequest(
        type(plain.policy), {}, worker.observation_space, worker.action_space, {}, 1, 0.99, 0
    )
    with pytest.raises(RuntimeError, match="reset"):
        worker.collect_rollout(request)


@pytest.mark.slow
def test_worker_rollout_run_trains_resumes_and_loads_as_ppo(tmp_path: Path) -> None:
    """Two BranchScan env processes, 2 rollouts of 16 steps each, resumed for a third."""
    config = TrainConfig(
        env_id=branch_gym.DISCRETE_ENV_ID_V2, timesteps=64, n_envs=2, seed=2, tracker="oracle",
        end_height_m=0.33, render_tracking_frames=False, checkpoint_every=32, eval_every=0,
        worker_rollouts=True, ppo=PPOConfig(n_steps=16, batch_size=32, n_epochs=1,
                                            cnn_output_dim=16, first_action_logit_init=2.0),
    )  # fmt: skip
    out = tmp_path / "run"
    assert train(config, out).num_timesteps == 64
    paths = RunPaths(out)
    first = read_checkpoint(paths)
    assert first.num_timesteps == 64 and min(first.episodes) >= 2  # whole scans in each env
    saved = TrainConfig.from_dict(json.loads(paths.config.read_text())["config"])
    assert saved.worker_rollouts
    resumed = train(TrainConfig(**{**config.__dict__, "timesteps": 96}), out, resume=True)
    assert (resumed.start_timesteps, resumed.num_timesteps) == (64, 96)
    assert read_checkpoint(paths).episodes[0] > first.episodes[0]
    agent = load_policy(paths.final_model)  # an ordinary PPO model file
    env = gym.make(branch_gym.DISCRETE_ENV_ID_V2, tracker="oracle", end_height_m=0.33)
    observation, _ = env.reset(seed=0)
    env.close()
    action, _ = agent.predict(observation)
    assert env.action_space.contains(int(action))
