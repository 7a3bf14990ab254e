"""Closed-loop scans in the simulator: follow controller + modeler + rotation (slow-ish)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.factory import AGENTS
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig, ScanSession
from branch_gym.scoring import score_scan

SHORT = ScanConfig(end_height_m=0.45)


@pytest.fixture(scope="module")
def session() -> ScanSession:
    s = ScanSession(SHORT)
    yield s
    s.close()


def _distance_to_primary(session: ScanSession) -> tuple[float, float]:
    """Horizontal camera-to-primary distance and the lateral offset in the image (m)."""
    T = session.world.T_world_camera
    axis = session.world.primary_point_at_height(T[2, 3], session.tree)
    rel = np.linalg.inv(T) @ np.append(axis, 1.0)
    return float(rel[2]), float(rel[0])


@pytest.mark.slow
def test_short_scan_reconstructs_primary_and_follows_it(session: ScanSession) -> None:
    session.reset(seed=3)
    depths, laterals = [], []
    while not session.done:
        session.step(0.0)
        depth, lateral = _distance_to_primary(session)
        depths.append(depth)
        laterals.append(lateral)
    assert session.stop_reason == "end_height"
    # The controller kept the branch at z_target (+ its radius: z is to the surface) and centred.
    radius = float(np.median(session.tree.primary.radii))
    assert np.max(np.abs(np.array(depths) - 0.20)) < 0.004 + radius
    assert np.max(np.abs(laterals)) < 0.005
    result = score_scan(session, "none")
    assert result.metrics.pb_residual_mean_m < 0.002
    assert result.metrics.pb_radius_rmse_m < 0.0005
    assert result.scan_time_s == pytest.approx((0.45 - 0.275) / 0.025, rel=0.05)
    assert result.rotations == 0


@pytest.mark.slow
def test_rotation_costs_time_and_returns_to_the_branch(session: ScanSession) -> None:
    session.reset(seed=3)
    session.step(0.0)
    t0, angle0 = session.scan_time_s, session.angle_deg
    step = session.step(22.5)
    assert step.rotated and session.rotations == 1
    assert session.angle_deg == pytest.approx(22.5, abs=0.5)
    heading = math.degrees(
        math.atan2(-session.world.T_world_camera[0, 2], session.world.T_world_camera[1, 2])
    )
    assert heading == pytest.approx(22.5, abs=1.0)
    # An arc of 22.5 deg at ~0.2 m radius at 2.5 cm/s takes ~3 s of scan time.
    assert session.scan_time_s - t0 > 0.9 * math.radians(22.5 - angle0) * 0.2 / 0.025
    depth, _ = _distance_to_primary(session)
    assert abs(depth - 0.20) < 0.015


@pytest.mark.slow
def test_same_seed_same_scan() -> None:
    a = run_trial(5, "periodic:45:2.5", SHORT, AGENTS).to_row()
    b = run_trial(5, "periodic:45:2.5", SHORT, AGENTS).to_row()
    for key in ("scan_time_s", "rotations", "n_iterations", "pb_residual_mean_m", "n_matched"):
        assert a[key] == b[key]


def test_bad_use_raises(session: ScanSession) -> None:
    with pytest.raises(ValueError, match="tracker"):
        ScanConfig(tracker="pips")
    with pytest.raises(ValueError, match="noisy"):
        ScanConfig(segmenter="perfect")
    with pytest.raises(ValueError, match="end_height_m"):
        ScanConfig(end_height_m=0.2)
    session.reset(seed=1)
    with pytest.raises(ValueError, match="finite"):
        session.step(float("nan"))
    session.done = True
    with pytest.raises(RuntimeError, match="scan is over"):
        session.step(0.0)
