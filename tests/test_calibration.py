"""Hold-logit calibration of a discrete student (research/calibration.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agents.ppo import load_model, resolve_model_path
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
