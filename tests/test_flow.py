"""The flow picture, DIS flow and frame pairing (``recon.segmentation.flow``).

Fast tests on synthetic data. The benchmark that chose the DIS preset renders orchard-world
frame pairs with exact flow; it is not a test: ``python tests/test_flow.py [--baselines]``.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from dataclasses import fields

import cv2
import flow_vis
import numpy as np
import pytest

from recon.segmentation.flow import (
    MIN_FLOW_SIDE_PX,
    DenseFlowConfig,
    FramePairer,
    FramePairingConfig,
    compute_flow,
    flow_picture,
    flow_to_picture,
    flow_to_picture_fast,
    swap_red_blue,
)

# ---------------------------------------------------------------------------------------------
# flow_to_picture


def _wheel_colour(fk: float) -> np.ndarray:
    """flow-vis's colour wheel at fractional index ``fk`` (linear between entries), 0-255."""
    wheel = flow_vis.make_colorwheel()
    k0 = math.floor(fk)
    f = fk - k0
    return (1 - f) * wheel[k0 % len(wheel)] + f * wheel[(k0 + 1) % len(wheel)]


# (u, v) unit directions and where flow-vis's wheel (55 entries, Baker et al. 2007) puts them:
# index (atan2(-v, -u) / pi + 1) / 2 * 54; +u with v = +0.0 sits at index 0 (atan2(-0.0, -1)).
DIRECTIONS = {
    "right (+u)": ((1.0, 0.0), 0.0, (255, 0, 0)),
    "down (+v)": ((0.0, 1.0), 13.5, (255, 229, 0)),
    "left (-u)": ((-1.0, 0.0), 27.0, (0, 209, 255)),
    "up (-v)": ((0.0, -1.0), 40.5, (88, 0, 255)),
    "down-right": ((1.0, 1.0), 6.75, (255, 114, 0)),
    "down-left": ((-1.0, 1.0), 20.25, (32, 255, 0)),
    "up-left": ((-1.0, -1.0), 33.75, (0, 52, 255)),
    "up-right": ((1.0, -1.0), 47.25, (220, 0, 255)),
}


@pytest.mark.parametrize("name", DIRECTIONS)
def test_picture_at_the_largest_flow_is_the_wheel_colour(name: str) -> None:
    (u, v), fk, rgb = DIRECTIONS[name]
    flow = np.zeros((3, 4, 2), np.float32)
    flow[1, 2] = np.array([u, v]) * 7.0 / math.hypot(u, v)  # the frame's largest flow: 7 px
    picture = flow_to_picture(flow)
    assert picture.dtype == np.uint8 and picture.shape == (3, 4, 3)
    assert tuple(picture[1, 2]) == rgb
    # within the epsilon flow-vis adds to the largest magnitude: the wheel entry itself
    assert np.abs(picture[1, 2] - np.floor(_wheel_colour(fk))).max() <= 1
    assert (picture[0, 0] == 255).all()  # zero flow: white


def test_picture_half_magnitude_is_paler_with_the_same_hue() -> None:
    flow = np.zeros((1, 4, 2), np.float64)
    flow[0, 0] = (0.0, -4.0)  # up, largest
    flow[0, 1] = (0.0, -2.0)  # up, half
    flow[0, 2] = (3.0, 0.0)  # right, 3/4
    picture = flow_to_picture(flow)
    full, half = picture[0, 0].astype(int), picture[0, 1].astype(int)
    assert tuple(full) == (88, 0, 255)
    # 1 - r (1 - c) with r = 1/2: halfway between the wheel colour and white
    assert tuple(half) == (171, 127, 255)
    assert (half >= full).all() and half.min() > full.min()
    hsv = cv2.cvtColor(picture, cv2.COLOR_RGB2HSV)
    assert abs(int(hsv[0, 0, 0]) - int(hsv[0, 1, 0])) <= 1
    assert hsv[0, 1, 1] < hsv[0, 0, 1]  # less saturated
    assert tuple(picture[0, 2]) == (255, 63, 63)
    assert tuple(picture[0, 3]) == (255, 255, 255)


def test_zero_flow_is_white_without_division_warnings() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for dtype in (np.float16, np.float32, np.float64):
            picture = flow_to_picture(np.zeros((5, 6, 2), dtype))
            assert picture.shape == (5, 6, 3) and (picture == 255).all()


def test_unknown_flow_is_white_and_left_out_of_the_normalisation() -> None:
    rng = np.random.default_rng(0)
    flow = rng.normal(0.0, 3.0, (20, 30, 2)).astype(np.float32)
    unknown = flow.copy()
    unknown[2, 3] = (np.nan, 1.0)
    unknown[4, 5] = (np.inf, -np.inf)
    unknown[6, 7] = (0.5, np.nan)
    cleaned = flow.copy()
    cleaned[2, 3] = cleaned[4, 5] = cleaned[6, 7] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        picture = flow_to_picture(unknown)
    np.testing.assert_array_equal(picture, flow_to_picture(cleaned))
    for y, x in ((2, 3), (4, 5), (6, 7)):
        assert (picture[y, x] == 255).all()
    assert (flow_to_picture(np.full((3, 3, 2), np.nan)) == 255).all()
    assert np.isnan(unknown[2, 3, 0])  # the input is not modified


@pytest.mark.parametrize("name", DIRECTIONS)
def test_fast_picture_codes_the_wheel_directions(name: str) -> None:
    (u, v), _, rgb = DIRECTIONS[name]
    flow = np.zeros((3, 4, 2), np.float32)
    flow[1, 2] = np.array([u, v]) * 7.0 / math.hypot(u, v)
    flow[0, 1] = flow[1, 2] / 2  # half way to white
    picture = flow_to_picture_fast(flow)
    assert np.abs(picture[1, 2].astype(int) - rgb).max() <= 1
    assert (picture[0, 0] == 255).all()
    half = 255 - (255 - np.asarray(rgb, float)) / 2
    assert np.abs(picture[0, 1] - half).max() <= 1


@pytest.mark.parametrize("scale", [0.01, 3.0, 250.0])
def test_fast_picture_is_within_one_level_of_flow_vis(scale: float) -> None:
    rng = np.random.default_rng(2)
    flow = rng.normal(0.0, scale, (60, 80, 2)).astype(np.float32)
    flow[5, 5], flow[6, 6], flow[7, 7] = (scale, 0.0), (-scale, 0.0), (0.0, -scale)  # the seam
    flow[8, 8] = (np.nan, 1.0)
    fast, reference = flow_to_picture_fast(flow), flow_to_picture(flow)
    assert fast.dtype == np.uint8 and fast.shape == (60, 80, 3)
    difference = np.abs(fast.astype(int) - reference.astype(int))
    largest = np.unravel_index(np.nanargmax(np.hypot(flow[..., 0], flow[..., 1])), (60, 80))
    difference[largest] = 0  # flow-vis sometimes darkens its largest pixel (its epsilon)
    assert difference.max() <= 1
    assert (fast[8, 8] == 255).all()
    assert (flow_to_picture_fast(np.zeros((4, 5, 2), np.float32)) == 255).all()
    with pytest.raises(ValueError, match="floating"):
        flow_to_picture_fast(np.zeros((4, 5, 2), np.int32))


@pytest.mark.parametrize("scale", [0.01, 0.5, 3.7, 250.0])
def test_picture_is_normalised_by_the_frames_largest_flow(scale: float) -> None:
    rng = np.random.default_rng(1)
    flow = rng.normal(0.0, 2.0, (40, 50, 2))
    difference = np.abs(
        flow_to_picture(flow * scale).astype(int) - flow_to_picture(flow).astype(int)
    )
    assert difference.max() <= 1  # flow-vis's 1e-5 epsilon on the largest magnitude
    assert (difference == 0).mean() > 0.99


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_picture_is_flow_vis_flow_to_color(dtype: type) -> None:
    rng = np.random.default_rng(2)
    for scale in (1e-3, 1.0, 40.0):
        flow = (rng.normal(0.0, 1.0, (24, 32, 2)) * scale).astype(dtype)
        np.testing.assert_array_equal(flow_to_picture(flow), flow_vis.flow_to_color(flow))


@pytest.mark.parametrize(
    ("flow", "message"),
    [
        (np.zeros((4, 4, 3), np.float32), "shape"),
        (np.zeros((4, 4), np.float32), "shape"),
        (np.zeros((1, 4, 4, 2), np.float32), "shape"),
        (np.zeros((4, 4, 2), np.int16), "floating"),
        (np.zeros((4, 4, 2), np.uint8), "floating"),
        ([[[0.0, 0.0]]], "numpy array"),
    ],
)
def test_picture_rejects_bad_flow(flow: object, message: str) -> None:
    with pytest.raises(ValueError, match=f"flow .*{message}"):
        flow_to_picture(flow)  # type: ignore[arg-type]


def test_swap_red_blue() -> None:
    picture = np.zeros((2, 3, 3), np.uint8)
    picture[..., 0], picture[..., 1], picture[..., 2] = 10, 20, 30
    swapped = swap_red_blue(picture)
    assert tuple(swapped[1, 2]) == (30, 20, 10) and swapped.flags.c_contiguous
    np.testing.assert_array_equal(swap_red_blue(swapped), picture)
    # the recorded real frame 7's trunk colour reads as upward motion once swapped
    assert tuple(swap_red_blue(np.array([[[255, 59, 83]]], np.uint8))[0, 0]) == (83, 59, 255)
    with pytest.raises(ValueError, match="picture"):
        swap_red_blue(np.zeros((2, 3), np.uint8))


# ---------------------------------------------------------------------------------------------
# compute_flow


def _texture(height: int = 240, width: int = 320, seed: int = 0) -> np.ndarray:
    """(H, W) float32 smooth random texture in [0, 255] (grain ~2 px)."""
    noise = np.random.default_rng(seed).random((height, width)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), 2.0)
    texture -= texture.min()
    return texture * (255.0 / texture.max())


def _shifted(texture: np.ndarray, du: float, dv: float) -> np.ndarray:
    """The texture moved by (du, dv) pixels (bilinear), as a grey (H, W, 3) uint8 frame."""
    M = np.float32([[1, 0, du], [0, 1, dv]])
    moved = cv2.warpAffine(
        texture,
        M,
        (texture.shape[1], texture.shape[0]),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT,
    )
    grey = np.clip(moved + 0.5, 0, 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


@pytest.mark.parametrize("shift", [(1.5, -0.75), (3.0, 2.0), (-0.25, 0.5)])
@pytest.mark.parametrize("direction", ["current_to_previous", "previous_to_current"])
def test_dis_recovers_a_known_shift(shift: tuple[float, float], direction: str) -> None:
    texture = _texture()
    previous, current = _shifted(texture, 0.0, 0.0), _shifted(texture, *shift)
    flow = compute_flow(previous, current, DenseFlowConfig(direction=direction))
    assert flow.dtype == np.float32 and flow.shape == (240, 320, 2)
    expected = np.array(shift) * (-1.0 if direction == "current_to_previous" else 1.0)
    error = np.linalg.norm(flow - expected, axis=2)[16:-16, 16:-16]  # interior
    assert error.mean() < 0.25 and np.percentile(error, 90) < 0.25, (
        error.mean(),
        np.percentile(error, 90),
    )


def test_dis_presets_and_finest_scale_run() -> None:
    texture = _texture(96, 128, seed=3)
    previous, current = _shifted(texture, 0.0, 0.0), _shifted(texture, 1.0, 0.0)
    for config in (
        DenseFlowConfig(preset="fast"),
        DenseFlowConfig(preset="medium"),
        DenseFlowConfig(finest_scale=0),
        DenseFlowConfig(preset="medium", finest_scale=2),
    ):
        flow = compute_flow(previous, current, config)
        assert np.median(flow[16:-16, 16:-16, 0]) == pytest.approx(-1.0, abs=0.25), config


def test_flow_picture_of_an_upward_camera_is_violet_blue() -> None:
    """The camera moves up: the scene moves down in the image; current-to-previous flow is up."""
    texture = _texture(seed=4)
    picture = flow_picture(_shifted(texture, 0.0, 0.0), _shifted(texture, 0.0, 2.0))
    hue = cv2.cvtColor(picture, cv2.COLOR_RGB2HSV)[16:-16, 16:-16, 0]
    reference = cv2.cvtColor(np.array([[[88, 0, 255]]], np.uint8), cv2.COLOR_RGB2HSV)[0, 0, 0]
    assert abs(float(np.median(hue)) - float(reference)) <= 5


@pytest.mark.parametrize(
    ("previous", "current", "message"),
    [
        (np.zeros((64, 64, 3), np.float32), np.zeros((64, 64, 3), np.uint8), "previous_rgb"),
        (np.zeros((64, 64, 3), np.uint8), np.zeros((64, 64), np.uint8), "rgb"),
        (np.zeros((64, 64, 3), np.uint8), np.zeros((64, 64, 4), np.uint8), "rgb"),
        (np.zeros((64, 64, 3), np.uint8), np.zeros((64, 65, 3), np.uint8), "same shape"),
        (np.zeros((16, 200, 3), np.uint8), np.zeros((16, 200, 3), np.uint8), "at least"),
        (np.zeros((64, 64, 3), np.uint8), [[0]], "rgb must be a numpy array"),
    ],
)
def test_compute_flow_rejects_bad_images(previous: object, current: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        compute_flow(previous, current)  # type: ignore[arg-type]


def test_smallest_frame_runs() -> None:
    frame = _shifted(_texture(MIN_FLOW_SIDE_PX, 200), 0.0, 0.0)
    assert compute_flow(frame, frame).shape == (MIN_FLOW_SIDE_PX, 200, 2)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("preset", "slow"),
        ("preset", 0),
        ("finest_scale", -1),
        ("finest_scale", 3),
        ("finest_scale", 1.0),
        ("finest_scale", True),
        ("direction", "forward"),
    ],
)
def test_flow_config_rejects_bad_values(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"DenseFlowConfig.{field}"):
        DenseFlowConfig(**{field: value})


# ---------------------------------------------------------------------------------------------
# FramePairer


def _pose(y_m: float = 0.0, x_m: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """(4, 4) camera pose at (x, y, 0) turned by ``yaw_deg`` about the camera's y axis."""
    angle = math.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [
        [math.cos(angle), 0.0, math.sin(angle)],
        [0.0, 1.0, 0.0],
        [-math.sin(angle), 0.0, math.cos(angle)],
    ]
    T[0, 3], T[1, 3] = x_m, y_m
    return T


def _frame(index: int) -> np.ndarray:
    """A (32, 40, 3) uint8 frame filled with ``index`` (to tell frames apart)."""
    return np.full((32, 40, 3), index, np.uint8)


def test_a_pair_moved_less_than_7_5_mm_is_not_used() -> None:
    pairer = FramePairer()
    assert pairer.config.min_translation_m == 0.0075
    assert pairer.add(_frame(0), _pose(0.0)) is None
    assert pairer.add(_frame(1), _pose(-0.0074)) is None  # 7.4 mm up
    partner = pairer.add(_frame(2), _pose(-0.0075))  # 7.5 mm from frame 0, 0.1 from frame 1
    assert partner is not None and partner[0, 0, 0] == 0
    pairer.reset()
    pairer.add(_frame(0), _pose(0.0))
    assert pairer.add(_frame(1), _pose(0.0, x_m=0.005)) is None  # 5 mm sideways


def test_a_pair_turned_by_0_5_deg_or_more_is_not_used() -> None:
    pairer = FramePairer()
    assert pairer.config.max_rotation_deg == 0.5
    pairer.add(_frame(0), _pose(0.0))
    assert pairer.add(_frame(1), _pose(-0.01, yaw_deg=0.5)) is None
    assert pairer.add(_frame(2), _pose(-0.01, yaw_deg=-0.7)) is None
    partner = pairer.add(_frame(3), _pose(-0.01, yaw_deg=0.49))
    assert partner is not None and partner[0, 0, 0] == 0


def test_the_most_recent_qualifying_frame_is_chosen() -> None:
    pairer = FramePairer()
    partners = []
    for i in range(11):  # every 2 mm up
        partner = pairer.add(_frame(i), _pose(-0.002 * i))
        partners.append(None if partner is None else int(partner[0, 0, 0]))
    # frame i pairs with frame i - 4 (8 mm; i - 3 is only 6 mm away)
    assert partners == [None] * 4 + [0, 1, 2, 3, 4, 5, 6]


def test_a_frame_that_turned_too_far_is_passed_over_for_an_older_one() -> None:
    pairer = FramePairer()
    pairer.add(_frame(0), _pose(0.0))
    pairer.add(_frame(1), _pose(-0.002, yaw_deg=1.0))  # turned
    partner = pairer.add(_frame(2), _pose(-0.012))  # 10 mm from 1, but 1 turned: 0 (12 mm)
    assert partner is not None and partner[0, 0, 0] == 0


def test_history_is_bounded_by_travel() -> None:
    step = 2.0**-8  # ~3.9 mm, exact in binary
    pairer = FramePairer(FramePairingConfig(history_travel_m=4 * step))
    for i in range(30):
        pairer.add(_frame(i), _pose(-step * i))
        assert len(pairer) == min(i + 1, 5)  # 4 steps of travel behind the newest, and it
    # back and forth: travel counts the path, not the distance from the newest
    pairer.reset()
    for i in range(30):
        pairer.add(_frame(i), _pose(-0.005 * (i % 2)))
        assert len(pairer) <= 5


def test_history_is_bounded_by_frame_count() -> None:
    pairer = FramePairer(FramePairingConfig(max_history_frames=6))
    for i in range(20):  # a paused camera
        assert pairer.add(_frame(i), _pose(0.0)) is None
        assert len(pairer) == min(i + 1, 6)
    # the paused frames pushed the older, qualifying ones out: nothing left to pair with
    pairer.reset()
    pairer.add(_frame(100), _pose(0.01))
    for i in range(6):
        pairer.add(_frame(i), _pose(0.0))
    assert pairer.add(_frame(50), _pose(0.0)) is None


def test_reset_starts_a_new_scan() -> None:
    pairer = FramePairer()
    pairer.add(_frame(0), _pose(0.0))
    pairer.reset()
    assert len(pairer) == 0
    assert pairer.add(np.zeros((48, 64, 3), np.uint8), _pose(-0.01)) is None  # new size too


def test_kept_frames_are_read_only_copies() -> None:
    pairer = FramePairer()
    frame = _frame(7)
    pairer.add(frame, _pose(0.0))
    frame[:] = 99
    partner = pairer.add(_frame(8), _pose(-0.01))
    assert partner is not None and (partner == 7).all()
    assert not partner.flags.writeable


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        (np.eye(3), "shape"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), "rotation"),
        (np.diag([-1.0, 1.0, 1.0, 1.0]), "rotation"),
        (np.vstack([np.eye(4)[:3], [0.0, 0.0, 1.0, 1.0]]), "last row"),
    ],
)
def test_pairer_rejects_bad_poses(pose: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=f"T_world_camera.*{message}"):
        FramePairer().add(_frame(0), pose)


def test_pairer_rejects_bad_images() -> None:
    pairer = FramePairer()
    with pytest.raises(ValueError, match="rgb must be uint8"):
        pairer.add(np.zeros((32, 40, 3), np.float32), _pose())
    with pytest.raises(ValueError, match="rgb must have shape"):
        pairer.add(np.zeros((32, 40), np.uint8), _pose())
    pairer.add(_frame(0), _pose())
    with pytest.raises(ValueError, match="reset"):
        pairer.add(np.zeros((33, 40, 3), np.uint8), _pose(-0.01))
    assert len(pairer) == 1


@pytest.mark.parametrize(
    ("field", "values"),
    [
        ("min_translation_m", [0.0, -0.001, math.nan, math.inf, True, "0.0075"]),
        ("max_rotation_deg", [0.0, -0.5, math.nan, math.inf, 181.0]),
        ("history_travel_m", [0.0, -1.0, math.nan, math.inf, 0.005]),
        ("max_history_frames", [0, -3, 1.5, True, None]),
    ],
)
def test_pairing_config_rejects_bad_values(field: str, values: list[object]) -> None:
    for value in values:
        with pytest.raises(ValueError, match=f"FramePairingConfig.{field}"):
            FramePairingConfig(**{field: value})


def test_every_config_field_is_checked() -> None:
    assert {f.name for f in fields(DenseFlowConfig)} == {"preset", "finest_scale", "direction"}
    assert {f.name for f in fields(FramePairingConfig)} == {
        "min_translation_m",
        "max_rotation_deg",
        "history_travel_m",
        "max_history_frames",
    }


# ---------------------------------------------------------------------------------------------
# Benchmark (not collected by pytest): python tests/test_flow.py [--baselines]


def _auc(positive: np.ndarray, negative: np.ndarray) -> float:
    """ROC AUC of scores: P(a positive scores above a negative), ties counted half."""
    scores = np.concatenate([positive, negative])
    order = np.argsort(scores, kind="stable")
    ranks = np.empty(len(scores))
    ranks[order] = np.arange(1, len(scores) + 1)
    # average ranks of ties
    _, inverse, counts = np.unique(scores, return_inverse=True, return_counts=True)
    sums = np.bincount(inverse, weights=ranks)
    ranks = (sums / counts)[inverse]
    n = len(positive)
    return float((ranks[:n].sum() - n * (n + 1) / 2) / (n * len(negative)))


def run_benchmark(seeds: range = range(10), steps: tuple[int, ...] = (18,)) -> None:
    """Time and score flow methods on orchard-world pairs with exact flow; print a table.

    Args:
        seeds: World seeds, one pair each.
        steps: Camera steps of 7.5 mm / 18 each (1/60 s at 25 mm/s up) between the frames.
    """
    from branch_gym.sim.scene.flow import ground_truth_flow
    from branch_gym.sim.world import World, WorldConfig

    cv2.setNumThreads(1)
    methods = {
        "DIS ultrafast": lambda a, b: compute_flow(a, b, DenseFlowConfig(preset="ultrafast")),
        "DIS fast": lambda a, b: compute_flow(a, b, DenseFlowConfig(preset="fast")),
        "DIS medium": lambda a, b: compute_flow(a, b, DenseFlowConfig(preset="medium")),
        "DIS ultrafast fs1": lambda a, b: compute_flow(a, b, DenseFlowConfig(finest_scale=1)),
        "Farneback": lambda a, b: cv2.calcOpticalFlowFarneback(
            cv2.cvtColor(b, cv2.COLOR_RGB2GRAY),
            cv2.cvtColor(a, cv2.COLOR_RGB2GRAY),
            None,
            0.5,
            3,
            15,
            3,
            5,
            1.2,
            0,
        ),
        "picture (flow-vis)": None,
    }
    world = World(WorldConfig.preset("orchard"))
    pairs = []
    for seed in seeds:
        world.reset(seed)
        T1, first = world.T_world_camera, world.render()
        done = 0
        for total in steps:
            for _ in range(total - done):
                world.apply_camera_twist(np.array([0, -0.025, 0, 0, 0, 0]), 1 / 60)
            done = total
            T2, second = world.T_world_camera, world.render()
            # current-to-previous: on frame 2's grid, pointing into frame 1
            truth = ground_truth_flow(second.depth_m, T2, T1, world.config.camera)
            tree = (second.labels >= 1) & (second.labels < 100)
            baseline = float(np.linalg.norm(T2[:3, 3] - T1[:3, 3]))
            pairs.append((total, baseline, first.rgb, second.rgb, truth, tree))
    world.close()
    print(f"{len(seeds)} orchard pairs a baseline, 320x240, one core (cv2.setNumThreads(1))")
    header = f"{'method':20s} {'mm':>5s} {'ms':>6s} {'EPE tree':>9s} {'EPE all':>8s} {'AUC':>6s}"
    print(header)
    for total in steps:
        selected = [p for p in pairs if p[0] == total]
        baseline_mm = 1000 * float(np.mean([p[1] for p in selected]))
        truth_motion = np.mean([np.linalg.norm(p[4], axis=2)[p[5]].mean() for p in selected])
        for name, method in methods.items():
            times, tree_epe, all_epe, aucs = [], [], [], []
            for _, _, previous, current, truth, tree in selected:
                call = method or (lambda a, b, t=truth: flow_to_picture(t))
                repeats = []
                for _ in range(5):
                    start = time.perf_counter()
                    flow = call(previous, current)
                    repeats.append(time.perf_counter() - start)
                times.append(min(repeats))
                if method is None:
                    continue
                error = np.linalg.norm(flow - truth, axis=2)
                known = np.isfinite(error)
                tree_epe.append(error[tree & known].mean())
                all_epe.append(error[known].mean())
                magnitude = np.linalg.norm(flow, axis=2)
                aucs.append(_auc(magnitude[tree], magnitude[~tree][::7]))
            if method is None:
                print(f"{name:20s} {baseline_mm:5.2f} {1000 * np.median(times):6.2f}")
                continue
            print(
                f"{name:20s} {baseline_mm:5.2f} {1000 * np.median(times):6.2f} "
                f"{np.mean(tree_epe):9.2f} {np.mean(all_epe):8.2f} {np.mean(aucs):6.3f}"
            )
        print(f"{'(exact flow)':20s} {baseline_mm:5.2f} {'':6s} {truth_motion:9.2f} (mean motion)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--baselines", action="store_true", help="also 1.25-5 mm between the frames"
    )
    arguments = parser.parse_args()
    run_benchmark(steps=(3, 6, 12, 18) if arguments.baselines else (18,))
