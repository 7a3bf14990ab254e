"""Upkeep of model secondaries across views (issue 17: rotations cost found branches).

Trust: any frame that shows two of a branch's points changes it, by whether its projection lands
on the mask (the authors' rule; a detection joining the branch in that frame does not count). The
refit with ``secondary_order_from_junction``: observations ordered from the junction (a branch
extended toward the trunk by a later view folded, seed 16).
``secondary_trust_tolerance_px`` (4 px for a learned segmenter's masks): a model a few pixels
beside a thin learned mask keeps its trust (issue 32: rotated views from pixels deleted found
branches).
"""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import camera_following, rasterise_mask, straight_tube

from recon.camera import CameraIntrinsics, project_points
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.model import BranchModel
from recon.model3d.secondary import SecondaryBranches, SecondaryDetection

INTRINSICS = CameraIntrinsics.from_fov()
PRIMARY = straight_tube([0.0, 0.0, 0.30], [0.0, 0.0, 0.70], 0.006)
BRANCH = straight_tube([0.0, 0.0, 0.45], [0.03, 0.0, 0.55], 0.004)  # steep: 10 cm tall
MARGIN_PX = ModelerConfig().image_margin_px


def _frame(camera_height_m: float, tubes: list) -> Frame:
    pose = camera_following(PRIMARY, camera_height_m)
    rgb = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    return Frame(rgb, rasterise_mask(tubes, pose, INTRINSICS), pose, INTRINSICS)


def _in_view(camera_height_m: float) -> float:
    pose = camera_following(PRIMARY, camera_height_m)
    pixels, _ = project_points(BRANCH.points, pose, INTRINSICS)
    return float(INTRINSICS.in_image(pixels, MARGIN_PX).mean())


def _trust_after(camera_height_m: float, config: ModelerConfig, mask_tubes=(PRIMARY,)) -> int:
    """Trust change of the branch in one frame whose mask draws ``mask_tubes`` (by default the
    primary only: the branch's projection lands off the mask wherever it is in view)."""
    branches = SecondaryBranches(config, np.random.default_rng(0))
    primary = BranchModel(PRIMARY.points[::10], PRIMARY.radii[::10])
    detection = SecondaryDetection(BRANCH.points[5::10], np.full(len(BRANCH.points[5::10]), 0.004))
    assert branches.add_detections([detection], primary) == 1
    (branch,) = branches._branches
    before = branch.trust
    branches.update_trust(_frame(camera_height_m, list(mask_tubes)))
    return branch.trust - before


def test_a_frame_showing_most_of_the_branch_off_the_mask_lowers_its_trust() -> None:
    assert _in_view(0.50) == 1.0
    assert _trust_after(0.50, ModelerConfig()) == -1


def test_a_frame_showing_only_its_end_at_the_border_leaves_the_trust_alone() -> None:
    assert 0.05 < _in_view(0.58) < 0.5  # the branch's top fifth, at the image's bottom edge
    # any two points in view count the frame
    assert _trust_after(0.58, ModelerConfig()) == -1


def _trust_changes_redetected_then_not(config: ModelerConfig) -> list[int]:
    """Trust changes over two frames whose masks miss the branch's model: in the first a
    detection joins the branch, in the second none does."""
    branches = SecondaryBranches(config, np.random.default_rng(0))
    primary = BranchModel(PRIMARY.points[::10], PRIMARY.radii[::10])
    detection = SecondaryDetection(BRANCH.points[5::10], np.full(len(BRANCH.points[5::10]), 0.004))
    assert branches.add_detections([detection], primary) == 1
    (branch,) = branches._branches
    changes = []
    for detections in ([detection], []):
        before = branch.trust
        assert branches.add_detections(detections, primary) == 0
        branches.update_trust(_frame(0.50, [PRIMARY]))
        changes.append(branch.trust - before)
    return changes


def test_a_branch_redetected_in_the_frame_loses_trust_where_its_model_misses_the_mask() -> None:
    assert _trust_changes_redetected_then_not(ModelerConfig()) == [-1, -1]  # authors' rule


def _trust_change_beside_a_thin_mask(offset_px: float, config: ModelerConfig) -> int:
    """Trust change of the branch's model in a frame whose mask draws the branch 1 mm thin and
    ``offset_px`` to the side of the model (a learned mask of a thin branch, a rotated view)."""
    pose = camera_following(PRIMARY, 0.50)
    middle = BRANCH.points[len(BRANCH.points) // 2]
    step_m = 1e-3
    moved = middle + np.array([step_m, 0.0, 0.0])
    (a, b), _ = project_points(np.array([middle, moved]), pose, INTRINSICS)
    shift = np.array([offset_px * step_m / np.linalg.norm(b - a), 0.0, 0.0])
    thin = straight_tube(BRANCH.points[0] + shift, BRANCH.points[-1] + shift, 0.001)
    return _trust_after(0.50, config, (PRIMARY, thin))


def test_the_trust_tolerance_keeps_a_branch_a_few_pixels_beside_a_learned_mask() -> None:
    exact = ModelerConfig().for_masks(learned=False)
    learned = ModelerConfig().for_masks(learned=True)
    assert exact.secondary_trust_tolerance_px == 0.0
    assert learned.secondary_trust_tolerance_px == ModelerConfig().consistency_tolerance_px
    assert _trust_change_beside_a_thin_mask(0.0, exact) == 1  # on the mask: supported
    assert _trust_change_beside_a_thin_mask(3.0, exact) == -1  # 3 px off: the authors' rule
    assert _trust_change_beside_a_thin_mask(3.0, learned) == 1
    assert _trust_change_beside_a_thin_mask(8.0, learned) == -1  # farther than 4 px


def test_a_set_trust_tolerance_is_kept_and_a_negative_one_refused() -> None:
    set_one = ModelerConfig(secondary_trust_tolerance_px=2.0)
    assert set_one.for_masks(learned=True).secondary_trust_tolerance_px == 2.0
    assert (
        ModelerConfig(secondary_trust_tolerance_px=0.0)
        .for_masks(learned=True)
        .secondary_trust_tolerance_px
        == 0.0
    )
    both = ModelerConfig(secondary_trust_tolerance_px=0.0, secondary_min_reach_m=0.0)
    assert both.for_masks(learned=True) is both
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="secondary_trust_tolerance_px"):
            ModelerConfig(secondary_trust_tolerance_px=bad)


def _refit_after_inward_extension(config: ModelerConfig) -> float:
    """Median distance (m) of the model to the branch after a detection of its outer part (from
    5 cm out) was extended toward the trunk by later, denser ones (views from another side)."""
    junction = np.array([0.0, 0.0, 0.45])
    along = np.linspace(0.0, 0.08, 161)[:, None]
    truth = junction + along * np.array([0.6, -0.8, 0.0]) + along**2 * np.array([0.0, 0.0, 2.0])
    rng = np.random.default_rng(0)
    outer = truth[100::3] + rng.normal(0.0, 0.001, truth[100::3].shape)
    inner = np.concatenate([truth[5:100:2]] * 3)
    inner += rng.normal(0.0, 0.001, inner.shape)
    branches = SecondaryBranches(config, np.random.default_rng(0))
    primary = BranchModel(PRIMARY.points[::10], PRIMARY.radii[::10])
    assert branches.add_detections([SecondaryDetection(outer, np.full(len(outer), 0.004))], primary)
    (branch,) = branches._branches
    branch.junction = junction  # where its ray back met the primary
    branches._merge_observations(branch, inner, np.full(len(inner), 0.004))
    model = branch.model.points[branch.n_extension :]
    return float(np.median(np.min(np.linalg.norm(model[:, None] - truth[None], axis=2), axis=1)))


def test_observations_ordered_from_the_junction_keep_an_extended_branch_on_itself() -> None:
    """Ordered from the first detection's first point (mid-branch by now), inner and outer
    observations interleave and the cubic folds; from the junction, the fit follows the branch."""
    assert _refit_after_inward_extension(ModelerConfig(secondary_order_from_junction=False)) > 0.01
    assert _refit_after_inward_extension(ModelerConfig(secondary_order_from_junction=True)) < 0.002
