"""UR5e kinematics in numpy, from the DH table: joint frames, forward kinematics, geometric
Jacobian, SO(3) log/exp, pose errors and a damped-Newton inverse kinematics; also
:func:`check_transform`, the validation of a target pose shared by the robot's motion and IK.

Conventions: standard (distal) DH, ``T_{i-1,i} = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
(``branch_gym/sim/robot/ur5e_spec.py``); lengths in metres, angles in radians.
"""

from __future__ import annotations

import math

import numpy as np

from branch_gym.sim.robot.ur5e_spec import DH_A_M, DH_ALPHA_RAD, DH_D_M, N_JOINTS

# IK iterations stop refining below these residuals (m, rad): far below any acceptance tolerance.
_IK_CONVERGED_M = 1e-9
_IK_CONVERGED_RAD = 1e-9
# Damping of the IK's least-squares steps, our choice: small, only to keep steps finite near a
# singular seed; it does not bias the converged solution.
_IK_DAMPING = 1e-4


def _check_q(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape != (N_JOINTS,):
        raise ValueError(f"joint vector must have shape ({N_JOINTS},), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"joint vector must be finite, got {q}")
    return q


def dh_joint_frames(q: np.ndarray) -> np.ndarray:
    """All DH frames of the arm, base to flange.

    Args:
        q: (6,) joint angles in radians.

    Returns:
        (7, 4, 4) poses of DH frames 0 (the robot base) to 6 (the flange), in the base frame.
        Frame ``i`` has its z axis on joint ``i+1``'s axis.
    """
    q = _check_q(q)
    frames = np.empty((N_JOINTS + 1, 4, 4))
    frames[0] = np.eye(4)
    for i in range(N_JOINTS):
        ct, st = math.cos(q[i]), math.sin(q[i])
        ca, sa = math.cos(DH_ALPHA_RAD[i]), math.sin(DH_ALPHA_RAD[i])
        a, d = DH_A_M[i], DH_D_M[i]
        step = np.array(
            [
                [ct, -st * ca, st * sa, a * ct],
                [st, ct * ca, -ct * sa, a * st],
                [0.0, sa, ca, d],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        frames[i + 1] = frames[i] @ step
    return frames


def dh_forward_kinematics(q: np.ndarray) -> np.ndarray:
    """Flange pose from the DH table.

    Args:
        q: (6,) joint angles in radians.

    Returns:
        (4, 4) ``T_base_flange`` in metres.
    """
    return dh_joint_frames(q)[-1]


def dh_jacobian(
    q: np.ndarray, T_flange_tool: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Geometric Jacobian of a tool point, from the DH table.

    Args:
        q: (6,) joint angles in radians.
        T_flange_tool: (4, 4) tool pose in the flange frame; identity (the flange) if None.

    Returns:
        ``(T_base_tool, J_base)``: the (4, 4) tool pose in the base frame and the (6, 6) Jacobian
        mapping joint rates (rad/s) to the tool origin's linear velocity (m/s, rows 0-2) and the
        angular velocity (rad/s, rows 3-5), both expressed in the base frame.
    """
    frames = dh_joint_frames(q)
    T_base_tool = frames[-1] if T_flange_tool is None else frames[-1] @ T_flange_tool
    axes = frames[:N_JOINTS, :3, 2]
    lever = T_base_tool[:3, 3] - frames[:N_JOINTS, :3, 3]
    J = np.empty((6, N_JOINTS))
    J[:3] = np.cross(axes, lever).T
    J[3:] = axes.T
    return T_base_tool, J


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (the SO(3) logarithm).

    Args:
        R: (3, 3) rotation matrix.

    Returns:
        (3,) rotation vector (axis x angle, rad), angle in [0, pi].
    """
    cos_angle = np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)
    angle = math.acos(cos_angle)
    skew = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * skew
    if angle < math.pi - 1e-6:
        return angle / (2.0 * math.sin(angle)) * skew
    # Near pi the skew part vanishes: take the axis from the symmetric part.
    axis_outer = 0.5 * (R + np.eye(3))
    axis = axis_outer[:, int(np.argmax(np.diag(axis_outer)))]
    axis = axis / np.linalg.norm(axis)
    return angle * axis


def rotation_exp(rotation_vector: np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (the SO(3) exponential, Rodrigues' formula).

    ``I + sin(a)/a K + (1 - cos(a))/a^2 K^2`` with ``K = [v]x`` and ``K^2 = v v^T - a^2 I``,
    written out on Python floats (called at every robot step: ~3x faster than array algebra).

    Args:
        rotation_vector: (3,) axis x angle (rad).

    Returns:
        (3, 3) rotation matrix.
    """
    x, y, z = (float(v) for v in rotation_vector)
    angle_sq = x * x + y * y + z * z
    angle = math.sqrt(angle_sq)
    if angle < 1e-9:
        return np.array([[1.0, -z, y], [z, 1.0, -x], [-y, x, 1.0]])
    a = math.sin(angle) / angle
    b = (1.0 - math.cos(angle)) / angle_sq
    return np.array(
        [
            [1.0 + b * (x * x - angle_sq), b * x * y - a * z, b * x * z + a * y],
            [b * x * y + a * z, 1.0 + b * (y * y - angle_sq), b * y * z - a * x],
            [b * x * z - a * y, b * y * z + a * x, 1.0 + b * (z * z - angle_sq)],
        ]
    )


def pose_error(T_world_target: np.ndarray, T_world_current: np.ndarray) -> np.ndarray:
    """World-frame error that takes ``current`` to ``target``.

    Returns:
        (6,) [position error (m), rotation vector of ``R_target R_current^T`` (rad)], world frame.
    """
    error = np.empty(6)
    error[:3] = T_world_target[:3, 3] - T_world_current[:3, 3]
    error[3:] = rotation_log(T_world_target[:3, :3] @ T_world_current[:3, :3].T)
    return error


def dh_inverse_kinematics(
    T_base_tool_target: np.ndarray,
    q_seed: np.ndarray,
    T_flange_tool: np.ndarray | None = None,
    max_iterations: int = 200,
    max_step_rad: float = 0.2,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles putting a tool frame at a pose: damped Newton steps on the DH model.

    Steps are clipped to ``max_step_rad`` per joint so that the iteration stays on the seed's IK
    branch (shoulder, elbow, wrist flip). It stops when the residual is negligible or after
    ``max_iterations``; the caller judges the residual.

    Args:
        T_base_tool_target: (4, 4) target tool pose in the base frame.
        q_seed: (6,) start joint angles (rad).
        T_flange_tool: (4, 4) tool pose in the flange frame; identity if None.
        max_iterations: Iteration budget.
        max_step_rad: Largest joint change per iteration.

    Returns:
        ``(q, residual)``: (6,) joint angles (rad, not wrapped) and the (6,) final
        :func:`pose_error` [m, rad] in the base frame.
    """
    q = _check_q(q_seed).copy()
    residual = np.zeros(6)
    for _ in range(max_iterations):
        T_base_tool, J = dh_jacobian(q, T_flange_tool)
        residual = pose_error(T_base_tool_target, T_base_tool)
        if (
            np.linalg.norm(residual[:3]) < _IK_CONVERGED_M
            and np.linalg.norm(residual[3:]) < _IK_CONVERGED_RAD
        ):
            break
        step = J.T @ np.linalg.solve(J @ J.T + _IK_DAMPING**2 * np.eye(6), residual)
        largest = float(np.max(np.abs(step)))
        if largest > max_step_rad:
            step *= max_step_rad / largest
        q = q + step
    return q, residual


def check_transform(T: np.ndarray, name: str) -> np.ndarray:
    """Validate a finite (4, 4) transform with a proper rotation block; ``name`` is for errors."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name} must be a finite (4, 4) transform, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} rotation part is not a rotation matrix")
    return T
