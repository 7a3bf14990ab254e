"""The 3D modeler (paper section IV): a stream of frames in, a tree model out.

Feed every frame to :meth:`Modeler.update`. The modeler stores a tracking frame every ~1 mm of
camera motion and runs one iteration every 10 mm:

1. fit 2D curves to the newest mask (:mod:`recon.curve2d.fit`);
2. check the 3D primary against them: Consistent, Inconsistent (skip the frame) or, on the 3rd
   Inconsistent in a row, Restart (delete the model seen in the last three frames);
3. lift the 2D samples to 3D (:mod:`recon.model3d.lifting`) and refit the visible primary
   (RANSAC cubic Bezier, :mod:`recon.model3d.primary`);
4. lift the secondary candidates, keep those connected to the primary, merge re-detections and
   prune branches the masks stop supporting (:mod:`recon.model3d.secondary`).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple

import numpy as np

from recon.camera import project_points
from recon.config import ModelerConfig
from recon.curve2d.fit import fit_mask_curves
from recon.curve2d.primary import PrimaryPrior
from recon.curve2d.types import Curve2DConfig, MaskCurves
from recon.frame import Frame
from recon.model import TreeModel
from recon.model3d.lifting import lift_pixels
from recon.model3d.primary import ProjectedModel, fit_visible_segment, project_model, splice
from recon.model3d.secondary import SecondaryBranches, SecondaryDetection
from recon.timing import stage_timer
from recon.tracking import PointTracker

logger = logging.getLogger(__name__)


class Outcome(str, Enum):
    """Result of one modeling iteration (paper IV)."""

    CONSISTENT = "consistent"
    INCONSISTENT = "inconsistent"
    RESTART = "restart"


@dataclass
class IterationReport:
    """What one iteration did and how long each stage took.

    Attributes:
        index: Iteration counter since the last reset.
        outcome: Consistent / Inconsistent / Restart.
        reason: Why (e.g. "no primary in mask", "model disagrees with mask", "initialised").
        consistency_fraction: Fraction of visible model points that agreed (NaN before a model).
        n_lifted: Primary points that survived lifting.
        n_secondary_detections: Secondary candidates lifted in 3D this iteration.
        n_new_secondaries: Model secondaries created this iteration.
        n_secondaries: Model secondaries after the iteration.
        mask_curves: The 2D curves of the newest mask (for observations and overlays).
        search_truncated: The 2D path search hit its cap.
        points_in_front: (K, 3) lifted primary points (world, m) the depth gate dropped for lying
            in front of the model: evidence of something between the camera and the primary,
            e.g. a side branch pointing at the camera (:class:`DepthGate`).
        timings_ms: Stage name -> milliseconds (curve2d, consistency, tracking, triangulation,
            fit3d, secondaries, total).
    """

    index: int
    outcome: Outcome
    reason: str
    consistency_fraction: float = float("nan")
    n_lifted: int = 0
    n_secondary_detections: int = 0
    n_new_secondaries: int = 0
    n_secondaries: int = 0
    mask_curves: MaskCurves | None = None
    search_truncated: bool = False
    points_in_front: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    timings_ms: dict[str, float] = field(default_factory=dict)


class Modeler:
    """Incremental tree reconstruction from frames (RGB, mask, pose, intrinsics).

    Args:
        tracker: Point tracker that lifts pixels (e.g. :class:`recon.tracking.LucasKanadeTracker`).
        config: Modeler thresholds (paper defaults).
        curve_config: 2D curve-fitting parameters (paper defaults).
        seed: Seed of the modeler's own random generator (RANSAC).
    """

    def __init__(
        self,
        tracker: PointTracker,
        config: ModelerConfig | None = None,
        curve_config: Curve2DConfig | None = None,
        seed: int | None = 0,
    ) -> None:
        self.tracker = tracker
        self.config = config or ModelerConfig()
        self.curve_config = curve_config or Curve2DConfig()
        self.reset(seed)

    def reset(self, seed: int | None = 0) -> None:
        """Forget the model and the stored frames."""
        self.rng = np.random.default_rng(seed)
        self._window: deque[Frame] = deque(maxlen=self.config.tracking_frames)
        self._recent_inconsistent: deque[Frame] = deque(
            maxlen=self.config.restart_after_inconsistent
        )
        self._last_iteration_position: np.ndarray | None = None
        self._inconsistent_streak = 0
        self._iterations = 0
        self._primary = None
        self.hold_primary = False
        self._secondaries = SecondaryBranches(self.config, self.rng)

    @property
    def model(self) -> TreeModel:
        """The current tree model (copies are cheap; arrays are shared)."""
        return TreeModel(self._primary, self._secondaries.models())

    # hold_primary: while True (the robot orbits the branch, so the view turns while the branch
    # stays), a mask that disagrees with the model is Inconsistent and never restarts it.

    @property
    def inconsistent_streak(self) -> int:
        """Inconsistent iterations in a row."""
        return self._inconsistent_streak

    # ---------------------------------------------------------------- frame scheduling
    def wants_frame(self, T_world_camera: np.ndarray) -> bool:
        """Whether a frame at this pose would be stored (lets a simulator skip renders)."""
        position = np.asarray(T_world_camera, float)[:3, 3]
        if not self._window:
            return True
        moved = np.linalg.norm(position - self._window[-1].T_world_camera[:3, 3])
        if moved < self.config.tracking_spacing_m * (1 - 1e-6):
            return False
        if self._last_iteration_position is None:
            return True
        since = np.linalg.norm(position - self._last_iteration_position)
        window_m = (self.config.tracking_frames - 1) * self.config.tracking_spacing_m
        return since >= self.config.iteration_spacing_m - window_m - self.config.tracking_spacing_m

    def iteration_due(self, T_world_camera: np.ndarray) -> bool:
        """Whether a frame at this pose would run an iteration (the others only fill the window).

        A simulator with a depth oracle tracker renders only these frames and hands the modeler
        :meth:`recon.frame.Frame.pose_only` frames in between.
        """
        if not self.wants_frame(T_world_camera):
            return False
        if len(self._window) + 1 < self.config.tracking_frames:
            return False
        if self._last_iteration_position is None:
            return True
        position = np.asarray(T_world_camera, float)[:3, 3]
        since = np.linalg.norm(position - self._last_iteration_position)
        return bool(since >= self.config.iteration_spacing_m * (1 - 1e-6))

    def update(self, frame: Frame) -> IterationReport | None:
        """Store ``frame`` if the camera moved enough and run an iteration when one is due.

        Returns:
            The iteration's report, or None when no iteration ran.
        """
        position = frame.T_world_camera[:3, 3]
        if self._window:
            moved = np.linalg.norm(position - self._window[-1].T_world_camera[:3, 3])
            if moved < self.config.tracking_spacing_m * (1 - 1e-6):
                return None
        self._window.append(frame)
        if len(self._window) < self.config.tracking_frames:
            return None
        if self._last_iteration_position is not None:
            since = np.linalg.norm(position - self._last_iteration_position)
            if since < self.config.iteration_spacing_m * (1 - 1e-6):
                return None
        return self.run_iteration(list(self._window))

    # ---------------------------------------------------------------- one iteration
    def run_iteration(self, frames: list[Frame]) -> IterationReport:
        """One modeling iteration on a tracking window (oldest first; the newest is current)."""
        if len(frames) < 2:
            raise ValueError(
                f"an iteration needs at least 2 frames to triangulate, got {len(frames)}"
            )
        timings: dict[str, float] = {}
        with stage_timer(timings, "total_ms"):
            return self._iterate(frames, timings)

    def _iterate(self, frames: list[Frame], timings: dict[str, float]) -> IterationReport:
        """The body of :meth:`run_iteration`; stage times go into ``timings`` (the report's)."""
        cfg = self.config
        frame = frames[-1]
        self._iterations += 1

        with stage_timer(timings, "curve2d_ms"):
            curves = fit_mask_curves(frame.mask, self.curve_config, prior=self._prior(frame))
        report = IterationReport(
            self._iterations,
            Outcome.CONSISTENT,
            "",
            mask_curves=curves,
            search_truncated=curves.search_truncated,
            timings_ms=timings,
        )
        if curves.primary is None:
            return self._inconsistent(report, frame, "no primary branch in the mask")

        # Consistency of the existing model with this mask.
        restart = skip = False
        projected = None
        with stage_timer(timings, "consistency_ms"):
            if self._primary is not None:
                projected = project_model(self._primary.points, frame, curves.primary.curve, cfg)
                report.consistency_fraction = projected.consistent_fraction
                if (
                    projected.visible.any()
                    and report.consistency_fraction < cfg.consistency_min_fraction
                ):
                    skip = (
                        self.hold_primary
                        or self._inconsistent_streak + 1 < cfg.restart_after_inconsistent
                    )
                    restart = not skip
        if skip:
            return self._inconsistent(report, frame, "model disagrees with mask")

        # Lift the primary samples and refit the visible part.
        liftable = curves.primary.liftable  # not on a bridged gap of the mask
        lifted = lift_pixels(
            frames,
            curves.primary.samples_px[liftable],
            curves.primary.radii_px[liftable],
            self.tracker,
            cfg,
        )
        timings.update(lifted.timings_ms)
        with stage_timer(timings, "fit3d_ms"):
            replace = np.zeros(0, dtype=bool)
            fit_points, fit_radii = lifted.centers, lifted.radii_m
            if projected is not None and not restart:
                gate = _depth_agrees(
                    lifted.centers,
                    curves.primary.samples_px[liftable][lifted.index],
                    projected,
                    frame,
                    cfg,
                )
                fit_points, fit_radii = fit_points[gate.keep], fit_radii[gate.keep]
                report.points_in_front = lifted.centers[gate.in_front]
            report.n_lifted = len(fit_points)
            if self._primary is not None:
                replace = projected.visible.copy()
                if restart:
                    for old in self._recent_inconsistent:
                        old_proj = project_model(
                            self._primary.points, old, curves.primary.curve, cfg
                        )
                        replace |= old_proj.visible
                else:
                    agree = projected.visible & projected.near_curve
                    fit_points = np.concatenate([self._primary.points[agree], fit_points])
                    fit_radii = np.concatenate([self._primary.radii[agree], fit_radii])
            up_world = -frame.T_world_camera[:3, 1]
            order = np.argsort(fit_points @ up_world)
            segment = fit_visible_segment(fit_points[order], fit_radii[order], frame, cfg, self.rng)
        if segment is None:
            reason = (
                "too few lifted points"
                if len(fit_points) < cfg.min_lifted_points
                else ("3D fit has too few inliers")
            )
            return self._inconsistent(report, frame, reason)
        self._primary = splice(self._primary, replace, segment[0], segment[1], up_world)
        if restart:
            report.outcome = Outcome.RESTART
            report.reason = "third inconsistent mask in a row: model re-initialised"
        else:
            report.reason = "initialised" if projected is None else "model agrees with mask"
        # Paper IV: the next iteration comes 10 mm after the last *successful* one.
        self._last_iteration_position = frame.T_world_camera[:3, 3].copy()
        self._inconsistent_streak = 0
        self._recent_inconsistent.clear()

        # Secondary branches.
        with stage_timer(timings, "secondaries_ms"):
            detections = self._lift_secondaries(frames, curves)
            report.n_secondary_detections = len(detections)
            report.n_new_secondaries = self._secondaries.add_detections(
                detections, self._primary, frame
            )
            self._secondaries.update_trust(frame)
            report.n_secondaries = len(self._secondaries.models())
        return report

    def _prior(self, frame: Frame) -> PrimaryPrior | None:
        """The model's visible primary projected into ``frame`` (guides the 2D primary choice)."""
        if self._primary is None:
            return None
        cfg = self.config
        pixels, depth = project_points(self._primary.points, frame.T_world_camera, frame.intrinsics)
        visible = (depth > 0) & frame.intrinsics.in_image(pixels, cfg.image_margin_px)
        if visible.sum() < 2:
            return None
        return PrimaryPrior(
            pixels[visible],
            cfg.consistency_tolerance_px,
            cfg.consistency_min_fraction,
            math.inf if cfg.primary_max_turn_deg is None else cfg.primary_max_turn_deg,
            cfg.primary_model_vouches,
        )

    def _lift_secondaries(
        self, frames: list[Frame], curves: MaskCurves
    ) -> list[SecondaryDetection]:
        """Lift all 2D secondary candidates in one tracking call."""
        queries, radii, owner = [], [], []
        for k, sec in enumerate(curves.secondaries):
            outside = sec.liftable
            queries.append(sec.samples_px[outside])
            radii.append(sec.radii_px[outside])
            owner.append(np.full(int(outside.sum()), k))
        if not queries or sum(len(q) for q in queries) == 0:
            return []
        lifted = lift_pixels(
            frames, np.concatenate(queries), np.concatenate(radii), self.tracker, self.config
        )
        owner_all = np.concatenate(owner)[lifted.index]
        pixels_all = np.concatenate(queries)[lifted.index]
        focal_px = frames[-1].intrinsics.fx
        detections = []
        for k in range(len(curves.secondaries)):
            sel = np.flatnonzero(owner_all == k)
            n = _plausible_prefix(
                lifted.centers[sel],
                pixels_all[sel],
                lifted.depth_m[sel],
                focal_px,
                self.config.secondary_max_foreshortening,
            )
            if n >= self.config.secondary_min_points:
                keep = sel[:n]
                junction_px = curves.secondaries[k].samples_px[0].copy()
                detections.append(
                    SecondaryDetection(lifted.centers[keep], lifted.radii_m[keep], junction_px)
                )
        return detections

    def _inconsistent(self, report: IterationReport, frame: Frame, reason: str) -> IterationReport:
        self._inconsistent_streak += 1
        self._recent_inconsistent.append(frame)
        report.outcome = Outcome.INCONSISTENT
        report.reason = reason
        report.n_secondaries = len(self._secondaries.models())
        return report


class DepthGate(NamedTuple):
    """What the primary's depth gate made of the lifted points (:func:`_depth_agrees`).

    Attributes:
        keep: (K,) True for the points the fit may use.
        in_front: (K,) True for the points dropped for lying in front of a trusted model (nearer
            the camera than ``primary_front_depth_gate_m``): something between the camera and the
            primary, e.g. a side branch pointing at the camera.
    """

    keep: np.ndarray
    in_front: np.ndarray


def _depth_agrees(
    centers: np.ndarray,
    pixels: np.ndarray,
    projected: ProjectedModel,
    frame: Frame,
    config: ModelerConfig,
) -> DepthGate:
    """Which lifted primary points agree in depth with the model there (see :class:`DepthGate`).

    Where the model's primary agrees with the mask, a lifted point farther than
    ``primary_depth_gate_m`` in camera depth from the model point nearest to it in the image
    (within ``primary_spacing_px``) lies on something else: a side branch pointing at the camera
    covers the trunk in the mask, and its surface, lifted, dragged the primary up to 14 cm off
    (measured, seed 1017). Points in front of the model (nearer the camera) are held to the
    tighter ``primary_front_depth_gate_m`` unless most of them are (then the model is off, and
    none counts as in front). Points with no model point near them are kept (new parts of the
    view).
    """
    keep = np.ones(len(centers), dtype=bool)
    in_front = np.zeros(len(centers), dtype=bool)
    model = projected.near_curve
    if config.primary_depth_gate_m <= 0 or not model.any() or len(centers) == 0:
        return DepthGate(keep, in_front)
    model_px, model_depth = projected.pixels[model], projected.depth_m[model]
    axis = frame.T_world_camera[:3, 2]
    depth = (centers - frame.T_world_camera[:3, 3]) @ axis
    d2 = np.linalg.norm(pixels[:, None, :] - model_px[None, :, :], axis=2)
    nearest = np.argmin(d2, axis=1)
    covered = d2[np.arange(len(centers)), nearest] <= config.primary_spacing_px
    offset = depth - model_depth[nearest]  # < 0: in front of the model
    front_gate_m = _front_gate_m(config)
    model_off = covered.any() and np.mean(-offset[covered] > front_gate_m) > 0.5
    if model_off:
        # Most new points lie in front of the model: the model is off (a rotation shows it from
        # a new side), not covered by a branch, which hides a part of the primary only.
        front_gate_m = config.primary_depth_gate_m
    else:
        in_front = covered & (-offset > front_gate_m)
    off = (offset > config.primary_depth_gate_m) | (-offset > front_gate_m)
    keep = ~(covered & off)
    anchored = np.flatnonzero(covered & keep)
    if len(anchored) == 0:
        return DepthGate(keep, in_front)
    # Beyond the model (the samples are in curve order), a new point must continue the last
    # accepted one in depth: the branch is cut at the first jump onto an occluder.
    for first, step in ((int(anchored[-1]), 1), (int(anchored[0]), -1)):
        beyond = np.arange(first + step, len(centers) if step > 0 else -1, step)
        beyond = beyond[~covered[beyond]]
        last = depth[first]
        for k, i in enumerate(beyond):
            change = depth[i] - last
            if change > config.primary_depth_gate_m or -change > front_gate_m:
                keep[beyond[k:]] = False
                break
            last = depth[i]
    return DepthGate(keep, in_front)


def _front_gate_m(config: ModelerConfig) -> float:
    """The depth gate for points in front of the model (``primary_front_depth_gate_m``, where
    set, else ``primary_depth_gate_m``)."""
    front = config.primary_front_depth_gate_m
    return front if front > 0 else config.primary_depth_gate_m


def _plausible_prefix(
    centers: np.ndarray,
    pixels: np.ndarray,
    depth_m: np.ndarray,
    focal_px: float,
    max_foreshortening: float,
) -> int:
    """How many leading points of a lifted branch (ordered from the junction) are plausible.

    A 3D step between consecutive samples cannot be much longer than its 2D step seen at that
    depth, unless the branch recedes almost along the viewing ray, where depth is ill-conditioned:
    the branch is cut before the first step longer than ``max_foreshortening`` times its image
    length (a receding tip lifted onto a far depth would otherwise stretch the branch).
    """
    if len(centers) < 2:
        return len(centers)
    step_3d = np.linalg.norm(np.diff(centers, axis=0), axis=1)
    step_2d = np.linalg.norm(np.diff(pixels, axis=0), axis=1)
    depth = 0.5 * (depth_m[:-1] + depth_m[1:])
    bad = np.flatnonzero(step_3d > max_foreshortening * step_2d * depth / focal_px)
    return int(bad[0]) + 1 if len(bad) else len(centers)
