"""The tree distribution (:class:`TreeConfig`) and its validation.

Defaults are the paper's simulated world; ``sim/tree/generator.py`` samples trees from it and
explains the geometry (world frame, placement, radius tapering).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

import numpy as np

YAW_MODES = ("uniform", "toward_camera", "away_from_camera", "toward_or_away_camera")
# Tree architectures: the paper's simulated tree, and two modern high-density orchard systems.
ARCHITECTURES = ("paper", "tall_spindle", "ufo")
# Instance labels 2 + i must stay below the first clutter label 100 (label-image convention).
_MAX_SECONDARIES = 98
# The tall-spindle leader preset (TreeConfig.tall_spindle_leader, sources in its docstring):
# branches from 0.60 m (feathers below 60 cm removed) to 1.75 m (a FoV above the 1.50 m scan
# top, so the top frames look as a taller tree's), 11-18 of them: 9.6-15.7 per metre.
LEADER_SECONDARY_BASE_HEIGHT_RANGE_M = (0.60, 1.75)
LEADER_SECONDARY_COUNT_RANGE = (11, 18)


@dataclass(frozen=True)
class TreeConfig:
    """The tree distribution. Defaults are the paper's simulated world.

    Ranges are ``(low, high)`` tuples sampled uniformly (integers inclusive); ``low == high``
    fixes a value. Angles in degrees, lengths in metres. Yaw is measured in the world xy plane
    from +x toward +y; elevation is the angle above the horizontal plane.

    Presets: :meth:`paper` (the defaults), :meth:`cluttered` and :meth:`hard` (the paper's tree
    with clutter), and two modern orchard architectures, :meth:`tall_spindle` and :meth:`ufo`;
    :meth:`tall_spindle_leader` is a tall-spindle leader at full height for a longer scan.
    """

    # Which tree this distribution models (one of ARCHITECTURES): a label for the world that
    # builds around the tree (e.g. the orchard row adds a UFO tree's cordon and other uprights);
    # the geometry comes from the fields below. "paper": the paper's simulated tree.
    architecture: str = "paper"

    # --- primary (reference.md "Simulated world", paper VI-A) ---
    primary_height_m: float = 1.0  # cubic Bezier from z = 0 to z = 1.0 m (top end height)
    # Bottom end height of the primary: 0 in the paper (from the ground); a UFO upright rises
    # from a low horizontal cordon (our choice for the preset: 0.15 m, below the scan start).
    primary_base_height_m: float = 0.0
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

    # Alley side cut back (a hedged fruiting wall): branches pointing within
    # alley_side_half_angle_deg of the camera's side end where they leave this horizontal
    # distance from their base, so the arm scanning at z_target passes. None: no cut (the
    # paper's branches, <= 15 cm, never reach the camera 20 cm away).
    alley_side_reach_m: float | None = None
    # The camera's side: the paper's largest rotation (45 deg) plus a margin (our choice).
    alley_side_half_angle_deg: float = 70.0

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
        reach_m = self.alley_side_reach_m
        _require(
            reach_m is None or (np.isfinite(reach_m) and reach_m > 0),
            "alley_side_reach_m",
            f"must be None or positive, got {reach_m}",
        )
        _require(
            0 <= self.alley_side_half_angle_deg <= 180,
            "alley_side_half_angle_deg",
            "must be in [0, 180]",
        )
        _require(self.yaw_mode in YAW_MODES, "yaw_mode", f"must be one of {YAW_MODES}")
        _require(
            self.architecture in ARCHITECTURES,
            "architecture",
            f"must be one of {ARCHITECTURES}, got {self.architecture!r}",
        )
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
        base_m = self.primary_base_height_m
        _require(
            bool(np.isfinite(base_m)) and 0 <= base_m < self.primary_height_m,
            "primary_base_height_m",
            f"must lie in [0, primary_height_m), got {base_m}",
        )
        lowest_use_m = min(
            self.placement_height_m,
            self.primary_radius_reference_height_m,
            self.secondary_base_height_range_m[0],
        )
        _require(
            base_m <= lowest_use_m,
            "primary_base_height_m",
            "must not exceed placement_height_m, primary_radius_reference_height_m or the low "
            f"end of secondary_base_height_range_m (the primary must reach them), got {base_m}",
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

    @classmethod
    def tall_spindle(cls) -> TreeConfig:
        """A tall-spindle (or V-trellis) leader with weak fruiting branches; no clutter.

        The leader is thick, nearly straight and nearly vertical: radius U(8, 14) mm at the
        reference height (real close-up frames, reference.md: trunks and leaders read 10-25 px
        wide at 0.2-0.5 m from the 416.8 px focal camera, i.e. radius ~5-15 mm). Fruiting
        branches (the secondaries) are near horizontal to drooping and kept under half the
        leader's diameter by pruning (orchard practice), which matches the real frames' side
        branches (2-10 px, mean ~7, against 10-25 px leaders: ratio ~0.4).
        """
        return cls(
            architecture="tall_spindle",
            # Leader: our choice for "nearly straight": a few cm of top offset, small tilt.
            primary_top_offset_range_m=(-0.03, 0.03),
            primary_max_tilt_deg=5.0,
            primary_radius_range_m=(0.008, 0.014),  # real frames (above)
            primary_taper_per_m=0.25,  # gentle taper: our choice
            # Fruiting branches: orchard practice (brief): 3-8 in the scan band, 10-30 cm long.
            secondary_count_range=(3, 8),
            secondary_base_height_range_m=(0.325, 0.75),  # the paper's scan band
            secondary_elevation_range_deg=(-25.0, 20.0),  # near horizontal to drooping
            secondary_length_range_m=(0.10, 0.30),
            # Radius 0.3-0.5 x the leader: the "under half the leader's diameter" pruning rule
            # (orchard practice); real frames' branch / leader width ratio ~0.4 (above).
            secondary_radius_scale_range=(0.3, 0.5),
            secondary_tip_radius_fraction=0.6,  # longer branches, more taper: our choice
            secondary_bend_strength_range_per_m=(0.0, 1.0),  # mild bending: our choice
        )

    @classmethod
    def tall_spindle_leader(cls) -> TreeConfig:
        """A full-height tall-spindle leader, scanned over 0.80 m of its fruiting zone.

        The tree stands on the ground at its real height; the scan covers the leader from
        :data:`branch_gym.sim.robot.home.LEADER_SCAN_START_HEIGHT_M` (0.70 m) to
        ``LEADER_SCAN_END_HEIGHT_M`` (1.50 m), from an arm lifted on a platform
        (``BasePlacement.platform()``); ``branch_gym.scan.leader_scan_config`` sets all three.
        Sources (docs/worlds.md, "A longer stretch"): the leader is ~3 m tall (Robinson 2007,
        Robinson et al. 2011), feathers below 60 cm are removed at planting (a training
        plan), so fruiting branches start at 0.6 m; branches are renewed when they pass half
        (OMAFRA) to two thirds (Robinson 2010) of the leader's diameter and trained at or
        below horizontal. Density: 10-15 feathers on the planted nursery tree (Robinson et
        al. 2011) spread over roughly its first metre of leader above 0.6 m, and the
        neighbours' ~8-12 per metre of dormant leader (``OrchardRowConfig.branches_per_m``):
        11-18 branches on the 1.15 m from 0.60 to 1.75 m, 9.6-15.7 per metre (mean 12.6).
        Branch shape, radius and angles as :meth:`tall_spindle`.
        """
        return replace(
            cls.tall_spindle(),
            primary_height_m=3.0,  # ~3 m (10 ft) leader (Robinson 2007)
            primary_radius_reference_height_m=1.1,  # middle of the 0.70-1.50 m scan
            placement_height_m=0.70,  # the scan's start height: the primary passes (0, 0) there
            secondary_count_range=LEADER_SECONDARY_COUNT_RANGE,
            secondary_base_height_range_m=LEADER_SECONDARY_BASE_HEIGHT_RANGE_M,
            # Bases closer than this share one height (the authors' rule, shorter: spindle
            # branches spiral up the leader one by one rather than in whorls; our choice).
            secondary_group_height_m=0.03,
            # The alley face hedged back to 12 cm from the leader where it faces the robot: the
            # camera 20 cm away and the wrist behind and below it pass (measured: uncut, 3 of
            # the first 4 orchard scans ended on a branch touching the flange or wrist).
            alley_side_reach_m=0.12,
        )

    @classmethod
    def ufo(cls) -> TreeConfig:
        """One upright of a UFO (upright fruiting offshoots) tree, with short lateral shoots.

        The primary is a vertical upright rising from a low horizontal cordon at
        ``primary_base_height_m`` (the cordon itself and the tree's other uprights are the
        world's to add: ``architecture="ufo"``); no clutter.
        """
        return cls(
            architecture="ufo",
            primary_base_height_m=0.15,  # cordon height: our choice, below the scan start
            # Upright: our choice for "near straight": a few cm of top offset, small tilt.
            primary_top_offset_range_m=(-0.03, 0.03),
            primary_max_tilt_deg=5.0,
            primary_radius_range_m=(0.005, 0.010),  # U(5, 10) mm: orchard practice (brief)
            # Short lateral fruiting shoots: orchard practice (brief).
            secondary_count_range=(2, 5),
            secondary_elevation_range_deg=(0.0, 60.0),
            secondary_length_range_m=(0.05, 0.15),
            secondary_radius_scale_range=(0.3, 0.6),
        )


def _require(condition: bool, name: str, problem: str) -> None:
    if not condition:
        raise ValueError(f"TreeConfig.{name} {problem}")


def _check_range(name: str, value: tuple[float, float]) -> None:
    _require(len(value) == 2, name, f"must be a (low, high) pair, got {value}")
    _require(bool(np.all(np.isfinite(value))), name, f"must be finite, got {value}")
    _require(value[0] <= value[1], name, f"is an inverted range (low > high): {value}")
