"""Training frames from the simulator: (previous, current) RGB pairs with class maps.

Shards are ``shard_XXXXX.npz`` files (written to a temporary name and renamed, so a killed run
leaves no half shard; a rerun skips the shards that exist) holding, for N pairs:

* ``rgb``: (N, 2, H, W, 3) uint8, previous and current frame;
* ``classes``: (N, 2, H, W) uint8 class maps of both frames (:data:`CLASS_BACKGROUND` ...);
* ``seeds``: (N,) int64 tree seed of each pair; ``presets``: (N,) int8 preset index.

Tree seeds come from a numpy Generator seeded by the CLI seed and the shard index, so shard k is
the same whatever shards were generated before it.
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from branch_gym.segmenter_training.config import (
    TRAIN_SEED_HIGH,
    TRAIN_SEED_LOW,
    GenerateConfig,
)
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.world import World, WorldConfig

logger = logging.getLogger(__name__)

CLASS_BACKGROUND = 0
CLASS_PRIMARY = 1
CLASS_SECONDARY = 2
CLASS_CLUTTER = 3  # renderer's background trees, wires (labels >= 100): not the scanned tree
# A training target's value for a pixel of another object in front of the scanned tree: not the
# tree, weighed apart in the loss (OrchardAugmentConfig.nearer_negative_flow_ratio).
TARGET_NEARER_NEGATIVE = 3
PRESETS = ("paper", "cluttered", "hard")
EVAL_PRESETS = (*PRESETS, "tall_spindle", "ufo")  # TreeConfig class methods
_FIRST_CLUTTER_LABEL = 100  # renderer convention: 100 + k is clutter object k


def labels_to_classes(labels: np.ndarray) -> np.ndarray:
    """(H, W) int renderer labels -> (H, W) uint8 classes (background/primary/secondary/clutter)."""
    classes = np.zeros(labels.shape, np.uint8)
    classes[labels == 1] = CLASS_PRIMARY
    classes[(labels >= 2) & (labels < _FIRST_CLUTTER_LABEL)] = CLASS_SECONDARY
    classes[labels >= _FIRST_CLUTTER_LABEL] = CLASS_CLUTTER
    return classes


def branch_target(classes: np.ndarray) -> np.ndarray:
    """The training target of a class map: the scanned tree, its side branches told apart.

    Args:
        classes: (H, W) uint8 classes (:func:`labels_to_classes`).

    Returns:
        (H, W) uint8: 0 not the scanned tree, ``CLASS_PRIMARY`` (1) the primary,
        ``CLASS_SECONDARY`` (2) a side branch (the training loss weighs them apart).
    """
    branch = (classes == CLASS_PRIMARY) | (classes == CLASS_SECONDARY)
    return np.where(branch, classes, 0).astype(np.uint8)


def branch_mask(labels: np.ndarray) -> np.ndarray:
    """(H, W) bool: the scanned tree's primary and secondaries (1 <= label < 100)."""
    return (labels >= 1) & (labels < _FIRST_CLUTTER_LABEL)


def preset_tree_config(name: str) -> TreeConfig:
    """The tree distribution of a preset name (one of :data:`EVAL_PRESETS`)."""
    if name not in EVAL_PRESETS:
        raise ValueError(f"tree preset must be one of {EVAL_PRESETS}, got {name!r}")
    return getattr(TreeConfig, name)()


def _random_world_config(
    config: GenerateConfig, rng: np.random.Generator
) -> tuple[WorldConfig, int]:
    preset = int(rng.choice(len(PRESETS), p=np.asarray(config.preset_weights)))
    tree = preset_tree_config(PRESETS[preset])
    if rng.random() < config.thick_primary_probability:
        low = tree.primary_radius_range_m[0]
        tree = replace(tree, primary_radius_range_m=(low, config.thick_radius_m))
    if PRESETS[preset] != "paper":
        wires = tuple(sorted(rng.uniform(0.3, 0.85, size=int(rng.integers(0, 4)))))
        tree = replace(
            tree,
            background_tree_count_range=(1, int(rng.integers(1, 5))),
            trellis_wire_heights_m=tuple(float(h) for h in wires),
            trellis_wire_distance_m=float(rng.uniform(0.1, 0.5)),
        )
    world = WorldConfig(
        tree=tree,
        z_target_m=float(rng.uniform(*config.z_target_range_m)),
        scan_start_height_m=float(rng.uniform(*config.start_height_range_m)),
    )
    return world, preset


def _move(world: World, twist: np.ndarray, distance: float, speed: float) -> bool:
    """Move along ``twist`` (unit-free direction scaled to ``speed``) for ``distance``."""
    if distance <= 0:
        return True
    return world.apply_camera_twist(twist * speed, distance / speed).ok


def render_tree_pairs(
    config: GenerateConfig, tree_seed: int, rng: np.random.Generator
) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """Frame pairs of one random tree.

    Args:
        config: What to render.
        tree_seed: Seed of ``World.reset``.
        rng: Draws the world variant and the camera motions.

    Returns:
        (list of (2, H, W, 3) uint8 pairs, list of (2, H, W) uint8 class maps, preset index);
        fewer than ``pairs_per_tree`` pairs when the arm cannot move further.
    """
    world_config, preset = _random_world_config(config, rng)
    world = World(world_config)
    rgbs: list[np.ndarray] = []
    classes: list[np.ndarray] = []
    try:
        world.reset(tree_seed)
        z = world_config.z_target_m
        # Orbit around the primary: move along x while turning about the camera y axis.
        angle = math.radians(rng.uniform(*config.orbit_range_deg))
        orbit = np.array([math.copysign(1.0, angle), 0, 0, 0, -math.copysign(1.0, angle) / z, 0])
        ok = _move(world, orbit, abs(angle) * z, config.speed_mps)
        roll = math.radians(rng.uniform(*config.roll_range_deg))
        if ok and roll:
            ok = world.apply_camera_twist(
                np.array([0, 0, 0, 0, 0, math.copysign(0.5, roll)]), abs(roll) / 0.5
            ).ok
        for _ in range(config.pairs_per_tree):
            if not ok:
                break
            up = np.array([rng.uniform(-1, 1) * config.lateral_speed_fraction, -1.0, 0, 0, 0, 0])
            up /= np.linalg.norm(up)
            if not _move(world, up, rng.uniform(*config.climb_range_m), config.speed_mps):
                break
            first = world.render()
            ok = _move(world, up, rng.uniform(*config.displacement_range_m), config.speed_mps)
            second = world.render()
            rgbs.append(np.stack([first.rgb, second.rgb]))
            classes.append(
                np.stack([labels_to_classes(first.labels), labels_to_classes(second.labels)])
            )
    finally:
        world.close()
    return rgbs, classes, preset


def shard_path(out_dir: Path, index: int) -> Path:
    """Path of shard ``index``."""
    return Path(out_dir) / f"shard_{index:05d}.npz"


def write_shard(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write an npz atomically (temporary file in the same folder, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".npz")
    os.close(fd)
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def generate_shard(config: GenerateConfig, seed: int, index: int) -> dict[str, np.ndarray]:
    """Render shard ``index`` of the data set of ``seed``.

    Args:
        config: What to render.
        seed: Data set seed (CLI ``--seed``).
        index: Shard index.

    Returns:
        The shard's arrays (module docstring).
    """
    rng = np.random.default_rng([seed, index])
    rgbs, classes, seeds, presets = [], [], [], []
    for _ in range(config.trees_per_shard):
        tree_seed = int(rng.integers(TRAIN_SEED_LOW, TRAIN_SEED_HIGH))
        try:
            pair_rgb, pair_classes, preset = render_tree_pairs(config, tree_seed, rng)
        except (RuntimeError, ValueError) as error:  # e.g. no home pose for this tree
            logger.warning("tree seed %d skipped: %s", tree_seed, error)
            continue
        rgbs += pair_rgb
        classes += pair_classes
        seeds += [tree_seed] * len(pair_rgb)
        presets += [preset] * len(pair_rgb)
    return {
        "rgb": np.asarray(rgbs, np.uint8),
        "classes": np.asarray(classes, np.uint8),
        "seeds": np.asarray(seeds, np.int64),
        "presets": np.asarray(presets, np.int8),
    }


def shard_count(config: GenerateConfig) -> int:
    """Number of shards of a data set."""
    return math.ceil(config.trees / config.trees_per_shard)


def load_shards(data_dir: Path) -> dict[str, np.ndarray]:
    """Concatenate every shard of a folder (sorted by name).

    Returns:
        ``rgb`` (N, 2, H, W, 3), ``classes`` (N, 2, H, W), ``seeds`` (N,), ``presets`` (N,).

    Raises:
        FileNotFoundError: No shard in ``data_dir``.
    """
    paths = sorted(Path(data_dir).glob("shard_*.npz"))
    if not paths:
        raise FileNotFoundError(f"no shard_*.npz in {data_dir}: run the generate command first")
    parts: dict[str, list[np.ndarray]] = {"rgb": [], "classes": [], "seeds": [], "presets": []}
    for path in paths:
        with np.load(path) as shard:
            if len(shard["seeds"]) == 0:
                continue
            for key in parts:
                parts[key].append(shard[key])
    return {key: np.concatenate(value) for key, value in parts.items()}
