"""Procedural trees with exact ground truth: one primary branch, its secondaries, and clutter.

This module samples trees; the ground-truth types (:class:`BranchGT`, :class:`TreeGT`) live in
``branch_gym/sim/tree/ground_truth.py`` and the distribution (:class:`TreeConfig`) in
``branch_gym/sim/tree/config.py``.

The distribution reproduces the authors' simulated world (reference.md, "Simulated world"; paper
section VI-A). World frame: z up, ground at z = 0. The primary branch rises from z = 0 to
z = 1 m and passes the origin (x, y) = (0, 0) at the scan start height (0.275 m), up to a small
jitter in y. The camera scans from the -y side looking along +y, so "toward the camera" is the
-y direction (yaw 270 deg) and background clutter lies at larger y, behind the scanned tree.

Radius tapering: every branch's radius changes linearly with arc length.

* Primary: ``r(s) = r_ref * (1 - primary_taper_per_m * (s - s_ref))``, where ``s`` is the arc
  length from the base, ``s_ref`` the arc length at ``primary_radius_reference_height_m`` (the
  middle of the scan band), and ``r_ref ~ U(3, 7.5) mm`` is therefore exactly the radius there.
* Secondary: from ``r_base`` (primary radius at its base height x U(0.8, 1.0)) at the base to
  ``r_base * secondary_tip_radius_fraction`` at the tip.

The authors' Blender tubes have constant radii: ``primary_taper_per_m=0`` and
``secondary_tip_radius_fraction=1`` reproduce them exactly.

Architectures (``TreeConfig.architecture``): the presets ``TreeConfig.tall_spindle()`` and
``TreeConfig.ufo()`` use this same sampler with other ranges; a UFO upright starts at
``primary_base_height_m`` (its cordon's height) instead of the ground.

Details: :func:`generate_tree` leaves ``TreeGT.details`` (spurs, pruning stubs, buds) empty. The
world that wants them calls ``branch_gym.sim.tree.details.grow_details`` with its own random
stream, so that adding details never changes the tree a seed gives.
"""

from __future__ import annotations

import math

import numpy as np

from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from branch_gym.sim.tree.polyline import (
    arc_lengths,
    axis_frame,
    eval_cubic_bezier,
    resample_polyline,
    segment_at_height,
)

__all__ = ["generate_tree", "sample_primary_bezier", "tree_from_seed"]

# The camera looks along +y from the -y side: a branch pointing at it points along -y.
_YAW_TOWARD_CAMERA_DEG = 270.0
_YAW_AWAY_FROM_CAMERA_DEG = 90.0
_FULL_TURN_DEG = 360.0


def tree_from_seed(seed: int, config: TreeConfig | None = None) -> TreeGT:
    """Generate the tree of ``seed``: same seed, same tree."""
    return generate_tree(config or TreeConfig(), np.random.default_rng(seed), seed=seed)


def generate_tree(config: TreeConfig, rng: np.random.Generator, seed: int | None = None) -> TreeGT:
    """Sample one tree: primary, secondaries and clutter, with dense ground truth.

    Args:
        config: The tree distribution.
        rng: Source of every random draw.
        seed: Recorded in the result (the seed ``rng`` was made from), not used for sampling.

    Returns:
        The tree in the world frame (z up, ground z = 0, camera on the -y side). Its
        ``details`` are left empty (``details.grow_details`` adds them from another stream).
    """
    primary = _sample_branch_trunk(config, rng, config.primary_radius_range_m)
    base_xy = _point_and_radius_at_height(primary, config.placement_height_m)[0][:2]
    shift = np.array(
        [-base_xy[0], -base_xy[1] + rng.uniform(*config.placement_jitter_y_range_m), 0]
    )
    primary.points += shift
    secondaries = _sample_secondaries(config, rng, primary)
    clutter = _sample_clutter(config, rng, [primary, *secondaries])
    recorded_seed = None if seed is None else int(seed)
    return TreeGT(primary=primary, secondaries=secondaries, clutter=clutter, seed=recorded_seed)


def sample_primary_bezier(config: TreeConfig, rng: np.random.Generator) -> np.ndarray:
    """Control points of a primary branch standing at the origin, before placement.

    The base is at (0, 0, primary_base_height_m), the top at (dx, dy, primary_height_m) with
    dx, dy drawn from ``primary_top_offset_range_m``. Each inner control point lies in a cone
    about the base-to-top axis: tilt U(0, max tilt), azimuth U(0, 360) deg, handle length
    U(0, max fraction x length).

    Returns:
        (4, 3) control points in metres.
    """
    start = np.array([0.0, 0.0, config.primary_base_height_m])
    top_dx_m, top_dy_m = rng.uniform(*config.primary_top_offset_range_m, size=2)
    end = np.array([top_dx_m, top_dy_m, config.primary_height_m])
    length_m = float(np.linalg.norm(end - start))
    frame = axis_frame((end - start) / length_m)
    handles = []
    for _ in range(2):
        handle_m = rng.uniform(0.0, config.primary_max_handle_fraction * length_m)
        tilt = rng.uniform(0.0, math.radians(config.primary_max_tilt_deg))
        azimuth = rng.uniform(0.0, 2 * math.pi)
        local = handle_m * np.array(
            [math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)]
        )
        handles.append(frame @ local)
    return np.stack([start, start + handles[0], end - handles[1], end])


def _sample_branch_trunk(
    config: TreeConfig, rng: np.random.Generator, radius_range_m: tuple[float, float]
) -> BranchGT:
    """A tapered primary-like trunk standing at the origin (also used for background trees)."""
    control = sample_primary_bezier(config, rng)
    radius_ref_m = rng.uniform(*radius_range_m)
    points = resample_polyline(eval_cubic_bezier(control), config.centerline_spacing_m)
    arc_m = arc_lengths(points)
    index, frac = segment_at_height(points, config.primary_radius_reference_height_m)
    s_ref = arc_m[index] + frac * (arc_m[index + 1] - arc_m[index])
    radii = radius_ref_m * (1.0 - config.primary_taper_per_m * (arc_m - s_ref))
    return BranchGT(points, radii)


def _sample_yaw_deg(config: TreeConfig, rng: np.random.Generator) -> float:
    if config.yaw_mode == "uniform":
        return float(rng.uniform(0.0, _FULL_TURN_DEG))
    if config.yaw_mode == "toward_camera":
        center = _YAW_TOWARD_CAMERA_DEG
    elif config.yaw_mode == "away_from_camera":
        center = _YAW_AWAY_FROM_CAMERA_DEG
    else:
        center = _YAW_TOWARD_CAMERA_DEG if rng.random() < 0.5 else _YAW_AWAY_FROM_CAMERA_DEG
    spread = rng.uniform(-config.yaw_spread_deg, config.yaw_spread_deg)
    return float((center + spread) % _FULL_TURN_DEG)


def _group_heights(heights_m: np.ndarray, group_height_m: float) -> list[tuple[float, int]]:
    """Merge sorted base heights closer than ``group_height_m`` to their group's first height."""
    groups: list[tuple[float, int]] = []
    for z in heights_m:
        if groups and z - groups[-1][0] < group_height_m:
            groups[-1] = (groups[-1][0], groups[-1][1] + 1)
        else:
            groups.append((float(z), 1))
    return groups


def _sample_secondaries(
    config: TreeConfig, rng: np.random.Generator, primary: BranchGT
) -> list[BranchGT]:
    low, high = config.secondary_count_range
    count = int(rng.integers(low, high + 1))
    heights_m = np.sort(rng.uniform(*config.secondary_base_height_range_m, size=count))
    branches = []
    for height_m, n_at_height in _group_heights(heights_m, config.secondary_group_height_m):
        base, primary_radius_m = _point_and_radius_at_height(primary, height_m)
        first_yaw_deg = _sample_yaw_deg(config, rng)
        for k in range(n_at_height):
            yaw = math.radians(first_yaw_deg + k * _FULL_TURN_DEG / n_at_height)
            elevation = math.radians(rng.uniform(*config.secondary_elevation_range_deg))
            direction = np.array(
                [
                    math.cos(elevation) * math.cos(yaw),
                    math.cos(elevation) * math.sin(yaw),
                    math.sin(elevation),
                ]
            )
            length_m = rng.uniform(*config.secondary_length_range_m)
            base_radius_m = primary_radius_m * rng.uniform(*config.secondary_radius_scale_range)
            strength = rng.uniform(*config.secondary_bend_strength_range_per_m)
            branch = _grow_secondary(config, base, direction, length_m, strength, base_radius_m)
            branches.append(_cut_back_alley_side(config, branch, yaw))
    return branches


def _cut_back_alley_side(config: TreeConfig, branch: BranchGT, yaw_rad: float) -> BranchGT:
    """``branch`` cut where it leaves ``config.alley_side_reach_m`` of the leader, if it points
    to the robot's side (yaw within ``alley_side_half_angle_deg`` of the camera direction).

    A hedged fruiting wall: the alley face is cut back so that the scanning camera passes
    (``TreeConfig.alley_side_reach_m``). No random draw: the tree of a seed keeps every other
    branch. Returns ``branch`` unchanged when the reach is None or it points elsewhere.
    """
    reach_m = config.alley_side_reach_m
    if reach_m is None:
        return branch
    off_camera_deg = (math.degrees(yaw_rad) - _YAW_TOWARD_CAMERA_DEG + 180.0) % 360.0 - 180.0
    if abs(off_camera_deg) > config.alley_side_half_angle_deg:
        return branch
    horizontal_m = np.linalg.norm(branch.points[:, :2] - branch.points[0, :2], axis=1)
    keep = int(np.searchsorted(horizontal_m > reach_m, True))  # first point beyond the reach
    if keep >= len(horizontal_m):
        return branch
    keep = max(keep, 2)
    return BranchGT(branch.points[:keep].copy(), branch.radii[:keep].copy())


def _grow_secondary(
    config: TreeConfig,
    base: np.ndarray,
    direction: np.ndarray,
    length_m: float,
    bend_strength_per_m: float,
    base_radius_m: float,
) -> BranchGT:
    """Grow a branch in equal steps, bending the direction upward after each step.

    Args:
        base: (3,) start point in metres (on the primary centerline).
        direction: (3,) unit initial direction.
        length_m: Branch length (arc length) in metres.
        bend_strength_per_m: Upward pull added to the direction per metre grown.
        base_radius_m: Radius at the base in metres.
    """
    steps = config.secondary_bend_steps
    step_m = length_m / steps
    headings = np.empty((steps, 3))
    headings[0] = direction
    for k in range(1, steps):
        heading = headings[k - 1] + np.array([0.0, 0.0, bend_strength_per_m * step_m])
        headings[k] = heading / math.sqrt(heading @ heading)
    # Walk the coarse polyline (segment k along headings[k], step_m long) at the dense spacing.
    arc_m = np.linspace(
        0.0, length_m, max(math.ceil(length_m / config.centerline_spacing_m), 1) + 1
    )
    segment = np.minimum((arc_m / step_m).astype(int), steps - 1)
    corners = base + np.concatenate([[np.zeros(3)], np.cumsum(headings * step_m, axis=0)])
    points = corners[segment] + (arc_m - segment * step_m)[:, None] * headings[segment]
    taper = 1.0 - (1.0 - config.secondary_tip_radius_fraction) * arc_m / length_m
    return BranchGT(points, base_radius_m * taper)


def _sample_clutter(
    config: TreeConfig, rng: np.random.Generator, scanned: list[BranchGT]
) -> list[BranchGT]:
    """Background trees and trellis wires, all behind the scanned tree's deepest point (max y)."""
    back_y_m = max(float(b.points[:, 1].max()) for b in scanned)
    clutter: list[BranchGT] = []
    low, high = config.background_tree_count_range
    for _ in range(int(rng.integers(low, high + 1))):
        trunk = _sample_branch_trunk(config, rng, config.background_tree_radius_range_m)
        group = [trunk, *_sample_secondaries(config, rng, trunk)]
        front_y_m = min(float(b.points[:, 1].min()) for b in group)
        shift = np.array(
            [
                rng.uniform(*config.background_tree_x_range_m),
                back_y_m + rng.uniform(*config.background_tree_distance_range_m) - front_y_m,
                0.0,
            ]
        )
        for branch in group:
            branch.points += shift
        clutter.extend(group)
    half = config.trellis_wire_half_length_m
    n_points = round(2 * half / config.centerline_spacing_m) + 1
    for height_m in config.trellis_wire_heights_m:
        x = np.linspace(-half, half, n_points)
        wire_y_m = back_y_m + config.trellis_wire_distance_m
        points = np.stack([x, np.full_like(x, wire_y_m), np.full_like(x, height_m)], axis=1)
        clutter.append(BranchGT(points, np.full(n_points, config.trellis_wire_radius_m)))
    return clutter


def _point_and_radius_at_height(branch: BranchGT, height_m: float) -> tuple[np.ndarray, float]:
    """(3,) centerline point and radius in metres where ``branch`` first reaches ``height_m``."""
    index, frac = segment_at_height(branch.points, height_m)
    point = branch.points[index] + frac * (branch.points[index + 1] - branch.points[index])
    radius_m = branch.radii[index] + frac * (branch.radii[index + 1] - branch.radii[index])
    return point, float(radius_m)
