"""Gymnasium's standard wrappers, the env spec round trip and vector envs on the branch_gym ids.

Scans end just above the 0.275 m start height with the depth-oracle tracker (a few steps of
~0.1 s) and actions stay small (a rotation is motion at scan speed: it costs rendered frames).
RecordVideo is covered by tests/test_env_video.py.
"""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.envs.registration import EnvSpec
from gymnasium.wrappers import FlattenObservation, FrameStackObservation, RecordEpisodeStatistics

import branch_gym
from branch_gym.env.layout import VECTOR_SIZE
from branch_gym.sim.tree.config import TreeConfig

# ~4 steps an episode: iterations at ~0.284, 0.294, 0.304, 0.314 m, then the end height.
SHORT = {"tracker": "oracle", "end_height_m": 0.32}
# Small target angles (x 45 deg): 2.25 deg, 0, -2.25 deg, 4.5 deg.
ACTIONS = [np.array([a], np.float32) for a in (0.05, 0.0, -0.05, 0.1)]
IMAGE_SIZE = 3 * 60 * 80


def _episode(env: gymnasium.Env, seed: int) -> tuple[list, list[float], list[dict]]:
    """Reset with ``seed`` and cycle through ACTIONS until the episode ends."""
    obs, info = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], [info]
    done, i = False, 0
    while not done:
        obs, reward, terminated, truncated, info = env.step(ACTIONS[i % len(ACTIONS)])
        observations.append(obs)
        rewards.append(float(reward))
        infos.append(info)
        done, i = terminated or truncated, i + 1
    return observations, rewards, infos


def _assert_obs_equal(a, b) -> None:
    if isinstance(a, dict):
        assert set(a) == set(b)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    else:
        np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def plain_episode() -> tuple[list, list[float], list[dict]]:
    """The reference: BranchScan-v0 without extra wrappers, tree seed 5."""
    env = gymnasium.make(branch_gym.ENV_ID_V0, **SHORT)
    episode = _episode(env, 5)
    env.close()
    return episode


def test_flatten_observation_concatenates_image_then_vector(plain_episode) -> None:
    env = FlattenObservation(gymnasium.make(branch_gym.ENV_ID_V0, **SHORT))
    assert env.observation_space.shape == (IMAGE_SIZE + VECTOR_SIZE,)
    observations, rewards, _ = _episode(env, 5)
    assert rewards == plain_episode[1]
    for flat, nested in zip(observations, plain_episode[0], strict=True):
        assert flat in env.observation_space
        # gymnasium's Dict order is sorted by key: "image" (raw 0..255), then "vector".
        expected = np.concatenate([nested["image"].reshape(-1), nested["vector"]])
        np.testing.assert_array_equal(flat, expected.astype(env.observation_space.dtype))
    env.close()
    # BranchScanFlat-v0 is the other order and scale: vector first, image / 255.
    assert gymnasium.make(branch_gym.FLAT_ENV_ID).observation_space.shape == (
        VECTOR_SIZE + IMAGE_SIZE,
    )


@pytest.mark.parametrize("env_id", [branch_gym.ENV_ID_V0, branch_gym.FLAT_ENV_ID])
def test_frame_stack_holds_the_last_observations(env_id: str, plain_episode) -> None:
    stack = 3
    env = FrameStackObservation(gymnasium.make(env_id, **SHORT), stack)
    observations, rewards, _ = _episode(env, 5)
    assert rewards == plain_episode[1]
    plain = plain_episode[0]
    if env_id == branch_gym.FLAT_ENV_ID:  # the flat layout of the same observations
        plain = [
            np.concatenate([o["vector"], o["image"].reshape(-1).astype(np.float32) / 255.0])
            for o in plain
        ]
    for t, stacked in enumerate(observations):
        assert stacked in env.observation_space
        # Frame k of the stack at step t is the observation of step t - (stack - 1) + k; before
        # the first step the reset observation pads the stack ("reset" padding).
        for k in range(stack):
            frame = plain[max(0, t - (stack - 1) + k)]
            if isinstance(stacked, dict):
                _assert_obs_equal({key: v[k] for key, v in stacked.items()}, frame)
            else:
                np.testing.assert_allclose(stacked[k], frame, atol=1e-6)
    env.close()


def test_record_episode_statistics_reports_return_and_length(plain_episode) -> None:
    env = RecordEpisodeStatistics(gymnasium.make(branch_gym.ENV_ID_V0, **SHORT))
    _, rewards, infos = _episode(env, 5)
    assert rewards == plain_episode[1]
    assert all("episode" not in info for info in infos[:-1])
    stats = infos[-1]["episode"]
    assert stats["l"] == len(rewards) >= 2
    assert stats["r"] == pytest.approx(sum(rewards), abs=1e-5)
    assert stats["t"] >= 0.0
    assert "final_metrics" in infos[-1]  # the env's own end-of-episode info is kept
    assert list(env.return_queue) == [pytest.approx(sum(rewards), abs=1e-5)]
    env.close()


def test_spec_and_kwargs_round_trip_through_make(plain_episode) -> None:
    kwargs = {**SHORT, "tree": "hard", "reward": {"match_reward": 2.0}, "speed_mps": 0.03}
    env = gymnasium.make(
        branch_gym.ENV_ID_V0, render_mode="rgb_array", max_episode_steps=50, **kwargs
    )
    assert env.spec.kwargs == {
        "action_type": "continuous", "paper_scoring": True, "render_mode": "rgb_array", **kwargs
    }  # fmt: skip
    # From the spec object, and from its JSON text (kwargs made of JSON values).
    for spec in (env.spec, EnvSpec.from_json(env.spec.to_json())):
        again = gymnasium.make(spec)
        assert again.unwrapped.config == env.unwrapped.config
        assert again.spec == env.spec and again.spec.max_episode_steps == 50
        assert again.render_mode == "rgb_array"
        again.close()
    env.close()
    # Wrappers are part of the spec: make(spec) rebuilds them around an equal env.
    wrapped = RecordEpisodeStatistics(
        FrameStackObservation(gymnasium.make(branch_gym.ENV_ID_V0, **SHORT), 2)
    )
    names = [w.name for w in wrapped.spec.additional_wrappers]
    assert names == ["FrameStackObservation", "RecordEpisodeStatistics"]
    rebuilt = gymnasium.make(wrapped.spec)
    assert rebuilt.observation_space == wrapped.observation_space
    assert rebuilt.unwrapped.config == wrapped.unwrapped.config
    observations, rewards, infos = _episode(rebuilt, 5)
    assert rewards == plain_episode[1] and infos[-1]["episode"]["l"] == len(rewards)
    _assert_obs_equal({k: v[-1] for k, v in observations[-1].items()}, plain_episode[0][-1])
    rebuilt.close()
    wrapped.close()
    # Kwargs that are objects (not JSON) still round trip through the spec object.
    tree = TreeConfig(secondary_count_range=(1, 1))
    custom = gymnasium.make(branch_gym.ENV_ID_V0, tree=tree, **SHORT)
    assert gymnasium.make(custom.spec).unwrapped.config.scan.world.tree == tree
    custom.close()


@pytest.mark.slow
def test_sync_and_async_vector_envs_step_identically() -> None:
    """Same seeds and actions: the same observations, rewards and ends, across autoresets."""
    num_envs, steps = 2, 10  # 10 steps: every env ends an episode and autoresets at least once
    actions = [
        np.stack([ACTIONS[(t + i) % len(ACTIONS)] for i in range(num_envs)]) for t in range(steps)
    ]
    runs = {}
    for mode in ("sync", "async"):
        envs = gymnasium.make_vec(
            branch_gym.ENV_ID_V0, num_envs=num_envs, vectorization_mode=mode, **SHORT
        )
        obs, info = envs.reset(seed=[3, 4])
        trace = [(obs, info["seed"])]
        for action in actions:
            obs, reward, terminated, truncated, info = envs.step(action)
            trace.append((obs, reward, terminated, truncated, info["seed"], info["scan_time_s"]))
        envs.close()
        runs[mode] = trace
    ends = sum(int(t[2].sum()) for t in runs["sync"][1:])
    assert ends >= num_envs
    for sync, other in zip(runs["sync"], runs["async"], strict=True):
        _assert_obs_equal(sync[0], other[0])
        for a, b in zip(sync[1:], other[1:], strict=True):
            np.testing.assert_array_equal(a, b)
    assert list(runs["sync"][0][1]) == [3, 4]  # reset(seed=[3, 4]) scans trees 3 and 4
