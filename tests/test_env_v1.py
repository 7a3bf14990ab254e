"""The v1 environment: coverage memory and price of scan time in the observation, hold action."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import branch_gym
from branch_gym.env.layout import COVERAGE_KEY, PRICE_KEY, flatten_observation
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig

ROOT = Path(__file__).resolve().parents[1]
SHORT = {"tracker": "oracle", "end_height_m": 0.36}


def test_v1_observations_fit_their_spaces_and_flatten_alike() -> None:
    dict_env = gymnasium.make(branch_gym.ENV_ID_V1, **SHORT)
    flat_env = gymnasium.make(branch_gym.ENV_ID_V1, flatten=True, **SHORT)
    try:
        obs, _ = dict_env.reset(seed=4, options={"branch_value_s": 100.0})
        flat, _ = flat_env.reset(seed=4, options={"branch_value_s": 100.0})
        assert dict_env.observation_space.contains(obs) and flat_env.observation_space.contains(
            flat
        )
        np.testing.assert_allclose(flatten_observation(obs), flat)
        assert obs[PRICE_KEY][0] == pytest.approx(np.log(100 / 25) / np.log(400 / 25))
        for _ in range(4):
            obs, *_ = dict_env.step(np.array([0.0], np.float32))
        seen = obs[COVERAGE_KEY].reshape(16, 8)[:, :5]
        assert seen[:, 2].any() and not np.delete(seen, 2, axis=1).any()  # only from 0 deg
    finally:
        dict_env.close()
        flat_env.close()


def test_the_price_sets_the_time_term_and_is_drawn_per_episode() -> None:
    env = gymnasium.make(branch_gym.ENV_ID_V1, **SHORT)
    try:
        env.reset(seed=1, options={"branch_value_s": 50.0})
        before = env.unwrapped.session.scan_time_s
        _, _, _, _, info = env.step(np.array([0.0], np.float32))
        elapsed = env.unwrapped.session.scan_time_s - before
        assert info["reward_terms"]["time"] == pytest.approx(-elapsed / 50.0)
        prices = {float(env.reset(seed=s)[0][PRICE_KEY][0]) for s in range(5)}
        assert len(prices) == 5 and all(0.0 <= p <= 1.0 for p in prices)
    finally:
        env.close()
    v0 = gymnasium.make(branch_gym.ENV_ID, **SHORT)
    with pytest.raises(ValueError, match="branch_value_s"):
        v0.reset(seed=0, options={"branch_value_s": 50.0})
    v0.close()


def test_the_hold_action_keeps_a_rotation() -> None:
    env = gymnasium.make(branch_gym.DISCRETE_ENV_ID_V1, **SHORT)
    try:
        env.reset(seed=2)
        env.step(4)  # target +22.5 deg
        assert env.unwrapped.session.angle_deg == pytest.approx(22.5, abs=0.6)
        _, _, _, _, info = env.step(0)  # hold
        assert not info["rotated"] and env.unwrapped.session.angle_deg == pytest.approx(
            22.5, abs=0.6
        )
        with pytest.raises(ValueError, match="out of range"):
            env.step(6)
    finally:
        env.close()


@pytest.mark.slow
def test_a_short_v1_training_run_writes_a_model_that_plays_at_a_given_price(tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location("train_cli", ROOT / "train.py")
    cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cli)
    out = tmp_path / "run"
    argv = [
        "--env", branch_gym.DISCRETE_ENV_ID_V1, "--timesteps", "64", "--out", str(out),
        "--tracker", "oracle", "--end-height", "0.33", "--n-envs", "1", "--seed", "3",
        "--n-steps", "32", "--batch-size", "32", "--n-epochs", "1",
        "--checkpoint-every", "64", "--eval-every", "64", "--eval-trees", "1",
    ]  # fmt: skip
    assert cli.main(argv) == 0
    model = out / "final_model.zip"
    result = run_trial(0, f"ppo:{model}@80", ScanConfig(tracker="oracle", end_height_m=0.33))
    assert result.n_iterations > 0 and result.policy == f"ppo:{model}@80"


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known shortfall (README, 'Learned rotation policies'): the shipped 83k-step policy "
    "turns to -22.5 deg once and holds at every price; its training has not converged",
)
def test_the_shipped_policy_rotates_more_when_scan_time_is_cheap() -> None:
    """One price-conditioned policy: a found branch worth 400 s buys more views than at 25 s."""
    model = ROOT / "models" / "ppo_v1.zip"
    scan = ScanConfig(tracker="oracle", end_height_m=0.5)
    rotations = {}
    for price in (25, 400):
        results = [run_trial(seed, f"ppo:{model}@{price}", scan) for seed in (0, 1, 2)]
        assert all(r.failure is None for r in results)
        rotations[price] = [r.rotations for r in results]
    assert sum(rotations[400]) > sum(rotations[25]), rotations
