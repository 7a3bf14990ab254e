"""The modeler on synthetic scans along known trees (no renderer: analytic masks and tracks)."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import (
    AnalyticTracker,
    bezier_tube,
    camera_following,
    side_branch,
    synthetic_frames,
    tree_truth,
)

from recon.camera import CameraIntrinsics, make_pose
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.metrics import evaluate
from recon.modeler import Modeler, Outcome

INTRINSICS = CameraIntrinsics.from_fov()
PRIMARY = bezier_tube(
    [[0, 0, 0], [0.01, 0.0, 0.33], [0.04, 0.02, 0.66], [0.05, 0.03, 1.0]], radius_m=0.005
)
SECONDARIES = [
    side_branch(PRIMARY, 0.40, yaw_deg=0, length_m=0.10, radius_m=0.004),
    side_branch(PRIMARY, 0.46, yaw_deg=160, length_m=0.10, radius_m=0.004),
]
TUBES = [PRIMARY, *SECONDARIES]


def _scan(modeler: Modeler, tubes, heights) -> list:
    reports = []
    for h in heights:
        frame = synthetic_frames(tubes, [camera_following(PRIMARY, h)], INTRINSICS)[0]
        report = modeler.update(frame)
        if report is not None:
            reports.append(report)
    return reports


@pytest.fixture(scope="module")
def scanned() -> tuple[Modeler, list]:
    modeler = Modeler(AnalyticTracker(TUBES))
    return modeler, _scan(modeler, TUBES, np.arange(0.30, 0.52, 0.001))


def test_scan_reconstructs_primary_and_secondaries(scanned) -> None:
    modeler, reports = scanned
    assert all(r.outcome is Outcome.CONSISTENT for r in reports)
    metrics = evaluate(modeler.model, tree_truth(PRIMARY, SECONDARIES), scanned_top_z_m=0.52)
    assert metrics.pb_residual_mean_m < 0.001  # issue asks 3 mm; exact tracks give ~0.1 mm
    assert metrics.pb_radius_rmse_m < 0.0005
    assert metrics.n_matched == 2
    assert metrics.n_spurious == 0
    assert metrics.n_duplicates == 0
    assert metrics.sb_residual_mean_m < 0.005
    assert np.all(np.isfinite(modeler.model.primary.points))


def test_iterations_every_10mm_with_8_frames(scanned) -> None:
    _, reports = scanned
    # 220 mm of motion, the first iteration after 7 mm (8 frames 1 mm apart), then every 10 mm.
    assert len(reports) == 1 + int((220 - 1 - 7) / 10)
    stages = {"curve2d_ms", "consistency_ms", "tracking_ms", "triangulation_ms", "fit3d_ms"}
    assert stages <= reports[-1].timings_ms.keys()
    assert reports[-1].timings_ms["total_ms"] > 0


def test_noisy_tracks_stay_within_3mm() -> None:
    tracker = AnalyticTracker(TUBES, pixel_noise_px=0.3, rng=np.random.default_rng(1))
    modeler = Modeler(tracker, seed=3)
    _scan(modeler, TUBES, np.arange(0.30, 0.45, 0.001))
    metrics = evaluate(modeler.model, tree_truth(PRIMARY, SECONDARIES), scanned_top_z_m=0.45)
    assert metrics.pb_residual_mean_m < 0.003


_MOVED = bezier_tube(  # PRIMARY 4 cm sideways: masks of it disagree with a model of PRIMARY
    [[0.04, 0, 0], [0.05, 0.0, 0.33], [0.08, 0.02, 0.66], [0.09, 0.03, 1.0]], radius_m=0.005
)


def _model_then_moved_masks(hold_primary: bool) -> tuple[Modeler, list, float]:
    """Model PRIMARY, then feed masks of the moved branch until a restart (or 4 cm of them)."""
    modeler = Modeler(AnalyticTracker(TUBES))
    _scan(modeler, TUBES, np.arange(0.30, 0.36, 0.001))
    assert modeler.model.primary is not None
    modeler.hold_primary = hold_primary
    modeler.tracker = AnalyticTracker([_MOVED])
    outcomes, h = [], 0.0
    for h in np.arange(0.361, 0.40, 0.001):
        frame = synthetic_frames([_MOVED], [camera_following(PRIMARY, h)], INTRINSICS)[0]
        report = modeler.update(frame)
        if report is not None:
            outcomes.append(report.outcome)
        if report is not None and report.outcome is Outcome.RESTART:
            break
    return modeler, outcomes, h


def test_held_primary_is_never_restarted() -> None:
    """While the robot orbits (hold_primary), disagreeing masks never replace the model."""
    modeler, outcomes, _ = _model_then_moved_masks(hold_primary=True)
    assert len(outcomes) >= 3
    assert set(outcomes) == {Outcome.INCONSISTENT}
    points = modeler.model.primary.points  # still on PRIMARY, 4 cm from the moved branch
    x_primary = np.interp(points[:, 2], PRIMARY.points[:, 2], PRIMARY.points[:, 0])
    assert np.all(np.abs(points[:, 0] - x_primary) < 0.003)


def test_restart_after_three_inconsistent_masks() -> None:
    modeler, outcomes, h = _model_then_moved_masks(hold_primary=False)
    moved = _MOVED
    assert outcomes[:3] == [Outcome.INCONSISTENT, Outcome.INCONSISTENT, Outcome.RESTART]
    # After the restart the model in view (near the camera height) lies on the moved branch.
    points = modeler.model.primary.points
    visible = np.abs(points[:, 2] - h) < 0.04
    x_expected = np.interp(points[visible, 2], moved.points[:, 2], moved.points[:, 0])
    assert np.all(np.abs(points[visible, 0] - x_expected) < 0.003)


@pytest.mark.parametrize("kind", ["empty", "full", "one_pixel", "speckled"])
def test_bad_masks_are_inconsistent_never_nan(kind: str) -> None:
    rng = np.random.default_rng(0)
    shape = (INTRINSICS.height, INTRINSICS.width)
    masks = {
        "empty": np.zeros(shape, bool),
        "full": np.ones(shape, bool),
        "one_pixel": np.zeros(shape, bool),
        "speckled": rng.random(shape) < 0.05,
    }
    masks["one_pixel"][120, 160] = True
    modeler = Modeler(AnalyticTracker(TUBES))
    _scan(modeler, TUBES, np.arange(0.30, 0.33, 0.001))
    before = modeler.model.primary.points.copy()
    rgb = np.zeros((*shape, 3), np.uint8)
    reports = []
    for h in np.arange(0.331, 0.36, 0.001):
        frame = Frame(rgb, masks[kind], camera_following(PRIMARY, h), INTRINSICS)
        report = modeler.update(frame)
        if report is not None:
            reports.append(report)
    assert reports and all(r.outcome is not Outcome.CONSISTENT for r in reports)
    model = modeler.model
    assert model.primary is not None and np.all(np.isfinite(model.primary.points))
    if all(r.outcome is Outcome.INCONSISTENT for r in reports):
        np.testing.assert_array_equal(model.primary.points, before)


def test_bad_frames_raise_clear_errors() -> None:
    rgb = np.zeros((240, 320, 3), np.uint8)
    mask = np.zeros((240, 320), bool)
    pose = make_pose(np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="T_world_camera"):
        Frame(rgb, mask, np.full((4, 4), np.nan), INTRINSICS)
    with pytest.raises(ValueError, match="mask must have shape"):
        Frame(rgb, np.zeros((10, 10), bool), pose, INTRINSICS)
    with pytest.raises(ValueError, match="rgb must have shape"):
        Frame(rgb[:, :100], mask, pose, INTRINSICS)
    with pytest.raises(ValueError, match="not binary"):
        Frame(rgb, np.full((240, 320), 0.5), pose, INTRINSICS)
    with pytest.raises(ValueError, match="tracking_frames"):
        ModelerConfig(tracking_frames=1)
    with pytest.raises(ValueError, match="iteration_spacing_m"):
        ModelerConfig(iteration_spacing_m=-1.0)
    for turn in (0.0, 180.0, float("nan"), "30"):
        with pytest.raises(ValueError, match="primary_max_turn_deg"):
            ModelerConfig(primary_max_turn_deg=turn)


def test_lifted_branch_is_cut_at_an_implausible_depth_jump() -> None:
    from recon.modeler import _plausible_prefix

    focal = INTRINSICS.fx
    pixels = np.array([[170.0, 120.0], [200.0, 120.0], [230.0, 120.0], [260.0, 120.0]])
    depth = np.full(4, 0.2)
    # Parallel to the image plane: each 30 px step is 30 * 0.2 / f metres long in 3D.
    step = 30 * 0.2 / focal
    centers = np.array([[0.0, 0.0, 0.5], [step, 0, 0.5], [2 * step, 0, 0.5], [3 * step, 0, 0.5]])
    assert _plausible_prefix(centers, pixels, depth, focal, 3.0) == 4
    # The tip jumps 10 cm deeper: cut before it.
    far = centers.copy()
    far[3, 1] += 0.10
    assert _plausible_prefix(far, pixels, depth, focal, 3.0) == 3
    # A receding branch (2.5x longer than its image) is kept.
    receding = centers.copy()
    receding[:, 1] = np.arange(4) * step * 2.3
    assert _plausible_prefix(receding, pixels, depth, focal, 3.0) == 4
