"""The authors' rotation controller as their code runs it (OSUrobotics/follow-the-leader).

``controller_3d.py`` of the authors' repository (``update_pan_target``, ``get_rotation_target``)
differs from the paper's description, which :class:`agents.baselines.PeriodicAgent` follows, in
two ways:

- **Stage distance.** Counted from the first 3D model (``pan_reference``), a rotation stage starts
  every ``vertical FoV at z_target / (2 x pan_frequency)`` of vertical travel
  (``mode_switch_dist``), where the periodic agent waits ``FoV / frequency``. The authors'
  experiment script ran ``pan_frequency`` 1 and 2 for the table columns the paper labels 1.5 and
  2.5 (``shared/spec/reference.md``), so ``ftl:22.5:1`` is the controller behind the paper's 22.5
  deg / 1.5 column: a stage every 0.5 FoV, against 0.67 FoV for ``periodic:22.5:1.5``
  (``docs/results/paper_table.md``, "The authors' controller").
- **Branch-aware targets.** The stages cycle through the intervals ``[0, +theta]``,
  ``[-theta/2, +theta/2]``, ``[-theta, 0]``, ``[-theta/2, +theta/2]`` (default targets +theta, 0,
  -theta, 0). Side branches of the current 3D model with an end in the image whose orbit angle
  (the rotation at which the branch points straight at the lens) lies within ``[default -
  theta/2, default + theta]`` are *pointing at the camera*; with any such branch the stage
  targets the candidate (the interval's ends, the midpoints between consecutive such angles)
  farthest from every one of them.

One deviation: a midpoint outside the stage's interval is not a candidate (the authors' code
keeps it; their comment calls the interval "the range of angles the robot arm can assume", and
outside it a midpoint can exceed the env's 45 deg).

The agent reads the env's reconstructed model and camera pose (not the ground truth): a single,
unwrapped-able env. Spec (``agents.factory``): ``ftl:ANGLE_DEG:PAN_FREQUENCY``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.baselines import BaselineAgent, check_periodic, parse_angle_frequency_spec
from branch_gym.env.layout import THETA_MAX_DEG
from recon.camera import CameraIntrinsics, project_points
from recon.model import TreeModel

SPEC_KIND = "ftl"
# Stages of the authors' cycle (``rotation_stage``, advanced before each choice): the interval
# of each stage in units of theta, and its default target.
STAGE_INTERVALS = ((-0.5, 0.5), (0.0, 1.0), (-0.5, 0.5), (-1.0, 0.0))
STAGE_DEFAULTS = (0.0, 1.0, 0.0, -1.0)
# A branch points at the camera when its orbit angle lies in [default + LOW, default + HIGH]
# x theta (``get_rotation_target``: target - theta/2 <= angle <= target + theta).
POINTING_WINDOW = (-0.5, 1.0)
# Branches whose horizontal extent is below this (m) have no heading to avoid.
MIN_HORIZONTAL_M = 1e-6


@dataclass(frozen=True)
class FtlConfig:
    """The authors' controller parameters (``controller_3d.py`` ROS parameters).

    Attributes:
        angle_deg: ``pan_magnitude_deg``, theta (the paper's 22.5 and 45 deg; the node's
            default is 15).
        pan_frequency: A stage every vertical FoV at z_target / (2 x pan_frequency) of travel
            (node default 1.5; the paper's trials ran 1 and 2, labelled 1.5 and 2.5).
    """

    angle_deg: float = 22.5
    pan_frequency: float = 1.0

    def __post_init__(self) -> None:
        check_periodic(self.angle_deg, self.pan_frequency, THETA_MAX_DEG)

    @property
    def stage_distance_fov(self) -> float:
        """Vertical travel between two stages, in vertical FoVs at z_target."""
        return 1.0 / (2.0 * self.pan_frequency)


def parse_ftl_spec(spec: str) -> FtlConfig | None:
    """The config of an ``ftl:ANGLE:FREQ`` spec; None for another kind of spec.

    >>> parse_ftl_spec("ftl:22.5:1")
    FtlConfig(angle_deg=22.5, pan_frequency=1.0)
    >>> parse_ftl_spec("none") is None
    True

    Raises:
        ValueError: a malformed ``ftl`` spec or bad parameters (naming the valid form).
    """
    parsed = parse_angle_frequency_spec(spec, SPEC_KIND, "ftl:22.5:1")
    return None if parsed is None else FtlConfig(*parsed)


def stage_target_deg(stage: int, theta_deg: float, pointing_deg: np.ndarray) -> float:
    """The target of a rotation stage, away from the branches pointing at the camera.

    Args:
        stage: The stage, 0-3 (1: ``[0, theta]``, 3: ``[-theta, 0]``, 0 and 2: the middle).
        theta_deg: The rotation magnitude (deg).
        pointing_deg: (B,) orbit angles (deg) of the model's in-image side branches: the
            rotation at which each points straight at the lens.

    Returns:
        The target angle (deg): the stage's default where no branch is in the pointing window,
        else the candidate farthest from every branch in it (first candidate on ties).
    """
    default = STAGE_DEFAULTS[stage] * theta_deg
    low, high = (bound * theta_deg for bound in STAGE_INTERVALS[stage])
    angles = np.asarray(pointing_deg, float).reshape(-1)
    window = (angles >= default + POINTING_WINDOW[0] * theta_deg) & (
        angles <= default + POINTING_WINDOW[1] * theta_deg
    )
    angles = np.sort(angles[window])
    if len(angles) == 0:
        return default
    midpoints = (angles[:-1] + angles[1:]) / 2.0
    candidates = [low, high] + [m for m in midpoints if low <= m <= high]
    clearance = [float(np.min(np.abs(angles - c))) for c in candidates]
    return float(candidates[int(np.argmax(clearance))])


def pointing_angles_deg(
    model: TreeModel,
    T_world_camera: np.ndarray,
    intrinsics: CameraIntrinsics,
    angle_deg: float,
) -> np.ndarray:
    """Orbit angles (deg) at which the model's in-image side branches point at the lens.

    A camera at orbit angle ``r`` looks along the heading ``home + r`` (the orbit is a yaw about
    world Z), so a branch whose horizontal base-to-tip heading is ``h`` points at it where
    ``r = h - home - 180``, wrapped to [-180, 180).

    Args:
        model: The reconstructed tree (world frame; side branches ordered base to tip).
        T_world_camera: (4, 4) camera pose now.
        intrinsics: Camera intrinsics.
        angle_deg: The camera's orbit angle now (deg).

    Returns:
        (B,) angles (deg) of the side branches with the base or the tip in the image.
    """
    axis = np.asarray(T_world_camera, float)[:3, 2]
    home_deg = _heading_deg(axis[:2]) - angle_deg
    angles = []
    for branch in model.secondaries:
        if len(branch.points) < 2:
            continue
        ends = branch.points[[0, -1]]
        pixels, _ = project_points(ends, T_world_camera, intrinsics)
        if not intrinsics.in_image(pixels).any():
            continue
        direction = ends[1, :2] - ends[0, :2]
        if np.hypot(*direction) < MIN_HORIZONTAL_M:
            continue
        angles.append(_wrap_deg(_heading_deg(direction) - home_deg - 180.0))
    return np.array(angles, float)


def _heading_deg(xy: np.ndarray) -> float:
    """Heading of a horizontal direction (deg, 0 along +y, counter-clockwise from above)."""
    return math.degrees(math.atan2(-xy[0], xy[1]))


def _wrap_deg(angle: float) -> float:
    return (angle + 180.0) % 360.0 - 180.0


class FtlAgent(BaselineAgent):
    """The authors' branch-aware rotation cycle (module docstring).

    Args:
        session: The env's :class:`branch_gym.scan.ScanSession` (``env.unwrapped.session``).
        config: Magnitude and pan frequency.
        theta_max_deg, action_angles_deg, trigger_angles_deg, hold_tolerance_deg: The env's
            action settings (see :meth:`BaselineAgent.for_env`).
    """

    def __init__(self, session: Any, config: FtlConfig, **action_settings: Any) -> None:
        super().__init__(**action_settings)
        if config.angle_deg > self.theta_max_deg:
            raise ValueError(
                f"ftl angle_deg {config.angle_deg} exceeds theta_max_deg {self.theta_max_deg}"
            )
        self.session = session
        self.config = config
        self._stage = 0
        self._stage_height_m = math.nan
        self._target_deg = 0.0

    @classmethod
    def for_env(cls, env: Any, config: FtlConfig) -> FtlAgent:
        """The agent for a single (possibly wrapped) ``BranchScan`` env."""
        return cls.for_session_env(env, config)

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        if len(vectors) != 1:
            raise ValueError("the ftl policy acts in a single env, not a batch")
        session = self.session
        height_m = session.camera_height_m
        if starts[0]:
            self._stage, self._stage_height_m, self._target_deg = 0, math.nan, 0.0
        if not math.isfinite(self._stage_height_m):
            if session.model.primary is None:  # the authors count travel from the first model
                return np.array([self._target_deg]), state
            self._stage_height_m = height_m
        stage_m = self.config.stage_distance_fov * session.vertical_fov_m
        if height_m - self._stage_height_m > stage_m:
            self._stage = (self._stage + 1) % len(STAGE_DEFAULTS)
            self._stage_height_m = height_m
            pointing = pointing_angles_deg(
                session.model, session.world.T_world_camera, session.intrinsics, session.angle_deg
            )
            self._target_deg = stage_target_deg(self._stage, self.config.angle_deg, pointing)
        return np.array([self._target_deg]), state
