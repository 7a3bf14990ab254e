"""Training frames from the orchard world: frame pairs as a scan pairs them, with the exact flow.

The paper's segmenter reads a frame and the flow against an earlier frame of the same scan,
taken when the camera has moved at least 7.5 mm and turned less than 0.5 deg since
(:class:`recon.segmentation.flow.FramePairer`). Each pair here is rendered that way in the
orchard world (:mod:`branch_gym.sim.scene.orchard_scene`): the camera starts at a random distance,
height and view angle of a random tree, climbs, then moves by a baseline drawn above the
paper's 7.5 mm while turning by less than 0.5 deg. Besides the two frames a pair stores the
renderer's exact flow of the current frame (from its depth and the two poses,
:func:`branch_gym.sim.scene.flow.ground_truth_flow`) and its labels, so that training can code
the exact flow, a corrupted copy of it, or a flow computed from the (augmented) frames.

Shards are ``shard_XXXXX.npz`` (written atomically; a rerun skips the shards that exist)
holding, for N pairs:

* ``rgb``: (N, 2, H, W, 3) uint8, the earlier and the current frame;
* ``flow``: (N, H, W, 2) float16, the current frame's exact flow to the earlier one, in pixels
  (the direction of :class:`recon.segmentation.flow.DenseFlowConfig`'s default; 0 where unknown);
* ``labels``: (N, H, W) uint16, the current frame's instance labels
  (:mod:`branch_gym.sim.scene.labels`); the target is ``1 <= label < 100`` (the scanned tree);
* ``seeds``: (N,) int64 tree seeds; ``architectures``: (N,) int8 index into
  ``OrchardPairsConfig.architectures``;
* ``n_secondaries``: (N,) int16 secondaries of the pair's tree, which place the labels of its
  details and uprights (:func:`branch_gym.sim.scene.labels.details_label`; shards written
  before it was stored lack it, and a target that needs it says so);
* ``baseline_m``: (N,) float32 camera translation between the two frames (m).

Tree seeds come from a Generator seeded by the data set seed and the shard index: shard k is
the same whatever shards were made before it, and the seeds lie in the training range, disjoint
from the evaluation seeds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from branch_gym.segmenter_training.config import TRAIN_SEED_HIGH, TRAIN_SEED_LOW
from branch_gym.sim.scene.flow import ground_truth_flow
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.world import WORLDS, World, WorldConfig
from recon.segmentation.flow import FramePairingConfig
from recon.validation import require_int, require_positive

logger = logging.getLogger(__name__)

ARCHITECTURES = ("paper", "hard", "tall_spindle", "ufo")
"""Tree presets (:class:`TreeConfig` class methods) the pairs are drawn from."""

_PAIRING = FramePairingConfig()


def _require_range(config: object, name: str, low: float | None = None) -> None:
    bounds = getattr(config, name)
    if len(bounds) != 2 or not bounds[0] <= bounds[1] or (low is not None and bounds[0] < low):
        floor = "" if low is None else f" with a lower bound >= {low}"
        raise ValueError(
            f"{type(config).__name__}.{name} must be a (low, high) range{floor}, got {bounds!r}"
        )


@dataclass(frozen=True)
class OrchardPairsConfig:
    """What :func:`render_orchard_pairs` renders.

    Attributes:
        trees: Number of trees of the data set.
        pairs_per_tree: Frame pairs per tree.
        trees_per_shard: Trees per shard file.
        architectures: Tree presets drawn from (:data:`ARCHITECTURES`).
        architecture_weights: Their probabilities.
        z_target_range_m: Camera-to-primary distance at home (paper V: 0.20 m; real close-ups
            0.15-0.45 m, ``../shared/data/real_dev``: our choice).
        start_height_range_m: Camera height at home (paper V-A: 0.275 m; up the scan band).
        orbit_range_deg: Orbit around the primary before the pairs (the rotation policies'
            views: the paper's 22.5-45 deg and more).
        roll_range_deg: Camera roll before the pairs.
        pitch_range_deg: Camera tilt up (positive) before the pairs. The scan looks level;
            real close-ups often look up at the tree against the sky (the horizon low in
            ``shared/data/real_dev``'s frames; our choice, for data sets that cover them).
        climb_range_m: Climb before each pair (frames along the scan).
        baseline_range_m: Camera translation between the frames of a pair. The paper pairs
            frames >= 7.5 mm apart (FramePairingConfig.min_translation_m) for its learned flow;
            DIS follows the thin tree only at shorter baselines (~2.5 mm,
            :class:`recon.segmentation.flow.DenseFlowConfig`), so data sets for the DIS flow
            are rendered with a shorter range.
        rotation_range_deg: Camera rotation between them, below the paper's 0.5 deg
            (FramePairingConfig.max_rotation_deg).
        lateral_fraction: Largest sideways and forward component of the pair's motion, as a
            fraction of the upward one (the scan follows the branch up, with corrections).
        speed_mps: Camera speed of the motions (paper: 2.5-5 cm/s): the motion blur.
        world: ``"orchard"``, or ``"clean"`` for pairs of the clean world (so that the
            segmenter keeps working there).
    """

    trees: int = 480
    pairs_per_tree: int = 6
    trees_per_shard: int = 8
    architectures: tuple[str, ...] = ARCHITECTURES
    architecture_weights: tuple[float, ...] = (0.4, 0.2, 0.2, 0.2)
    z_target_range_m: tuple[float, float] = (0.15, 0.45)
    start_height_range_m: tuple[float, float] = (0.26, 0.5)
    orbit_range_deg: tuple[float, float] = (-45.0, 45.0)
    roll_range_deg: tuple[float, float] = (-10.0, 10.0)
    pitch_range_deg: tuple[float, float] = (0.0, 0.0)
    climb_range_m: tuple[float, float] = (0.0, 0.08)
    baseline_range_m: tuple[float, float] = (_PAIRING.min_translation_m, 0.03)
    rotation_range_deg: tuple[float, float] = (0.0, 0.45)
    lateral_fraction: float = 0.6
    speed_mps: float = 0.05
    world: str = "orchard"

    def __post_init__(self) -> None:
        require_int(self, "trees", "pairs_per_tree", "trees_per_shard", minimum=1)
        if self.world not in WORLDS:
            raise ValueError(
                f"OrchardPairsConfig.world must be one of {WORLDS}, got {self.world!r}"
            )
        unknown = set(self.architectures) - set(ARCHITECTURES)
        if not self.architectures or unknown:
            raise ValueError(
                f"OrchardPairsConfig.architectures must name presets of {ARCHITECTURES}, "
                f"got {self.architectures!r}"
            )
        weights = np.asarray(self.architecture_weights, float)
        if len(weights) != len(self.architectures) or (weights < 0).any() or weights.sum() <= 0:
            raise ValueError(
                "OrchardPairsConfig.architecture_weights must hold one non-negative weight per "
                f"architecture, not all 0, got {self.architecture_weights!r}"
            )
        for name in ("z_target_range_m", "start_height_range_m", "climb_range_m"):
            _require_range(self, name, 0.0)
        _require_range(self, "orbit_range_deg")
        _require_range(self, "roll_range_deg")
        _require_range(self, "pitch_range_deg")
        _require_range(self, "baseline_range_m", 0.0)
        if self.baseline_range_m[0] <= 0.0:
            raise ValueError(
                "OrchardPairsConfig.baseline_range_m must start above 0 m (the frames must "
                f"differ), got {self.baseline_range_m!r}"
            )
        _require_range(self, "rotation_range_deg", 0.0)
        if self.rotation_range_deg[1] >= _PAIRING.max_rotation_deg:
            raise ValueError(
                "OrchardPairsConfig.rotation_range_deg must stay below the pairing threshold "
                f"{_PAIRING.max_rotation_deg} deg, got {self.rotation_range_deg!r}"
            )
        require_positive(self, "speed_mps")
        if not 0.0 <= self.lateral_fraction <= 2.0:
            raise ValueError(
                "OrchardPairsConfig.lateral_fraction must be in [0, 2], "
                f"got {self.lateral_fraction}"
            )

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        return asdict(self)

    @property
    def shards(self) -> int:
        """Number of shard files of the data set."""
        return math.ceil(self.trees / self.trees_per_shard)


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _move(world: World, twist: np.ndarray, duration_s: float) -> bool:
    return duration_s <= 0 or world.apply_camera_twist(twist, duration_s).ok


def orbit_camera(world: World, angle_deg: float, speed_mps: float, distance_m: float) -> bool:
    """Orbit the camera by ``angle_deg`` about the vertical axis ``distance_m`` ahead of it.

    Args:
        world: The world whose camera moves.
        angle_deg: Orbit angle (positive: the camera moves to its right, camera +x).
        speed_mps: Camera speed along the arc.
        distance_m: Radius of the orbit (the camera's distance to the primary).

    Returns:
        Whether the arm completed the motion.
    """
    sign = math.copysign(1.0, angle_deg)
    orbit = np.array([sign * speed_mps, 0, 0, 0, -sign * speed_mps / distance_m, 0])
    return _move(world, orbit, abs(math.radians(angle_deg)) * distance_m / speed_mps)


def _pair_twist(config: OrchardPairsConfig, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A camera-frame twist and its duration: up (camera -y) with sideways/forward parts."""
    lateral = rng.uniform(-config.lateral_fraction, config.lateral_fraction, 2)
    direction = np.array([lateral[0], -1.0, 0.5 * lateral[1]])
    direction /= np.linalg.norm(direction)
    duration_s = _uniform(rng, config.baseline_range_m) / config.speed_mps
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    turn_rad = math.radians(_uniform(rng, config.rotation_range_deg))
    return np.concatenate([direction * config.speed_mps, axis * turn_rad / duration_s]), duration_s


def render_orchard_pairs(
    config: OrchardPairsConfig, tree_seed: int, rng: np.random.Generator
) -> dict[str, list]:
    """The frame pairs of one tree of the orchard (or clean) world.

    Args:
        config: What to render.
        tree_seed: Seed of ``World.reset`` (the tree and its orchard).
        rng: Draws the architecture, the camera's start and every motion.

    Returns:
        Lists ``rgb``, ``flow``, ``labels`` (module docstring), the ``architecture`` index and
        the tree's ``n_secondaries``; fewer than ``pairs_per_tree`` pairs when the arm cannot
        move further.
    """
    weights = np.asarray(config.architecture_weights, float)
    architecture = int(rng.choice(len(config.architectures), p=weights / weights.sum()))
    tree = getattr(TreeConfig, config.architectures[architecture])()
    world_config = replace(
        WorldConfig.preset(config.world, tree),
        z_target_m=_uniform(rng, config.z_target_range_m),
        scan_start_height_m=_uniform(rng, config.start_height_range_m),
    )
    out: dict[str, list] = {
        "rgb": [],
        "flow": [],
        "labels": [],
        "baseline_m": [],
        "architecture": architecture,
        "n_secondaries": 0,
    }
    world = World(world_config)
    try:
        world.reset(tree_seed)
        out["n_secondaries"] = len(world.tree.secondaries)
        z = world_config.z_target_m
        speed = config.speed_mps
        ok = orbit_camera(world, _uniform(rng, config.orbit_range_deg), speed, z)
        roll = math.radians(_uniform(rng, config.roll_range_deg))
        if ok and roll:
            ok = _move(world, np.array([0, 0, 0, 0, 0, math.copysign(0.5, roll)]), abs(roll) / 0.5)
        pitch = 0.0
        if config.pitch_range_deg != (0.0, 0.0):  # drawn only then: older data sets stay
            pitch = math.radians(_uniform(rng, config.pitch_range_deg))
        if ok and pitch:  # about the camera's x axis: positive turns the view up
            ok = _move(
                world, np.array([0, 0, 0, math.copysign(0.5, pitch), 0, 0]), abs(pitch) / 0.5
            )
        for _ in range(config.pairs_per_tree):
            climb_s = _uniform(rng, config.climb_range_m) / speed
            if not ok or not _move(world, np.array([0, -speed, 0, 0, 0, 0]), climb_s):
                break
            earlier = world.render()
            T_earlier = world.T_world_camera
            twist, duration_s = _pair_twist(config, rng)
            ok = _move(world, twist, duration_s)
            current = world.render()
            flow = ground_truth_flow(
                current.depth_m, world.T_world_camera, T_earlier, world_config.camera
            )
            out["rgb"].append(np.stack([earlier.rgb, current.rgb]))
            out["flow"].append(np.nan_to_num(flow, nan=0.0).astype(np.float16))
            out["labels"].append(current.labels.astype(np.uint16))
            out["baseline_m"].append(
                float(np.linalg.norm(world.T_world_camera[:3, 3] - T_earlier[:3, 3]))
            )
    finally:
        world.close()
    return out


def generate_orchard_shard(
    config: OrchardPairsConfig, seed: int, index: int, evaluation: bool = False
) -> dict[str, np.ndarray]:
    """Render shard ``index`` of the data set of ``seed`` (module docstring).

    Args:
        config: What to render.
        seed: Data set seed: draws the tree seeds (training) and every camera motion.
        index: Shard index.
        evaluation: Use the evaluation trees, seeds 0 .. trees - 1 (the seeds of ``eval.py``'s
            tables), instead of random training seeds (>= TRAIN_SEED_LOW).
    """
    rng = np.random.default_rng([seed, index])
    parts: dict[str, list] = {
        "rgb": [],
        "flow": [],
        "labels": [],
        "baseline_m": [],
        "seeds": [],
        "arch": [],
        "n_secondaries": [],
    }
    first_tree = index * config.trees_per_shard
    for tree in range(first_tree, min(config.trees, first_tree + config.trees_per_shard)):
        drawn = int(rng.integers(TRAIN_SEED_LOW, TRAIN_SEED_HIGH))
        tree_seed = tree if evaluation else drawn
        try:
            pairs = render_orchard_pairs(config, tree_seed, rng)
        except (RuntimeError, ValueError) as error:  # e.g. no home pose for this tree
            logger.warning("tree seed %d skipped: %s", tree_seed, error)
            continue
        for key in ("rgb", "flow", "labels", "baseline_m"):
            parts[key] += pairs[key]
        parts["seeds"] += [tree_seed] * len(pairs["rgb"])
        parts["arch"] += [pairs["architecture"]] * len(pairs["rgb"])
        parts["n_secondaries"] += [pairs["n_secondaries"]] * len(pairs["rgb"])
    h, w = WorldConfig().camera.height, WorldConfig().camera.width
    return {
        "rgb": np.asarray(parts["rgb"], np.uint8).reshape(-1, 2, h, w, 3),
        "flow": np.asarray(parts["flow"], np.float16).reshape(-1, h, w, 2),
        "labels": np.asarray(parts["labels"], np.uint16).reshape(-1, h, w),
        "baseline_m": np.asarray(parts["baseline_m"], np.float32),
        "seeds": np.asarray(parts["seeds"], np.int64),
        "architectures": np.asarray(parts["arch"], np.int8),
        "n_secondaries": np.asarray(parts["n_secondaries"], np.int16),
    }


ORCHARD_KEYS = ("rgb", "flow", "labels", "seeds", "architectures")
"""The arrays training reads (``baseline_m`` is a record of the pair, not read)."""
OPTIONAL_ORCHARD_KEYS = ("n_secondaries",)
"""Arrays read when every shard has them (older shards lack them)."""


def load_orchard_shards(data_dir: Path) -> dict[str, np.ndarray]:
    """Concatenate every orchard shard of a folder (sorted by name).

    Returns:
        The arrays of the module docstring, over all shards; an optional array
        (:data:`OPTIONAL_ORCHARD_KEYS`) only when every shard holds it.

    Raises:
        FileNotFoundError: No shard in ``data_dir``.
        ValueError: A shard that is not an orchard shard (its missing keys named).
    """
    paths = sorted(Path(data_dir).glob("shard_*.npz"))
    if not paths:
        raise FileNotFoundError(
            f"no shard_*.npz in {data_dir}: run `python -m branch_gym.segmenter_training "
            "generate-orchard` first"
        )
    parts: dict[str, list[np.ndarray]] = {key: [] for key in ORCHARD_KEYS + OPTIONAL_ORCHARD_KEYS}
    for path in paths:
        with np.load(path) as shard:
            missing = [key for key in ORCHARD_KEYS if key not in shard]
            if missing:
                raise ValueError(f"{path} is not an orchard shard: it lacks {missing}")
            for key in ORCHARD_KEYS + OPTIONAL_ORCHARD_KEYS:
                if key in shard:
                    parts[key].append(shard[key])
    return {
        key: np.concatenate(value)
        for key, value in parts.items()
        if key in ORCHARD_KEYS or len(value) == len(paths)
    }
