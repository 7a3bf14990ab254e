"""The paper's rotation policies (agents/baselines.py) and their specs (agents/factory.py)."""

from __future__ import annotations

import numpy as np
import pytest

from agents.baselines import NoRotationAgent, PeriodicAgent, parse_periodic_spec
from agents.factory import check_spec
from branch_gym.env.layout import THETA_MAX_DEG, VECTOR_SIZE, VectorField
from branch_gym.policy import Policy


def _obs(angle_deg: float, travel_fov: float, started: bool = True) -> np.ndarray:
    vector = np.zeros(VECTOR_SIZE, np.float32)
    vector[VectorField.ANGLE] = angle_deg / THETA_MAX_DEG
    vector[VectorField.TRAVEL_FOV] = travel_fov
    vector[VectorField.OUTCOME_CONSISTENT] = 1.0 if started else 0.0
    return vector


def test_periodic_cycles_plus_zero_minus_zero_every_fov_over_frequency() -> None:
    agent = PeriodicAgent(22.5, 1.5)
    interval = 1 / 1.5
    action, _ = agent.predict(_obs(0.0, interval * 0.99), episode_start=True)
    assert float(action[0]) * THETA_MAX_DEG == 0.0
    targets, angle = [], 0.0
    for _ in range(5):
        action, _ = agent.predict(_obs(angle, interval))
        angle = float(action[0]) * THETA_MAX_DEG
        targets.append(angle)
        held, _ = agent.predict(_obs(angle, 0.01))  # between rotations nothing changes
        assert float(held[0]) * THETA_MAX_DEG == angle
    assert targets == [22.5, 0.0, -22.5, 0.0, 22.5]
    action, _ = agent.predict(_obs(0.0, interval), episode_start=True)  # a new episode
    assert float(action[0]) * THETA_MAX_DEG == 22.5


def test_none_never_rotates_and_both_satisfy_the_agent_protocol() -> None:
    agent = NoRotationAgent()
    action, _ = agent.predict(_obs(0.0, 10.0))
    assert float(action[0]) == 0.0
    assert isinstance(agent, Policy) and isinstance(PeriodicAgent(45, 2.5), Policy)


def test_periodic_specs_parse() -> None:
    assert parse_periodic_spec("periodic:45:2.5") == (45.0, 2.5)
    assert parse_periodic_spec("none") is None
    check_spec("none")
    check_spec("periodic:22.5:1.5")


@pytest.mark.parametrize(
    "spec", ["", "periodic", "periodic:x:1", "periodic:45", "spin:1:2", "none:1"]
)
def test_bad_specs_raise(spec: str) -> None:
    with pytest.raises(ValueError, match="policy spec"):
        check_spec(spec)


@pytest.mark.parametrize(("angle", "freq"), [(0, 1.5), (120, 1.5), (22.5, 0), (22.5, float("nan"))])
def test_bad_periodic_parameters_raise(angle: float, freq: float) -> None:
    with pytest.raises(ValueError, match="periodic rotation"):
        PeriodicAgent(angle, freq)
