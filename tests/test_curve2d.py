"""Tests for recon.curve2d (skeleton, fit) on synthetic masks with known centrelines."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from recon.curve2d.fit import fit_mask_curves, points_in_mask
from recon.curve2d.skeleton import SkeletonConfig, extract_skeleton, preprocess_mask
from recon.curve2d.types import Curve2D, Curve2DConfig, MaskCurves
from recon.geometry.bezier import CubicBezier

H, W = 240, 320
_PIXELS = np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1).reshape(-1, 2).astype(float)

# A curved primary leaving the image at the top and bottom, 21 px wide.
PRIMARY = CubicBezier(np.array([[150.0, 265.0], [190.0, 170.0], [125.0, 75.0], [172.0, -25.0]]))
PRIMARY_HALF_WIDTH = 10.5
SIDE_HALF_WIDTH = 6.5
SIDE_LENGTH = 75.0
# (curve parameter of the junction on the primary, direction angle in image coordinates)
SIDES = ((0.3, -20.0), (0.5, 215.0), (0.72, -40.0))


def _dense(curve: CubicBezier) -> np.ndarray:
    return curve.resample_by_arclength(0.25)[0]


def _tube(centreline: np.ndarray, half_width: float) -> np.ndarray:
    """(H, W) mask of pixel centres within ``half_width`` of a dense (N, 2) centreline."""
    dist = cKDTree(centreline).query(_PIXELS, distance_upper_bound=half_width + 1.0)[0]
    return (dist <= half_width).reshape(H, W)


def _segment(start: np.ndarray, angle_deg: float, length: float) -> np.ndarray:
    direction = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    return start + np.linspace(0.0, length, int(length * 4) + 1)[:, None] * direction


def _branch_mask() -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """Primary with three side branches; returns the mask and (junction, tip) per side."""
    mask = _tube(_dense(PRIMARY), PRIMARY_HALF_WIDTH)
    sides = []
    for t, angle in SIDES:
        junction = PRIMARY(np.array([t]))[0]
        segment = _segment(junction, angle, SIDE_LENGTH)
        mask |= _tube(segment, SIDE_HALF_WIDTH)
        sides.append((junction, segment[-1]))
    return mask, sides


@pytest.fixture(scope="module")
def branch() -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]], MaskCurves]:
    mask, sides = _branch_mask()
    return mask, sides, fit_mask_curves(mask)


def test_primary_follows_the_drawn_centreline(branch) -> None:
    _, _, result = branch
    primary = result.primary
    assert primary is not None
    dist = cKDTree(_dense(PRIMARY)).query(primary.curve(np.linspace(0.0, 1.0, 200)))[0]
    assert dist.max() < 2.0
    # It spans the view between the 10 px border bands, bottom to top.
    assert primary.samples_px[0, 1] > H - 10 - 3 and primary.samples_px[-1, 1] < 10 + 3
    assert np.all(np.diff(primary.samples_px[:, 1]) < 0)
    spacing = np.linalg.norm(np.diff(primary.samples_px, axis=0), axis=1)
    assert spacing.max() <= 30.0 + 1e-6 and spacing.min() > 25.0
    assert primary.inlier_fraction > 0.95 and not primary.inside_primary.any()


def test_primary_radii_match_the_drawn_half_width(branch) -> None:
    _, _, result = branch
    np.testing.assert_allclose(result.primary.radii_px, PRIMARY_HALF_WIDTH, atol=1.5)


def test_primary_score_counts_unique_inlier_rows(branch) -> None:
    _, _, result = branch
    graph = result.skeleton
    inliers = result.primary.curve.closest_params(graph.pixels_uv)[1] <= 4.0
    assert result.primary.score == len(np.unique(graph.pixels_uv[inliers, 1]))
    assert not result.search_truncated and result.paths_evaluated >= 1


def test_side_branches_are_found_with_their_directions(branch) -> None:
    _, sides, result = branch
    assert len(result.secondaries) == len(sides)
    for junction, tip in sides:
        ends = np.array([s.curve.control_points[-1] for s in result.secondaries])
        secondary = result.secondaries[int(np.argmin(np.linalg.norm(ends - tip, axis=1)))]
        start, end = secondary.samples_px[0], secondary.samples_px[-1]
        drawn = (tip - junction) / np.linalg.norm(tip - junction)
        fitted = (end - start) / np.linalg.norm(end - start)
        assert drawn @ fitted > np.cos(np.radians(15.0))
        assert np.linalg.norm(start - junction) < PRIMARY_HALF_WIDTH
        assert np.linalg.norm(end - tip) < SIDE_HALF_WIDTH + 4.0
        # Its first samples lie inside the primary's silhouette, the tip does not.
        assert secondary.inside_primary[0] and not secondary.inside_primary[-1]
        outside = secondary.radii_px[~secondary.inside_primary]
        np.testing.assert_allclose(np.median(outside), SIDE_HALF_WIDTH, atol=1.5)
        assert len(secondary.samples_px) >= 3 and secondary.length_px >= 20.0


def test_samples_lie_in_the_mask(branch) -> None:
    mask, _, result = branch
    for curve in [result.primary, *result.secondaries]:
        assert points_in_mask(mask, curve.samples_px).all()


def test_motion_direction_orients_the_primary() -> None:
    horizontal = _tube(_segment(np.array([-20.0, 110.0]), 5.0, 360.0), 9.0)
    right = fit_mask_curves(horizontal, motion_direction_uv=np.array([1.0, 0.0])).primary
    left = fit_mask_curves(horizontal, motion_direction_uv=np.array([-1.0, 0.0])).primary
    assert right is not None and left is not None
    assert np.all(np.diff(right.samples_px[:, 0]) > 0) and np.all(
        np.diff(left.samples_px[:, 0]) < 0
    )
    np.testing.assert_allclose(right.samples_px, left.samples_px[::-1], atol=0.5)
    config = Curve2DConfig(motion_direction_uv=(1.0, 0.0), score="projected_extent")
    assert fit_mask_curves(horizontal, config).primary.score > 250.0


def test_rotated_view_gives_the_rotated_curve(branch) -> None:
    mask, _, result = branch
    # Transpose the image: (u, v) -> (v, u); the scan direction "up" becomes "left".
    rotated = fit_mask_curves(mask.T, motion_direction_uv=np.array([-1.0, 0.0]))
    assert rotated.primary is not None and len(rotated.secondaries) == 3
    truth = _dense(PRIMARY)[:, ::-1]
    assert cKDTree(truth).query(rotated.primary.samples_px)[0].max() < 2.0
    np.testing.assert_allclose(
        rotated.primary.samples_px[[0, -1]], result.primary.samples_px[[0, -1], ::-1], atol=2.0
    )


def _speckle(density: float, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).random((H, W)) < density


@pytest.mark.parametrize(
    "mask",
    [
        np.zeros((H, W), dtype=bool),
        np.ones((H, W), dtype=np.uint8),
        np.pad(np.ones((1, 1), dtype=bool), ((100, H - 101), (50, W - 51))),
        _speckle(0.03),
        _speckle(0.3),
        _speckle(0.5),
    ],
    ids=["empty", "full", "one-pixel", "speckle-3%", "speckle-30%", "speckle-50%"],
)
def test_masks_without_a_branch_give_no_primary(mask: np.ndarray) -> None:
    result = fit_mask_curves(mask)
    assert result.primary is None and result.secondaries == []


def _vertical_trunk(half_width: float, top: int = 0, bottom: int = H, tilt_px: float = 8.0):
    """A straight trunk of ``half_width`` from row ``top`` to ``bottom``, leaning by
    ``tilt_px`` over the view's height, and its centreline."""
    rows = np.arange(top, bottom, 0.5)
    centre = np.stack([W / 2 + tilt_px * (rows / H - 0.5), rows], axis=1)
    return _tube(centre, half_width), centre


@pytest.mark.parametrize("half_width", [28.0, 33.0])
def test_a_thick_trunk_that_spans_the_view_is_the_primary(half_width: float) -> None:
    """A trunk close to the camera is wider than the elongation test allows (the view holds
    fewer than four of its diameters) and is still the branch to follow."""
    mask, centre = _vertical_trunk(half_width)
    result = fit_mask_curves(mask)
    assert result.primary is not None
    assert cKDTree(centre).query(result.primary.samples_px)[0].max() < 2.0
    narrow_only = Curve2DConfig(max_spanning_width=0.1)  # the elongation test alone
    assert fit_mask_curves(mask, narrow_only).primary is None


@pytest.mark.parametrize(
    ("half_width", "top", "bottom"),
    [(28.0, 60, 180), (110.0, 0, H)],
    ids=["thick-and-short", "wider-than-half-the-view"],
)
def test_thick_masks_that_do_not_span_the_view_or_fill_it_give_no_primary(
    half_width: float, top: int, bottom: int
) -> None:
    mask, _ = _vertical_trunk(half_width, top, bottom)
    assert fit_mask_curves(mask).primary is None


def test_branch_survives_speckle_noise() -> None:
    mask, _ = _branch_mask()
    result = fit_mask_curves(mask | _speckle(0.02, seed=1))
    assert result.primary is not None
    dist = cKDTree(_dense(PRIMARY)).query(result.primary.samples_px)[0]
    assert dist.max() < 2.5


@pytest.mark.parametrize(
    "mask",
    [np.full((H, W), 2, dtype=np.uint8), np.full((H, W), 0.5), np.zeros((H, W, 3), dtype=bool)],
    ids=["uint8-255", "float", "3d"],
)
def test_non_binary_masks_raise(mask: np.ndarray) -> None:
    with pytest.raises(ValueError, match="mask"):
        fit_mask_curves(mask)


def test_bad_configs_raise() -> None:
    with pytest.raises(ValueError, match="motion_direction_uv"):
        Curve2DConfig(motion_direction_uv=(0.0, 0.0))
    with pytest.raises(ValueError, match="inlier_threshold_px"):
        Curve2DConfig(inlier_threshold_px=0.0)
    with pytest.raises(ValueError, match="min_samples"):
        Curve2DConfig(min_samples=1)
    with pytest.raises(ValueError, match="border_px"):
        SkeletonConfig(border_px=-1)
    with pytest.raises(ValueError, match="method"):
        SkeletonConfig(method="thin")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="motion_direction_uv"):
        fit_mask_curves(np.zeros((H, W), bool), motion_direction_uv=np.array([np.nan, 1.0]))


def test_mesh_of_loops_terminates_with_truncated_search() -> None:
    mesh = np.zeros((H, W), dtype=np.uint8)
    for x in range(15, W - 10, 25):
        cv2.line(mesh, (x, 0), (x, H - 1), 1, 3)
    for y in range(15, H - 10, 25):
        cv2.line(mesh, (0, y), (W - 1, y), 1, 3)
    result = fit_mask_curves(mesh.astype(bool))  # returns: the search is bounded, not timed here
    assert result.search_truncated
    config = Curve2DConfig()
    assert result.paths_evaluated <= config.max_primary_paths + config.max_secondary_paths
    # The large skeleton goes through the rasterised inlier prefilter: the score is still exact.
    graph = result.skeleton
    assert len(graph.pixels_uv) > 1500
    inliers = result.primary.curve.closest_params(graph.pixels_uv)[1] <= 4.0
    assert result.primary.score == len(np.unique(graph.pixels_uv[inliers, 1]))


def test_preprocess_clears_border_and_fills_small_holes_only() -> None:
    mask = np.zeros((H, W), dtype=bool)
    mask[5:200, 40:140] = True
    mask[50:60, 60:70] = False  # 100 px hole: filled
    mask[100:130, 60:80] = False  # 600 px hole: kept
    clean = preprocess_mask(mask)
    assert not clean[:10].any() and clean[10:200, 40:140].sum() == 190 * 100 - 600
    assert not clean[100:130, 60:80].any()


def test_skeleton_graph_of_a_t_junction() -> None:
    mask = np.zeros((H, W), dtype=bool)
    mask[40:200, 150:161] = True  # vertical bar, 11 px wide
    mask[110:121, 60:160] = True  # arm to the left
    graph = extract_skeleton(mask)
    assert sorted(graph.node_kind) == ["endpoint"] * 3 + ["junction"]
    junction = graph.node_kind.index("junction")
    assert len(graph.incident_edges(junction)) == 3
    np.testing.assert_allclose(graph.node_uv[junction], [155.0, 115.0], atol=6.0)
    for edge in graph.edges:
        steps = np.abs(np.diff(edge.pixels_uv, axis=0)).max(axis=1)
        assert steps.max() <= 2  # a connected pixel path (node clusters may skip one pixel)
        np.testing.assert_allclose(np.median(edge.radii_px), 5.5, atol=1.0)
    assert len(graph.pixels_uv) == len(np.unique(graph.pixels_uv, axis=0))


def test_skeleton_graph_splits_a_pure_loop() -> None:
    ring = np.zeros((H, W), dtype=np.uint8)
    cv2.circle(ring, (160, 120), 60, 1, 9)
    graph = extract_skeleton(ring.astype(bool))
    assert graph.node_kind.count("loop") == 2 and len(graph.edges) == 2
    assert all(edge.start != edge.end for edge in graph.edges)
    length = sum(edge.length_px for edge in graph.edges)
    assert length == pytest.approx(2 * np.pi * 60, rel=0.1)
    assert fit_mask_curves(ring.astype(bool)).primary is not None  # one side of the ring


def test_medial_axis_method_also_finds_the_primary(branch) -> None:
    mask, _, _ = branch
    config = Curve2DConfig(skeleton=SkeletonConfig(method="medial_axis"))
    primary = fit_mask_curves(mask, config).primary
    assert primary is not None
    assert cKDTree(_dense(PRIMARY)).query(primary.samples_px)[0].max() < 2.5


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    bottom_u=st.floats(90.0, 230.0),
    top_shift=st.floats(-70.0, 70.0),
    bend=st.tuples(st.floats(-35.0, 35.0), st.floats(-35.0, 35.0)),
    half_width=st.floats(3.5, 13.0),
)
def test_random_smooth_branches_are_recovered(
    bottom_u: float, top_shift: float, bend: tuple[float, float], half_width: float
) -> None:
    top_u = bottom_u + top_shift
    control = np.array(
        [
            [bottom_u, H + 25.0],
            [bottom_u + (top_u - bottom_u) / 3 + bend[0], H * 2 / 3],
            [bottom_u + 2 * (top_u - bottom_u) / 3 + bend[1], H / 3],
            [top_u, -25.0],
        ]
    )
    truth = _dense(CubicBezier(control))
    mask = _tube(truth, half_width)
    result = fit_mask_curves(mask)
    primary = result.primary
    assert primary is not None
    samples = primary.samples_px
    assert np.all((samples >= 0) & (samples < [W, H]))
    assert points_in_mask(mask, samples).all()
    assert cKDTree(truth).query(primary.curve(np.linspace(0.0, 1.0, 100)))[0].max() < 2.5
    # Radii come from the distance transform at skeleton pixels (paper IV-B): integer-spaced
    # distances on a skeleton up to a pixel off-centre, so up to ~1 px short on wide branches.
    np.testing.assert_allclose(np.median(primary.radii_px), half_width, atol=1.25)
    assert samples[0, 1] - samples[-1, 1] > 0.9 * (H - 20)  # spans the view bottom to top


def test_medial_axis_is_deterministic_for_a_seed(branch) -> None:
    mask, _, _ = branch
    config = Curve2DConfig(skeleton=SkeletonConfig(method="medial_axis", medial_axis_seed=3))
    a, b = fit_mask_curves(mask, config), fit_mask_curves(mask, config)
    np.testing.assert_array_equal(a.skeleton.pixels_uv, b.skeleton.pixels_uv)
    np.testing.assert_array_equal(a.primary.samples_px, b.primary.samples_px)


def test_helpers_for_mask_and_skeleton_queries(branch) -> None:
    mask, _, result = branch
    samples = result.primary.samples_px
    query = np.vstack([samples, [[-5.0, 10.0], [W + 3.0, 10.0], [np.nan, 5.0], [5.0, 5.0]]])
    inside = points_in_mask(mask, query)
    np.testing.assert_array_equal(inside, [True] * len(samples) + [False] * 4)
    dist, index = result.skeleton.nearest_pixel(samples)
    assert np.all(dist < 2.0)
    np.testing.assert_allclose(result.skeleton.pixels_uv[index], samples, atol=2.0)


def test_curve2d_fills_sample_parameters_when_not_given(branch) -> None:
    _, _, result = branch
    primary = result.primary
    rebuilt = Curve2D(
        primary.curve,
        primary.samples_px,
        primary.radii_px,
        primary.score,
        primary.inlier_fraction,
        primary.pixel_path,
    )
    np.testing.assert_allclose(rebuilt.sample_t, primary.sample_t, atol=1e-6)
    assert not rebuilt.inside_primary.any()
