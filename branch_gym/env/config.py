"""Configuration of :class:`branch_gym.env.BranchScanEnv`: frozen dataclasses, keywords, options.

``gymnasium.make("BranchScan-v0", tracker="oracle", tree="hard", end_height_m=0.5)`` reaches
:func:`env_config_from_kwargs`, which turns the keywords into an :class:`EnvConfig`. The
shortcuts ``world`` ("clean" or "orchard"), ``tracker``, ``segmenter``, ``tree``,
``end_height_m``, ``speed_mps`` and
``render_tracking_frames``, ``control_dt_s`` change the scan
settings (``scan``, a :class:`branch_gym.scan.ScanConfig`); every other keyword is an
:class:`EnvConfig` field.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from branch_gym.config_utils import check_keys, is_number
from branch_gym.env.coverage import CoverageConfig
from branch_gym.env.layout import (
    ACTION_TYPES,
    DISCRETE_ANGLES_DEG,
    THETA_MAX_DEG,
    TRIGGER_ANGLES_DEG,
)
from branch_gym.env.reward import RewardConfig
from branch_gym.scan import ScanConfig, leader_scan_config
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.ground_truth import TreeGT
from branch_gym.sim.validation import require_int, require_positive
from branch_gym.sim.world import WORLDS, WorldConfig

TREE_PRESETS = ("paper", "cluttered", "hard", "tall_spindle", "ufo", "tall_spindle_leader")
# Tree presets scanned over a stretch of their own: choosing one also sets the scan's start and
# end heights and the robot's base (docs/worlds.md, "A longer stretch").
STRETCH_PRESETS: dict[str, Callable[[ScanConfig], ScanConfig]] = {
    "tall_spindle_leader": leader_scan_config,
}
RESET_OPTIONS = ("tree", "branch_value_s")
SCAN_SHORTCUTS = (
    "world",
    "tracker",
    "segmenter",
    "tree",
    "end_height_m",
    "speed_mps",
    "render_tracking_frames",
    "control_dt_s",
    "max_scan_time_s",
)
# Rotation of 180 deg or more about the branch would look at it from behind the tree's far side.
_MAX_THETA_DEG = 90.0


@dataclass(frozen=True)
class ObservationConfig:
    """How the pipeline's state becomes an observation.

    Attributes:
        image_height: Observation image rows (our choice: the 240-row camera image / 4; SB3's
            default CNN needs at least 36).
        image_width: Observation image columns (our choice: 320 / 4).
        count_scale: Branch counts are divided by this and clipped to [0, 1] (our choice: the
            paper's trees hold at most 5 secondaries, the "hard" preset 8).
        travel_clip_fov: Travel since the last rotation is clipped to [0, this] vertical FoVs
            (our choice: a whole 0.275 -> 0.75 m scan is ~4 FoVs of 0.115 m).
        explained_tolerance_px: A 2D side-branch sample is explained by a projected 3D secondary
            within this many pixels of its drawn width (our choice: twice the paper's 4 px
            consistency tolerance, section IV).
        explained_min_fraction: A 2D candidate is explained when at least this fraction of its
            samples (outside the primary's silhouette) are (our choice: a majority).
    """

    image_height: int = 60
    image_width: int = 80
    count_scale: float = 10.0
    travel_clip_fov: float = 10.0
    explained_tolerance_px: float = 8.0
    explained_min_fraction: float = 0.5

    def __post_init__(self) -> None:
        require_int(self, "image_height", "image_width", minimum=1)
        require_positive(self, "count_scale", "travel_clip_fov", "explained_tolerance_px")
        if not (is_number(self.explained_min_fraction) and 0.0 < self.explained_min_fraction <= 1):
            raise ValueError(
                "ObservationConfig.explained_min_fraction must be in (0, 1], got "
                f"{self.explained_min_fraction!r}"
            )


@dataclass(frozen=True)
class EnvConfig:
    """Everything a :class:`branch_gym.env.BranchScanEnv` is made of.

    Attributes:
        action_type: One of :data:`branch_gym.env.layout.ACTION_TYPES` (their spaces and
            meanings: ``ACTION_DESCRIPTIONS`` there, decoding: :mod:`branch_gym.env.actions`).
        theta_max_deg: Angle of the continuous action's bounds and the normaliser of angles in
            the observation (the paper's largest angle, Table I: 45 deg).
        discrete_angles_deg: Target angles of the discrete action (the paper's angles, Table I);
            within +-theta_max_deg (checked for discrete envs only).
        trigger_angles_deg: Cycle angles of the trigger actions (the paper's angles, Table I);
            positive, at most theta_max_deg (checked for trigger envs only).
        flatten: Return one flat float32 vector instead of the Dict (MLP-only libraries).
        info_timings: Put wall-clock stage timings in ``info["timings_ms"]`` (and the wall-clock
            columns in ``final_metrics``). Off by default: they are measurements, not simulation
            state, so two runs with the same seed and actions would differ there, and
            gymnasium's check_env requires equal infos.
        coverage: The view-coverage memory of the scan band (v1 observations,
            :mod:`branch_gym.env.coverage`), or None (v0: no memory).
        branch_value_s: The price of scan time, in seconds of scan time a found branch is
            worth: ``(low, high)`` draws it log-uniformly per episode and puts it in the
            observation (``price``: 0 at ``low``, 1 at ``high``), so one policy learns every
            price; the reward's time term is then ``match_reward / value`` per second. None
            keeps ``reward.time_penalty_per_s`` (v0). ``reset(options={"branch_value_s": v})``
            fixes it for one episode.
        score_cache: Score against the ground truth only when the score can have changed (the
            model's arrays or the secondaries in scope; :mod:`branch_gym.env.score_cache`);
            False scores after every step (the reference path). Same results either way.
        paper_scoring: Score the reward as the paper (ids up to v2): a spurious branch is any
            reconstruction that is a candidate of no side branch, the tree's own spurs, a
            neighbour's branch or a wire included, and branches are in scope up to the height
            reached. False (v3 and later): spurious means nothing there, and branches are in
            scope up to the planned end height (:mod:`recon.metrics`).
        observation: Observation image size and scales.
        reward: Reward weights.
        scan: The scan (tracker, segmenter, tree distribution, speed, end height, world).
    """

    action_type: str = "continuous"
    theta_max_deg: float = THETA_MAX_DEG
    discrete_angles_deg: tuple[float, ...] = DISCRETE_ANGLES_DEG
    trigger_angles_deg: tuple[float, ...] = TRIGGER_ANGLES_DEG
    flatten: bool = False
    info_timings: bool = False
    score_cache: bool = True
    paper_scoring: bool = False
    coverage: CoverageConfig | None = None
    branch_value_s: tuple[float, float] | None = None
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    scan: ScanConfig = field(default_factory=ScanConfig)

    def __post_init__(self) -> None:
        if self.action_type not in ACTION_TYPES:
            raise ValueError(
                f"EnvConfig.action_type must be one of {ACTION_TYPES}, got {self.action_type!r}"
            )
        theta = self.theta_max_deg
        if not (is_number(theta) and 0.0 < theta <= _MAX_THETA_DEG):
            raise ValueError(
                f"EnvConfig.theta_max_deg must be in (0, {_MAX_THETA_DEG}], got {theta!r}"
            )
        # Only a discrete (trigger) env's angles must lie within the normaliser's range.
        limit = theta if self.action_type == "discrete" else math.inf
        _set_angles(
            self,
            "discrete_angles_deg",
            lambda a: abs(a) <= limit,
            f"finite angles (within +-theta_max_deg={theta} for a discrete env)",
        )
        limit = theta if self.action_type == "trigger" else math.inf
        _set_angles(
            self,
            "trigger_angles_deg",
            lambda a: 0.0 < a <= limit,
            f"positive angles (at most theta_max_deg={theta} for a trigger env)",
        )
        if self.branch_value_s is not None:
            object.__setattr__(
                self, "branch_value_s", price_range(self.branch_value_s, "EnvConfig.branch_value_s")
            )
        if self.coverage is not None and not isinstance(self.coverage, CoverageConfig):
            raise ValueError(f"EnvConfig.coverage must be a CoverageConfig, got {self.coverage!r}")
        for name, kind in (
            ("flatten", bool),
            ("info_timings", bool),
            ("score_cache", bool),
            ("paper_scoring", bool),
            ("observation", ObservationConfig),
            ("reward", RewardConfig),
            ("scan", ScanConfig),
        ):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"EnvConfig.{name} must be a {kind.__name__}, got {getattr(self, name)!r}"
                )


def tree_config(tree: str | TreeConfig) -> TreeConfig:
    """A tree distribution from a preset name (:data:`TREE_PRESETS`) or a TreeConfig.

    Raises:
        ValueError: anything else, naming the presets.
    """
    if isinstance(tree, TreeConfig):
        return tree
    if isinstance(tree, str) and tree in TREE_PRESETS:
        return getattr(TreeConfig, tree)()
    raise ValueError(f"tree must be one of {TREE_PRESETS} or a TreeConfig, got {tree!r}")


def scan_with_tree(scan: ScanConfig, tree: str | TreeConfig) -> ScanConfig:
    """``scan`` with the tree ``tree`` (a preset name or a TreeConfig).

    A preset in :data:`STRETCH_PRESETS` also sets the scan's start and end heights and the
    robot's base for its stretch; any other tree keeps ``scan``'s.

    Raises:
        ValueError: an unknown tree (see :func:`tree_config`).
    """
    config = tree_config(tree)
    if isinstance(tree, str) and tree in STRETCH_PRESETS:
        return STRETCH_PRESETS[tree](scan)
    return replace(scan, world=replace(scan.world, tree=config))


def price_range(values: Any, name: str = "branch_value_s") -> tuple[float, float]:
    """A (low, high) range of branch values: two finite positive seconds, low <= high.

    Raises:
        ValueError: anything else (``name`` in the message).
    """
    try:
        pair = tuple(values)
    except TypeError:
        pair = ()
    if not (
        len(pair) == 2
        and all(is_number(v) and math.isfinite(v) and v > 0 for v in pair)
        and pair[0] <= pair[1]
    ):
        raise ValueError(
            f"{name} must be (low, high) positive seconds with low <= high, got {values!r}"
        )
    return float(pair[0]), float(pair[1])


def draw_branch_value_s(rng: np.random.Generator, bounds_s: tuple[float, float]) -> float:
    """A branch value drawn log-uniformly on ``bounds_s`` (low, high) seconds from ``rng``."""
    low, high = bounds_s
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def env_config_from_kwargs(kwargs: dict[str, Any]) -> EnvConfig:
    """Parse the environment's keyword arguments (see the module docstring).

    ``reward`` and ``observation`` accept a config or a dict of its fields; ``scan`` a
    :class:`ScanConfig` that the shortcuts then modify.

    Raises:
        ValueError: an unknown keyword (named, with the closest valid one) or a bad value (the
            configs name the offending field).
    """
    valid = [f.name for f in fields(EnvConfig)] + list(SCAN_SHORTCUTS)
    for key in kwargs:
        if key not in valid:
            close = difflib.get_close_matches(key, valid, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(f"unknown BranchScanEnv keyword {key!r}{hint}; valid: {sorted(valid)}")
    kwargs = dict(kwargs)
    shortcuts = {k: kwargs.pop(k) for k in SCAN_SHORTCUTS if k in kwargs}
    scan = kwargs.pop("scan", None) or ScanConfig()
    if not isinstance(scan, ScanConfig):
        raise ValueError(f"scan must be a ScanConfig, got {scan!r}")
    if "world" in shortcuts:
        name = shortcuts.pop("world")
        if not isinstance(name, str) or name not in WORLDS:
            raise ValueError(f"world must be one of {WORLDS}, got {name!r}")
        scan = replace(scan, world=WorldConfig.preset(name, tree=scan.world.tree))
    if "tree" in shortcuts:
        scan = scan_with_tree(scan, shortcuts.pop("tree"))
    for key, valid_type in (("tracker", str), ("segmenter", str)):
        if key in shortcuts and not isinstance(shortcuts[key], valid_type):
            raise ValueError(f"{key} must be a str, got {shortcuts[key]!r}")
    for key in ("end_height_m", "speed_mps", "control_dt_s", "max_scan_time_s"):
        if key in shortcuts and not is_number(shortcuts[key]):
            raise ValueError(f"{key} must be a number, got {shortcuts[key]!r}")
    if "render_tracking_frames" in shortcuts and not isinstance(
        shortcuts["render_tracking_frames"], bool
    ):
        raise ValueError(
            f"render_tracking_frames must be a bool, got {shortcuts['render_tracking_frames']!r}"
        )
    if shortcuts:
        scan = scan.replace(**shortcuts)  # ScanConfig names the offending field
    if isinstance(kwargs.get("reward"), dict):
        kwargs["reward"] = RewardConfig.from_dict(kwargs["reward"])
    if isinstance(kwargs.get("observation"), dict):
        check_keys(ObservationConfig, kwargs["observation"])
        kwargs["observation"] = ObservationConfig(**kwargs["observation"])
    return EnvConfig(scan=scan, **kwargs)


def tree_from_options(options: dict[str, Any] | None) -> TreeGT | None:
    """The ``tree`` option of ``reset(options=...)``: a ground truth to scan instead of a seed's.

    Raises:
        ValueError: an unknown option (named) or a ``tree`` that is not a TreeGT.
    """
    options = options or {}
    unknown = sorted(set(options) - set(RESET_OPTIONS))
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}: expected some of {RESET_OPTIONS}")
    tree = options.get("tree")
    if tree is not None and not isinstance(tree, TreeGT):
        raise ValueError(f"reset option 'tree' must be a TreeGT, got {type(tree).__name__}")
    return tree


def branch_value_from_options(options: dict[str, Any] | None) -> float | None:
    """The ``branch_value_s`` option of ``reset(options=...)`` (seconds), or None.

    Raises:
        ValueError: not a positive finite number.
    """
    value = (options or {}).get("branch_value_s")
    if value is None:
        return None
    if not (is_number(value) and math.isfinite(value) and value > 0):
        raise ValueError(f"reset option 'branch_value_s' must be positive seconds, got {value!r}")
    return float(value)


def _set_angles(
    config: EnvConfig, name: str, valid: Callable[[float], bool], requirement: str
) -> None:
    """Check the angle sequence field ``name`` of ``config`` and store it as a float tuple.

    Raises:
        ValueError: It is not a non-empty sequence of finite numbers that pass ``valid``
            (``requirement`` says what they must be).
    """
    value = getattr(config, name)
    try:
        angles = tuple(value)
    except TypeError:
        angles = ()
    if not angles or not all(is_number(a) and math.isfinite(a) and valid(a) for a in angles):
        raise ValueError(
            f"EnvConfig.{name} must be a non-empty sequence of {requirement}, got {value!r}"
        )
    object.__setattr__(config, name, tuple(float(a) for a in angles))
