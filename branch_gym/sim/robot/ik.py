"""Inverse kinematics of the camera pose for the simulated UR5e (``branch_gym/sim/robot/arm.py``).

The DH solver (:func:`branch_gym.sim.robot.kinematics.dh_inverse_kinematics`) with the robot's base
pose, camera mount, IK tolerances and joint limits. :class:`CameraIK` holds those; the robot
(:class:`branch_gym.sim.robot.arm.UR5e`) owns one and passes it the seed.
"""

from __future__ import annotations

import math

import numpy as np

from branch_gym.sim.robot.config import InverseKinematicsError, RobotConfig
from branch_gym.sim.robot.kinematics import check_transform, dh_inverse_kinematics
from branch_gym.sim.robot.ur5e_spec import N_JOINTS


class CameraIK:
    """Camera-pose inverse kinematics of one robot (owned by ``UR5e``).

    Args:
        config: IK iterations, step and tolerances.
        T_world_base: (4, 4) pose of the robot base in the world.
        T_flange_camera: (4, 4) camera pose in the tool-flange frame (the mount).
        limit_rad: Joint limit (rad, symmetric) less the margin.
    """

    def __init__(
        self,
        config: RobotConfig,
        T_world_base: np.ndarray,
        T_flange_camera: np.ndarray,
        limit_rad: float,
    ) -> None:
        self.config = config
        self._T_base_world = np.linalg.inv(T_world_base)
        self._T_flange_camera = T_flange_camera
        self._limit_rad = limit_rad

    def solve(self, T_world_camera_target: np.ndarray, q_seed: np.ndarray) -> np.ndarray:
        """Joint angles that put the camera at a pose, by damped Newton steps on the DH model.

        Converges to the solution on the seed's IK branch (elbow, wrist flip); it does not move
        the robot.

        Args:
            T_world_camera_target: (4, 4) target camera pose in the world.
            q_seed: (6,) start (rad).

        Returns:
            (6,) joint angles in radians, within the joint limits less the margin.

        Raises:
            InverseKinematicsError: The residual stays above ``ik_position_tolerance_m`` /
                ``ik_angle_tolerance_deg`` (unreachable from this seed), or the solution breaks a
                joint limit.
        """
        T_target = check_transform(T_world_camera_target, "T_world_camera_target")
        q = np.asarray(q_seed, dtype=float).copy()
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
