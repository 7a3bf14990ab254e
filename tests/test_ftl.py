"""The authors' branch-aware rotation (agents/ftl.py): targets, geometry, stages, specs."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from agents.factory import check_spec
from agents.ftl import FtlAgent, FtlConfig, parse_ftl_spec, pointing_angles_deg, stage_target_deg
from agents.paper import PAPER_TABLE_I, paper_column
from branch_gym.env.layout import VECTOR_SIZE, VectorField
from recon.camera import CameraIntrinsics
from recon.model import BranchModel, TreeModel

INTRINSICS = CameraIntrinsics.from_fov()
DISTANCE_M = 0.2  # z_target: the branch is this far in front of the camera


def camera_looking_along_y(height_m: float = 0.5) -> np.ndarray:
    """A camera at (0, -DISTANCE_M, height) looking along +y, image up = world up."""
    T = np.eye(4)
    T[:3, 0] = (1.0, 0.0, 0.0)  # image u: +x
    T[:3, 1] = (0.0, 0.0, -1.0)  # image v: down
    T[:3, 2] = (0.0, 1.0, 0.0)  # optical axis: +y
    T[:3, 3] = (0.0, -DISTANCE_M, height_m)
    return T


def side_branch(heading_to_camera_deg: float, height_m: float = 0.5) -> BranchModel:
    """A 6 cm side branch from the primary (at the origin) whose horizontal direction is the
    camera's direction (-y) turned counter-clockwise by ``heading_to_camera_deg``."""
    angle = math.radians(heading_to_camera_deg)
    direction = np.array([math.sin(angle), -math.cos(angle), 0.2])
    points = np.array([0.0, 0.0, height_m]) + np.linspace(0.0, 0.06, 7)[:, None] * direction
    return BranchModel(points, np.full(len(points), 0.004))


def model_with(*branches: BranchModel) -> TreeModel:
    primary = BranchModel(np.array([[0, 0, z] for z in np.linspace(0.3, 0.7, 9)]), np.full(9, 0.01))
    return TreeModel(primary, list(branches))


def test_stage_targets_avoid_branches_pointing_at_the_camera():
    theta = 22.5
    # No branch: the authors' cycle 0 (stage 0), +theta, 0, -theta.
    assert [stage_target_deg(s, theta, np.zeros(0)) for s in range(4)] == [0.0, theta, 0.0, -theta]
    # Stage 1 ([0, theta]) with a branch pointing where the default would look: the other end.
    assert stage_target_deg(1, theta, np.array([22.0])) == 0.0
    assert stage_target_deg(1, theta, np.array([3.0])) == theta
    # Middle stage, branches at -5 and +10: their midpoint (2.5) is 7.5 from both, the ends
    # -11.25 and 11.25 only 6.25 and 1.25.
    assert stage_target_deg(0, theta, np.array([10.0, -5.0])) == pytest.approx(2.5)
    # Outside the pointing window ([default - theta/2, default + theta]): ignored.
    assert stage_target_deg(1, theta, np.array([-20.0, 60.0])) == theta
    # A midpoint outside the stage's interval is no candidate: stage 3 is [-theta, 0].
    target = stage_target_deg(3, theta, np.array([-33.0, 0.0]))
    assert -theta <= target <= 0.0


def test_pointing_angles_follow_the_orbit_convention():
    T = camera_looking_along_y()
    model = model_with(side_branch(0.0), side_branch(30.0), side_branch(-60.0))
    angles = pointing_angles_deg(model, T, INTRINSICS, angle_deg=0.0)
    np.testing.assert_allclose(angles, [0.0, 30.0, -60.0], atol=1e-9)
    # The same view reached by an orbit of +10 deg: the angles are absolute orbit angles.
    np.testing.assert_allclose(
        pointing_angles_deg(model, T, INTRINSICS, angle_deg=10.0), [10.0, 40.0, -50.0], atol=1e-9
    )
    # A branch whose ends both lie outside the image is not considered.
    far_above = side_branch(0.0, height_m=1.5)
    assert len(pointing_angles_deg(model_with(far_above), T, INTRINSICS, 0.0)) == 0


def _session(model: TreeModel, height_m: float, angle_deg: float = 0.0) -> SimpleNamespace:
    return SimpleNamespace(
        model=model,
        camera_height_m=height_m,
        vertical_fov_m=INTRINSICS.vertical_fov_length_m(DISTANCE_M),
        world=SimpleNamespace(T_world_camera=camera_looking_along_y(height_m)),
        intrinsics=INTRINSICS,
        angle_deg=angle_deg,
    )


def _observation(started: bool = True) -> np.ndarray:
    vector = np.zeros(VECTOR_SIZE, np.float32)
    vector[VectorField.OUTCOME_CONSISTENT] = float(started)
    return vector


def test_agent_steps_a_stage_every_half_fov_over_frequency_and_avoids_the_branch():
    # A side branch pointing at the camera from +22.5 deg: where stage 1 would rotate to.
    session = _session(model_with(side_branch(22.5)), height_m=0.40)
    config = FtlConfig(angle_deg=22.5, pan_frequency=1.0)
    agent = FtlAgent(session, config)
    stage_m = config.stage_distance_fov * session.vertical_fov_m
    assert config.stage_distance_fov == 0.5

    def act(height_m: float) -> float:
        session.camera_height_m = height_m
        session.world.T_world_camera = camera_looking_along_y(height_m)
        action, _ = agent.predict(_observation())
        return float(action[0]) * agent.theta_max_deg

    assert act(0.40) == 0.0  # the reference: no stage yet
    assert act(0.40 + 0.9 * stage_m) == 0.0
    # Stage 1: the interval [0, 22.5] and the branch at 22.5 -> 0 (hold), not +22.5.
    session.model = model_with(side_branch(22.5, height_m=0.40 + 1.1 * stage_m))
    assert act(0.40 + 1.1 * stage_m) == 0.0
    # Stage 2 (middle) and 3 ([-22.5, 0]) with no branch in view: their defaults.
    session.model = model_with()
    assert act(0.40 + 2.2 * stage_m) == 0.0
    assert act(0.40 + 3.3 * stage_m) == -22.5
    # A new episode starts the cycle again, and waits for a model before counting travel.
    session.model = TreeModel()
    action, _ = agent.predict(_observation(started=False))
    assert float(action[0]) == 0.0
    session.camera_height_m += 5 * stage_m
    assert float(agent.predict(_observation())[0][0]) == 0.0


def test_specs_and_the_paper_columns():
    assert parse_ftl_spec("ftl:45:2") == FtlConfig(45.0, 2.0)
    assert parse_ftl_spec("periodic:45:2") is None
    for bad in ("ftl", "ftl:45", "ftl:a:1", "ftl:90:1", "ftl:22.5:0", "ftl:22.5:nan"):
        with pytest.raises(ValueError, match=r"ftl|angle|frequency"):
            check_spec(bad)
    # The authors' script ran pan_frequency 1 and 2 for the columns labelled 1.5 and 2.5.
    assert paper_column("ftl:22.5:1") is PAPER_TABLE_I[(22.5, 1.5)]
    assert paper_column("ftl:45:2") is PAPER_TABLE_I[(45.0, 2.5)]
    assert paper_column("ftl:22.5:1.5") is None
