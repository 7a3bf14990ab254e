"""IoU of a segmenter against the renderer's labels, on trees never trained on.

Evaluation trees are seeds ``EVAL_SEED_OFFSET + i`` (0, 1, ...; training seeds are >= 1e6) of a
tree preset in the clean or the orchard world, scanned as in ``eval.py``: the camera starts at
the home pose (0.20 m from the primary, 0.275 m high) and climbs straight up; every
``frame_spacing_m`` a frame is segmented, with the frame ``previous_offset_m`` of climb before
it as the previous frame (flow input; 10 mm, past the paper's 7.5 mm pairing threshold). With
``orbit_deg`` the camera first orbits the primary by that angle (the views after a rotation).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np
from tqdm import tqdm

from branch_gym.segmenter_training.config import EVAL_SEED_OFFSET
from branch_gym.segmenter_training.generate import branch_mask, preset_tree_config
from branch_gym.segmenter_training.orchard_pairs import orbit_camera
from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.scene.labels import (
    FIRST_SECONDARY_LABEL,
    PART_NAMES,
    details_label,
    label_parts,
)
from branch_gym.sim.world import World, WorldConfig
from recon.segmentation.metrics import mask_iou, pooled_iou
from recon.segmentation.segmenter import LearnedSegmenter

logger = logging.getLogger(__name__)

# "In front of the tree" (our choice): past the tree's own depth spread, trunks 1-4 cm thick.
IN_FRONT_M = 0.03


@dataclass(frozen=True)
class EvaluateConfig:
    """Which frames are scored.

    Attributes:
        trees: Trees per preset (seeds ``EVAL_SEED_OFFSET + 0 .. trees - 1``).
        frames_per_tree: Scored frames per tree.
        frame_spacing_m: Camera climb between scored frames.
        previous_offset_m: Climb between the previous frame and the scored one (the modeler's
            10 mm iteration spacing, paper IV).
        speed_mps: Climb speed.
        world: ``"clean"`` or ``"orchard"`` (:meth:`WorldConfig.preset`).
        orbit_deg: Orbit the camera by this angle about the primary before climbing (the views
            after a rotation stage; 0: the home view, straight on).
    """

    trees: int = 20
    frames_per_tree: int = 6
    frame_spacing_m: float = 0.06
    previous_offset_m: float = 0.01
    speed_mps: float = 0.025
    world: str = "clean"
    orbit_deg: float = 0.0


def render_eval_frames(
    preset: str, seed: int, config: EvaluateConfig, camera: CameraSpec | None = None
):
    """Yield (previous_rgb, rgb, labels, details_label, depth_m) along a straight-up scan of
    tree ``seed``.

    ``details_label`` is the label of the tree's spurs, stubs and buds
    (:func:`branch_gym.sim.scene.labels.details_label`); ``depth_m`` the (H, W) z-depth of
    the frame (inf for the sky). ``camera`` replaces the world's camera (e.g.
    ``CameraSpec.scaled``: the same views at another resolution).
    """
    world_config = WorldConfig.preset(config.world, preset_tree_config(preset))
    if camera is not None:
        world_config = replace(world_config, camera=camera)
    world = World(world_config)
    try:
        world.reset(seed)
        details = details_label(len(world.tree.secondaries))
        distance_m = world.config.z_target_m
        if config.orbit_deg and not orbit_camera(
            world, config.orbit_deg, config.speed_mps, distance_m
        ):
            return
        up = np.array([0.0, -config.speed_mps, 0.0, 0.0, 0.0, 0.0])
        for _ in range(config.frames_per_tree):
            previous = world.render()
            if not world.apply_camera_twist(up, config.previous_offset_m / config.speed_mps).ok:
                return
            current = world.render()
            yield previous.rgb, current.rgb, current.labels, details, current.depth_m
            gap = config.frame_spacing_m - config.previous_offset_m
            if not world.apply_camera_twist(up, gap / config.speed_mps).ok:
                return
    finally:
        world.close()


def evaluate_segmenters(
    variants: dict[str, tuple[LearnedSegmenter, bool]],
    preset: str,
    config: EvaluateConfig | None = None,
    progress: bool = True,
) -> dict[str, dict[str, float]]:
    """IoU of several segmenters (or input modes) on the same frames of unseen trees.

    Args:
        variants: name -> (segmenter, use_previous); use_previous False: RGB only.
        preset: A tree preset (:data:`~branch_gym.segmenter_training.generate.EVAL_PRESETS`).
        config: Trees and frames.
        progress: Show a tqdm bar.

    Returns:
        name -> {``iou`` (pooled over all frames: total intersection / total union),
        ``iou_frame_mean``, ``iou_frame_p10`` (10th percentile over frames),
        ``side_branch_recall`` (share of the side branches' pixels, spurs and buds included, in
        the mask, pooled), ``iou_ignoring_details`` (pooled IoU with the tree's spurs, stubs and
        buds left out of the score, neither to be found nor wrong: the target of real hand
        masks), ``side_branch_recall_without_details`` (the same recall of the side branches
        alone), ``frames``, ``segment_ms_mean``}.
    """
    config = config or EvaluateConfig()
    counts = {name: [0, 0] for name in variants}
    scored_counts = {name: [0, 0] for name in variants}  # details left out
    side_counts = {name: [0, 0] for name in variants}  # side-branch pixels found, all
    scored_side_counts = {name: [0, 0] for name in variants}  # the same, details left out
    per_frame: dict[str, list[float]] = {name: [] for name in variants}
    n_parts = len(PART_NAMES)
    wrong_parts = {name: np.zeros(n_parts, np.int64) for name in variants}
    missed_parts = {name: np.zeros(n_parts, np.int64) for name in variants}
    wrong_in_front = dict.fromkeys(variants, 0)
    times: dict[str, list[float]] = {name: [] for name in variants}
    seeds = range(EVAL_SEED_OFFSET, EVAL_SEED_OFFSET + config.trees)
    for seed in tqdm(seeds, desc=f"eval {preset}", unit="tree", disable=not progress):
        for previous, rgb, labels, details, depth_m in render_eval_frames(preset, seed, config):
            truth = branch_mask(labels)
            side = truth & (labels >= FIRST_SECONDARY_LABEL)
            scored = labels != details
            parts = label_parts(labels, details - FIRST_SECONDARY_LABEL)
            in_front = _in_front(depth_m, truth)
            for name, (segmenter, use_previous) in variants.items():
                t0 = time.perf_counter()
                mask = segmenter.segment(rgb, previous if use_previous else None)
                times[name].append(time.perf_counter() - t0)
                counts[name][0] += int(np.count_nonzero(mask & truth))
                counts[name][1] += int(np.count_nonzero(mask | truth))
                scored_counts[name][0] += int(np.count_nonzero(mask & truth & scored))
                scored_counts[name][1] += int(np.count_nonzero((mask | truth) & scored))
                per_frame[name].append(mask_iou(mask, truth))
                wrong_parts[name] += np.bincount(parts[mask & ~truth], minlength=n_parts)
                missed_parts[name] += np.bincount(parts[truth & ~mask], minlength=n_parts)
                wrong_in_front[name] += int(np.count_nonzero(mask & ~truth & in_front))
                side_counts[name][0] += int(np.count_nonzero(mask & side))
                side_counts[name][1] += int(np.count_nonzero(side))
                scored_side_counts[name][0] += int(np.count_nonzero(mask & side & scored))
                scored_side_counts[name][1] += int(np.count_nonzero(side & scored))
    return {
        name: {
            "iou": pooled_iou(*counts[name]),
            "iou_frame_mean": float(np.mean(per_frame[name])),
            "iou_frame_p10": float(np.percentile(per_frame[name], 10)),
            "side_branch_recall": side_counts[name][0] / max(side_counts[name][1], 1),
            "iou_ignoring_details": pooled_iou(*scored_counts[name]),
            "side_branch_recall_without_details": scored_side_counts[name][0]
            / max(scored_side_counts[name][1], 1),
            "false_positive_parts": _shares(wrong_parts[name]),
            "missed_parts": _shares(missed_parts[name]),
            "false_positive_in_front": wrong_in_front[name] / max(int(wrong_parts[name].sum()), 1),
            "frames": len(per_frame[name]),
            "segment_ms_mean": 1000 * float(np.mean(times[name])),
        }
        for name in variants
    }


def _in_front(depth_m: np.ndarray, tree: np.ndarray) -> np.ndarray:
    """(H, W) bool: nearer than the tree's median depth by ``IN_FRONT_M`` (none without tree)."""
    if not tree.any():
        return np.zeros_like(tree)
    return depth_m < float(np.median(depth_m[tree])) - IN_FRONT_M


def _shares(counts: np.ndarray) -> dict[str, float]:
    """{part: share of the total} for the parts counted at least once, largest first."""
    total = int(counts.sum())
    order = np.argsort(-counts, kind="stable")
    return {PART_NAMES[k]: int(counts[k]) / total for k in order if counts[k] > 0}


def evaluate_segmenter(
    segmenter: LearnedSegmenter,
    preset: str,
    config: EvaluateConfig | None = None,
    use_previous: bool = True,
    progress: bool = True,
) -> dict[str, float]:
    """IoU of one segmenter on unseen trees of ``preset`` (see :func:`evaluate_segmenters`)."""
    variants = {"segmenter": (segmenter, use_previous)}
    return evaluate_segmenters(variants, preset, config, progress)["segmenter"]
