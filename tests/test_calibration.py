"""Hold-logit calibration of a discrete student (research/calibration.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agents.ppo import resolve_model_path
from branch_gym.training.model_files import load_model
from research.calibration import calibration_path, main, shift_hold_logit


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from stable_baselines3 import PPO

    path = tmp_path_factory.mktemp("models") / "student.zip"
    PPO("MlpPolicy", "CartPole-v1", n_steps=8, batch_size=8, seed=0, device="cpu").save(path)
    return path


def _actions(path: Path) -> np.ndarray:
    observations = np.random.default_rng(0).normal(size=(64, 4)).astype(np.float32)
    return load_model(path).predict(observations, deterministic=True)[0]


def test_the_shift_moves_the_decision_toward_or_away_from_hold(source: Path, tmp_path: Path):
    eager = shift_hold_logit(source, -50.0, tmp_path / "eager.zip")
    calm = shift_hold_logit(source, 50.0, tmp_path / "calm.zip")
    assert (_actions(eager) != 0).all() and (_actions(calm) == 0).all()
    unchanged = shift_hold_logit(source, 0.0, tmp_path / "same.zip")
    np.testing.assert_array_equal(_actions(unchanged), _actions(source))
    provenance = json.loads(calibration_path(eager).read_text())
    assert provenance == {"source_model": str(source), "hold_logit_shift": -50.0}


def test_bad_calibration_requests_fail_clearly(source: Path, tmp_path: Path, capsys) -> None:
    with pytest.raises(ValueError, match="finite"):
        shift_hold_logit(source, float("nan"), tmp_path / "x.zip")
    with pytest.raises(ValueError, match="differ"):
        shift_hold_logit(source, 1.0, source)
    assert main([str(tmp_path / "missing.zip"), "--hold-logit-shift", "1", "--out", "x.zip"]) == 2
    assert "does not exist" in capsys.readouterr().err
    from stable_baselines3 import PPO

    continuous = tmp_path / "continuous.zip"
    PPO("MlpPolicy", "Pendulum-v1", n_steps=8, batch_size=8, device="cpu").save(continuous)
    with pytest.raises(ValueError, match="discrete"):
        shift_hold_logit(continuous, 1.0, tmp_path / "y.zip")


def test_return_too_makes_leaving_home_rarer_but_not_coming_back(tmp_path: Path) -> None:
    # A shipped discrete_hold student: action 0 holds, k >= 1 turns to DISCRETE_ANGLES_DEG[k - 1].
    from branch_gym.env.layout import DISCRETE_ANGLES_DEG

    home = 1 + DISCRETE_ANGLES_DEG.index(0.0)
    before = load_model(resolve_model_path("ppo_dagger_v2")).policy.action_net.bias.detach().numpy()
    out = shift_hold_logit("ppo_dagger_v2", 2.0, tmp_path / "calm.zip", return_too=True)
    after = load_model(out).policy.action_net.bias.detach().numpy()
    shifted = np.zeros_like(before)
    shifted[[0, home]] = 2.0  # hold and the turn back to 0: leaving is 2 logits less likely
    np.testing.assert_allclose(after - before, shifted, atol=1e-6)
    assert json.loads(calibration_path(out).read_text())["return_logit_shift"] == 2.0


def test_return_too_needs_a_discrete_hold_model(source: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="discrete_hold"):
        shift_hold_logit(source, 1.0, tmp_path / "z.zip", return_too=True)


def _logits_and_values(path: Path, price: float) -> tuple[np.ndarray, np.ndarray]:
    """Action logits (relative to the last action's) and values of 16 random observations."""
    import torch

    model = load_model(path)
    rng = np.random.default_rng(0)
    observation = {
        key: rng.uniform(space.low, space.high, size=(16, *space.shape)).astype(space.dtype)
        for key, space in model.observation_space.spaces.items()
    }
    observation["price"][:] = price
    tensors, _ = model.policy.obs_to_tensor(observation)
    with torch.no_grad():
        logits = model.policy.get_distribution(tensors).distribution.logits.numpy()
        values = model.policy.predict_values(tensors).numpy()
    return logits - logits[:, -1:], values


def test_a_top_price_shift_makes_one_network_of_two_thresholds(tmp_path: Path) -> None:
    # One sloped file answers the lowest price as the shift of 2 and the highest as that of -1,
    # and halfway between (the price feature 0.5: 100 s a branch) as their mean.
    sloped = shift_hold_logit(
        "ppo_dagger_v2", 2.0, tmp_path / "sloped.zip", return_too=True, top_price_shift=-1.0
    )
    for price, shift in ((0.0, 2.0), (0.5, 0.5), (1.0, -1.0)):
        fixed = shift_hold_logit("ppo_dagger_v2", shift, tmp_path / "f.zip", return_too=True)
        got, got_values = _logits_and_values(sloped, price)
        want, want_values = _logits_and_values(fixed, price)
        np.testing.assert_allclose(got, want, atol=1e-4)
        np.testing.assert_array_equal(got_values, want_values)
    assert json.loads(calibration_path(sloped).read_text())["top_price_shift"] == -1.0


def test_a_top_price_shift_needs_the_price_input(source: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="price"):
        shift_hold_logit(source, 1.0, tmp_path / "p.zip", top_price_shift=0.0)
    with pytest.raises(ValueError, match="finite"):
        shift_hold_logit("ppo_dagger_v2", 1.0, tmp_path / "q.zip", top_price_shift=float("inf"))
