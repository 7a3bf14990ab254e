"""Reconstruction cost on one core: one modeler iteration on 320x240 frames, rendering excluded.

Frames of straight-up scans (0.275 -> 0.75 m at 2.5 cm/s, no rotation) of a few paper-default
trees are rendered first, with the ground-truth segmenter, exactly as a scan would feed them to a
:class:`recon.modeler.Modeler` (a recording modeler decides which frames are needed). The recorded
frames are then replayed into a fresh modeler with a fresh Lucas-Kanade tracker, and the figures
are the medians of the iteration reports' own stage timings (``IterationReport.timings_ms``):

* ``recon_iteration_ms``: whole iteration (``total_ms``). Target: <= 15 ms on one core.
* ``recon_curve2d_ms``, ``recon_consistency_ms``, ``recon_tracking_ms``,
  ``recon_triangulation_ms``, ``recon_fit3d_ms``, ``recon_secondaries_ms``: one per stage, the
  median over the iterations that ran the stage (an Inconsistent iteration stops early).
"""

from __future__ import annotations

import cv2
import numpy as np

from branch_gym.sim.robot.home import SCAN_END_HEIGHT_M
from branch_gym.sim.segmentation import GroundTruthSegmenter
from branch_gym.sim.world import World
from recon.camera import CameraIntrinsics
from recon.frame import Frame
from recon.modeler import IterationReport, Modeler
from recon.tracking import LucasKanadeTracker

SEEDS = (0, 1, 2, 3)  # fixed paper-default trees
SCAN_SPEED_MPS = 0.025  # reference.md "Scan": sim speed 2.5 cm/s
SEGMENTER_SEED = 0  # the ground-truth segmenter draws nothing, but the protocol takes an rng
STAGES = ("curve2d", "consistency", "tracking", "triangulation", "fit3d", "secondaries")
TOTAL_KEY = "total_ms"


def record_scan(world: World, seed: int) -> list[Frame]:
    """Frames of a straight-up scan of the tree of ``seed``, as a modeler takes them.

    Args:
        world: The world (reset here).
        seed: Tree seed.

    Returns:
        The frames in scan order (RGB, ground-truth mask, pose, intrinsics, depth).
    """
    world.reset(seed)
    spec = world.config.camera
    intrinsics = CameraIntrinsics(spec.width, spec.height, spec.fx, spec.fy, spec.cx, spec.cy)
    segmenter, rng = GroundTruthSegmenter(), np.random.default_rng(SEGMENTER_SEED)
    recorder = Modeler(LucasKanadeTracker())  # only decides which frames a scan renders
    up_twist = np.array([0.0, -SCAN_SPEED_MPS, 0.0, 0.0, 0.0, 0.0])  # image up = camera -y
    step_s = world.config.robot.control_time_step_s
    frames = []
    while world.T_world_camera[2, 3] < SCAN_END_HEIGHT_M:
        T = world.T_world_camera
        if recorder.wants_frame(T):
            images = world.render()
            mask = segmenter.segment(images.rgb, images.labels, rng)
            frame = Frame(images.rgb, mask, T, intrinsics, depth_m=images.depth_m)
            recorder.update(frame)
            frames.append(frame)
        if not world.apply_camera_twist(up_twist, step_s).ok:
            break
    return frames


def replay(frames: list[Frame]) -> list[IterationReport]:
    """Feed recorded frames to a fresh modeler (fresh LK tracker); its iteration reports."""
    modeler = Modeler(LucasKanadeTracker())
    reports = [modeler.update(frame) for frame in frames]
    return [report for report in reports if report is not None]


def summarise(reports: list[IterationReport]) -> dict[str, float]:
    """Median milliseconds of the whole iteration and of each stage (module docstring keys)."""
    figures = {"recon_iteration_ms": float(np.median([r.timings_ms[TOTAL_KEY] for r in reports]))}
    for stage in STAGES:
        key = f"{stage}_ms"
        values = [r.timings_ms[key] for r in reports if key in r.timings_ms]
        figures[f"recon_{key}"] = float(np.median(values)) if values else float("nan")
    return figures


def run() -> dict[str, float]:
    """Reconstruction benchmark figures (module docstring), medians in milliseconds, one core."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core, as the target (OpenCV ignores OMP_NUM_THREADS)
    world = World()
    try:
        recordings = [record_scan(world, seed) for seed in SEEDS]
    finally:
        world.close()
    try:
        replay(recordings[0])  # warm-up: lazy imports, first-call caches; not timed
        reports = [report for frames in recordings for report in replay(frames)]
    finally:
        cv2.setNumThreads(threads)
    if not reports:
        raise RuntimeError("the recorded scans produced no modeler iteration")
    return summarise(reports)
