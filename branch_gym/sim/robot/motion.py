"""Camera motion of the simulated UR5e: camera-frame twists, DLS twist control, straight moves.

Motion is kinematic (no dynamics): a camera-frame twist becomes joint rates by damped least
squares on the pybullet Jacobian of the camera link, integrated with the midpoint rule at a fixed
control step. Each step is checked before it is kept, and a failed step leaves the robot where it
was and says why (:class:`MotionStatus`): singularity, joint limit, joint speed or collision.

:class:`CameraMotion` does this for :class:`branch_gym.sim.robot.arm.UR5e`, which owns one and
hands it everything it uses explicitly: the configuration and joint limit, the current
:class:`KinematicState`, a Jacobian provider (joint angles -> world-axes Jacobian) and a checked
commit of a new joint vector. Its only state is the manipulability of the last Jacobian it
committed (the next step starts there).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from scipy.linalg import lapack

from branch_gym.sim.robot.config import MotionStatus, RobotConfig
from branch_gym.sim.robot.kinematics import check_transform, pose_error, rotation_exp
from branch_gym.sim.robot.ur5e_spec import JOINT_NAMES, N_JOINTS

logger = logging.getLogger(__name__)

_IDENTITY = np.eye(N_JOINTS)  # the right-hand side that makes gesv an inverse

JacobianProvider = Callable[[np.ndarray], np.ndarray]
"""Joint angles (6,) -> (6, 6) Jacobian of the camera origin, world axes (state untouched)."""


class KinematicState(NamedTuple):
    """The arm's cached kinematic state at one joint vector.

    Attributes:
        q: (6,) joint angles in radians.
        T_world_camera: (4, 4) camera pose (OpenCV axes) in the world.
        J_world: (6, 6) Jacobian of the camera origin at ``q``, world axes.
    """

    q: np.ndarray
    T_world_camera: np.ndarray
    J_world: np.ndarray


def camera_frame_jacobian(J_world: np.ndarray, R_world_camera: np.ndarray) -> np.ndarray:
    """(6, 6) Jacobian to the camera twist [v, w] in camera axes, from the world-axes one."""
    J = np.empty_like(J_world)
    J[:3] = R_world_camera.T @ J_world[:3]
    J[3:] = R_world_camera.T @ J_world[3:]
    return J


def manipulability(J_world: np.ndarray) -> float:
    """``sqrt(det(J J^T))`` of a square Jacobian (rotating its rows does not change it)."""
    return abs(float(np.linalg.det(J_world)))


def camera_twist_from_world(
    T_world_camera: np.ndarray,
    linear_velocity_world_mps: np.ndarray,
    angular_velocity_world_radps: np.ndarray,
) -> np.ndarray:
    """Express a world-frame velocity of the camera as a camera-frame twist.

    Args:
        T_world_camera: (4, 4) current camera pose.
        linear_velocity_world_mps: (3,) velocity of the camera origin, world axes (m/s).
        angular_velocity_world_radps: (3,) angular velocity, world axes (rad/s).

    Returns:
        (6,) [v (m/s), w (rad/s)] in camera axes, as :meth:`UR5e.apply_camera_twist` takes it.
    """
    R_world_camera = np.asarray(T_world_camera, dtype=float)[:3, :3]
    return np.concatenate(
        [
            R_world_camera.T @ np.asarray(linear_velocity_world_mps, dtype=float),
            R_world_camera.T @ np.asarray(angular_velocity_world_radps, dtype=float),
        ]
    )


def orbit_camera_twist(
    T_world_camera: np.ndarray, pivot_world_m: np.ndarray, yaw_rate_radps: float
) -> np.ndarray:
    """Camera twist that turns the camera about the world-vertical axis through a pivot.

    The camera-frame twist of a rotation about a fixed world axis is constant, so applying this
    twist for ``angle / yaw_rate_radps`` seconds moves the camera exactly along the circle (up to
    the integration error).

    Args:
        T_world_camera: (4, 4) current camera pose.
        pivot_world_m: (3,) a point on the rotation axis (e.g. the branch point looked at), m.
        yaw_rate_radps: Rotation rate about +z (rad/s), right-handed.

    Returns:
        (6,) camera-frame twist [v (m/s), w (rad/s)].
    """
    omega_world = np.array([0.0, 0.0, float(yaw_rate_radps)])
    lever_m = np.asarray(T_world_camera, dtype=float)[:3, 3] - np.asarray(pivot_world_m, float)
    return camera_twist_from_world(T_world_camera, np.cross(omega_world, lever_m), omega_world)


class CameraMotion:
    """Twist control and straight-line moves of an arm's camera (owned by ``UR5e``).

    Args:
        config: Control step, damping, speed limits, singularity threshold, move gains.
        limit_rad: Joint limit (rad, symmetric) less the margin.
        state: Returns the arm's current kinematic state.
        world_jacobian: The Jacobian provider.
        commit: Sets the joints to ``q`` (with its Jacobian) and checks for contact; on contact
            it puts the previous state back and returns the description, else returns None.
    """

    def __init__(
        self,
        config: RobotConfig,
        limit_rad: float,
        state: Callable[[], KinematicState],
        world_jacobian: JacobianProvider,
        commit: Callable[[np.ndarray, np.ndarray], str | None],
    ) -> None:
        self.config = config
        self._limit_rad = limit_rad
        self._state = state
        self._world_jacobian = world_jacobian
        self._commit = commit
        # (Jacobian committed by the last step, its manipulability): the next step's start.
        self._committed: tuple[np.ndarray, float] | None = None

    def apply_camera_twist(self, twist_camera: np.ndarray, dt_s: float) -> MotionStatus:
        """Move the camera with a constant camera-frame twist for ``dt_s`` seconds.

        The command is split into equal sub-steps of at most ``control_time_step_s``. Each sub-step
        maps the twist to joint rates by damped least squares, integrates them, and keeps the
        result only if it passes the checks; otherwise the robot stays at the last good sub-step.

        Args:
            twist_camera: (6,) [v (m/s), w (rad/s)], velocity of the camera origin and angular
                velocity, both in camera axes (OpenCV: x right, y down, z forward).
            dt_s: Duration in seconds.

        Returns:
            The status; ``elapsed_s`` is the time actually moved.

        Raises:
            ValueError: The twist is not a finite (6,) vector or ``dt_s`` is not positive.
        """
        twist = np.asarray(twist_camera, dtype=float)
        if twist.shape != (6,) or not np.all(np.isfinite(twist)):
            raise ValueError(f"twist_camera must be a finite (6,) vector, got {twist_camera}")
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be positive and finite, got {dt_s}")
        n_steps = max(1, math.ceil(dt_s / self.config.control_time_step_s - 1e-9))
        step_s = dt_s / n_steps
        for k in range(n_steps):
            status = self._step(twist, step_s)
            if not status.ok:
                logger.debug("camera twist stopped: %s (%s)", status.reason, status.detail)
                return replace(status, elapsed_s=k * step_s)
        return MotionStatus(True, "ok", status.manipulability, dt_s)

    def _joint_rates(
        self, J_world: np.ndarray, R_world_camera: np.ndarray, twist: np.ndarray
    ) -> tuple[np.ndarray, float | None]:
        """Damped least-squares joint rates for a camera-frame twist, and the manipulability
        (None where the direct solve applies: it is not needed then, see :meth:`_step`)."""
        if self.config.dls_direct_solve:
            direct = self._undamped_joint_rates(J_world, R_world_camera, twist)
            if direct is not None:
                return direct, None
        U, sigma, Vt = np.linalg.svd(camera_frame_jacobian(J_world, R_world_camera))
        gains = sigma / (sigma**2 + self._damping_sq(sigma[-1]))
        return Vt.T @ (gains * (U.T @ twist)), float(np.prod(sigma))

    def _undamped_joint_rates(
        self, J_world: np.ndarray, R_world_camera: np.ndarray, twist: np.ndarray
    ) -> np.ndarray | None:
        """``J^-1 twist`` where the damping is provably zero, else None.

        The camera-frame Jacobian is the world one with its rows rotated, so its inverse maps
        the twist rotated to world axes. ``||J^-1||_2 <= ||J^-1||_F``: a Frobenius norm of at
        most ``1 / damping_sigma_band`` proves ``sigma_min >= damping_sigma_band``, where
        :meth:`_damping_sq` is 0 and the SVD formula is the plain inverse.
        """
        # LAPACK gesv against the identity, as numpy.linalg.inv computes it (the same result),
        # without numpy's checks and dispatch: 2 instead of 6 us, twice per control step.
        _, _, J_inv, info = lapack.dgesv(J_world, _IDENTITY)
        if info != 0:  # exactly singular (info > 0); < 0 would be a bad argument
            return None
        entries = J_inv.ravel()
        if float(entries @ entries) * self.config.damping_sigma_band**2 > 1.0:
            return None
        # [R v, R w]: both halves of the twist rotated by one (3, 3) @ (3, 2) product.
        twist_world = (R_world_camera @ twist.reshape(2, 3).T).T.ravel()
        return J_inv @ twist_world

    def _step(self, twist: np.ndarray, step_s: float) -> MotionStatus:
        """One checked control step, integrated with the midpoint rule (second order)."""
        config = self.config
        q, T_world_camera, J_world = self._state()
        R_world_camera = T_world_camera[:3, :3]
        q_rate, manipulability_now = self._joint_rates(J_world, R_world_camera, twist)
        if manipulability_now is None:  # |det J|: the last step's, when it committed this J
            committed = self._committed
            if committed is not None and committed[0] is J_world:
                manipulability_now = committed[1]
            else:
                manipulability_now = manipulability(J_world)
        # Midpoint: the camera's mid-step orientation is known from the commanded body rate.
        q_mid = q + 0.5 * step_s * q_rate
        R_mid = R_world_camera @ rotation_exp(0.5 * step_s * twist[3:])
        q_rate, _ = self._joint_rates(self._world_jacobian(q_mid), R_mid, twist)
        q_next = q + q_rate * step_s
        J_next = self._world_jacobian(q_next)
        manipulability_next = manipulability(J_next)
        worst = min(manipulability_now, manipulability_next)
        if worst < config.manipulability_threshold:
            return MotionStatus(
                False,
                "singularity",
                worst,
                detail=f"manipulability {worst:.4g} < {config.manipulability_threshold}",
            )
        speed_ratio = np.abs(q_rate) / config.max_joint_speed_radps
        abs_next = np.abs(q_next)
        beyond = None  # the joints past the limit and moving away from zero (rarely any)
        if abs_next.max() > self._limit_rad:
            beyond = (abs_next > self._limit_rad) & (abs_next > np.abs(q))
        if speed_ratio.max() > 1.0:
            joint = int(np.argmax(speed_ratio))
            reason = "joint_speed"
            detail = f"{JOINT_NAMES[joint]} at {math.degrees(q_rate[joint]):.1f} deg/s"
        elif beyond is not None and beyond.any():
            joint = int(np.argmax(beyond))
            reason = "joint_limit"
            detail = f"{JOINT_NAMES[joint]} would reach {math.degrees(q_next[joint]):.1f} deg"
        else:
            contact = self._commit(q_next, J_next)
            if contact is None:
                self._committed = (J_next, manipulability_next)
                return MotionStatus(True, "ok", manipulability_next)
            reason, detail = "collision", contact
        return MotionStatus(False, reason, manipulability_now, detail=detail)

    def _damping_sq(self, smallest_sigma: float) -> float:
        """lambda^2 of the variable-damping DLS: 0 above the band, up to damping_max^2 at 0."""
        band = self.config.damping_sigma_band
        if smallest_sigma >= band:
            return 0.0
        return (1.0 - (smallest_sigma / band) ** 2) * self.config.damping_max**2

    def move_camera_to(
        self, T_target: np.ndarray, speed_mps: float, angular_radps: float, max_s: float | None
    ) -> MotionStatus:
        """Move the camera to a pose along a straight line, turning along the shortest rotation.

        Proportional law on the world-frame pose error, saturated so that neither speed exceeds
        its limit; position and rotation errors shrink by the same factor each step, so the
        camera origin stays on the line and both arrive together.

        Args:
            T_target: (4, 4) target camera pose.
            speed_mps: Linear speed limit of the camera origin (m/s).
            angular_radps: Angular speed limit (rad/s).
            max_s: Give up ("timeout") after this much simulated time; if None twice the
                saturated travel time plus 2 s.

        Returns:
            The status; ``elapsed_s`` is the simulated time the move took.
        """
        T_target = check_transform(T_target, "T_world_camera_target")
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise ValueError(f"speed_mps must be positive, got {speed_mps}")
        if not (math.isfinite(angular_radps) and angular_radps > 0):
            raise ValueError(f"angular_speed_radps must be positive, got {angular_radps}")
        config = self.config
        error = pose_error(T_target, self._state().T_world_camera)
        if max_s is None:
            travel_s = max(
                np.linalg.norm(error[:3]) / speed_mps,
                np.linalg.norm(error[3:]) / angular_radps,
            )
            max_s = 2.0 * travel_s + 2.0
        angle_tolerance_rad = math.radians(config.move_angle_tolerance_deg)
        elapsed_s = 0.0
        while True:
            T_world_camera = self._state().T_world_camera
            error = pose_error(T_target, T_world_camera)
            position_error_m = float(np.linalg.norm(error[:3]))
            angle_error_rad = float(np.linalg.norm(error[3:]))
            if (
                position_error_m <= config.move_position_tolerance_m
                and angle_error_rad <= angle_tolerance_rad
            ):
                return MotionStatus(True, "ok", manipulability(self._state().J_world), elapsed_s)
            if elapsed_s >= max_s:
                return MotionStatus(
                    False,
                    "timeout",
                    manipulability(self._state().J_world),
                    elapsed_s,
                    detail=f"{position_error_m * 1e3:.2f} mm, "
                    f"{math.degrees(angle_error_rad):.3f} deg left after {elapsed_s:.2f} s",
                )
            command = config.move_gain_per_s * error
            scale = min(
                1.0,
                speed_mps / max(np.linalg.norm(command[:3]), 1e-12),
                angular_radps / max(np.linalg.norm(command[3:]), 1e-12),
            )
            command *= scale
            twist = camera_twist_from_world(T_world_camera, command[:3], command[3:])
            status = self.apply_camera_twist(twist, config.control_time_step_s)
            elapsed_s += status.elapsed_s
            if not status.ok:
                return replace(status, elapsed_s=elapsed_s)
