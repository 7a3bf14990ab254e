"""The scanned tree's small parts: fruiting spurs, pruning stubs and buds (never scored).

A dormant apple tree is more than a primary and a few side branches: its wood carries short
fruiting spurs, the stubs that pruning cuts left, and buds (reference.md, "Real close-up frames
of a dormant orchard row"; ``shared/data/real_dev/7.png`` shows spurs and stubs on a leader).
They belong to the scanned tree (a segmenter must keep them), but they are not side branches:
they go to ``TreeGT.details``, not ``TreeGT.secondaries``, and the evaluation never scores them.

Geometry. Each detail is a short straight :class:`BranchGT` that starts on its parent's
centerline (the primary's or a secondary's), like the secondaries do, and leaves it at an angle
drawn from the kind's ``*_angle_range_deg``, measured from the parent's tangent (pointing to the
parent's tip). Its drawn length is the part outside the parent: the polyline runs from the
centerline through the parent's surface (``parent radius / sin(angle)`` further along, the
parent taken as a locally straight tube) and on for that length. The radius stays at the base
radius inside the parent and then tapers linearly to ``base x *_tip_radius_fraction`` at the tip.

* Spurs (primary and secondaries): radius in millimetres, on the parent's upper side (outward
  and upward).
* Pruning stubs (primary and secondaries): radius a fraction of the parent's, any side; a tip
  fraction near 1 leaves a flat cut end.
* Buds (secondaries only): tiny, any side, leaning toward the parent's tip.

No detail is thicker than ``MAX_PARENT_RADIUS_FRACTION`` x its parent's radius there.

Details on the primary stay out of the scoring's way: the evaluation ignores reconstructed side
branches whose base-to-tip vector is at most 2.5 cm long horizontally (``recon/metrics.py``), so a
primary detail reaching further than ``primary_max_reach_m`` horizontally from the centerline is
shortened to fit (dropped when that leaves less than its kind's shortest length), and a primary
detail whose height span comes within ``secondary_base_clearance_m`` of a secondary's base is
dropped. Every draw comes from the ``rng`` passed in, in a fixed order that does not depend on
these geometric checks: the same tree, config and seed give the same details.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields

import numpy as np

from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from branch_gym.sim.tree.polyline import arc_lengths

__all__ = ["MAX_PARENT_RADIUS_FRACTION", "DetailConfig", "grow_details"]

logger = logging.getLogger(__name__)

# The evaluation ignores reconstructed side branches no longer than this horizontally
# (recon/metrics.py, min_horizontal_length_m; reference.md "Evaluation"). branch_gym.sim never
# imports recon: the value is repeated here.
EVALUATION_MIN_HORIZONTAL_LENGTH_M = 0.025
# A detail is never thicker than this fraction of its parent's radius at its base (our choice:
# the thickest pruning stubs, 0.9 x the parent).
MAX_PARENT_RADIUS_FRACTION = 0.9
# Details on a secondary start this many primary radii from its base, out of the primary.
_JUNCTION_CLEARANCE_PRIMARY_RADII = 2.0
# Angles from the parent's tangent must leave the parent sideways: within (0, 180) deg.
_MAX_ANGLE_DEG = 180.0
# Tangents closer to vertical than this (|t_z|) get their perpendicular frame from +x, not +z.
_NEAR_VERTICAL_COS = 0.9
# Below this length, "the parent's upward side" is undefined (a vertical parent): any side.
_MIN_UP_NORM = 1e-9
_UP = np.array([0.0, 0.0, 1.0])
_X_AXIS = np.array([1.0, 0.0, 0.0])


@dataclass(frozen=True)
class DetailConfig:
    """How many spurs, pruning stubs and buds a scanned tree carries, and their shapes.

    The default holds no detail (every density 0); :meth:`orchard` is a dormant apple tree.
    Ranges are ``(low, high)`` tuples sampled uniformly; ``low == high`` fixes a value. Lengths
    in metres, angles in degrees from the parent's tangent (0 = along the parent toward its
    tip, 90 = square to it). Densities are counts per metre of parent arc length (Poisson).
    """

    # --- fruiting spurs, on the primary and the secondaries (orchard practice) ---
    spur_density_per_m: float = 0.0  # none by default; orchard(): 6 / m
    spur_length_range_m: tuple[float, float] = (0.01, 0.03)  # short, stubby: 1-3 cm
    spur_radius_range_m: tuple[float, float] = (0.0015, 0.0035)  # 1.5-3.5 mm
    spur_angle_range_deg: tuple[float, float] = (45.0, 90.0)  # outward, upper side: our choice
    spur_tip_radius_fraction: float = 0.7  # stubby, blunt tip: our choice

    # --- pruning stubs, on the primary and the secondaries (orchard practice) ---
    stub_density_per_m: float = 0.0  # none by default; orchard(): 2 / m
    stub_length_range_m: tuple[float, float] = (0.005, 0.025)  # cut 0.5-2.5 cm from the parent
    stub_radius_scale_range: tuple[float, float] = (0.5, 0.9)  # x the parent's radius there
    # Like the cut branches were: the paper's secondary elevations -15..45 deg on an upright.
    stub_angle_range_deg: tuple[float, float] = (45.0, 105.0)
    stub_tip_radius_fraction: float = 0.95  # nearly no taper: a flat cut end (our choice)

    # --- buds, along the secondaries (orchard practice) ---
    bud_density_per_m: float = 0.0  # none by default; orchard(): 30 / m (every ~3 cm)
    bud_length_range_m: tuple[float, float] = (0.002, 0.005)  # 2-5 mm
    bud_radius_range_m: tuple[float, float] = (0.001, 0.002)  # 1-2 mm
    bud_angle_range_deg: tuple[float, float] = (20.0, 50.0)  # leaning toward the tip: our choice
    bud_tip_radius_fraction: float = 0.3  # pointed: our choice

    # --- placement on the primary (keeps details out of the scoring; see the module doc) ---
    # Horizontal reach from the primary's centerline to a detail's tip: under the evaluation's
    # 2.5 cm with 5 mm to spare for reconstruction error (our choice).
    primary_max_reach_m: float = 0.02
    # No primary detail within 1 cm in height of a secondary's base (task brief).
    secondary_base_clearance_m: float = 0.01
    centerline_spacing_m: float = 0.001  # 1 mm, as the tree's ground truth (TreeConfig)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if "_range" in f.name:
                _check_range(f.name, value)
            else:
                _require(bool(np.isfinite(value)), f.name, f"must be finite, got {value}")
        for name in (
            "spur_length_range_m",
            "spur_radius_range_m",
            "stub_length_range_m",
            "stub_radius_scale_range",
            "bud_length_range_m",
            "bud_radius_range_m",
            "primary_max_reach_m",
            "centerline_spacing_m",
        ):
            _require(np.min(getattr(self, name)) > 0, name, "must be positive")
        for name in (
            "spur_density_per_m",
            "stub_density_per_m",
            "bud_density_per_m",
            "secondary_base_clearance_m",
        ):
            _require(getattr(self, name) >= 0, name, "must be non-negative")
        for name in ("spur_angle_range_deg", "stub_angle_range_deg", "bud_angle_range_deg"):
            low, high = getattr(self, name)
            _require(0 < low and high < _MAX_ANGLE_DEG, name, "must lie in (0, 180) deg")
        for name in (
            "spur_tip_radius_fraction",
            "stub_tip_radius_fraction",
            "bud_tip_radius_fraction",
        ):
            _require(0 < getattr(self, name) <= 1, name, "must be in (0, 1]")
        _require(
            self.stub_radius_scale_range[1] <= MAX_PARENT_RADIUS_FRACTION,
            "stub_radius_scale_range",
            f"must not exceed {MAX_PARENT_RADIUS_FRACTION} (x the parent's radius)",
        )
        _require(
            self.primary_max_reach_m <= EVALUATION_MIN_HORIZONTAL_LENGTH_M,
            "primary_max_reach_m",
            f"must not exceed the evaluation's {EVALUATION_MIN_HORIZONTAL_LENGTH_M} m (the "
            "shortest horizontal extent it scores)",
        )

    @classmethod
    def orchard(cls) -> DetailConfig:
        """A dormant apple tree: spurs, a few pruning stubs, and buds along the secondaries.

        Densities are our choice from orchard practice: a spur every ~15 cm of older wood, a
        pruning stub every ~50 cm, a bud every ~3 cm of one-year shoots.
        """
        return cls(spur_density_per_m=6.0, stub_density_per_m=2.0, bud_density_per_m=30.0)

    @property
    def is_empty(self) -> bool:
        """True when no detail can grow (every density 0)."""
        return not (self.spur_density_per_m or self.stub_density_per_m or self.bud_density_per_m)


@dataclass(frozen=True)
class _Kind:
    """One kind of detail, read from a :class:`DetailConfig`."""

    name: str
    density_per_m: float
    length_range_m: tuple[float, float]
    radius_range: tuple[float, float]  # metres, or x parent radius when radius_is_scale
    radius_is_scale: bool
    angle_range_deg: tuple[float, float]
    tip_radius_fraction: float
    upper_side_only: bool
    on_primary: bool


def _kinds(config: DetailConfig) -> tuple[_Kind, ...]:
    return (
        _Kind(
            "spur",
            config.spur_density_per_m,
            config.spur_length_range_m,
            config.spur_radius_range_m,
            radius_is_scale=False,
            angle_range_deg=config.spur_angle_range_deg,
            tip_radius_fraction=config.spur_tip_radius_fraction,
            upper_side_only=True,
            on_primary=True,
        ),
        _Kind(
            "stub",
            config.stub_density_per_m,
            config.stub_length_range_m,
            config.stub_radius_scale_range,
            radius_is_scale=True,
            angle_range_deg=config.stub_angle_range_deg,
            tip_radius_fraction=config.stub_tip_radius_fraction,
            upper_side_only=False,
            on_primary=True,
        ),
        _Kind(
            "bud",
            config.bud_density_per_m,
            config.bud_length_range_m,
            config.bud_radius_range_m,
            radius_is_scale=False,
            angle_range_deg=config.bud_angle_range_deg,
            tip_radius_fraction=config.bud_tip_radius_fraction,
            upper_side_only=False,
            on_primary=False,
        ),
    )


def grow_details(tree: TreeGT, config: DetailConfig, rng: np.random.Generator) -> list[BranchGT]:
    """Grow the scanned tree's spurs, pruning stubs and buds.

    Kinds in the order spurs, stubs, buds; within a kind, parents in the order primary, then
    secondaries. A kind with density 0 draws nothing, so the default :class:`DetailConfig`
    leaves ``rng`` untouched. ``tree`` is not modified: the caller stores the result in
    ``tree.details``.

    Args:
        tree: The scanned tree (world frame); its primary and secondaries carry the details.
        config: Densities and shapes.
        rng: Source of every random draw.

    Returns:
        The details, each a short branch from its parent's centerline to its tip: (N >= 2, 3)
        points in metres, world frame, with positive radii tapering toward the tip.
    """
    if config.is_empty:
        return []
    base_heights_m = np.array([b.points[0, 2] for b in tree.secondaries])
    details: list[BranchGT] = []
    for kind in _kinds(config):
        if kind.density_per_m == 0:
            continue
        if kind.on_primary:
            details += _grow_on_parent(
                tree.primary, 0.0, kind, config, rng, on_primary=True, base_heights_m=base_heights_m
            )
        for secondary in tree.secondaries:
            nearest = np.argmin(np.linalg.norm(tree.primary.points - secondary.points[0], axis=1))
            start_m = _JUNCTION_CLEARANCE_PRIMARY_RADII * float(tree.primary.radii[nearest])
            details += _grow_on_parent(
                secondary, start_m, kind, config, rng, on_primary=False, base_heights_m=None
            )
    logger.debug("grew %d details on tree seed %s", len(details), tree.seed)
    return details


def _grow_on_parent(
    parent: BranchGT,
    start_m: float,
    kind: _Kind,
    config: DetailConfig,
    rng: np.random.Generator,
    *,
    on_primary: bool,
    base_heights_m: np.ndarray | None,
) -> list[BranchGT]:
    """Details of one kind along ``parent`` from arc length ``start_m`` to its tip.

    Args:
        parent: The carrying branch.
        start_m: Arc length in metres before which no detail starts (a secondary's junction).
        kind: What to grow.
        config: For spacing and the primary's placement limits.
        rng: Source of every random draw.
        on_primary: Whether ``parent`` is the primary (reach and clearance checks apply).
        base_heights_m: (S,) secondary base heights in metres (primary only).
    """
    arc_m = arc_lengths(parent.points)
    usable_m = arc_m[-1] - start_m
    if usable_m <= 0:
        return []
    grown = []
    for _ in range(int(rng.poisson(kind.density_per_m * usable_m))):
        # Always the same five draws per detail, whatever the checks below decide.
        at_m = rng.uniform(start_m, arc_m[-1])
        length_m = rng.uniform(*kind.length_range_m)
        radius_draw = rng.uniform(*kind.radius_range)
        angle = math.radians(rng.uniform(*kind.angle_range_deg))
        azimuth = rng.uniform(0.0, 2.0 * math.pi)
        center, tangent, parent_radius_m = _frame_at(parent, arc_m, at_m)
        radius_m = radius_draw * parent_radius_m if kind.radius_is_scale else radius_draw
        radius_m = min(radius_m, MAX_PARENT_RADIUS_FRACTION * parent_radius_m)
        radial = _radial(tangent, azimuth, kind.upper_side_only)
        direction = math.cos(angle) * tangent + math.sin(angle) * radial
        inside_m = parent_radius_m / math.sin(angle)  # centerline to the parent's surface
        if on_primary:
            horizontal = float(np.linalg.norm(direction[:2]))
            if horizontal > 0:
                length_m = min(length_m, config.primary_max_reach_m / horizontal - inside_m)
            if length_m < kind.length_range_m[0]:
                continue
        detail = _straight_detail(
            center, direction, inside_m, length_m, radius_m, kind.tip_radius_fraction, config
        )
        if on_primary and _near_a_base(detail, base_heights_m, config.secondary_base_clearance_m):
            continue
        grown.append(detail)
    return grown


def _frame_at(
    branch: BranchGT, arc_m: np.ndarray, at_m: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """(3,) centerline point, (3,) unit tangent (base -> tip) and radius at arc length ``at_m``."""
    index = int(np.clip(np.searchsorted(arc_m, at_m) - 1, 0, len(arc_m) - 2))
    step = branch.points[index + 1] - branch.points[index]
    step_m = arc_m[index + 1] - arc_m[index]
    frac = float(np.clip((at_m - arc_m[index]) / step_m, 0.0, 1.0)) if step_m > 0 else 0.0
    point = branch.points[index] + frac * step
    radius_m = branch.radii[index] + frac * (branch.radii[index + 1] - branch.radii[index])
    return point, step / np.linalg.norm(step), float(radius_m)


def _radial(tangent: np.ndarray, azimuth: float, upper_side_only: bool) -> np.ndarray:
    """(3,) unit vector square to ``tangent`` at ``azimuth`` (on its upper side if asked)."""
    helper = _UP if abs(tangent[2]) < _NEAR_VERTICAL_COS else _X_AXIS
    first = np.cross(tangent, helper)
    first /= np.linalg.norm(first)
    second = np.cross(tangent, first)
    radial = math.cos(azimuth) * first + math.sin(azimuth) * second
    if upper_side_only:
        up = _UP - (_UP @ tangent) * tangent  # the parent's upward side, square to it
        up_norm = float(np.linalg.norm(up))
        if up_norm > _MIN_UP_NORM:
            up /= up_norm
            along_up = float(radial @ up)
            if along_up < 0:
                radial = radial - 2.0 * along_up * up
    return radial


def _straight_detail(
    center: np.ndarray,
    direction: np.ndarray,
    inside_m: float,
    length_m: float,
    radius_m: float,
    tip_radius_fraction: float,
    config: DetailConfig,
) -> BranchGT:
    """A straight detail from ``center`` along ``direction``: ``inside_m`` + ``length_m`` long.

    The radius is ``radius_m`` inside the parent and tapers linearly over the outside part to
    ``radius_m * tip_radius_fraction`` at the tip.
    """
    total_m = inside_m + length_m
    n_points = max(math.ceil(total_m / config.centerline_spacing_m), 1) + 1
    along_m = np.linspace(0.0, total_m, n_points)
    outside = np.clip((along_m - inside_m) / length_m, 0.0, 1.0)
    radii = radius_m * (1.0 - (1.0 - tip_radius_fraction) * outside)
    return BranchGT(center + along_m[:, None] * direction, radii)


def _near_a_base(detail: BranchGT, base_heights_m: np.ndarray | None, clearance_m: float) -> bool:
    """Whether the detail's height span (with its radius) comes within ``clearance_m`` of a base."""
    if base_heights_m is None or len(base_heights_m) == 0:
        return False
    margin_m = clearance_m + float(detail.radii.max())
    low_m = float(detail.points[:, 2].min()) - margin_m
    high_m = float(detail.points[:, 2].max()) + margin_m
    return bool(np.any((base_heights_m > low_m) & (base_heights_m < high_m)))


def _require(condition: bool, name: str, problem: str) -> None:
    if not condition:
        raise ValueError(f"DetailConfig.{name} {problem}")


def _check_range(name: str, value: tuple[float, float]) -> None:
    _require(len(value) == 2, name, f"must be a (low, high) pair, got {value}")
    _require(bool(np.all(np.isfinite(value))), name, f"must be finite, got {value}")
    _require(value[0] <= value[1], name, f"is an inverted range (low > high): {value}")
