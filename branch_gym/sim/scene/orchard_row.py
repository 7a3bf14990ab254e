"""The orchard row around the scanned tree, as geometry: neighbours, rows behind, trellis.

World frame as in ``sim/tree/generator.py``: z up, ground z = 0, the scanned primary near
(x, y) = (0, 0), the camera on the -y side looking along +y. The row runs along x:

* **Neighbours** of the same architecture stand along the row at x = +-(0.6-1.2 m) steps
  (paper VI-C; dormant apple rows, reference.md "Real close-up frames"), as real geometry with
  true depth: trunks, branches, and many thin twigs (1-6 mm thick). Some of their branches
  reach across the scanned tree on the camera's side (the occluders that cost the paper's
  orchard trials their branches, section VII). For a UFO tree the neighbours along the cordon
  are the scanned tree's own uprights, 0.2-0.35 m apart.
* **Rows behind** at 3-4 m and one more row beyond, drawn as depth-correct impostors (one
  textured plane per row, ``sim/scene/impostor.py``): at 3 m and more the depth spread of a
  tree (< 0.5 m) moves its flow by under a fifth, and a pixel covers ~8 mm.
* **Trellis**: 2-4 sagging wires along the row at the row's heights (one in the scan band), posts
  every 4-8 m, and clips where the scan-band wire crosses the scanned tree.

:func:`generate_row` draws all of it from a generator; nothing here touches pybullet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from branch_gym.sim.validation import require_positive

__all__ = [
    "ROW_PARTS",
    "BackRow",
    "OrchardRow",
    "OrchardRowConfig",
    "Post",
    "RowTree",
    "ScanView",
    "generate_row",
    "potentially_visible",
]

_CULL_ROTATIONS = 25  # orbit poses tested per side (5 deg apart at 60 deg)
_WIRE_POINTS = 49  # 0.5 m steps over 24 m: the sag between posts is smooth at that spacing
_SIGNED_RANGES = ("wire_offset_y_range_m",)  # ranges that may hold negative values
# OrchardRowConfig.visible_height_m holds for scans up to the paper's 0.75 m; a band reaching
# higher (the tall-spindle leader's, docs/worlds.md) raises it by as much.
_PAPER_BAND_TOP_M = 0.75
# Parts of the row an ablation can leave out (OrchardRowConfig.left_out).
ROW_PARTS = ("neighbours", "crossing", "wires")


@dataclass(frozen=True)
class OrchardRowConfig:
    """The row around the scanned tree. Ranges are ``(low, high)`` drawn uniformly.

    Attributes:
        neighbour_spacing_range_m: Tree-to-tree distance along the row (task brief: 0.6-1.2 m).
        neighbours_per_side: Neighbour trees built as geometry on each side (our choice: two per
            side cover what the camera sees at up to 45 deg of rotation).
        upright_spacing_range_m: Upright-to-upright distance along a UFO cordon (orchard
            practice: 20-35 cm).
        uprights_per_side: UFO uprights on each side built as geometry.
        trunk_height_range_m: Neighbour height (tall-spindle rows: 2.5-3.5 m; only the lower
            part is ever in view).
        trunk_radius_range_m: Neighbour trunk radius at the scan band (real trunks 10-25 px wide
            at 0.2-0.5 m: ~8-20 mm).
        branches_per_m: Branches per metre of trunk (dormant apple leaders: ~8-12).
        branch_length_range_m: Branch length (our choice, tall-spindle practice).
        branch_radius_fraction_range: Branch base radius over the trunk's (under half: pruning).
        twigs_per_branch_range: Upright one-year shoots per branch (dormant rows: many).
        twig_length_range_m: Shoot length (our choice: 10-50 cm).
        twig_radius_range_m: Shoot base radius (task brief: twigs 1-6 mm thick).
        trained_along_row_fraction: Fraction of branches trained into the row's plane
            (tall-spindle and V-trellis practice; the rest point anywhere): they reach into the
            scanned tree's view at its depth, where parallax cannot separate them.
        row_plane_spread_deg: Yaw spread of those branches about the row direction.
        crossing_branch_count_range: Neighbour branches reaching across the scanned tree on
            the camera's side, within the scan band (our choice: 0-3; some twigs stand in
            front of the scanned tree, task brief).
        crossing_radius_range_m: Their radius where they leave the neighbour (thin wood, 4-10 mm
            thick; they taper to twig size where they cross).
        crossing_gap_range_m: How far in front of the scanned tree's axis they cross (our
            choice: between the camera, 0.2 m away, and the bark).
        visible_height_m: Geometry above this height is dropped: a level camera at most 0.8 m
            high with a +-16 deg vertical field of view never sees it within 2.5 m (LOD).
        cull_max_rotation_deg: Neighbour branches no scan pose can see are dropped: poses on
            the orbit about the scanned axis up to this rotation (the paper's largest is 45 deg)
            at the scan band's heights, looking at the axis (view-volume culling, as renderers
            do; it changes no pixel of a scan within that rotation).
        cull_margin_deg: Angular margin of that test beyond the camera's field of view.
        back_row_distance_range_m: Distance of the next row behind (task brief: 3-4 m).
        far_row_extra_range_m: The row after it, this much farther (orchard rows ~3.5 m apart).
        back_row_half_length_m: Rows behind span x in +-this (what a 45 deg rotation can see).
        wire_count_range: Trellis wires (task brief: 2-4).
        scan_band_wire_height_range_m: Height of the one wire inside the scan band (our choice).
        upper_wire_height_range_m: Heights of the other wires (orchard practice: 0.9-2.2 m).
        wire_offset_y_range_m: Wires' y relative to the scanned axis (a tree is tied to them).
        wire_radius_range_m: Wire radius (task brief: 2-4 mm thick).
        wire_sag_range_m: Sag between two posts (our choice: taut high-tensile wire).
        post_spacing_range_m: Distance between posts (orchard practice: 4-8 m in our rows).
        post_radius_range_m: Post radius (task brief: 8-12 cm wide).
        post_height_range_m: Post height above the ground.
        post_clearance_m: No post closer than this to the scanned tree along the row (the robot
            scans it from 0.2 m).
        clip_length_range_m: Length of a clip where the scan-band wire meets the scanned tree.
        left_out: Parts of :data:`ROW_PARTS` drawn as usual and then left out of the scene
            ("neighbours": the neighbour trees, not a UFO tree's own uprights; "crossing": the
            branches reaching across the scanned tree; "wires": wires and clips). Every other
            draw, the scene's after the row's included, stays that of the full orchard: an
            ablation compares the same scenes, one part apart.
    """

    neighbour_spacing_range_m: tuple[float, float] = (0.6, 1.2)
    neighbours_per_side: int = 2
    upright_spacing_range_m: tuple[float, float] = (0.2, 0.35)
    uprights_per_side: int = 4
    trunk_height_range_m: tuple[float, float] = (2.2, 3.2)
    trunk_radius_range_m: tuple[float, float] = (0.008, 0.02)
    branches_per_m: float = 10.0
    branch_length_range_m: tuple[float, float] = (0.2, 0.7)
    branch_radius_fraction_range: tuple[float, float] = (0.25, 0.5)
    twigs_per_branch_range: tuple[int, int] = (1, 5)
    twig_length_range_m: tuple[float, float] = (0.1, 0.5)
    twig_radius_range_m: tuple[float, float] = (0.0008, 0.003)
    trained_along_row_fraction: float = 0.7
    row_plane_spread_deg: float = 35.0
    crossing_branch_count_range: tuple[int, int] = (0, 3)
    crossing_radius_range_m: tuple[float, float] = (0.002, 0.005)
    crossing_gap_range_m: tuple[float, float] = (0.03, 0.12)
    visible_height_m: float = 1.7
    cull_max_rotation_deg: float = 50.0
    cull_margin_deg: float = 5.0
    back_row_distance_range_m: tuple[float, float] = (3.0, 4.0)
    far_row_extra_range_m: tuple[float, float] = (3.0, 4.0)
    back_row_half_length_m: float = 12.0
    wire_count_range: tuple[int, int] = (2, 4)
    scan_band_wire_height_range_m: tuple[float, float] = (0.4, 0.7)
    upper_wire_height_range_m: tuple[float, float] = (0.9, 2.2)
    wire_offset_y_range_m: tuple[float, float] = (-0.04, 0.04)
    wire_radius_range_m: tuple[float, float] = (0.001, 0.002)
    wire_sag_range_m: tuple[float, float] = (0.005, 0.03)
    post_spacing_range_m: tuple[float, float] = (4.0, 8.0)
    post_radius_range_m: tuple[float, float] = (0.04, 0.06)
    post_height_range_m: tuple[float, float] = (2.5, 3.2)
    post_clearance_m: float = 0.4
    clip_length_range_m: tuple[float, float] = (0.01, 0.025)
    left_out: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        parts = self.left_out
        if not isinstance(parts, tuple) or not all(part in ROW_PARTS for part in parts):
            raise ValueError(
                f"OrchardRowConfig.left_out must name parts of {ROW_PARTS}, got {self.left_out!r}"
            )
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name.endswith("_range") or "_range_" in f.name:
                signed = f.name in _SIGNED_RANGES
                if not (
                    len(value) == 2
                    and all(np.isfinite(v) for v in value)
                    and (signed or 0 <= value[0])
                    and value[0] <= value[1]
                ):
                    raise ValueError(
                        f"OrchardRowConfig.{f.name} must be a finite (low, high) pair with "
                        f"{'' if signed else '0 <= '}low <= high, got {value!r}"
                    )
        for name in ("twigs_per_branch_range", "crossing_branch_count_range", "wire_count_range"):
            if any(int(v) != v for v in getattr(self, name)):
                raise ValueError(f"OrchardRowConfig.{name} must hold integers")
        for name in ("neighbours_per_side", "uprights_per_side"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 0):
                raise ValueError(f"OrchardRowConfig.{name} must be an integer >= 0, got {value!r}")
        if not 0.0 <= self.trained_along_row_fraction <= 1.0:
            raise ValueError(
                "OrchardRowConfig.trained_along_row_fraction must be in [0, 1], got "
                f"{self.trained_along_row_fraction!r}"
            )
        require_positive(
            self, "row_plane_spread_deg", "branches_per_m", "visible_height_m",
            "back_row_half_length_m",
            "post_clearance_m", "cull_max_rotation_deg", "cull_margin_deg",
        )  # fmt: skip
        for name in (
            "neighbour_spacing_range_m", "upright_spacing_range_m", "trunk_height_range_m",
            "trunk_radius_range_m", "twig_radius_range_m", "wire_radius_range_m",
            "post_spacing_range_m", "post_radius_range_m", "post_height_range_m",
            "back_row_distance_range_m", "branch_length_range_m", "twig_length_range_m",
            "crossing_radius_range_m",
        ):  # fmt: skip
            if getattr(self, name)[0] <= 0:
                raise ValueError(f"OrchardRowConfig.{name} must be positive, got "
                                 f"{getattr(self, name)!r}")  # fmt: skip


@dataclass
class RowTree:
    """One tree of the row, as branches for meshing.

    Attributes:
        branches: Trunk first, then branches and twigs (polylines with radii, world frame).
        same_tree: True for an upright of the scanned (UFO) tree itself: labelled with it.
    """

    branches: list[RowBranch]
    same_tree: bool = False


@dataclass(frozen=True)
class Post:
    """A trellis post: a vertical cylinder.

    Attributes:
        x_m: Position along the row.
        y_m: Position across the row.
        radius_m: Radius.
        height_m: Height above the ground.
    """

    x_m: float
    y_m: float
    radius_m: float
    height_m: float


@dataclass(frozen=True)
class BackRow:
    """A row behind the scanned one, drawn as an impostor plane (``sim/scene/impostor.py``).

    Attributes:
        y_m: Distance of the row's plane (world y).
        strip: Which row strip of the process's strips.
        offset_m: World x of the strip's first column (the strip wraps along the row).
        mirrored: The strip runs along -x.
    """

    y_m: float
    strip: int
    offset_m: float
    mirrored: bool


@dataclass
class OrchardRow:
    """Everything around the scanned tree, in the world frame.

    Attributes:
        trees: Neighbours (and, for a UFO tree, its other uprights), as geometry.
        cordon: The UFO cordon (part of the scanned tree), or None.
        wires: Trellis wires (polylines along x).
        clips: Clips on the scan-band wire next to the scanned tree.
        posts: Trellis posts.
        back_rows: The rows behind, as placements of impostor sprites.
    """

    trees: list[RowTree] = field(default_factory=list)
    cordon: BranchGT | None = None
    wires: list[BranchGT] = field(default_factory=list)
    clips: list[BranchGT] = field(default_factory=list)
    posts: list[Post] = field(default_factory=list)
    back_rows: list[BackRow] = field(default_factory=list)


@dataclass(frozen=True)
class RowBranch:
    """One branch or twig of the row, for meshing (no ground-truth checks: thousands a scene).

    Attributes:
        points: (N, 3) centerline in metres, world frame, base -> tip.
        radii: (N,) radius in metres.
    """

    points: np.ndarray
    radii: np.ndarray


_STEPS = {n: np.arange(n, dtype=float) for n in (5, 6, 8)}


def _linspace(start: float, stop: float, count: int) -> np.ndarray:
    """``np.linspace(start, stop, count)``, value for value, without its per-call overhead."""
    values = _STEPS[count] * ((stop - start) / (count - 1)) + start
    values[-1] = stop
    return values


def _polyline(start: np.ndarray, direction: np.ndarray, length_m: float, bend: np.ndarray,
              points: int = 5) -> np.ndarray:  # fmt: skip
    """(points, 3) a gently bending path: ``start + s d + s^2 bend``."""
    s = _linspace(0.0, length_m, points)[:, None]
    return start + s * direction + s**2 * bend


def _tapered(path: np.ndarray, base_radius_m: float, tip_radius_m: float) -> RowBranch:
    return RowBranch(path, _linspace(base_radius_m, max(tip_radius_m, 1e-4), len(path)))


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _direction(yaw: float, elevation: float) -> np.ndarray:
    return np.array(
        [math.cos(elevation) * math.cos(yaw), math.cos(elevation) * math.sin(yaw),
         math.sin(elevation)]
    )  # fmt: skip


def _grow_twigs(
    config: OrchardRowConfig, rng: np.random.Generator, branch: RowBranch, out: list[RowBranch]
) -> None:
    """Upright one-year shoots along ``branch`` (appended to ``out``)."""
    for _ in range(int(rng.integers(config.twigs_per_branch_range[0],
                                    config.twigs_per_branch_range[1] + 1))):  # fmt: skip
        index = int(rng.integers(len(branch.points) // 3, len(branch.points)))
        base = branch.points[index]
        yaw = rng.uniform(0.0, 2 * math.pi)
        direction = _direction(yaw, math.radians(rng.uniform(45.0, 85.0)))
        length = rng.uniform(*config.twig_length_range_m)
        radius = min(rng.uniform(*config.twig_radius_range_m), 0.8 * float(branch.radii[index]))
        bend = rng.normal(0.0, 0.15, 3)
        out.append(_tapered(_polyline(base, direction, length, bend), radius, 0.3 * radius))


def grow_row_tree(
    config: OrchardRowConfig,
    rng: np.random.Generator,
    base_xy: np.ndarray,
    base_height_m: float,
    radius_m: float,
    height_m: float,
    lateral_only: bool,
    max_height_m: float,
) -> list[RowBranch]:
    """A trunk with branches and twigs, standing at ``base_xy`` (z from ``base_height_m``).

    ``lateral_only`` keeps branches short (UFO uprights carry short shoots, not scaffolds).
    """
    top = np.array([*base_xy + rng.normal(0.0, 0.05, 2), height_m])
    bottom = np.array([*base_xy, base_height_m])
    trunk_path = bottom + np.linspace(0.0, 1.0, 8)[:, None] * (top - bottom)
    trunk_path[:, :2] += np.sin(np.linspace(0, math.pi, 8))[:, None] * rng.normal(0, 0.03, 2)
    trunk = _tapered(trunk_path, radius_m * 1.2, radius_m * 0.25)
    branches = [trunk]
    n_branches = rng.poisson(config.branches_per_m * (height_m - base_height_m))
    for _ in range(n_branches):
        z = rng.uniform(base_height_m + 0.25, min(height_m, max_height_m))
        fraction = (z - base_height_m) / (height_m - base_height_m)
        base = bottom + fraction * (top - bottom)
        trunk_radius = float(np.interp(fraction, [0, 1], [radius_m * 1.2, radius_m * 0.25]))
        yaw = rng.uniform(0.0, 2 * math.pi)
        if rng.random() < config.trained_along_row_fraction:  # trained into the row's plane
            yaw = rng.choice([0.0, math.pi]) + math.radians(
                rng.uniform(-config.row_plane_spread_deg, config.row_plane_spread_deg)
            )
        elevation = math.radians(rng.uniform(-20.0, 35.0))
        length = rng.uniform(*config.branch_length_range_m) * (0.4 if lateral_only else 1.0)
        length *= 1.0 - 0.5 * fraction  # shorter toward the top (tall-spindle cone)
        radius = trunk_radius * rng.uniform(*config.branch_radius_fraction_range)
        droop = np.array([0.0, 0.0, rng.uniform(-0.4, 0.3)])
        branch = _tapered(_polyline(base, _direction(yaw, elevation), length, droop), radius,
                          0.2 * radius)  # fmt: skip
        branches.append(branch)
        _grow_twigs(config, rng, branch, branches)
    for _ in range(int(rng.integers(1, 4))):  # shoots straight off the trunk
        _grow_twigs(config, rng, trunk, branches)
    return [b for b in branches if b.points[:, 2].min() < max_height_m]


def _crossing_branch(
    config: OrchardRowConfig,
    rng: np.random.Generator,
    neighbour_x_m: float,
    scanned: TreeGT,
    band_m: tuple[float, float],
) -> list[RowBranch]:
    """A neighbour's branch reaching past the scanned tree on the camera's side, with twigs."""
    z = rng.uniform(*band_m)
    axis = scanned.primary.points[np.argmin(np.abs(scanned.primary.points[:, 2] - z))]
    radius_at_axis = float(
        scanned.primary.radii[np.argmin(np.abs(scanned.primary.points[:, 2] - z))]
    )
    gap = rng.uniform(*config.crossing_gap_range_m)
    crossing = np.array([axis[0], axis[1] - radius_at_axis - gap, z + rng.uniform(-0.05, 0.05)])
    start = np.array([neighbour_x_m, rng.uniform(-0.1, 0.0), z - rng.uniform(0.0, 0.15)])
    overshoot = rng.uniform(0.05, 0.25)
    end = crossing + overshoot * _unit(crossing - start) + np.array([0, 0, rng.uniform(0, 0.05)])
    t = np.linspace(0.0, 1.0, 6)[:, None]
    mid = 0.5 * (start + end)
    control = crossing + (crossing - mid)  # a quadratic Bezier through ``crossing`` at t = 0.5
    path = (1 - t) ** 2 * start + 2 * (1 - t) * t * control + t**2 * end
    base_radius = rng.uniform(*config.crossing_radius_range_m)
    branch = _tapered(path, base_radius, rng.uniform(*config.twig_radius_range_m))
    twigs: list[RowBranch] = []
    _grow_twigs(config, rng, branch, twigs)
    return [branch, *twigs]


def _wire(
    rng: np.random.Generator, config: OrchardRowConfig, height_m: float, y_m: float,
    post_x: list[float], half_length_m: float,
) -> BranchGT:  # fmt: skip
    """A wire along x that sags between posts (parabolic spans)."""
    x = np.linspace(-half_length_m, half_length_m, _WIRE_POINTS)
    supports = np.array(sorted([-half_length_m, *post_x, half_length_m]))
    span = np.searchsorted(supports, x, side="right").clip(1, len(supports) - 1)
    left, right = supports[span - 1], supports[span]
    phase = (x - left) / np.maximum(right - left, 1e-9)
    sag = rng.uniform(*config.wire_sag_range_m)
    z = height_m - 4.0 * sag * phase * (1.0 - phase)
    radius = rng.uniform(*config.wire_radius_range_m)
    return BranchGT(np.stack([x, np.full_like(x, y_m), z], 1), np.full(len(x), radius))


@dataclass(frozen=True)
class ScanView:
    """Where the scanning camera can be: on an orbit about the scanned axis, looking at it.

    Attributes:
        axis_xy: (K, 2) the scanned axis in the horizontal plane at K heights of the band
            (the camera follows it), metres.
        distance_m: Orbit radius (z_target).
        band_m: (low, high) camera heights in metres.
        half_fov_deg: (horizontal, vertical) half fields of view of the camera.
    """

    axis_xy: tuple[tuple[float, float], ...]
    distance_m: float
    band_m: tuple[float, float]
    half_fov_deg: tuple[float, float]


def visible_branches(
    branches: list[RowBranch], view: ScanView, config: OrchardRowConfig
) -> list[RowBranch]:
    """The branches some pose of ``view`` can see (:func:`potentially_visible`, in one pass)."""
    if not branches:
        return []
    points = np.concatenate([b.points for b in branches])
    owner = np.repeat(np.arange(len(branches)), [len(b.points) for b in branches])
    seen = np.bincount(owner[_visible_points(points, view, config)], minlength=len(branches))
    return [b for b, count in zip(branches, seen, strict=True) if count > 0]


def potentially_visible(points: np.ndarray, view: ScanView, config: OrchardRowConfig) -> bool:
    """Whether some pose of ``view`` can see any of ``points`` (N, 3) (see
    ``OrchardRowConfig.cull_max_rotation_deg``)."""
    return bool(_visible_points(points, view, config).any())


def _visible_points(points: np.ndarray, view: ScanView, config: OrchardRowConfig) -> np.ndarray:
    """(N,) bool: which of ``points`` (N, 3) some pose of ``view`` can see."""
    rotations = np.radians(np.linspace(-config.cull_max_rotation_deg,
                                       config.cull_max_rotation_deg, _CULL_ROTATIONS))  # fmt: skip
    look = np.stack([-np.sin(rotations), np.cos(rotations)], axis=1)  # (R, 2) view directions
    cameras = (np.asarray(view.axis_xy)[:, None, :] - view.distance_m * look).reshape(-1, 2)
    look = np.tile(look, (len(view.axis_xy), 1))
    relative = points[None, :, :2] - cameras[:, None, :]  # (R, N, 2)
    along = np.einsum("rnk,rk->rn", relative, look)
    across = np.abs(relative[..., 0] * look[:, None, 1] - relative[..., 1] * look[:, None, 0])
    half_h = math.tan(math.radians(view.half_fov_deg[0] + config.cull_margin_deg))
    half_v = math.tan(math.radians(view.half_fov_deg[1] + config.cull_margin_deg))
    z = points[None, :, 2]
    inside = (
        (along > 0)
        & (across <= half_h * along)
        & (z >= view.band_m[0] - half_v * along)
        & (z <= view.band_m[1] + half_v * along)
    )
    return inside.any(axis=0)


def generate_row(
    config: OrchardRowConfig,
    rng: np.random.Generator,
    scanned: TreeGT,
    architecture: str,
    band_m: tuple[float, float],
    strip_count: int,
    view: ScanView | None = None,
) -> OrchardRow:
    """Draw the row around ``scanned``.

    Args:
        config: The row distribution.
        rng: Source of every draw.
        scanned: The scanned tree (crossing branches pass in front of its primary).
        architecture: The tree architecture ("paper", "tall_spindle" or "ufo").
        band_m: (low, high) heights of the scan band in metres.
        strip_count: Number of row strips the rows behind choose from.
        view: The scanning camera's poses: neighbour branches none of them can see are
            dropped (None keeps every branch).

    Returns:
        The row, world frame.
    """
    row = OrchardRow()
    primary = scanned.primary
    ufo = architecture == "ufo"
    base_z = float(primary.points[0, 2])
    # Neighbours (or the UFO tree's own uprights) along x on both sides.
    spacing = config.upright_spacing_range_m if ufo else config.neighbour_spacing_range_m
    per_side = config.uprights_per_side if ufo else config.neighbours_per_side
    neighbour_x: list[float] = []
    for side in (-1.0, 1.0):
        x = float(primary.points[0, 0])
        for _ in range(per_side):
            x += side * rng.uniform(*spacing)
            neighbour_x.append(x)
            radius = (
                float(primary.radii[len(primary.radii) // 2]) * rng.uniform(0.7, 1.3)
                if ufo else rng.uniform(*config.trunk_radius_range_m)
            )  # fmt: skip
            height = rng.uniform(*config.trunk_height_range_m)
            base_xy = np.array([x, rng.normal(0.0, 0.02)])
            branches = grow_row_tree(
                config, rng, base_xy, base_z if ufo else 0.0, radius, height,
                lateral_only=ufo,
                max_height_m=config.visible_height_m + max(0.0, band_m[1] - _PAPER_BAND_TOP_M),
            )  # fmt: skip
            if view is not None:
                branches = visible_branches(branches, view, config)
            row.trees.append(RowTree(branches, same_tree=ufo))
    if ufo:
        xs = [float(primary.points[0, 0]), *neighbour_x]
        half = 0.5 * (max(xs) - min(xs)) + 0.3
        centre = 0.5 * (max(xs) + min(xs))
        path = np.array([[centre - half, 0.0, base_z], [centre + half, 0.0, base_z]])
        cordon_radius = 1.6 * float(primary.radii[0])
        row.cordon = BranchGT(np.linspace(path[0], path[1], 9), np.full(9, cordon_radius))
        # The next trees along the row (UFO rows: ~2-3 m of cordon per tree) stay out of view.
    if "neighbours" in config.left_out:
        row.trees = [tree for tree in row.trees if tree.same_tree]
    low, high = config.crossing_branch_count_range
    for _ in range(int(rng.integers(low, high + 1))):
        nearest = min((x for x in neighbour_x), key=lambda x: abs(x) + rng.uniform(0, 0.3),
                      default=0.8)  # fmt: skip
        tree = RowTree(_crossing_branch(config, rng, nearest, scanned, band_m))
        if "crossing" not in config.left_out:
            row.trees.append(tree)
    # Posts, then wires hung on them.
    post_spacing = rng.uniform(*config.post_spacing_range_m)
    first = rng.uniform(0.0, post_spacing)
    half_length = config.back_row_half_length_m
    post_x = [
        float(x) for x in np.arange(-half_length + first, half_length, post_spacing)
        if abs(x) >= config.post_clearance_m
    ]  # fmt: skip
    for x in post_x:
        row.posts.append(
            Post(x, rng.normal(0.0, 0.02), rng.uniform(*config.post_radius_range_m),
                 rng.uniform(*config.post_height_range_m))
        )  # fmt: skip
    n_wires = int(rng.integers(config.wire_count_range[0], config.wire_count_range[1] + 1))
    if n_wires:
        heights = [rng.uniform(*config.scan_band_wire_height_range_m)]
        heights += list(np.sort(rng.uniform(*config.upper_wire_height_range_m, n_wires - 1)))
        for index, height in enumerate(heights):
            y = rng.uniform(*config.wire_offset_y_range_m)
            wire = _wire(rng, config, height, y, post_x, half_length)
            row.wires.append(wire)
            if index == 0:  # a clip where the scan-band wire meets the scanned tree
                axis = primary.points[np.argmin(np.abs(primary.points[:, 2] - height))]
                length = rng.uniform(*config.clip_length_range_m)
                clip = np.array([[axis[0] - length / 2, y, height], [axis[0] + length / 2, y,
                                 height]])  # fmt: skip
                row.clips.append(BranchGT(clip, np.full(2, 2.5 * float(wire.radii[0]))))
    if "wires" in config.left_out:
        row.wires, row.clips = [], []
    # Rows behind: which prebuilt strip of trees, where along it, which way round.
    distance = rng.uniform(*config.back_row_distance_range_m)
    for extra in (0.0, rng.uniform(*config.far_row_extra_range_m)):
        row.back_rows.append(
            BackRow(
                y_m=float(distance + extra),
                strip=int(rng.integers(0, strip_count)),
                offset_m=float(rng.uniform(-half_length, half_length)),
                mirrored=bool(rng.random() < 0.5),
            )
        )
    return row
