"""The 2D-junction connection of a side branch whose tip alone is lifted (issue 13).

A branch approaching the camera almost along the optical axis covers the primary in the mask; only
its tip leaves the silhouette and lifts, and a few points there give no usable direction for the
3D connection test. Its 2D candidate still says where it leaves the primary: the branch connects
there when the straight run from that junction to the lifted tip lies on the mask.
"""

from __future__ import annotations

import numpy as np
from synthetic import camera_following, rasterise_mask, straight_tube

from recon.camera import CameraIntrinsics, project_points
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.model import BranchModel
from recon.model3d.secondary import SecondaryBranches, SecondaryDetection

INTRINSICS = CameraIntrinsics.from_fov()
PRIMARY = straight_tube([0.0, 0.0, 0.30], [0.0, 0.0, 0.60], 0.006)
JUNCTION = np.array([0.0, 0.0, 0.45])
TIP = JUNCTION + 0.06 * np.array([0.12, -0.97, 0.21])  # 7 deg off the optical axis, toward it
BRANCH = straight_tube(JUNCTION, TIP, 0.004)
POSE = camera_following(PRIMARY, 0.44)


def _tip_detection(
    junction_px: np.ndarray | None, offset_m: np.ndarray | None = None
) -> SecondaryDetection:
    """Four points over the last 5 mm of the branch, ordered sideways: a useless direction."""
    along = TIP - JUNCTION
    offset_m = np.zeros(3) if offset_m is None else offset_m
    tip_points = JUNCTION + offset_m + np.outer([0.92, 0.94, 0.96, 0.98], along)
    tip_points += np.outer([0.0, 0.003, 0.006, 0.009], [1.0, 0.0, -0.3])  # sideways drift
    return SecondaryDetection(tip_points, np.full(4, 0.004), junction_px)


def _frame(tubes: list) -> Frame:
    rgb = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    return Frame(rgb, rasterise_mask(tubes, POSE, INTRINSICS), POSE, INTRINSICS)


def _junction_px() -> np.ndarray:
    return project_points(JUNCTION[None], POSE, INTRINSICS)[0][0]


def _branches() -> tuple[SecondaryBranches, BranchModel]:
    primary = BranchModel(PRIMARY.points[::10], PRIMARY.radii[::10])
    return SecondaryBranches(ModelerConfig(), np.random.default_rng(0)), primary


def test_the_tip_of_an_approaching_branch_fails_the_3d_connection_test() -> None:
    branches, primary = _branches()
    detection = _tip_detection(None)
    assert branches._junction(detection.points, primary.points) is None
    assert branches.add_detections([detection], primary, _frame([PRIMARY, BRANCH])) == 0


def test_it_connects_at_its_2d_junction() -> None:
    branches, primary = _branches()
    created = branches.add_detections(
        [_tip_detection(_junction_px())], primary, _frame([PRIMARY, BRANCH])
    )
    assert created == 1
    (model,) = branches.models()
    assert np.linalg.norm(model.points[0] - JUNCTION) < 0.01  # reported from the junction
    assert np.linalg.norm(model.points[-1] - TIP) < 0.01


def test_a_tip_whose_run_to_the_junction_is_off_the_mask_is_not_connected() -> None:
    """Lifted points on a blob beside the primary (the run crosses background) stay out."""
    branches, primary = _branches()
    offset = np.array([0.04, 0.0, 0.0])
    blob = straight_tube(TIP + offset - [0.0, 0.0, 0.004], TIP + offset + [0, 0, 0.004], 0.004)
    frame = _frame([PRIMARY, blob])
    detection = _tip_detection(_junction_px(), offset)
    assert branches.add_detections([detection], primary, frame) == 0


def test_a_2d_junction_away_from_the_primary_is_not_used() -> None:
    branches, primary = _branches()
    far_px = _junction_px() + np.array([40.0, 0.0])
    frame = _frame([PRIMARY, BRANCH])
    assert branches.add_detections([_tip_detection(far_px)], primary, frame) == 0
