"""Slow environment tests: action types agree, vector envs, many episodes, an SB3 learner."""

from __future__ import annotations

import gc
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import branch_gym
from agents.baselines import PeriodicAgent
from agents.factory import AGENTS
from branch_gym.env import BranchScanEnv
from branch_gym.env.layout import VECTOR_SIZE
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig

# Metrics compared between a plain scan and an env episode (all of TreeMetrics.to_dict's counts
# and errors; NaN became None in the env's info).
_COMPARED = (
    "scan_time_s",
    "rotations",
    "n_iterations",
    "failure",
    "stop_reason",
    "pb_residual_mean_m",
    "pb_radius_rmse_m",
    "pb_n_points",
    "sb_residual_mean_m",
    "n_gt",
    "n_matched",
    "n_missed",
    "n_spurious",
    "n_duplicates",
    "matches",
)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("env_id", "tracker"), [(branch_gym.ENV_ID_V0, "lk"), (branch_gym.DISCRETE_ENV_ID_V0, "oracle")]
)
def test_periodic_agent_scans_alike_in_every_action_type(env_id: str, tracker: str) -> None:
    config = ScanConfig(tracker=tracker, end_height_m=0.45)
    reference = run_trial(7, "periodic:22.5:1.5", config, AGENTS).to_row()  # continuous env
    env = gymnasium.make(env_id, scan=config)
    agent = PeriodicAgent.for_env(env, 22.5, 1.5)
    obs, _ = env.reset(seed=7)
    state, start, done = None, True, False
    while not done:
        action, state = agent.predict(obs, state=state, episode_start=start)
        obs, _, terminated, truncated, info = env.step(action)
        start, done = False, terminated or truncated
    final = info["final_metrics"]
    assert final["rotations"] >= 2  # the agent did rotate
    for key in _COMPARED:
        expected = reference[key]
        expected = None if isinstance(expected, float) and np.isnan(expected) else expected
        expected = "" if key == "failure" and expected is None else expected
        assert final[key] == expected, key
    env.close()


@pytest.mark.slow
def test_async_vector_env_runs_with_autoreset_and_a_batched_agent() -> None:
    n_envs, n_steps = 2, 100
    envs = gymnasium.make_vec(
        branch_gym.ENV_ID_V0,
        num_envs=n_envs,
        vectorization_mode="async",
        tracker="oracle",
        end_height_m=0.35,
        theta_max_deg=4.0,  # cheap rotations: a 4 deg arc is ~14 mm of motion
    )
    agent = PeriodicAgent.for_env(envs, 4.0, 2.5)
    obs, _ = envs.reset(seed=[0, 1])
    starts = np.ones(n_envs, bool)
    episodes = np.zeros(n_envs, int)
    rotations = 0
    for _ in range(n_steps):
        actions, _ = agent.predict(obs, episode_start=starts)
        assert actions.shape == (n_envs, 1)
        obs, rewards, terminated, truncated, info = envs.step(actions)
        assert obs["vector"].shape == (n_envs, VECTOR_SIZE) and np.all(np.isfinite(rewards))
        starts = terminated | truncated  # the next step autoresets these envs
        episodes += starts
        if "final_metrics" in info:
            rotations += int(np.sum(info["final_metrics"]["rotations"][info["_final_metrics"]]))
    envs.close()
    assert np.all(episodes >= 3)
    assert rotations >= 1


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_300_random_episodes_without_errors_or_memory_growth() -> None:
    # One-step episodes (the end height 1 mm above the start) whose random actions rotate by up
    # to 1 deg half of the time (the rotation tolerance is 0.5 deg): many resets, cheap steps.
    env = BranchScanEnv(tracker="oracle", end_height_m=0.276, theta_max_deg=1.0)
    env.action_space.seed(0)

    def episodes(seeds: range) -> int:
        steps = 0
        for seed in seeds:
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done, steps = terminated or truncated, steps + 1
        return steps

    episodes(range(1000, 1020))  # warm-up: caches, allocator pools
    gc.collect()
    before = _rss_mb()
    steps = episodes(range(300))
    gc.collect()
    grown = _rss_mb() - before
    env.close()
    assert steps >= 300
    assert grown < 50.0, f"resident memory grew by {grown:.1f} MB over 300 episodes"


@pytest.mark.slow
def test_sb3_ppo_learns_from_the_dict_observation_with_its_cnn() -> None:
    from stable_baselines3 import PPO

    env = gymnasium.make(
        branch_gym.DISCRETE_ENV_ID_V0,
        tracker="oracle",
        end_height_m=0.32,
        theta_max_deg=4.0,
        discrete_angles_deg=(-4.0, 0.0, 4.0),  # cheap rotations
    )
    model = PPO("MultiInputPolicy", env, n_steps=32, batch_size=16, n_epochs=1, seed=0)
    model.learn(total_timesteps=32)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(int(action))
    env.close()
