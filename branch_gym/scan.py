"""The one scan loop: world, sensing, the modeler (recon) and the follow controller, together.

:class:`ScanSession` is what the Gymnasium environment drives (and through it ``eval.py``,
training and the demo). One :meth:`ScanSession.step` takes a target rotation angle, rotates the
camera about the branch if the angle changed (:class:`branch_gym.control.OrbitMove`: rotating is
motion at the set speed and costs scan time), then follows the primary branch until the modeler
has run its next iteration. Frames come from :class:`branch_gym.sensing.Sensor`; scoring against
the ground truth is :func:`branch_gym.scoring.score_scan`.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from branch_gym.control import (
    ROTATION_TOLERANCE_DEG,
    FollowControllerConfig,
    OrbitMove,
    PrimaryBranchController,
)
from branch_gym.sensing import Sensor, check_segmenter_spec
from branch_gym.sim.robot.home import (
    LEADER_SCAN_END_HEIGHT_M,
    LEADER_SCAN_START_HEIGHT_M,
    BasePlacement,
)
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.ground_truth import TreeGT
from branch_gym.sim.validation import require_positive
from branch_gym.sim.world import World, WorldConfig
from recon.config import ModelerConfig
from recon.curve2d.types import Curve2DConfig
from recon.frame import Frame
from recon.model import TreeModel
from recon.modeler import IterationReport, Modeler, Outcome
from recon.segmentation.flow import FramePairingConfig
from recon.segmentation.spec import is_learned_segmenter
from recon.tracking import TRACKERS, make_tracker

logger = logging.getLogger(__name__)

# A control period within this fraction of a whole number of robot sub-steps is that number.
_STEP_ROUNDING = 1e-9
# The scored band starts this far above the scan's start: the authors' analysis scores
# 0.325 < z < 0.75 m of a scan from 0.275 m (reference.md, "Evaluation").
SCORED_BAND_START_OFFSET_M = 0.05
# A coarser control period (s) measured against the default: the twist held over 3 robot
# sub-steps of 1/60 s. It moved the camera path by up to 2.1 mm (ScanConfig.control_dt_s).
TRAINING_CONTROL_DT_S = 1.0 / 20.0


@dataclass(frozen=True)
class ScanConfig:
    """One scan's settings.

    Attributes:
        speed_mps: Camera speed while following and rotating (reference.md: 2.5 cm/s in sim).
        end_height_m: The scan ends when the camera reaches this height (paper V-A: 0.75 m).
        control_dt_s: Control period (s): how often the follow controller (and the orbit) sets
            a new twist. The robot integrates in sub-steps of its own
            (``RobotConfig.control_time_step_s``, 1/60 s) and the modeler is offered a frame
            after every sub-step, so a longer period holds the twist over several sub-steps
            without moving where frames are taken. Default 1/60 s: one command per sub-step, as
            the authors' controller. Measured with 1/20 s (:data:`TRAINING_CONTROL_DT_S`):
            camera paths 0.8-2.1 mm apart and one matched branch changed in 2 trees, beyond the
            0.1 mm tolerance, so no preset uses it.
        tracker: "lk" (Lucas-Kanade on the rendered images, the default) or "oracle" (exact
            tracks from the renderer's depth, for ablations and fast training).
        segmenter: "gt", "noisy:mild" | "noisy:moderate" | "noisy:severe", or "learned" |
            "learned:PATH" (from RGB; :mod:`branch_gym.sensing`).
        lost_branch_iterations: Non-consistent iterations in a row that end the scan as
            "lost_branch" (our choice: ~2 cm of travel without a usable mask).
        orbit_holds_model: Whether a rotation holds the model: its iterations neither restart
            the primary (:attr:`recon.modeler.Modeler.hold_primary`) nor count toward
            ``lost_branch_iterations``. Default True (ours): an orbit keeps the camera at one
            height, so an occluder crossing the branch (a wire, a neighbour's branch) stays in
            view for the whole orbit; its iterations (one per ~1 cm of arc) restarted the model
            on the occluder or ended the scan where following would have risen past it
            (orchard-v1's test split: 14 of 303 rotating scans lost, none of 101 without
            rotation; docs/results/history.md). False is the rule paper-v1 was published with.
        max_scan_time_s: Simulated time limit ("timeout"); our choice: 5x a straight scan.
        rotation_tolerance_deg: Target angles closer than this to the current one are no move.
        render_tracking_frames: Render every frame of the tracking window (default). False
            renders only the frames a modeling iteration runs on and feeds pose-only frames in
            between: ~8x fewer renders, valid with the oracle tracker only (fast training).
        controller: Follow controller gains (speed is taken from ``speed_mps``).
        modeler: Reconstruction thresholds (:meth:`modeler_config` resolves the ones left to
            the mask source).
        curve2d: The modeler's 2D stage, the curves it fits to each mask
            (:class:`recon.curve2d.types.Curve2DConfig`: the paper's rules and ours, e.g.
            ``max_primary_turn_deg``, off by default). Its defaults hash as the scans before the
            field (``branch_gym.evaluation.trials.HASH_NEUTRAL_DEFAULTS``).
        world: The simulated world; a name ("clean", the default, or "orchard": sky, row,
            trellis, camera model; :meth:`WorldConfig.preset`) stands for that preset with
            the paper's tree.
        frame_pairing: Which earlier rendered frame a flow-picture segmenter
            (``segmenter="learned..."`` with weights that read the flow picture) takes the
            optical flow against: moved >= 7.5 mm and turned < 0.5 deg since (the authors'
            code; :class:`recon.segmentation.flow.FramePairingConfig`). Unused by the other
            segmenters.
    """

    speed_mps: float = 0.025
    end_height_m: float = 0.75
    control_dt_s: float = 1.0 / 60.0
    tracker: str = "lk"
    segmenter: str = "gt"
    lost_branch_iterations: int = 20
    orbit_holds_model: bool = True
    max_scan_time_s: float = 100.0
    rotation_tolerance_deg: float = ROTATION_TOLERANCE_DEG
    render_tracking_frames: bool = True
    controller: FollowControllerConfig = field(default_factory=FollowControllerConfig)
    modeler: ModelerConfig = field(default_factory=ModelerConfig)
    curve2d: Curve2DConfig = field(default_factory=Curve2DConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    frame_pairing: FramePairingConfig = field(default_factory=FramePairingConfig)

    def __post_init__(self) -> None:
        if isinstance(self.world, str):
            object.__setattr__(self, "world", WorldConfig.preset(self.world))
        if not isinstance(self.world, WorldConfig):
            raise ValueError(
                f"ScanConfig.world must be a WorldConfig or a world name, got {self.world!r}"
            )
        require_positive(
            self, "speed_mps", "control_dt_s", "max_scan_time_s", "rotation_tolerance_deg"
        )
        if not self.world.scan_start_height_m < self.end_height_m:
            raise ValueError(
                f"ScanConfig.end_height_m ({self.end_height_m}) must be above the start height "
                f"({self.world.scan_start_height_m})"
            )
        if self.tracker not in TRACKERS:
            raise ValueError(f"ScanConfig.tracker must be one of {TRACKERS}, got {self.tracker!r}")
        check_segmenter_spec(self.segmenter)  # a ValueError naming the valid segmenters
        if not self.render_tracking_frames and self.tracker != "oracle":
            raise ValueError(
                "ScanConfig.render_tracking_frames=False needs tracker='oracle': an image tracker "
                f"needs every frame rendered (tracker={self.tracker!r})"
            )
        if self.lost_branch_iterations < 1:
            raise ValueError("ScanConfig.lost_branch_iterations must be >= 1")
        if not isinstance(self.frame_pairing, FramePairingConfig):
            raise ValueError(
                f"ScanConfig.frame_pairing must be a FramePairingConfig, got {self.frame_pairing!r}"
            )
        if not isinstance(self.curve2d, Curve2DConfig):
            raise ValueError(f"ScanConfig.curve2d must be a Curve2DConfig, got {self.curve2d!r}")

    def modeler_config(self) -> ModelerConfig:
        """``modeler`` with the settings left to the mask source resolved for ``segmenter``."""
        return self.modeler.for_masks(learned=is_learned_segmenter(self.segmenter))

    def make_modeler(self) -> Modeler:
        """The modeler a scan of this config runs: its tracker, :meth:`modeler_config` and the
        2D stage's ``curve2d``."""
        return Modeler(make_tracker(self.tracker), self.modeler_config(), self.curve2d)

    def replace(self, **changes: object) -> ScanConfig:
        """A copy with some fields changed."""
        return replace(self, **changes)

    @property
    def metrics_band_m(self) -> tuple[float, float]:
        """(low, high) heights of the scored band (m): ``recon.metrics.MetricsConfig``'s
        ``band_min_z_m`` and ``band_max_z_m`` for this scan.

        The authors' analysis scores 0.325 < z < 0.75 m for a scan from 0.275 to 0.75 m
        (reference.md, "Evaluation"): from :data:`SCORED_BAND_START_OFFSET_M` above the scan's
        start height to its end height.
        """
        start_m = self.world.scan_start_height_m
        return (start_m + SCORED_BAND_START_OFFSET_M, self.end_height_m)


def leader_scan_config(config: ScanConfig | None = None) -> ScanConfig:
    """``config`` scanning a tall-spindle leader over 0.70 -> 1.50 m from a lifted arm.

    Sets the tree (``TreeConfig.tall_spindle_leader``), the scan's start and end heights
    (``LEADER_SCAN_START_HEIGHT_M``, ``LEADER_SCAN_END_HEIGHT_M``) and the robot's base
    (``BasePlacement.platform``); the world (clean or orchard) and everything else stay
    ``config``'s. Score it with :attr:`ScanConfig.metrics_band_m` (docs/worlds.md, "A longer
    stretch").
    """
    config = config or ScanConfig()
    world = config.world
    robot = replace(world.robot, base=BasePlacement.platform())
    world = replace(
        world,
        tree=TreeConfig.tall_spindle_leader(),
        robot=robot,
        scan_start_height_m=LEADER_SCAN_START_HEIGHT_M,
    )
    return config.replace(world=world, end_height_m=LEADER_SCAN_END_HEIGHT_M)


def reference_scan_config(config: ScanConfig | None = None) -> ScanConfig:
    """``config`` on the reference (slow) path: every contact check in full, an SVD every step.

    The fast path (the defaults) must reproduce it within the tolerances the equivalence tests
    state (``tests/test_speed_equivalence.py``).
    """
    config = config or ScanConfig()
    robot = replace(config.world.robot, contact_query_m=0.0, dls_direct_solve=False)
    return config.replace(world=replace(config.world, robot=robot))


def training_scan_config(config: ScanConfig | None = None, hold_twist: bool = False) -> ScanConfig:
    """The fast training mode of ``config``: the oracle tracker, renders only for iterations.

    Args:
        config: The settings to start from (the defaults if None).
        hold_twist: Also set a new twist only every :data:`TRAINING_CONTROL_DT_S` (frames are
            still taken on the 1/60 s grid; not within the 0.1 mm tolerance, see
            ``ScanConfig.control_dt_s``); False keeps ``config.control_dt_s``.
    """
    config = config or ScanConfig()
    changes: dict[str, object] = {"tracker": "oracle", "render_tracking_frames": False}
    if hold_twist:
        changes["control_dt_s"] = TRAINING_CONTROL_DT_S
    return config.replace(**changes)


@dataclass
class StepResult:
    """What one :meth:`ScanSession.step` did.

    Attributes:
        reports: Modeler iterations run during the step (rotation included), oldest first.
        done: The scan is over (end height or failure).
        rotated: A rotation move was performed.
    """

    reports: list[IterationReport]
    done: bool
    rotated: bool = False


class ScanSession:
    """A reusable scan: ``reset(seed)``, then ``step(angle)`` until ``done``, then ``result()``."""

    def __init__(self, config: ScanConfig | None = None) -> None:
        self.config = config or ScanConfig()
        self.world = World(self.config.world)
        self.sensor = Sensor(self.world, self.config.segmenter, self.config.frame_pairing)
        self.intrinsics = self.sensor.intrinsics
        self.modeler = self.config.make_modeler()
        controller_config = replace(self.config.controller, speed_mps=self.config.speed_mps)
        self.controller = PrimaryBranchController(controller_config, self.intrinsics)
        self.vertical_fov_m = self.intrinsics.vertical_fov_length_m(controller_config.z_target_m)
        self.tree: TreeGT | None = None
        self._primary = None
        self._substep_s = self.config.world.robot.control_time_step_s
        # The orbit's twist follows the pose along the circle: it is set every sub-step.
        self._orbit_dt_s = min(self.config.control_dt_s, self._substep_s)
        # Called with every frame handed to the modeler, pose-only ones included (recording).
        self.frame_listeners: list[Callable[[Frame], None]] = []

    # ------------------------------------------------------------------ lifecycle
    def reset(self, seed: int, tree: TreeGT | None = None) -> TreeGT:
        """Start a scan of the tree of ``seed`` from the home pose."""
        self.tree = self.world.reset(seed, tree)
        self.modeler.reset(seed)
        self._primary = self.modeler.model.primary
        self.sensor.reset(seed)
        self.scan_time_s = 0.0
        self.angle_deg = 0.0
        self.rotations = 0
        self.done = False
        self.failure: str | None = None
        self.stop_reason: str | None = None
        self.reports: list[IterationReport] = []
        self._non_consistent_streak = 0
        self._model_held = False
        self._rotation_end_height_m = self.world.T_world_camera[2, 3]
        self.wall_start_s = time.perf_counter()  # wall clock, for ScanResult.wall_time_s
        self._observe()
        return self.tree

    def close(self) -> None:
        self.world.close()

    # ------------------------------------------------------------------ state
    @property
    def camera_height_m(self) -> float:
        return float(self.world.T_world_camera[2, 3])

    @property
    def travel_since_rotation_m(self) -> float:
        """Vertical camera travel since the last rotation ended (or the scan started)."""
        return self.camera_height_m - self._rotation_end_height_m

    @property
    def progress(self) -> float:
        """Fraction of the scan height range covered, in [0, 1]."""
        start = self.config.world.scan_start_height_m
        span = self.config.end_height_m - start
        return float(np.clip((self.camera_height_m - start) / span, 0.0, 1.0))

    @property
    def model(self) -> TreeModel:
        return self.modeler.model

    # ------------------------------------------------------------------ stepping
    def step(self, target_angle_deg: float) -> StepResult:
        """Rotate to ``target_angle_deg`` if it differs, then follow until the next iteration."""
        if self.tree is None:
            raise RuntimeError("ScanSession.reset(seed) must be called before step()")
        if self.done:
            raise RuntimeError("the scan is over: call reset(seed) to start a new one")
        if not math.isfinite(target_angle_deg):
            raise ValueError(f"target_angle_deg must be finite, got {target_angle_deg}")
        start = len(self.reports)
        rotated = False
        if abs(target_angle_deg - self.angle_deg) > self.config.rotation_tolerance_deg:
            rotated = True
            self._rotate_to(target_angle_deg)
        n_before = len(self.reports)
        while not self.done and len(self.reports) == n_before:
            command = self.controller.command(self._primary, self.world.T_world_camera)
            self._move(command.twist_camera, self.config.control_dt_s)
        return StepResult(self.reports[start:], self.done, rotated)

    def _rotate_to(self, target_angle_deg: float) -> None:
        """Orbit the camera about the world-vertical axis through the followed branch point."""
        orbit = OrbitMove(
            self.controller,
            self._primary,
            self.world.T_world_camera,
            target_angle_deg - self.angle_deg,
            self.config.speed_mps,
        )
        self._model_held = self.modeler.hold_primary = self.config.orbit_holds_model
        while not self.done and not orbit.finished:
            twist, dt_s = orbit.command(self.world.T_world_camera, self._orbit_dt_s)
            if not self._move(twist, dt_s):
                break
            self.angle_deg += orbit.advance(self.world.T_world_camera)
        self._model_held = self.modeler.hold_primary = False
        self.rotations += 1
        self._rotation_end_height_m = self.camera_height_m

    def _move(self, twist_camera: np.ndarray, dt_s: float) -> bool:
        """Apply one control step, sub-step by sub-step: feed the modeler, check the stops."""
        n_steps = max(1, math.ceil(dt_s / self._substep_s - _STEP_ROUNDING))
        step_s = dt_s / n_steps
        for _ in range(n_steps):
            status = self.world.apply_camera_twist(twist_camera, step_s)
            if not status.ok:
                self._stop(status.reason)
                return False
            self.scan_time_s += step_s
            self._observe()
            if self.done:
                return False
            if self.camera_height_m >= self.config.end_height_m:
                self._stop("end_height")
            elif self.scan_time_s >= self.config.max_scan_time_s:
                self._stop("timeout")
            if self.done:
                return False
        return True

    def _observe(self) -> None:
        """Render and feed a frame when the modeler wants one.

        Only a frame that runs an iteration is segmented: the modeler reads no other frame's
        mask. A frame listener (a recording) gets every frame's mask.
        """
        T = self.world.T_world_camera
        if not self.modeler.wants_frame(T):
            return
        iteration = self.modeler.iteration_due(T)
        if not self.config.render_tracking_frames and not iteration:
            self._feed(self.sensor.pose_only(self.scan_time_s))
            return
        segment = iteration or bool(self.frame_listeners)
        report = self._feed(self.sensor.capture(self.scan_time_s, segment=segment))
        if report is None:
            return
        if not segment:  # iteration_due() and update() disagree: the mask read was empty
            raise RuntimeError("the modeler ran an iteration on a frame that was not segmented")
        self.reports.append(report)
        self._primary = self.modeler.model.primary  # the model changes only in an iteration
        if report.outcome is Outcome.CONSISTENT:
            self._non_consistent_streak = 0
        elif not self._model_held:
            self._non_consistent_streak += 1
            if self._non_consistent_streak >= self.config.lost_branch_iterations:
                self._stop("lost_branch")

    def _feed(self, frame: Frame) -> IterationReport | None:
        for listener in self.frame_listeners:
            listener(frame)
        return self.modeler.update(frame)

    def _stop(self, reason: str) -> None:
        self.done = True
        self.stop_reason = reason
        self.failure = None if reason == "end_height" else reason
        logger.debug("scan stopped: %s at height %.3f m", reason, self.camera_height_m)
