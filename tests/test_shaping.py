"""Potential-based view shaping: the potential, the telescoping sum on a real env, the config."""

from __future__ import annotations

from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import branch_gym  # noqa: F401  (registers the env ids)
from branch_gym.scan import ScanConfig
from branch_gym.training.config import TrainConfig
from branch_gym.training.privileged_state import matched_branches
from branch_gym.training.shaping import SHAPING_TERM, ViewShapingWrapper, view_potential

SCORED_ENV_ID = "BranchScanDiscrete-v3"
CHEAP_ENV = {"tracker": "oracle", "render_tracking_frames": False, "segmenter": "gt"}


def _branch(base_z: float, direction: tuple[float, float]) -> SimpleNamespace:
    base = np.array([0.0, 0.0, base_z])
    return SimpleNamespace(points=np.stack([base, base + np.array([*direction, 0.0]) * 0.1]))


def _session(branches: list[SimpleNamespace], angle_deg: float) -> SimpleNamespace:
    return SimpleNamespace(
        tree=SimpleNamespace(secondaries=branches),
        config=ScanConfig(),
        camera_height_m=0.5,
        vertical_fov_m=0.1,
        angle_deg=angle_deg,
        progress=0.4,
    )


def test_the_potential_counts_the_pending_branches_the_view_shows_well() -> None:
    # View band 0.45-0.55 m (half a FoV each side); good view: >= 45 deg from the optical axis,
    # which at rotation r lies along heading r.
    branches = [
        _branch(0.51, (0.0, 1.0)),  # 0: heading 0
        _branch(0.48, (-1.0, 0.0)),  # 1: heading 90 deg
        _branch(0.49, (-np.sin(np.pi / 3), 0.5)),  # 2: heading 60 deg
        _branch(0.60, (-1.0, 0.0)),  # 3: ahead of the band
        _branch(0.52, (-1.0, 0.0)),  # 4: matched
    ]
    # Rotation 0: branch 0 along the axis; 1 at 90 deg and 2 at 60 deg shown well.
    assert view_potential(_session(branches, 0.0), {4}, weight=0.5) == pytest.approx(1.0)
    # Rotation 90: branch 0 at 90 deg; 1 along the axis, 2 at 30 deg.
    assert view_potential(_session(branches, 90.0), {4}, weight=0.5) == pytest.approx(0.5)
    # Rotation -30: branch 0 at 30 deg; 1 at 120 (a line: 60) and 2 at 90 deg shown well.
    assert view_potential(_session(branches, -30.0), {4}, weight=2.0) == pytest.approx(4.0)
    assert view_potential(_session(branches, -30.0), {1, 4}, weight=2.0) == pytest.approx(2.0)
    assert view_potential(_session([], 0.0), set(), weight=1.0) == 0.0


def test_the_shaping_telescopes_to_the_potentials_on_a_real_env() -> None:
    gamma, weight = 0.9, 0.7
    env = ViewShapingWrapper(gym.make(SCORED_ENV_ID, **CHEAP_ENV), weight=weight, gamma=gamma)
    try:
        _, info = env.reset(seed=3)
        start = view_potential(env.unwrapped.session, matched_branches(info), weight)
        discounted, potentials, terminated, truncated = 0.0, [start], False, False
        actions = [0, 1, 2, 3, 4, 5] * 4  # every action, turning the camera both ways
        for t, action in enumerate(actions):
            _, reward, terminated, truncated, info = env.step(action)
            terms = info["reward_terms"]
            shaping = terms[SHAPING_TERM]
            env_terms = sum(v for k, v in terms.items() if k != SHAPING_TERM)
            assert reward == pytest.approx(env_terms + shaping, abs=1e-9)
            discounted += gamma**t * shaping
            potentials.append(view_potential(env.unwrapped.session, matched_branches(info), weight))
            if terminated or truncated:
                break
        final = 0.0 if terminated else potentials[-1]
        assert discounted == pytest.approx(gamma ** (t + 1) * final - start, abs=1e-9)
        assert max(potentials) > 0.0  # a well-shown pending branch was seen: the test can fail
    finally:
        env.close()


def test_the_config_and_the_wrapper_refuse_bad_settings() -> None:
    with pytest.raises(ValueError, match="privileged_critic"):
        TrainConfig(env_id=SCORED_ENV_ID, view_shaping_weight=1.0)
    for bad in (-1.0, float("nan"), "1"):
        with pytest.raises(ValueError, match="view_shaping_weight"):
            TrainConfig(env_id=SCORED_ENV_ID, privileged_critic=True, view_shaping_weight=bad)
    assert TrainConfig(env_id=SCORED_ENV_ID, privileged_critic=True, view_shaping_weight=0.5)
    env = gym.make(SCORED_ENV_ID, **CHEAP_ENV)
    try:
        with pytest.raises(ValueError, match="gamma"):
            ViewShapingWrapper(env, weight=1.0, gamma=1.5)
        with pytest.raises(ValueError, match="weight"):
            ViewShapingWrapper(env, weight=0.0, gamma=0.99)
    finally:
        env.close()


def test_a_run_with_the_weight_shapes_its_training_envs_outside_the_monitor() -> None:
    from stable_baselines3.common.monitor import Monitor

    from branch_gym.training.envs import make_env

    config = TrainConfig(
        env_id=SCORED_ENV_ID, privileged_critic=True, view_shaping_weight=0.5, **CHEAP_ENV
    )
    env = make_env(config, rank=0)
    try:
        assert isinstance(env, ViewShapingWrapper) and isinstance(env.env, Monitor)
        assert (env.weight, env.gamma) == (0.5, config.ppo.gamma)
    finally:
        env.close()
    plain = make_env(TrainConfig(env_id=SCORED_ENV_ID, **CHEAP_ENV), rank=0)
    assert isinstance(plain, Monitor)
    plain.close()
