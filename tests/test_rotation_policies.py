"""Rotation policies (agents/rotation.py)."""

from __future__ import annotations

import pytest

from agents.rotation import NoRotation, PeriodicRotation, RotationState, make_policy


def _state(angle: float, travel: float) -> RotationState:
    return RotationState(angle_deg=angle, travel_since_rotation_m=travel, vertical_fov_m=0.115)


def test_periodic_cycles_plus_zero_minus_zero_every_fov_over_frequency() -> None:
    policy = make_policy("periodic:22.5:1.5")
    interval = 0.115 / 1.5
    assert policy.target_angle_deg(_state(0.0, interval * 0.99)) == 0.0
    targets, angle = [], 0.0
    for _ in range(5):
        angle = policy.target_angle_deg(_state(angle, interval))
        targets.append(angle)
        # Between rotations nothing changes.
        assert policy.target_angle_deg(_state(angle, 0.01)) == angle
    assert targets == [22.5, 0.0, -22.5, 0.0, 22.5]
    policy.reset()
    assert policy.target_angle_deg(_state(0.0, interval)) == 22.5


def test_none_never_rotates_and_specs_round_trip() -> None:
    assert isinstance(make_policy("none"), NoRotation)
    assert make_policy("none").target_angle_deg(_state(0.0, 10.0)) == 0.0
    assert make_policy("periodic:45:2.5").spec == "periodic:45:2.5"
    assert isinstance(make_policy("periodic:45:2.5"), PeriodicRotation)


@pytest.mark.parametrize(
    "spec", ["", "periodic", "periodic:x:1", "periodic:45", "spin:1:2", "none:1"]
)
def test_bad_specs_raise(spec: str) -> None:
    with pytest.raises(ValueError, match="rotation policy spec"):
        make_policy(spec)


@pytest.mark.parametrize(("angle", "freq"), [(0, 1.5), (120, 1.5), (22.5, 0), (22.5, float("nan"))])
def test_bad_periodic_parameters_raise(angle: float, freq: float) -> None:
    with pytest.raises(ValueError, match="periodic rotation"):
        PeriodicRotation(angle, freq)
