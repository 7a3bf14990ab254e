"""2D curve fitting on masks as real segmenters draw them (issue 13, part 3): side branches cut
off the trunk by small gaps, eroded and ragged borders, thin and broken masks, a second trunk in
view and wires crossing. Synthetic masks at 320x240, drawn with the helpers of test_curve2d."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree
from test_curve2d import PRIMARY, PRIMARY_HALF_WIDTH, SIDE_HALF_WIDTH, H, W, _dense, _segment, _tube

from recon.curve2d.fit import fit_mask_curves
from recon.curve2d.path_search import SearchGraph
from recon.curve2d.primary import PrimaryPrior, find_primary
from recon.curve2d.skeleton import SkeletonConfig
from recon.curve2d.skeleton_graph import SkeletonEdge, SkeletonGraph
from recon.curve2d.types import Curve2DConfig
from recon.geometry.bezier import CubicBezier

_GRID = np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1).reshape(-1, 2).astype(float)
_PRIMARY_DENSE = _dense(PRIMARY)
# Distance of every pixel centre to the primary's centreline.
_TO_PRIMARY = cKDTree(_PRIMARY_DENSE).query(_GRID)[0].reshape(H, W)
_JUNCTION_T = 0.5
_SIDE_ANGLE_DEG = -20.0  # up and to the right in the image
_SIDE_LENGTH = 75.0


def _primary_mask(half_width: float = PRIMARY_HALF_WIDTH) -> np.ndarray:
    return _TO_PRIMARY <= half_width


def _side(angle_deg: float = _SIDE_ANGLE_DEG, t: float = _JUNCTION_T) -> np.ndarray:
    junction = PRIMARY(np.array([t]))[0]
    return _segment(junction, angle_deg, _SIDE_LENGTH)


def _gapped_side(gap_px: float, angle_deg: float = _SIDE_ANGLE_DEG) -> np.ndarray:
    """A side branch whose mask stops ``gap_px`` short of the trunk's silhouette."""
    return _tube(_side(angle_deg), SIDE_HALF_WIDTH) & (_TO_PRIMARY > PRIMARY_HALF_WIDTH + gap_px)


def _matching_secondary(result, segment: np.ndarray):
    """The fitted secondary ending nearest the drawn segment's tip, if it runs along it."""
    tip = segment[-1]
    for secondary in result.secondaries:
        end = secondary.samples_px[-1]
        drawn = (segment[-1] - segment[0]) / np.linalg.norm(segment[-1] - segment[0])
        fitted = end - secondary.samples_px[0]
        fitted /= np.linalg.norm(fitted)
        if np.linalg.norm(end - tip) < SIDE_HALF_WIDTH + 5.0 and drawn @ fitted > np.cos(
            np.radians(15.0)
        ):
            return secondary
    return None


def _primary_error_px(result) -> float:
    return float(cKDTree(_PRIMARY_DENSE).query(result.primary.samples_px)[0].max())


@pytest.mark.parametrize("gap_px", [2, 4, 6])
def test_side_branch_is_found_across_a_junction_gap(gap_px: int) -> None:
    mask = _primary_mask() | _gapped_side(gap_px)
    assert not np.any(
        mask
        & _tube(_side(), SIDE_HALF_WIDTH)
        & ~_primary_mask()
        & (_TO_PRIMARY <= PRIMARY_HALF_WIDTH + gap_px)
    )  # the gap is really there
    result = fit_mask_curves(mask)
    assert result.primary is not None and _primary_error_px(result) < 2.0
    secondary = _matching_secondary(result, _side())
    assert secondary is not None, f"no side branch across a {gap_px} px gap"
    # It starts at the junction on the primary's axis, its junction samples are skipped when
    # lifting, and every sample it lifts lies on the mask.
    assert np.linalg.norm(secondary.samples_px[0] - _side()[0]) < PRIMARY_HALF_WIDTH
    lifted = secondary.samples_px[secondary.liftable]
    assert len(lifted) >= 5
    assert mask[np.rint(lifted[:, 1]).astype(int), np.rint(lifted[:, 0]).astype(int)].all()


def test_gaps_wider_than_the_limit_are_not_bridged() -> None:
    mask = _primary_mask() | _gapped_side(12)
    result = fit_mask_curves(mask)
    assert _matching_secondary(result, _side()) is None
    disabled = Curve2DConfig(skeleton=SkeletonConfig(max_gap_px=0.0))
    assert (
        _matching_secondary(fit_mask_curves(_primary_mask() | _gapped_side(4), disabled), _side())
        is None
    )


@pytest.mark.parametrize("gap_px", [3, 6])
@pytest.mark.parametrize("blob_radius_px", [5.0, 9.0])
def test_no_side_branch_is_invented_for_a_lone_blob(gap_px: int, blob_radius_px: float) -> None:
    junction = PRIMARY(np.array([_JUNCTION_T]))[0]
    centre = junction + np.array([PRIMARY_HALF_WIDTH + gap_px + blob_radius_px, 0.0])
    blob = (np.linalg.norm(_GRID - centre, axis=1) <= blob_radius_px).reshape(H, W)
    result = fit_mask_curves(_primary_mask() | blob)
    assert result.primary is not None and _primary_error_px(result) < 2.0
    assert result.secondaries == []
    assert len(result.skeleton.bridge_uv) == 0


def test_a_branch_running_alongside_the_trunk_is_not_bridged() -> None:
    """A second, parallel stem 5 px beside the trunk is not a side branch of it."""
    offset = PRIMARY.control_points + np.array([PRIMARY_HALF_WIDTH + 5 + 4.0, 0.0])
    stem = _tube(_dense(CubicBezier(offset)), 4.0) & (_GRID[:, 1].reshape(H, W) > 60)
    result = fit_mask_curves(_primary_mask() | (stem & ~_primary_mask()))
    assert result.primary is not None and _primary_error_px(result) < 2.5
    assert result.secondaries == []


def _ragged(mask: np.ndarray, amplitude_px: int, seed: int) -> np.ndarray:
    """Erode or dilate the border by up to ``amplitude_px`` in random patches (hand labels)."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.standard_normal((H, W)), (0, 0), 3.0)
    noise /= np.abs(noise).max()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * amplitude_px + 1,) * 2)
    grown = cv2.dilate(mask.view(np.uint8), kernel).astype(bool)
    shrunk = cv2.erode(mask.view(np.uint8), kernel).astype(bool)
    return np.where(noise > 0.3, grown, np.where(noise < -0.3, shrunk, mask))


def _tree_mask() -> tuple[np.ndarray, list[np.ndarray]]:
    sides = [_side(-20.0, 0.3), _side(200.0, 0.55), _side(-35.0, 0.75)]
    mask = _primary_mask()
    for segment in sides:
        mask |= _tube(segment, SIDE_HALF_WIDTH)
    return mask, sides


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ragged_and_eroded_borders_keep_primary_and_side_branches(seed: int) -> None:
    mask, sides = _tree_mask()
    for ragged in (_ragged(mask, 2, seed), cv2.erode(mask.view(np.uint8), np.ones((3, 3))) > 0):
        result = fit_mask_curves(ragged)
        assert result.primary is not None and _primary_error_px(result) < 3.0
        found = [_matching_secondary(result, s) for s in sides]
        assert all(f is not None for f in found)
        # Ragged borders make skeleton spurs, not extra side branches.
        assert len(result.secondaries) <= len(sides) + 1


def test_thin_mask_is_fitted() -> None:
    mask = _primary_mask(2.5) | _tube(_side(), 2.0)
    result = fit_mask_curves(mask)
    assert result.primary is not None and _primary_error_px(result) < 2.0
    assert _matching_secondary(result, _side()) is not None


@pytest.mark.parametrize("gap_px", [2, 4])
def test_broken_trunk_is_one_primary(gap_px: int) -> None:
    """A trunk mask broken across by a small gap still gives one primary spanning the view."""
    rows = _GRID[:, 1].reshape(H, W)
    mask = _primary_mask() & ~((rows >= 120) & (rows < 120 + gap_px))
    result = fit_mask_curves(mask)
    assert result.primary is not None and _primary_error_px(result) < 2.0
    assert result.primary.samples_px[0, 1] > H - 15 and result.primary.samples_px[-1, 1] < 15
    # The samples on the gap are not lifted.
    lifted = result.primary.samples_px[result.primary.liftable]
    assert mask[np.rint(lifted[:, 1]).astype(int), np.rint(lifted[:, 0]).astype(int)].all()


def _cut_trunk(gap_px: int, far_half_width: float = PRIMARY_HALF_WIDTH, shift_px: float = 0.0):
    """The trunk cut across at row 120 by an occluder ``gap_px`` tall (a wire or a tie in front
    of it); above the cut, it is ``far_half_width`` wide and shifted by ``shift_px`` in u."""
    rows = _GRID[:, 1].reshape(H, W)
    shifted = CubicBezier(PRIMARY.control_points + np.array([shift_px, 0.0]))
    above = _tube(_dense(shifted), far_half_width) & (rows < 120)
    return (_primary_mask() & (rows >= 120 + gap_px)) | above


@pytest.mark.parametrize("gap_px", [10, 18])
def test_a_trunk_cut_by_an_occluder_is_one_primary(gap_px: int) -> None:
    """Wider than the small-gap rule, narrower than a trunk diameter: an occlusion bridge joins
    the pieces (``SkeletonConfig.occlusion_gap_radii``); the bridged samples are not lifted."""
    mask = _cut_trunk(gap_px)
    result = fit_mask_curves(mask)
    assert result.primary is not None and _primary_error_px(result) < 2.0
    assert result.primary.samples_px[0, 1] > H - 15 and result.primary.samples_px[-1, 1] < 15
    lifted = result.primary.samples_px[result.primary.liftable]
    assert mask[np.rint(lifted[:, 1]).astype(int), np.rint(lifted[:, 0]).astype(int)].all()
    off = Curve2DConfig(skeleton=SkeletonConfig(occlusion_gap_radii=0.0))
    unbridged = fit_mask_curves(mask, off).primary
    assert unbridged is None or np.ptp(unbridged.samples_px[:, 1]) < 0.6 * H


@pytest.mark.parametrize(
    ("gap_px", "far_half_width", "shift_px"),
    [(30, PRIMARY_HALF_WIDTH, 0.0), (12, 4.0, 0.0), (12, PRIMARY_HALF_WIDTH, 18.0)],
    ids=["gap-wider-than-a-diameter", "thinner-beyond", "beside-not-beyond"],
)
def test_pieces_that_do_not_continue_the_branch_are_not_bridged(
    gap_px: int, far_half_width: float, shift_px: float
) -> None:
    result = fit_mask_curves(_cut_trunk(gap_px, far_half_width, shift_px))
    assert len(result.skeleton.bridge_uv) == 0


def test_two_trunks_in_view_give_one_primary_with_its_side_branches() -> None:
    """With the model's trunk as prior (every iteration after the first), the followed trunk
    stays the primary; without one, either trunk may be taken, never a mix, and the other trunk
    never becomes a side branch."""
    mask, sides = _tree_mask()
    other = CubicBezier(np.array([[280.0, 265.0], [275.0, 170.0], [290.0, 75.0], [285.0, -25.0]]))
    other_dense = _dense(other)
    both = mask | _tube(other_dense, 7.0)
    prior = PrimaryPrior(PRIMARY(np.linspace(0.05, 0.95, 20)), 4.0, 0.6)
    result = fit_mask_curves(both, prior=prior)
    assert result.primary is not None and _primary_error_px(result) < 2.0
    assert all(_matching_secondary(result, s) is not None for s in sides)
    samples = np.concatenate([s.samples_px for s in result.secondaries])
    assert cKDTree(other_dense).query(samples)[0].min() > 7.0
    unguided = fit_mask_curves(both)
    to_first = cKDTree(_PRIMARY_DENSE).query(unguided.primary.samples_px)[0].max()
    to_other = cKDTree(other_dense).query(unguided.primary.samples_px)[0].max()
    assert min(to_first, to_other) < 2.0


@pytest.mark.parametrize("angle_deg", [0.0, -10.0, -25.0])
def test_wire_crossing_the_trunk_leaves_the_primary_on_the_trunk(angle_deg: float) -> None:
    """A thin wire across the trunk, between side branches (one crossing a side branch takes
    its candidate over: a known limit)."""
    mask, sides = _tree_mask()
    centre = PRIMARY(np.array([0.45]))[0]
    direction = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    wire = centre + np.linspace(-400.0, 400.0, 3201)[:, None] * direction
    result = fit_mask_curves(mask | _tube(wire, 1.5))
    assert result.primary is not None and _primary_error_px(result) < 2.0
    assert all(_matching_secondary(result, s) is not None for s in sides)


def _line_pixels(a: tuple[int, int], b: tuple[int, int]) -> np.ndarray:
    """(P, 2) int pixels (u, v) from ``a`` to ``b``, one per unit step of the longer axis."""
    n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]))) + 1
    return np.rint(np.linspace(a, b, n)).astype(int)


def _crossing_graph() -> SkeletonGraph:
    """The skeleton of a primary crossed by side branches on both sides at one height, as the
    mask of tree 40 gave it (measured): the crossing split into two junctions on one row, the
    top of the primary and the left branch at junction 0, its bottom and the right branch at 1."""
    nodes = [(164, 174), (166, 174), (150, 10), (309, 149), (10, 180), (170, 229)]
    kinds = ("junction", "junction", "endpoint", "endpoint", "endpoint", "endpoint")
    ends = [(0, 2), (0, 1), (0, 4), (1, 3), (1, 5)]
    edges = []
    for start, end in ends:
        pixels = _line_pixels(nodes[start], nodes[end])
        edges.append(SkeletonEdge(start, end, pixels, np.full(len(pixels), 8.0)))
    pixels = np.unique(np.concatenate([e.pixels_uv for e in edges]), axis=0)
    return SkeletonGraph(
        pixels, np.full(len(pixels), 8.0), np.array(nodes, float), kinds, tuple(edges)
    )


def test_a_level_edge_between_the_junctions_of_a_crossing_keeps_the_primary_whole() -> None:
    direction = np.array([0.0, -1.0])
    spans = {}
    for level_px in (0.0, Curve2DConfig().crossing_level_px):
        config = Curve2DConfig(crossing_level_px=level_px)
        _, curve, _, _, _ = find_primary(SearchGraph(_crossing_graph()), direction, config)
        v = curve(np.linspace(0.0, 1.0, 50))[:, 1]
        spans[level_px] = (v.min(), v.max())
    # Every edge oriented up cuts the primary at the crossing: an L (a side branch, then the
    # primary) wins. Walking the level edge both ways gives the whole primary, 10 -> 229 px.
    assert spans[0.0][1] - spans[0.0][0] < 200
    whole = spans[Curve2DConfig().crossing_level_px]
    assert whole[0] < 15 and whole[1] > 225
    with pytest.raises(ValueError, match="crossing_level_px"):
        Curve2DConfig(crossing_level_px=-1.0)


def _cut_trunk_with_side_branch() -> tuple[np.ndarray, PrimaryPrior]:
    """A vertical trunk cut by a 30 px occluder (wider than it: never bridged) just above a side
    branch that leaves it at 45 degrees, and the model's trunk below the cut as the prior."""
    column = 160.0
    lower = np.stack([np.full(301, column), np.linspace(250.0, 165.0, 301)], axis=1)
    upper = np.stack([np.full(601, column), np.linspace(135.0, -10.0, 601)], axis=1)
    side = _segment(np.array([column, 195.0]), -135.0, 230.0)  # up and to the left
    mask = _tube(lower, 12.0) | _tube(upper, 12.0) | _tube(side, 8.0)
    mask[135:165, 146:175] = False  # the occluder across the trunk: background in the mask
    model = np.stack([np.full(14, column), np.linspace(235.0, 195.0, 14)], axis=1)  # base to top
    return mask, PrimaryPrior(model, 4.0, 0.6)


def test_primary_does_not_turn_off_the_model_into_a_side_branch() -> None:
    """The path along the model's pixels into the side branch is the longest one; without a turn
    limit it becomes the primary (the scan then follows the side branch: the orchard's lost
    scans), with one the trunk beyond the occluder is chosen (the model's stub below the cut is
    too short to be a primary), which the modeler then finds inconsistent and restarts on."""
    mask, prior = _cut_trunk_with_side_branch()
    unlimited = fit_mask_curves(mask, prior=prior)
    assert unlimited.primary is not None
    assert unlimited.primary.samples_px[:, 0].min() < 100.0  # along the side branch
    limited = fit_mask_curves(mask, prior=dataclasses.replace(prior, max_turn_deg=30.0))
    assert limited.primary is not None
    samples = limited.primary.samples_px
    assert np.abs(samples[:, 0] - 160.0).max() < 3.0 and samples[:, 1].max() < 140.0


def test_turn_limit_keeps_a_primary_that_bends_gently() -> None:
    """A trunk bending 20 degrees beyond the model's end, with no cut, stays the primary."""
    lower = np.stack([np.full(301, 160.0), np.linspace(250.0, 150.0, 301)], axis=1)
    bend = _segment(lower[-1], -90.0 - 20.0, 160.0)  # up, leaning 20 degrees left
    mask = _tube(np.concatenate([lower, bend]), 10.0)
    model = np.stack([np.full(14, 160.0), np.linspace(235.0, 160.0, 14)], axis=1)
    prior = PrimaryPrior(model, 4.0, 0.6, max_turn_deg=30.0)
    assert not prior.turns_away(fit_mask_curves(mask).primary.curve)
    result = fit_mask_curves(mask, prior=prior)
    assert result.primary is not None and result.primary.samples_px[:, 1].min() < 20.0


def test_model_vouches_for_a_short_piece_of_a_thick_trunk() -> None:
    """An occluder across a thick trunk leaves a piece shorter than four diameters: no primary
    without the model (a blob must not start one); with the model's agreeing projection and
    ``vouches`` it stays the primary."""
    trunk = np.stack([np.full(481, 160.0), np.linspace(250.0, 130.0, 481)], axis=1)
    mask = _tube(trunk, 25.0)
    model = np.stack([np.full(10, 160.0), np.linspace(225.0, 140.0, 10)], axis=1)
    prior = PrimaryPrior(model, 4.0, 0.6)
    assert fit_mask_curves(mask).primary is None
    assert fit_mask_curves(mask, prior=prior).primary is None
    vouched = fit_mask_curves(mask, prior=dataclasses.replace(prior, vouches=True)).primary
    assert vouched is not None and np.abs(vouched.samples_px[:, 0] - 160.0).max() < 2.0


def test_model_vouches_only_for_pieces_that_agree_with_it() -> None:
    """The same short thick piece with the model 60 px to its side: no primary, turn limit or
    not (the fallback past the model's stub takes no blob)."""
    trunk = np.stack([np.full(481, 160.0), np.linspace(250.0, 130.0, 481)], axis=1)
    model = np.stack([np.full(10, 220.0), np.linspace(225.0, 140.0, 10)], axis=1)
    prior = PrimaryPrior(model, 4.0, 0.6, max_turn_deg=30.0, vouches=True)
    assert fit_mask_curves(_tube(trunk, 25.0), prior=prior).primary is None
