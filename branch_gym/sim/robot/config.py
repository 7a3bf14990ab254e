"""Configuration and outcome types of the simulated UR5e (``branch_gym/sim/robot/arm.py``).

:class:`RobotConfig` holds the placement, camera mount, motion checks, DLS damping, IK tolerances
and move gains; :class:`MotionStatus` says how a motion command ended and
:class:`InverseKinematicsError` that a camera pose is out of reach.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from branch_gym.sim.robot.camera_mount import CameraMountConfig
from branch_gym.sim.robot.home import BasePlacement
from branch_gym.sim.robot.ur5e_spec import JOINT_LIMIT_RAD
from branch_gym.sim.validation import require_non_negative, require_positive

MotionReason = Literal["ok", "singularity", "joint_limit", "joint_speed", "collision", "timeout"]


@dataclass(frozen=True)
class MotionStatus:
    """Outcome of a motion command.

    Attributes:
        ok: The whole motion was carried out.
        reason: "ok", or the first failure: "singularity" (manipulability below the threshold),
            "joint_limit", "joint_speed" (a joint rate over its limit), "collision" (with an
            obstacle or between non-adjacent links), "timeout" (``move_camera_to`` only).
        manipulability: ``sqrt(det(J J^T))`` of the camera Jacobian at the final configuration,
            or at the rejected one on a singularity.
        elapsed_s: Simulated time actually moved (s); the failed step is not counted.
        detail: Human-readable context for a failure (which joint, which bodies).
    """

    ok: bool
    reason: MotionReason
    manipulability: float
    elapsed_s: float = 0.0
    detail: str = ""


class InverseKinematicsError(RuntimeError):
    """The IK could not reach the requested camera pose within tolerance (or within limits)."""


@dataclass(frozen=True)
class RobotConfig:
    """The robot, its camera and its motion checks.

    Attributes:
        base: Base placement and home seed (``branch_gym/sim/robot/home.py``; chosen by a sweep).
        mount: Camera mount on the flange (``branch_gym/sim/robot/ur5e.py``).
        control_time_step_s: Largest integration step; longer commands are split into equal
            sub-steps. Our choice: one sub-step per scan control step (reference.md: ~30 steps per
            10 mm at 2.5 cm/s, i.e. ~13 ms).
        manipulability_threshold: A step whose start or end has ``sqrt(det(J J^T))`` below this
            fails with "singularity". Our choice, measured: the scan workspace stays >= 0.077 with
            the default placement (``sim/robot/home.py``), so 0.01 only stops motions that
            leave it, e.g. within ~6 deg of the wrist singularity (wrist 2 = 0).
        damping_max: Largest DLS damping factor lambda (units of the Jacobian's singular values).
            Our choice: small, so that tracking stays exact away from singularities.
        damping_sigma_band: Damping grows from 0 as the smallest singular value of the camera
            Jacobian falls below this value (variable damping, Chiaverini 1997). Our choice,
            measured: the scan workspace keeps it >= 0.16, so tracking there is undamped.
        joint_limit_margin_deg: Steps may not end closer than this to a joint limit (unless they
            move away from it). Our choice.
        max_joint_speed_radps: Joint rate limit (rad/s); UR5e datasheet: 180 deg/s on all joints.
        self_collision: Check non-adjacent links against each other after every step.
        collision_margin_m: Bodies closer than this count as touching. Our choice: exact contact.
        ground_height_m: Moving links may not reach below this height (the world's ground, which
            the scene paints instead of making it a body); None disables the check.
        ik_position_tolerance_m: IK must reach the target position within this (task brief: 1 mm).
        ik_angle_tolerance_deg: IK must reach the target orientation within this (brief: 0.5 deg).
        ik_max_iterations: Least-squares iterations before IK gives up. Our choice, measured:
            a few are enough from a nearby seed; failures take all of them.
        ik_max_step_rad: Largest joint change per IK iteration (keeps the solution on the seed's
            branch). Our choice.
        move_gain_per_s: Proportional gain of :meth:`UR5e.move_camera_to` (1/s). Our choice:
            gain x step = 0.17 is well inside Euler stability, and settling takes ~0.3 s.
        move_position_tolerance_m: :meth:`UR5e.move_camera_to` stops within this of the target.
        move_angle_tolerance_deg: ... and within this angle. Our choice for both: far below the
            reconstruction's resolution (0.5 mm per pixel at 0.2 m).
        contact_query_m: Contact checks measure the clearance up to this distance (m) and skip
            the steps whose joint motion since that check cannot have closed it (a conservative
            bound: every joint's rotation times the farthest reach of the links it carries), so
            a contact is still found at the same step. 0 checks every step in full (the
            reference path). Our choice, measured: 5 cm lets the straight scans skip ~90 % of the
            checks; a larger query costs more in pybullet's narrow phase.
        dls_direct_solve: Solve the joint rates with one inverse where a cheap bound (the
            Frobenius norm of the inverse) proves the smallest singular value at or above
            ``damping_sigma_band``, i.e. where the damped least squares is undamped anyway (the
            whole scan workspace, see above); False runs the SVD at every step (the reference
            path). Both agree to rounding (~1e-15 rad/s).
    """

    base: BasePlacement = field(default_factory=BasePlacement)
    mount: CameraMountConfig = field(default_factory=CameraMountConfig)
    control_time_step_s: float = 1.0 / 60.0
    manipulability_threshold: float = 0.01
    damping_max: float = 0.02
    damping_sigma_band: float = 0.05
    joint_limit_margin_deg: float = 5.0
    max_joint_speed_radps: float = math.radians(180.0)
    self_collision: bool = True
    collision_margin_m: float = 0.0
    ground_height_m: float | None = 0.0
    ik_position_tolerance_m: float = 1e-3
    ik_angle_tolerance_deg: float = 0.5
    ik_max_iterations: int = 200
    ik_max_step_rad: float = 0.2
    move_gain_per_s: float = 10.0
    move_position_tolerance_m: float = 2e-4
    move_angle_tolerance_deg: float = 0.05
    contact_query_m: float = 0.05
    dls_direct_solve: bool = True

    def __post_init__(self) -> None:
        positive = (
            "control_time_step_s",
            "manipulability_threshold",
            "damping_sigma_band",
            "max_joint_speed_radps",
            "ik_position_tolerance_m",
            "ik_angle_tolerance_deg",
            "ik_max_step_rad",
            "move_gain_per_s",
            "move_position_tolerance_m",
            "move_angle_tolerance_deg",
        )
        require_positive(self, *positive)
        require_non_negative(self, "damping_max", "collision_margin_m", "contact_query_m")
        if self.ground_height_m is not None and not math.isfinite(self.ground_height_m):
            raise ValueError(
                f"RobotConfig.ground_height_m must be finite, got {self.ground_height_m}"
            )
        if not 0 <= self.joint_limit_margin_deg < math.degrees(JOINT_LIMIT_RAD):
            raise ValueError(
                f"RobotConfig.joint_limit_margin_deg must be in [0, 360), "
                f"got {self.joint_limit_margin_deg}"
            )
        if self.ik_max_iterations < 1:
            raise ValueError(
                f"RobotConfig.ik_max_iterations must be >= 1, got {self.ik_max_iterations}"
            )
        if self.move_gain_per_s * self.control_time_step_s >= 1.0:
            raise ValueError(
                "RobotConfig.move_gain_per_s x control_time_step_s must be < 1 (Euler stability), "
                f"got {self.move_gain_per_s * self.control_time_step_s}"
            )
