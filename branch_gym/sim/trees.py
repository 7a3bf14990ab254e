"""Procedural trees with exact ground truth: one primary branch, its secondaries, and clutter.

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
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

YAW_MODES = ("uniform", "toward_camera", "away_from_camera", "toward_or_away_camera")
# The camera looks along +y from the -y side: a branch pointing at it points along -y.
_YAW_TOWARD_CAMERA_DEG = 270.0
_YAW_AWAY_FROM_CAMERA_DEG = 90.0
# Instance labels 2 + i must stay below the first clutter label 100 (label-image convention).
_MAX_SECONDARIES = 98
_FULL_TURN_DEG = 360.0
# Bezier samples before resampling by arc length (~1 mm chords: sagitta far below 1 um).
_BEZIER_EVAL_SAMPLES = 1024


@dataclass(eq=False)
class BranchGT:
    """Ground truth of one branch: a dense centerline with a radius per point.

    Attributes:
        points: (N, 3) dense centerline in metres, world frame, ordered base -> tip
            (primary: bottom -> top), N >= 2.
        radii: (N,) radius in metres at each point, all positive.
    """

    points: np.ndarray
    radii: np.ndarray

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=float)
        self.radii = np.asarray(self.radii, dtype=float)
        if self.points.ndim != 2 or self.points.shape[1] != 3 or len(self.points) < 2:
            raise ValueError(f"points must have shape (N >= 2, 3), got {self.points.shape}")
        if self.radii.shape != (len(self.points),):
            raise ValueError(f"radii must have shape ({len(self.points)},), got {self.radii.shape}")
        if not (np.all(np.isfinite(self.points)) and np.all(np.isfinite(self.radii))):
            raise ValueError("points and radii must be finite")
        if np.any(self.radii <= 0):
            raise ValueError("radii must be positive")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BranchGT):
            return NotImplemented
        return np.array_equal(self.points, other.points) and np.array_equal(self.radii, other.radii)

    __hash__ = None  # type: ignore[assignment]  # mutable arrays: not hashable

    @property
    def length_m(self) -> float:
        """Polyline length in metres."""
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def to_dict(self) -> dict:
        return {"points": self.points.tolist(), "radii": self.radii.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> BranchGT:
        return cls(np.asarray(data["points"], dtype=float), np.asarray(data["radii"], dtype=float))


@dataclass
class TreeGT:
    """Ground truth of one generated tree.

    Attributes:
        primary: The scanned primary branch (bottom -> top).
        secondaries: Side branches, each starting on the primary centerline at its base.
        clutter: Background trees and trellis wires: rendered, not part of the scanned tree.
        seed: The seed the tree was generated from, when known.
    """

    primary: BranchGT
    secondaries: list[BranchGT] = field(default_factory=list)
    clutter: list[BranchGT] = field(default_factory=list)
    seed: int | None = None

    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "primary": self.primary.to_dict(),
            "secondaries": [b.to_dict() for b in self.secondaries],
            "clutter": [b.to_dict() for b in self.clutter],
        }

    @classmethod
    def from_dict(cls, data: dict) -> TreeGT:
        seed = data.get("seed")
        return cls(
            primary=BranchGT.from_dict(data["primary"]),
            secondaries=[BranchGT.from_dict(b) for b in data.get("secondaries", [])],
            clutter=[BranchGT.from_dict(b) for b in data.get("clutter", [])],
            seed=None if seed is None else int(seed),
        )

    def save_json(self, path: str | Path) -> None:
        """Write the tree as JSON; floats are written with round-trip exact precision."""
        Path(path).write_text(json.dumps(self.to_dict()))

    @classmethod
    def load_json(cls, path: str | Path) -> TreeGT:
        return cls.from_dict(json.loads(Path(path).read_text()))


@dataclass(frozen=True)
class TreeConfig:
    """The tree distribution. Defaults are the paper's simulated world.

    Ranges are ``(low, high)`` tuples sampled uniformly (integers inclusive); ``low == high``
    fixes a value. Angles in degrees, lengths in metres. Yaw is measured in the world xy plane
    from +x toward +y; elevation is the angle above the horizontal plane.
    """

    # --- primary (reference.md "Simulated world", paper VI-A) ---
    primary_height_m: float = 1.0  # cubic Bezier from z = 0 to z = 1.0 m
    primary_top_offset_range_m: tuple[float, float] = (-0.10, 0.10)  # top end x, y offset
    primary_max_tilt_deg: float = 30.0  # inner control points tilted at most 30 deg
    primary_max_handle_fraction: float = 0.5  # handle length at most half the branch length
    primary_radius_range_m: tuple[float, float] = (0.003, 0.0075)  # radius ~ U(3, 7.5) mm
    # Height where the sampled radius holds: middle of the scan band 0.275-0.75 m (task brief).
    primary_radius_reference_height_m: float = 0.5
    # Fractional radius loss per metre of arc length going up; project choice (mild; the
    # authors' tubes are constant, 0 reproduces them).
    primary_taper_per_m: float = 0.2
    # The primary passes (x, y) = (0, 0) at the scan start height 0.275 m (reference.md, "Scan").
    placement_height_m: float = 0.275
    placement_jitter_y_range_m: tuple[float, float] = (-0.02, 0.02)  # U(-2, 2) cm jitter
    centerline_spacing_m: float = 0.001  # dense ground truth: 1 mm spacing (task brief)

    # --- secondaries (reference.md "Simulated world", paper VI-A) ---
    secondary_count_range: tuple[int, int] = (0, 5)  # 0 to 5 per tree
    secondary_base_height_range_m: tuple[float, float] = (0.325, 0.75)  # paper (code: 0.70)
    secondary_group_height_m: float = 0.05  # bases closer than 5 cm share one height
    secondary_elevation_range_deg: tuple[float, float] = (-15.0, 45.0)  # elevation [-15, 45]
    yaw_mode: str = "uniform"  # "yaw can be any value"; other modes: harder variants
    yaw_spread_deg: float = 30.0  # half-width of the yaw spread in non-uniform modes
    secondary_length_range_m: tuple[float, float] = (0.05, 0.15)  # length ~ U(5, 15) cm
    secondary_radius_scale_range: tuple[float, float] = (0.8, 1.0)  # x primary radius
    secondary_tip_radius_fraction: float = 0.8  # mild taper: project choice (authors: 1.0)
    secondary_bend_steps: int = 10  # upward bending steps (authors' code: 10)
    # Upward bending strength per metre (authors' code: phototropism coefficient U(0, 2)).
    secondary_bend_strength_range_per_m: tuple[float, float] = (0.0, 2.0)

    # --- clutter (harder variants; off in the paper's world) ---
    background_tree_count_range: tuple[int, int] = (0, 0)
    # Distance behind the scanned tree's deepest point; orchard trees were 30-40 cm behind (VI-C).
    background_tree_distance_range_m: tuple[float, float] = (0.3, 1.0)
    background_tree_x_range_m: tuple[float, float] = (-0.3, 0.3)  # lateral spread, in view
    background_tree_radius_range_m: tuple[float, float] = (0.005, 0.015)  # project choice
    trellis_wire_heights_m: tuple[float, ...] = ()  # horizontal wires along x at these heights
    trellis_wire_distance_m: float = 0.3  # behind the scanned tree's deepest point
    trellis_wire_radius_m: float = 0.0015  # ~3 mm trellis wire: project choice
    trellis_wire_half_length_m: float = 0.5  # wires span x in [-0.5, 0.5] m

    def __post_init__(self) -> None:
        for f in fields(self):
            if "_range" in f.name:
                _check_range(f.name, getattr(self, f.name))
        positive = (
            "primary_height_m",
            "primary_radius_range_m",
            "centerline_spacing_m",
            "secondary_length_range_m",
            "secondary_radius_scale_range",
            "secondary_bend_steps",
            "background_tree_radius_range_m",
            "trellis_wire_radius_m",
            "trellis_wire_half_length_m",
        )
        for name in positive:
            _require(np.min(getattr(self, name)) > 0, name, "must be positive")
        non_negative = (
            "secondary_count_range",
            "secondary_group_height_m",
            "secondary_bend_strength_range_per_m",
            "background_tree_count_range",
            "background_tree_distance_range_m",
            "trellis_wire_distance_m",
        )
        for name in non_negative:
            _require(np.min(getattr(self, name)) >= 0, name, "must be non-negative")
        for name in (
            "secondary_count_range",
            "background_tree_count_range",
            "secondary_bend_steps",
        ):
            values = np.atleast_1d(getattr(self, name))
            _require(all(int(v) == v for v in values), name, "must hold integers")
        _require(
            self.secondary_count_range[1] <= _MAX_SECONDARIES,
            "secondary_count_range",
            f"allows at most {_MAX_SECONDARIES} branches (instance labels 2 + i < 100)",
        )
        _require(0 <= self.primary_max_tilt_deg < 90, "primary_max_tilt_deg", "must be in [0, 90)")
        _require(
            0 <= self.primary_max_handle_fraction <= 1,
            "primary_max_handle_fraction",
            "must be in [0, 1]",
        )
        _require(0 <= self.primary_taper_per_m < 1, "primary_taper_per_m", "must be in [0, 1)")
        _require(
            0 < self.secondary_tip_radius_fraction <= 1,
            "secondary_tip_radius_fraction",
            "must be in (0, 1]",
        )
        _require(0 <= self.yaw_spread_deg <= 180, "yaw_spread_deg", "must be in [0, 180]")
        _require(self.yaw_mode in YAW_MODES, "yaw_mode", f"must be one of {YAW_MODES}")
        elevation = self.secondary_elevation_range_deg
        _require(
            -90 <= elevation[0] and elevation[1] <= 90,
            "secondary_elevation_range_deg",
            "must lie in [-90, 90]",
        )
        heights = (
            "placement_height_m",
            "primary_radius_reference_height_m",
            "secondary_base_height_range_m",
            "trellis_wire_heights_m",
        )
        for name in heights:
            values = np.atleast_1d(np.asarray(getattr(self, name), dtype=float))
            _require(
                bool(np.all((values >= 0) & (values <= self.primary_height_m))),
                name,
                "must lie within [0, primary_height_m]",
            )

    def to_dict(self) -> dict:
        """Plain JSON-able values (tuples become lists)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TreeConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise TypeError."""
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})

    @classmethod
    def paper(cls) -> TreeConfig:
        """The paper's simulated world (the defaults)."""
        return cls()

    @classmethod
    def cluttered(cls) -> TreeConfig:
        """The paper's tree in front of 1-3 background trees and two trellis wires."""
        return cls(
            background_tree_count_range=(1, 3),
            trellis_wire_heights_m=(0.45, 0.65),
        )

    @classmethod
    def hard(cls) -> TreeConfig:
        """Clutter, more and thinner secondaries, pointing at or away from the camera."""
        return replace(
            cls.cluttered(),
            secondary_count_range=(2, 8),
            secondary_radius_scale_range=(0.4, 0.8),
            yaw_mode="toward_or_away_camera",
            yaw_spread_deg=30.0,
        )


def _require(condition: bool, name: str, problem: str) -> None:
    if not condition:
        raise ValueError(f"TreeConfig.{name} {problem}")


def _check_range(name: str, value: tuple[float, float]) -> None:
    _require(len(value) == 2, name, f"must be a (low, high) pair, got {value}")
    _require(bool(np.all(np.isfinite(value))), name, f"must be finite, got {value}")
    _require(value[0] <= value[1], name, f"is an inverted range (low > high): {value}")


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
        The tree in the world frame (z up, ground z = 0, camera on the -y side).
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

    The base is at (0, 0, 0), the top at (dx, dy, primary_height_m) with dx, dy drawn from
    ``primary_top_offset_range_m``. Each inner control point lies in a cone about the base-to-top
    axis: tilt U(0, max tilt), azimuth U(0, 360) deg, handle length U(0, max fraction x length).

    Returns:
        (4, 3) control points in metres.
    """
    start = np.zeros(3)
    top_dx_m, top_dy_m = rng.uniform(*config.primary_top_offset_range_m, size=2)
    end = np.array([top_dx_m, top_dy_m, config.primary_height_m])
    length_m = float(np.linalg.norm(end - start))
    frame = _axis_frame((end - start) / length_m)
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
    points = _resample_polyline(_eval_cubic_bezier(control), config.centerline_spacing_m)
    arc_m = _arc_lengths(points)
    index, frac = _segment_at_height(points, config.primary_radius_reference_height_m)
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
            branches.append(
                _grow_secondary(config, base, direction, length_m, strength, base_radius_m)
            )
    return branches


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


# --- polyline geometry -------------------------------------------------------------------------


def _axis_frame(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose columns are x, y, z axes with z = ``axis`` (unit, not along x)."""
    y_axis = np.cross(axis, [1.0, 0.0, 0.0])
    y_axis /= np.linalg.norm(y_axis)
    return np.stack([np.cross(y_axis, axis), y_axis, axis], axis=1)


def _eval_cubic_bezier(control: np.ndarray) -> np.ndarray:
    """(S, 3) points of the cubic Bezier with (4, 3) ``control`` points, uniform in parameter."""
    t = np.linspace(0.0, 1.0, _BEZIER_EVAL_SAMPLES)[:, None]
    u = 1.0 - t
    return (
        u**3 * control[0]
        + 3 * u**2 * t * control[1]
        + 3 * u * t**2 * control[2]
        + t**3 * control[3]
    )


def _arc_lengths(points: np.ndarray) -> np.ndarray:
    """(N,) arc length in metres from the first of the (N, 3) ``points`` to each point."""
    steps = np.diff(points, axis=0)
    return np.concatenate([[0.0], np.cumsum(np.sqrt(np.einsum("ij,ij->i", steps, steps)))])


def _resample_polyline(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """Resample (N, 3) ``points`` evenly by arc length, at most ``spacing_m`` apart, same ends."""
    arc_m = _arc_lengths(points)
    n_out = max(math.ceil(arc_m[-1] / spacing_m) + 1, 2)
    targets = np.linspace(0.0, arc_m[-1], n_out)
    return np.stack([np.interp(targets, arc_m, points[:, k]) for k in range(3)], axis=1)


def _segment_at_height(points: np.ndarray, height_m: float) -> tuple[int, float]:
    """Segment index i and fraction in [0, 1] where the (N, 3) polyline first reaches height_m."""
    rising_z = np.maximum.accumulate(points[:, 2])
    index = int(np.clip(np.searchsorted(rising_z, height_m) - 1, 0, len(points) - 2))
    z0, z1 = points[index, 2], points[index + 1, 2]
    frac = 0.0 if z1 == z0 else float(np.clip((height_m - z0) / (z1 - z0), 0.0, 1.0))
    return index, frac


def _point_and_radius_at_height(branch: BranchGT, height_m: float) -> tuple[np.ndarray, float]:
    """(3,) centerline point and radius in metres where ``branch`` first reaches ``height_m``."""
    index, frac = _segment_at_height(branch.points, height_m)
    point = branch.points[index] + frac * (branch.points[index + 1] - branch.points[index])
    radius_m = branch.radii[index] + frac * (branch.radii[index + 1] - branch.radii[index])
    return point, float(radius_m)
