"""Procedural tree generator: ranges, determinism, JSON round trip, validation, clutter."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.generator import generate_tree, sample_primary_bezier, tree_from_seed
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT

N_SEEDS = 200
SLACK = 1e-9  # float tolerance on range checks


def _trees(config: TreeConfig, n: int = N_SEEDS) -> list[TreeGT]:
    return [tree_from_seed(seed, config) for seed in range(n)]


def _height_point(branch: BranchGT, height_m: float) -> tuple[np.ndarray, float]:
    """Centerline point and radius where a bottom-to-top branch crosses height_m."""
    z = branch.points[:, 2]
    point = np.array([np.interp(height_m, z, branch.points[:, k]) for k in range(3)])
    return point, float(np.interp(height_m, z, branch.radii))


def _elevation_deg(vector: np.ndarray) -> float:
    return math.degrees(math.asin(vector[2] / np.linalg.norm(vector)))


@pytest.fixture(scope="module")
def paper_trees() -> list[TreeGT]:
    return _trees(TreeConfig.paper())


def test_primary_spans_ground_to_top_densely(paper_trees: list[TreeGT]) -> None:
    for tree in paper_trees:
        points = tree.primary.points
        assert points[0, 2] == pytest.approx(0.0, abs=SLACK)
        assert points[-1, 2] == pytest.approx(1.0, abs=SLACK)
        assert np.all(np.diff(points[:, 2]) > 0), "primary must run bottom -> top"
        spacing = np.linalg.norm(np.diff(points, axis=0), axis=1)
        assert spacing.max() <= 0.001 + SLACK


def test_primary_placement_and_top_offset(paper_trees: list[TreeGT]) -> None:
    jitters = []
    for tree in paper_trees:
        at_scan_start, _ = _height_point(tree.primary, 0.275)
        assert at_scan_start[0] == pytest.approx(0.0, abs=1e-6)
        assert -0.02 - SLACK <= at_scan_start[1] <= 0.02 + SLACK
        jitters.append(at_scan_start[1])
        top_offset = tree.primary.points[-1, :2] - tree.primary.points[0, :2]
        assert np.all(np.abs(top_offset) <= 0.10 + SLACK)
    assert np.std(jitters) > 0.005, "the y jitter must actually vary"


def test_primary_radius_at_scan_band_and_taper(paper_trees: list[TreeGT]) -> None:
    radii = [_height_point(tree.primary, 0.5)[1] for tree in paper_trees]
    assert min(radii) >= 0.003 - SLACK and max(radii) <= 0.0075 + SLACK
    assert max(radii) - min(radii) > 0.003, "radius must span most of U(3, 7.5) mm"
    for tree in paper_trees[:20]:
        assert np.all(np.diff(tree.primary.radii) < 0), "default taper: thinner going up"


def test_constant_radius_without_taper() -> None:
    config = replace(TreeConfig(), primary_taper_per_m=0.0, secondary_tip_radius_fraction=1.0)
    for tree in _trees(config, 20):
        for branch in [tree.primary, *tree.secondaries]:
            assert np.ptp(branch.radii) == pytest.approx(0.0, abs=1e-15)


def test_primary_control_points_tilt_and_handle_length() -> None:
    config = TreeConfig()
    rng = np.random.default_rng(7)
    max_tilt = 0.0
    for _ in range(500):
        control = sample_primary_bezier(config, rng)
        axis = control[3] - control[0]
        length = np.linalg.norm(axis)
        for handle in (control[1] - control[0], control[3] - control[2]):
            handle_length = np.linalg.norm(handle)
            assert handle_length <= 0.5 * length + SLACK
            if handle_length > 1e-6:
                cos_tilt = handle @ axis / (handle_length * length)
                max_tilt = max(max_tilt, math.degrees(math.acos(min(cos_tilt, 1.0))))
    assert 25.0 < max_tilt <= 30.0 + 1e-6


def test_secondary_ranges(paper_trees: list[TreeGT]) -> None:
    counts = [len(tree.secondaries) for tree in paper_trees]
    assert min(counts) == 0 and max(counts) == 5
    elevations, lengths = [], []
    for tree in paper_trees:
        for branch in tree.secondaries:
            base = branch.points[0]
            assert 0.325 - SLACK <= base[2] <= 0.75 + SLACK
            on_primary, primary_radius = _height_point(tree.primary, base[2])
            assert np.linalg.norm(base - on_primary) < 1e-6, "secondary starts on the primary"
            assert 0.8 * primary_radius - SLACK <= branch.radii[0] <= primary_radius + SLACK
            assert branch.radii[-1] == pytest.approx(0.8 * branch.radii[0])
            elevations.append(_elevation_deg(branch.points[1] - branch.points[0]))
            lengths.append(branch.length_m)
            assert np.linalg.norm(np.diff(branch.points, axis=0), axis=1).max() <= 0.001 + SLACK
            tip_elevation = _elevation_deg(branch.points[-1] - branch.points[-2])
            assert tip_elevation >= elevations[-1] - 1e-6, "bending is upward only"
    assert min(elevations) >= -15 - 1e-6 and max(elevations) <= 45 + 1e-6
    assert min(elevations) < -10 and max(elevations) > 40
    assert min(lengths) >= 0.05 - 1e-6 and max(lengths) <= 0.15 + 1e-6
    assert min(lengths) < 0.06 and max(lengths) > 0.14


def test_close_bases_share_height_with_even_yaw() -> None:
    config = replace(TreeConfig(), secondary_count_range=(5, 5))
    seen_shared = False
    for tree in _trees(config, 50):
        heights = np.array([b.points[0, 2] for b in tree.secondaries])
        unique = np.unique(heights)
        assert np.all(np.diff(unique) >= 0.05), "distinct base heights are >= 5 cm apart"
        for height in unique:
            group = [b for b, z in zip(tree.secondaries, heights, strict=True) if z == height]
            yaws = sorted(
                math.degrees(
                    math.atan2(b.points[1, 1] - b.points[0, 1], b.points[1, 0] - b.points[0, 0])
                )
                % 360.0
                for b in group
            )
            if len(group) > 1:
                seen_shared = True
                gaps = np.diff([*yaws, yaws[0] + 360.0])
                np.testing.assert_allclose(gaps, 360.0 / len(group), atol=1e-6)
    assert seen_shared


@pytest.mark.parametrize(
    ("yaw_mode", "center_deg"), [("toward_camera", 270.0), ("away_from_camera", 90.0)]
)
def test_yaw_modes_point_at_or_away_from_camera(yaw_mode: str, center_deg: float) -> None:
    # One secondary per tree: no height group, so its yaw is the mode's yaw (+- spread).
    config = replace(
        TreeConfig(), yaw_mode=yaw_mode, yaw_spread_deg=20.0, secondary_count_range=(1, 1)
    )
    for tree in _trees(config, 50):
        step = tree.secondaries[0].points[1] - tree.secondaries[0].points[0]
        yaw = math.degrees(math.atan2(step[1], step[0])) % 360.0
        assert abs((yaw - center_deg + 180.0) % 360.0 - 180.0) <= 20.0 + 1e-6


def test_same_seed_same_tree_different_seed_different_tree() -> None:
    config = TreeConfig.hard()
    assert tree_from_seed(11, config) == tree_from_seed(11, config)
    assert generate_tree(config, np.random.default_rng(3)) == generate_tree(
        config, np.random.default_rng(3)
    )
    first, second = tree_from_seed(11, config), tree_from_seed(12, config)
    assert first != second
    assert not np.allclose(first.primary.points[-1], second.primary.points[-1])


def test_json_round_trip_is_exact(tmp_path) -> None:
    tree = tree_from_seed(5, TreeConfig.hard())
    path = tmp_path / "tree.json"
    tree.save_json(path)
    loaded = TreeGT.load_json(path)
    assert loaded == tree
    assert loaded.seed == 5
    assert len(loaded.clutter) == len(tree.clutter) > 0
    assert TreeGT.from_dict(tree.to_dict()) == tree


def test_config_dict_round_trip() -> None:
    config = TreeConfig.hard()
    assert TreeConfig.from_dict(config.to_dict()) == config


def test_clutter_off_by_default_and_behind_the_tree() -> None:
    assert all(not tree.clutter for tree in _trees(TreeConfig(), 20))
    config = TreeConfig.cluttered()
    for tree in _trees(config, 30):
        scanned_back = max(b.points[:, 1].max() for b in [tree.primary, *tree.secondaries])
        assert len(tree.clutter) >= 1 + len(config.trellis_wire_heights_m)
        for branch in tree.clutter:
            assert branch.points[:, 1].min() >= scanned_back + 0.3 - 1e-9
        wires = tree.clutter[-2:]
        for wire, height in zip(wires, config.trellis_wire_heights_m, strict=True):
            assert np.all(wire.points[:, 2] == height)
            assert np.all(wire.radii == config.trellis_wire_radius_m)


def test_hard_preset_has_more_and_thinner_secondaries() -> None:
    paper = _trees(TreeConfig.paper(), 50)
    hard = _trees(TreeConfig.hard(), 50)
    assert np.mean([len(t.secondaries) for t in hard]) > np.mean(
        [len(t.secondaries) for t in paper]
    )
    ratio = [
        b.radii[0] / _height_point(t.primary, b.points[0, 2])[1]
        for t in hard
        for b in t.secondaries
    ]
    assert min(ratio) >= 0.4 - 1e-9 and max(ratio) <= 0.8 + 1e-9


@pytest.mark.parametrize(
    ("field_name", "value"),
    [
        ("primary_radius_range_m", (-0.003, 0.0075)),
        ("primary_radius_range_m", (0.0075, 0.003)),
        ("secondary_count_range", (-1, 5)),
        ("secondary_count_range", (3, 2)),
        ("secondary_count_range", (0, 1.5)),
        ("secondary_length_range_m", (0.15, 0.05)),
        ("secondary_elevation_range_deg", (-100.0, 45.0)),
        ("secondary_base_height_range_m", (0.325, 1.5)),
        ("primary_max_tilt_deg", 95.0),
        ("primary_taper_per_m", -0.1),
        ("secondary_tip_radius_fraction", 0.0),
        ("centerline_spacing_m", 0.0),
        ("background_tree_count_range", (-2, 1)),
        ("trellis_wire_heights_m", (0.5, -0.1)),
        ("trellis_wire_radius_m", -0.001),
        ("yaw_mode", "sideways"),
        ("placement_jitter_y_range_m", (0.02, float("nan"))),
    ],
)
def test_invalid_config_names_the_field(field_name: str, value: object) -> None:
    with pytest.raises(ValueError, match=field_name):
        TreeConfig(**{field_name: value})


def test_branch_gt_rejects_bad_shapes() -> None:
    with pytest.raises(ValueError, match="points"):
        BranchGT(np.zeros((5, 2)), np.ones(5))
    with pytest.raises(ValueError, match="radii"):
        BranchGT(np.zeros((5, 3)), np.ones(4))
    with pytest.raises(ValueError, match="positive"):
        BranchGT(np.zeros((5, 3)), np.zeros(5))
