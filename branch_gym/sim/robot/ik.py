"""Inverse kinematics of the camera pose for the simulated UR5e (``branch_gym/sim/robot/arm.py``).

The DH solver (:func:`branch_gym.sim.robot.kinematics.dh_inverse_kinematics`) with the robot's base
pose, camera mount, IK tolerances and joint limits. :class:`CameraIKMixin` is one of the bases of
:class:`branch_gym.sim.robot.arm.UR5e`, which provides ``config``, ``q``, ``_T_base_world``,
``_T_flange_camera`` and ``_limit_rad``.
"""

from __future__ import annotations

import math

import numpy as np

from branch_gym.sim.robot.config import InverseKinematicsError, RobotConfig
from branch_gym.sim.robot.kinematics import check_transform, dh_inverse_kinematics
from branch_gym.sim.robot.ur5e_spec import N_JOINTS


class CameraIKMixin:
    """Camera-pose inverse kinematics (mixed into ``UR5e``)."""

    config: RobotConfig
    _T_base_world: np.ndarray
    _T_flange_camera: np.ndarray
    _limit_rad: float

    def solve_ik(
        self, T_world_camera_target: np.ndarray, q_seed: np.ndarray | None = None
    ) -> np.ndarray:
        """Joint angles that put the camera at a pose, by damped Newton steps on the DH model.

        Converges to the solution on the seed's IK branch (elbow, wrist flip); it does not move
        the robot.

        Args:
            T_world_camera_target: (4, 4) target camera pose in the world.
            q_seed: (6,) start (rad); the current joint angles if None.

        Returns:
            (6,) joint angles in radians, within the joint limits less the margin.

        Raises:
            InverseKinematicsError: The residual stays above ``ik_position_tolerance_m`` /
                ``ik_angle_tolerance_deg`` (unreachable from this seed), or the solution breaks a
                joint limit.
        """
        T_target = check_transform(T_world_camera_target, "T_world_camera_target")
        q = self.q if q_seed is None else np.asarray(q_seed, dtype=float).copy()
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_seed must be a finite ({N_JOINTS},) vector, got {q_seed}")
        config = self.config
        q, error = dh_inverse_kinematics(
            self._T_base_world @ T_target,
            q,
            self._T_flange_camera,
            max_iterations=config.ik_max_iterations,
            max_step_rad=config.ik_max_step_rad,
        )
        position_error_m = float(np.linalg.norm(error[:3]))
        angle_error_deg = math.degrees(float(np.linalg.norm(error[3:])))
        if (
            position_error_m > config.ik_position_tolerance_m
            or angle_error_deg > config.ik_angle_tolerance_deg
        ):
            target_m = np.round(T_target[:3, 3], 4).tolist()
            raise InverseKinematicsError(
                f"IK did not reach the camera pose at {target_m} m (world): residual "
                f"{position_error_m * 1e3:.1f} mm / {angle_error_deg:.2f} deg after "
                f"{config.ik_max_iterations} iterations; the pose is out of reach from this seed"
            )
        # Angles are 2 pi periodic: bring each into the limits if an equivalent angle fits.
        q = np.where(q > self._limit_rad, q - 2 * math.pi, q)
        q = np.where(q < -self._limit_rad, q + 2 * math.pi, q)
        if np.any(np.abs(q) > self._limit_rad):
            raise InverseKinematicsError(
                f"IK solution {np.round(np.degrees(q), 1).tolist()} deg breaks the joint limits"
            )
        return q
