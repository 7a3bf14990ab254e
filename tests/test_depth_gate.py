"""The primary's depth gate (issue 13): a branch approaching the camera over the primary must not
pull it forward, and a model that is off as a whole must still be corrected."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import camera_following, straight_tube

from recon.camera import CameraIntrinsics, project_points
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.model3d.primary import ProjectedModel
from recon.modeler import DepthGate, _depth_agrees

INTRINSICS = CameraIntrinsics.from_fov()
PRIMARY = straight_tube([0.0, 0.0, 0.35], [0.0, 0.0, 0.55], 0.006, n=9)
POSE = camera_following(PRIMARY, 0.45)  # 0.20 m in front, looking along +y


def _frame() -> Frame:
    shape = (INTRINSICS.height, INTRINSICS.width)
    return Frame(np.zeros((*shape, 3), np.uint8), np.zeros(shape, bool), POSE, INTRINSICS)


def _projected(model_points: np.ndarray) -> ProjectedModel:
    pixels, depth = project_points(model_points, POSE, INTRINSICS)
    visible = np.ones(len(model_points), bool)
    return ProjectedModel(pixels, depth, visible, visible.copy())


def _gate(lifted: np.ndarray, config: ModelerConfig | None = None) -> DepthGate:
    pixels, _ = project_points(lifted, POSE, INTRINSICS)
    return _depth_agrees(
        lifted, pixels, _projected(PRIMARY.points), _frame(), config or ModelerConfig()
    )


def test_points_on_a_branch_in_front_of_the_primary_are_dropped() -> None:
    """Two of nine samples lie 2 cm nearer the camera: a branch covering the trunk."""
    lifted = PRIMARY.points.copy()
    lifted[4:6, 1] -= 0.02
    keep, in_front = _gate(lifted)
    assert not keep[4:6].any() and keep[:4].all() and keep[6:].all()
    # ... and reported as evidence of something in front of the primary (the observation's)
    assert in_front[4:6].all() and not in_front[:4].any() and not in_front[6:].any()


def test_the_gate_behind_the_model_stays_at_the_paper_scale() -> None:
    lifted = PRIMARY.points.copy()
    lifted[4:6, 1] += 0.02  # 2 cm behind: within primary_depth_gate_m (3 cm)
    assert _gate(lifted).keep.all()
    lifted[4:6, 1] += 0.02  # 4 cm behind: dropped, not in front
    gate = _gate(lifted)
    assert not gate.keep[4:6].any() and not gate.in_front.any()


def test_a_model_off_as_a_whole_is_corrected() -> None:
    """Every new point 2 cm in front (a rotation shows the model is off): none is dropped."""
    lifted = PRIMARY.points.copy()
    lifted[:, 1] -= 0.02
    gate = _gate(lifted)
    assert gate.keep.all() and not gate.in_front.any()


def test_beyond_the_model_a_step_toward_the_camera_cuts_the_primary() -> None:
    """The model covers the lower half; above it the samples climb onto a near branch."""
    model = PRIMARY.points[:5]
    lifted = PRIMARY.points.copy()
    lifted[6:, 1] -= 0.02  # a 2 cm step toward the camera after sample 5
    pixels, _ = project_points(lifted, POSE, INTRINSICS)
    keep, _ = _depth_agrees(lifted, pixels, _projected(model), _frame(), ModelerConfig())
    assert keep[:6].all() and not keep[6:].any()


def test_without_a_front_gate_the_near_branch_is_kept() -> None:
    lifted = PRIMARY.points.copy()
    lifted[4:6, 1] -= 0.02
    assert _gate(lifted, ModelerConfig(primary_front_depth_gate_m=0.0)).keep.all()


def test_bad_gate_and_junction_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="primary_front_depth_gate_m"):
        ModelerConfig(primary_front_depth_gate_m=-0.01)
    with pytest.raises(ValueError, match="secondary_junction_on_mask"):
        ModelerConfig(secondary_junction_on_mask=1.5)
    with pytest.raises(ValueError, match="secondary_junction_px"):
        ModelerConfig(secondary_junction_px=0.0)
