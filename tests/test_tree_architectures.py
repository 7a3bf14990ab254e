"""Orchard tree architectures (tall spindle, UFO) and the scanned tree's spurs, stubs and buds.

Also pins the paper's trees: adding architectures must not change them (within a micrometre:
another CPU's numpy may round the last bits differently, so no hashes of floats).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from branch_gym.sim.tree.config import ARCHITECTURES, TreeConfig
from branch_gym.sim.tree.details import (
    EVALUATION_MIN_HORIZONTAL_LENGTH_M,
    MAX_PARENT_RADIUS_FRACTION,
    DetailConfig,
    grow_details,
)
from branch_gym.sim.tree.generator import tree_from_seed
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT

N_SEEDS = 40
SLACK = 1e-9  # float tolerance on range checks
SPACING_M = 0.001  # dense ground-truth spacing
ON_CENTERLINE_M = 0.5 * SPACING_M + SLACK  # a base on a 1 mm polyline is this close to a vertex
# Largest angle (deg) of any primary segment from vertical in the near-straight presets.
NEARLY_VERTICAL_DEG = 10.0

# Summaries of tree_from_seed(seed, preset).to_dict() for the presets that existed before the
# architectures and details were added, made with that generator (commit f98e49e, via
# `git archive`): per branch its point count (exact), 9 evenly spaced points and radii, the
# centroid, mean radius and polyline length, rounded to 1e-7 m.
BEFORE_DETAILS = Path(__file__).parent / "data" / "tree_presets_reference.json"
# A changed generator moves points by millimetres; another CPU's rounding by ~1e-15 m.
SAME_TREE_ATOL_M = 1e-6
REFERENCE_SAMPLES = 9


def _trees(config: TreeConfig, n: int = N_SEEDS) -> list[TreeGT]:
    return [tree_from_seed(seed, config) for seed in range(n)]


def _radius_at_height(branch: BranchGT, height_m: float) -> float:
    return float(np.interp(height_m, branch.points[:, 2], branch.radii))


def _elevation_deg(vector: np.ndarray) -> float:
    return math.degrees(math.asin(vector[2] / np.linalg.norm(vector)))


def _max_angle_from_vertical_deg(branch: BranchGT) -> float:
    steps = np.diff(branch.points, axis=0)
    cos = steps[:, 2] / np.linalg.norm(steps, axis=1)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max())


def _only(kind: str) -> DetailConfig:
    """The orchard's details of one kind ("spur", "stub" or "bud"), the others off."""
    densities = {f"{name}_density_per_m": 0.0 for name in ("spur", "stub", "bud")}
    orchard = DetailConfig.orchard()
    densities[f"{kind}_density_per_m"] = getattr(orchard, f"{kind}_density_per_m")
    return replace(orchard, **densities)


def _with_details(tree: TreeGT, config: DetailConfig, seed: int) -> list[BranchGT]:
    return grow_details(tree, config, np.random.default_rng(seed))


def _parent(tree: TreeGT, detail: BranchGT) -> tuple[BranchGT, float]:
    """The branch whose centerline holds the detail's base, and the base's distance to it."""
    candidates = [tree.primary, *tree.secondaries]
    distances = [np.linalg.norm(b.points - detail.points[0], axis=1).min() for b in candidates]
    index = int(np.argmin(distances))
    return candidates[index], float(distances[index])


def _outside_length_m(detail: BranchGT) -> float:
    """Length of the tapering part (outside the parent), to within one point spacing."""
    steps = np.linalg.norm(np.diff(detail.points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    last_full = int(np.flatnonzero(detail.radii == detail.radii[0])[-1])
    return float(arc[-1] - arc[last_full])


# --- the paper's trees are unchanged ---


def _branch_summary(branch: dict) -> dict:
    """What the reference file keeps of one branch of ``TreeGT.to_dict()``."""
    points = np.asarray(branch["points"], float)
    radii = np.asarray(branch["radii"], float)
    index = np.linspace(0, len(points) - 1, REFERENCE_SAMPLES).round().astype(int)
    return {
        "n_points": len(points),
        "points": points[index],
        "radii": radii[index],
        "centroid": points.mean(axis=0),
        "mean_radius": radii.mean(),
        "length": np.linalg.norm(np.diff(points, axis=0), axis=1).sum(),
    }


def _assert_same_branches(got: list[dict], want: list[dict], where: str) -> None:
    assert len(got) == len(want), f"{where}: {len(got)} branches, {len(want)} before"
    for i, (branch, before) in enumerate(zip(got, want, strict=True)):
        summary = _branch_summary(branch)
        assert summary.pop("n_points") == before["n_points"], f"{where}[{i}] point count"
        for key, value in summary.items():
            np.testing.assert_allclose(
                value, before[key], rtol=0, atol=SAME_TREE_ATOL_M, err_msg=f"{where}[{i}].{key}"
            )


_BEFORE = json.loads(BEFORE_DETAILS.read_text())


@pytest.mark.parametrize("key", sorted(_BEFORE))
def test_existing_presets_generate_the_same_trees(key: str) -> None:
    preset, seed = key.split(":")
    data = tree_from_seed(int(seed), getattr(TreeConfig, preset)()).to_dict()
    assert "details" not in data, "a tree without details writes the old JSON"
    before = _BEFORE[key]
    assert data["seed"] == before["seed"]
    _assert_same_branches([data["primary"]], [before["primary"]], f"{key} primary")
    _assert_same_branches(data["secondaries"], before["secondaries"], f"{key} secondaries")
    _assert_same_branches(data.get("clutter", []), before["clutter"], f"{key} clutter")


def test_the_same_tree_check_sees_a_millimetre() -> None:
    """The comparison above is not vacuous: a primary moved by 1 mm fails it."""
    data = tree_from_seed(0, TreeConfig.paper()).to_dict()
    moved = dict(data["primary"], points=(np.asarray(data["primary"]["points"]) + 1e-3).tolist())
    with pytest.raises(AssertionError, match="primary"):
        _assert_same_branches([moved], [_BEFORE["paper:0"]["primary"]], "paper:0 primary")


def test_default_is_the_paper_architecture() -> None:
    config = TreeConfig()
    assert config == TreeConfig.paper()
    assert config.architecture == "paper" and config.primary_base_height_m == 0.0
    assert tree_from_seed(0).details == []
    assert set(ARCHITECTURES) == {"paper", "tall_spindle", "ufo"}
    for preset in (TreeConfig.tall_spindle(), TreeConfig.ufo()):
        assert TreeConfig.from_dict(preset.to_dict()) == preset


def test_old_config_dicts_still_load() -> None:
    data = TreeConfig.hard().to_dict()
    del data["architecture"], data["primary_base_height_m"]
    assert TreeConfig.from_dict(data) == TreeConfig.hard()


# --- the architectures ---


@pytest.fixture(scope="module")
def spindle_trees() -> list[TreeGT]:
    return _trees(TreeConfig.tall_spindle())


@pytest.fixture(scope="module")
def ufo_trees() -> list[TreeGT]:
    return _trees(TreeConfig.ufo())


def _check_secondaries(
    trees: list[TreeGT], config: TreeConfig
) -> tuple[list[int], list[float], list[float]]:
    """Checks every secondary against ``config``'s ranges; returns counts, ratios, elevations."""
    counts, ratios, elevations = [], [], []
    for tree in trees:
        counts.append(len(tree.secondaries))
        for branch in tree.secondaries:
            base = branch.points[0]
            low, high = config.secondary_base_height_range_m
            assert low - SLACK <= base[2] <= high + SLACK
            ratios.append(branch.radii[0] / _radius_at_height(tree.primary, base[2]))
            elevations.append(_elevation_deg(branch.points[1] - branch.points[0]))
            low, high = config.secondary_length_range_m
            assert low - 1e-6 <= branch.length_m <= high + 1e-6
    low, high = config.secondary_count_range
    assert min(counts) >= low and max(counts) <= high
    low, high = config.secondary_radius_scale_range
    assert min(ratios) >= low - 1e-6 and max(ratios) <= high + 1e-6
    low, high = config.secondary_elevation_range_deg
    assert min(elevations) >= low - 1e-6 and max(elevations) <= high + 1e-6
    return counts, ratios, elevations


def test_tall_spindle_leader_is_thick_straight_and_upright(spindle_trees: list[TreeGT]) -> None:
    radii = [_radius_at_height(t.primary, 0.5) for t in spindle_trees]
    assert min(radii) >= 0.008 - SLACK and max(radii) <= 0.014 + SLACK
    for tree in spindle_trees:
        assert tree.primary.points[0, 2] == pytest.approx(0.0, abs=SLACK)
        assert _max_angle_from_vertical_deg(tree.primary) < NEARLY_VERTICAL_DEG
        top_offset = tree.primary.points[-1, :2] - tree.primary.points[0, :2]
        assert np.all(np.abs(top_offset) <= 0.03 + SLACK)
        assert not tree.clutter


def test_tall_spindle_fruiting_branches(spindle_trees: list[TreeGT]) -> None:
    config = TreeConfig.tall_spindle()
    assert config.architecture == "tall_spindle"
    assert config.secondary_base_height_range_m == (0.325, 0.75), "inside the paper's scan band"
    counts, ratios, elevations = _check_secondaries(spindle_trees, config)
    assert min(counts) >= 3 and max(counts) <= 8 and max(counts) > min(counts)
    assert max(ratios) < 0.5 + 1e-6, "pruning keeps branches under half the leader"
    assert min(elevations) < -15 and max(elevations) > 10, "drooping to near horizontal"


def test_ufo_upright_starts_on_its_cordon(ufo_trees: list[TreeGT]) -> None:
    config = TreeConfig.ufo()
    assert config.architecture == "ufo" and config.primary_base_height_m == 0.15
    radii = [_radius_at_height(t.primary, 0.5) for t in ufo_trees]
    assert min(radii) >= 0.005 - SLACK and max(radii) <= 0.010 + SLACK
    for tree in ufo_trees:
        points = tree.primary.points
        assert points[0, 2] == pytest.approx(0.15, abs=SLACK)
        assert points[-1, 2] == pytest.approx(1.0, abs=SLACK)
        assert np.all(np.diff(points[:, 2]) > 0)
        assert _max_angle_from_vertical_deg(tree.primary) < NEARLY_VERTICAL_DEG
        at_scan_start = np.array([np.interp(0.275, points[:, 2], points[:, k]) for k in (0, 1)])
        assert at_scan_start[0] == pytest.approx(0.0, abs=1e-6), "placed like the paper's"


def test_ufo_lateral_shoots(ufo_trees: list[TreeGT]) -> None:
    counts, ratios, elevations = _check_secondaries(ufo_trees, TreeConfig.ufo())
    assert min(counts) >= 2 and max(counts) <= 5
    assert min(ratios) < 0.35 and max(ratios) > 0.55
    assert min(elevations) >= -1e-6 and max(elevations) > 50


# --- details ---


@pytest.fixture(scope="module")
def detail_trees() -> list[TreeGT]:
    """Trees of every architecture, with many secondaries to put details near their bases."""
    configs = [
        TreeConfig.paper(),
        TreeConfig.hard(),
        TreeConfig.tall_spindle(),
        TreeConfig.ufo(),
    ]
    return [tree_from_seed(seed, config) for config in configs for seed in range(8)]


def test_default_details_are_none_and_draw_nothing() -> None:
    tree = tree_from_seed(0, TreeConfig.tall_spindle())
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    assert DetailConfig() == DetailConfig() and DetailConfig().is_empty
    assert grow_details(tree, DetailConfig(), rng) == []
    assert rng.bit_generator.state == state


@pytest.mark.parametrize(
    ("kind", "radius_range", "radius_is_scale"),
    [
        ("spur", (0.0015, 0.0035), False),
        ("stub", (0.5, 0.9), True),
        ("bud", (0.001, 0.002), False),
    ],
)
def test_detail_shapes(
    detail_trees: list[TreeGT],
    kind: str,
    radius_range: tuple[float, float],
    radius_is_scale: bool,
) -> None:
    config = _only(kind)
    low_m, high_m = getattr(config, f"{kind}_length_range_m")
    tip_fraction = getattr(config, f"{kind}_tip_radius_fraction")
    n_details = 0
    for seed, tree in enumerate(detail_trees):
        for detail in _with_details(tree, config, seed):
            n_details += 1
            parent, distance_m = _parent(tree, detail)
            assert distance_m <= ON_CENTERLINE_M, "a detail starts on its parent's centerline"
            if kind == "bud":
                assert parent is not tree.primary, "buds grow on the secondaries"
            assert len(detail.points) >= 2 and np.all(detail.radii > 0)
            assert np.all(np.diff(detail.radii) <= SLACK), "tapering toward the tip"
            assert detail.radii[-1] == pytest.approx(tip_fraction * detail.radii[0])
            assert low_m - SLACK <= _outside_length_m(detail) <= high_m + SPACING_M + SLACK
            parent_radius_m = float(
                parent.radii[np.argmin(np.linalg.norm(parent.points - detail.points[0], axis=1))]
            )
            scale = parent_radius_m if radius_is_scale else 1.0
            assert detail.radii[0] <= radius_range[1] * scale + 1e-5
            assert detail.radii[0] <= MAX_PARENT_RADIUS_FRACTION * parent_radius_m + 1e-5
            if not radius_is_scale:
                clamped = MAX_PARENT_RADIUS_FRACTION * parent_radius_m
                assert detail.radii[0] >= min(radius_range[0], clamped) - 1e-5
            if kind == "spur" and parent is tree.primary:
                assert detail.points[-1, 2] >= detail.points[0, 2], "spurs point upward"
    assert n_details > 20


def test_primary_details_stay_out_of_the_scoring(detail_trees: list[TreeGT]) -> None:
    config = DetailConfig.orchard()
    n_primary = 0
    for seed, tree in enumerate(detail_trees):
        bases_m = np.array([b.points[0, 2] for b in tree.secondaries])
        for detail in _with_details(tree, config, seed):
            if _parent(tree, detail)[0] is not tree.primary:
                continue
            n_primary += 1
            horizontal_m = np.linalg.norm(detail.points[-1, :2] - detail.points[0, :2])
            assert horizontal_m < EVALUATION_MIN_HORIZONTAL_LENGTH_M
            assert horizontal_m <= config.primary_max_reach_m + SLACK
            if len(bases_m):
                gaps_m = np.abs(detail.points[:, 2][:, None] - bases_m[None, :])
                assert gaps_m.min() >= config.secondary_base_clearance_m
    assert n_primary > 20


def test_details_are_deterministic_and_vary_with_the_seed() -> None:
    tree = tree_from_seed(4, TreeConfig.tall_spindle())
    config = DetailConfig.orchard()
    first = _with_details(tree, config, 9)
    assert first == _with_details(tree, config, 9)
    assert first != _with_details(tree, config, 10)
    assert tree.details == [], "grow_details does not modify the tree"


def test_tree_json_round_trip_with_details(tmp_path) -> None:
    tree = tree_from_seed(2, TreeConfig.ufo())
    plain = tree.to_dict()
    tree.details = _with_details(tree, DetailConfig.orchard(), 2)
    assert tree.details
    data = tree.to_dict()
    assert len(data["details"]) == len(tree.details)
    path = tmp_path / "tree.json"
    tree.save_json(path)
    loaded = TreeGT.load_json(path)
    assert loaded == tree and loaded.details == tree.details
    old = TreeGT.from_dict(plain)  # a file written before details existed
    assert old.details == [] and old == tree_from_seed(2, TreeConfig.ufo())


# --- validation ---


@pytest.mark.parametrize(
    ("field_name", "value"),
    [
        ("architecture", "bonsai"),
        ("primary_base_height_m", -0.1),
        ("primary_base_height_m", 1.0),
        ("primary_base_height_m", 0.3),  # above the placement height 0.275 m
        ("primary_base_height_m", float("nan")),
    ],
)
def test_invalid_tree_config_names_the_new_field(field_name: str, value: object) -> None:
    with pytest.raises(ValueError, match=field_name):
        TreeConfig(**{field_name: value})


@pytest.mark.parametrize(
    ("field_name", "value"),
    [
        ("spur_density_per_m", -1.0),
        ("spur_density_per_m", float("inf")),
        ("spur_length_range_m", (0.03, 0.01)),
        ("spur_length_range_m", (0.0, 0.03)),
        ("spur_radius_range_m", (-0.001, 0.003)),
        ("spur_angle_range_deg", (0.0, 90.0)),
        ("spur_tip_radius_fraction", 0.0),
        ("stub_density_per_m", -0.5),
        ("stub_length_range_m", (0.005, float("nan"))),
        ("stub_radius_scale_range", (0.5, 1.2)),
        ("stub_radius_scale_range", (0.0, 0.5)),
        ("stub_angle_range_deg", (45.0, 180.0)),
        ("stub_tip_radius_fraction", 1.5),
        ("bud_density_per_m", -3.0),
        ("bud_length_range_m", (0.002,)),
        ("bud_radius_range_m", (0.002, 0.001)),
        ("bud_angle_range_deg", (-10.0, 50.0)),
        ("bud_tip_radius_fraction", -0.3),
        ("primary_max_reach_m", 0.0),
        ("primary_max_reach_m", 0.03),
        ("secondary_base_clearance_m", -0.01),
        ("centerline_spacing_m", 0.0),
    ],
)
def test_invalid_detail_config_names_the_field(field_name: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"DetailConfig.{field_name}"):
        DetailConfig(**{field_name: value})
