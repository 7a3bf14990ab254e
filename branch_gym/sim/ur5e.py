"""The UR5e model: DH kinematics in numpy and a URDF generated from the same table.

The URDF is written from the official DH parameters, so the pybullet model and
:func:`dh_forward_kinematics` agree by construction (``tests/test_robot.py`` checks it). Each URDF
link frame ``L_i`` is the DH frame ``i-1`` rotated by ``q_i`` about its z axis (the joint axis);
joint ``i+1`` then sits at ``Tz(d_i) Tx(a_i) Rx(alpha_i)`` in ``L_i``. After joint 6 come two fixed
links: ``flange`` (the DH frame 6, UR's ``tool0``: z out of the flange face) and ``camera_optical``
(OpenCV axes: x right, y down, z along the optical axis).

Link geometry is a few capsules and cylinders of roughly the real link sizes, for contact checks
only. Every link's inertial frame coincides with its link frame, so pybullet's link "centre of
mass" pose is the URDF link frame and ``calculateJacobian`` at local position 0 is the link origin.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Official UR5e DH parameters, Universal Robots "DH parameters for calculations of kinematics and
# dynamics" (support article; also reference.md "Costs measured"). Standard (distal) DH convention:
# T_{i-1,i} = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i). Lengths in metres, angles in radians.
DH_D_M = np.array([0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996])
DH_A_M = np.array([0.0, -0.425, -0.3922, 0.0, 0.0, 0.0])
DH_ALPHA_RAD = np.array([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])

N_JOINTS = 6
JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
LINK_NAMES = (
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
FLANGE_LINK = "flange"
CAMERA_LINK = "camera_optical"

# UR5e technical specifications (Universal Robots datasheet, "Joint ranges" and "Speed" rows):
# every joint +-360 deg; base, shoulder, elbow and the three wrists all 180 deg/s.
JOINT_LIMIT_RAD = 2.0 * math.pi
JOINT_SPEED_LIMIT_RADPS = np.full(N_JOINTS, math.radians(180.0))
# Rated joint torques (datasheet: size-3 joints 150 Nm, size-1 wrist joints 28 Nm); URDF needs them.
JOINT_EFFORT_NM = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
# Link masses in kg from Universal Robots' published dynamics parameters (unused: kinematic sim).
LINK_MASS_KG = (3.761, 8.058, 2.846, 1.37, 1.3, 0.365)
BASE_MASS_KG = 4.0

# IK iterations stop refining below these residuals (m, rad): far below any acceptance tolerance.
_IK_CONVERGED_M = 1e-9
_IK_CONVERGED_RAD = 1e-9
# Damping of the IK's least-squares steps, our choice: small, only to keep steps finite near a
# singular seed; it does not bias the converged solution.
_IK_DAMPING = 1e-4

# Collision geometry, our choice from the UR5e drawings: (kind, radius_m, length_m, xyz, rpy) in
# the URDF link frame; capsule/cylinder axes run along their local z. Lengths are the cylindrical
# part (pybullet capsules add a hemisphere of the radius at each end).
_HALF_PI = math.pi / 2
_Geometry = tuple[str, float, float, tuple[float, float, float], tuple[float, float, float]]
_BASE_GEOMETRY: tuple[_Geometry, ...] = (("cylinder", 0.075, 0.086, (0.0, 0.0, 0.043), (0, 0, 0)),)
_LINK_GEOMETRY: tuple[tuple[_Geometry, ...], ...] = (
    # shoulder: joint-1 housing, and the joint-2 housing along -y at the shoulder height d1.
    (
        ("cylinder", 0.060, 0.090, (0.0, 0.0, 0.131), (0, 0, 0)),
        ("cylinder", 0.060, 0.130, (0.0, -0.065, 0.1625), (_HALF_PI, 0, 0)),
    ),
    # upper arm: tube from the shoulder to the elbow, offset 0.138 m along the joint axis.
    (("capsule", 0.054, 0.425, (-0.2125, 0.0, 0.138), (0, _HALF_PI, 0)),),
    # forearm: elbow housing along the joint axis, then the tube to the wrist (elbow offset -0.131).
    (
        ("cylinder", 0.045, 0.120, (0.0, 0.0, 0.066), (0, 0, 0)),
        ("capsule", 0.040, 0.3922, (-0.1961, 0.0, 0.007), (0, _HALF_PI, 0)),
    ),
    # wrist 1: housing about the joint-4 axis, from the forearm tube past the wrist-2 axis (d4).
    (("cylinder", 0.045, 0.178, (0.0, 0.0, 0.089), (0, 0, 0)),),
    # wrist 2: housing about the joint-5 axis, from the wrist-1 housing to the wrist-3 axis.
    (("cylinder", 0.045, 0.100, (0.0, 0.0, 0.0947), (0, 0, 0)),),
    # wrist 3: housing about the joint-6 axis, ending at the tool flange (d6).
    (("cylinder", 0.0375, 0.050, (0.0, 0.0, 0.0746), (0, 0, 0)),),
)


# A camera bracket longer than this is no longer "on the flange" (sanity bound, our choice).
_MAX_MOUNT_OFFSET_M = 0.3
# Bracket plate between the flange face and the camera housing (x, y, z in the flange frame), our
# choice: as wide as the flange, spanning from the joint-6 axis to under the camera.
_BRACKET_SIZE_M = (0.07, 0.05, 0.012)


@dataclass(frozen=True)
class CameraMountConfig:
    """Where the camera sits on the tool flange (the fixed ``T_flange_camera``).

    The camera rides on top of the flange on a small bracket: image up is the flange normal
    (flange z) and the optical axis is perpendicular to it. Scanning with the optical axis
    horizontal then holds the flange pointing straight up, the UR's most comfortable wrist posture
    (wrist 2 at +-90 deg, far from the wrist singularity), and turning the camera about a vertical
    axis is mostly wrist 3. A camera looking along the flange normal would instead need wrist 2 to
    follow every yaw, reaching its singularity within the +-45 deg rotations (measured:
    ``branch_gym/sim/home.py``).

    Attributes:
        axial_offset_m: Optical centre above the flange face along flange z. Our choice: a 14 mm
            bracket plate plus half the 42 mm height of an Intel RealSense D405 (the paper's lab
            camera; Intel datasheet).
        forward_offset_m: Optical centre ahead of the joint-6 axis along the optical axis. Our
            choice: keeps the wrist housings (radius <= 45 mm) behind the image plane.
        azimuth_deg: Direction of the optical axis about flange z, from flange x. Our choice:
            along flange -y, which puts wrist 3 near -14 deg at the home pose (measured).
        housing_size_m: Camera box (x, y, z in the camera frame) modelled behind the optical centre
            for contact checks (D405: 42 x 42 x 23 mm, Intel datasheet).
    """

    axial_offset_m: float = 0.035
    forward_offset_m: float = 0.04
    azimuth_deg: float = -90.0
    housing_size_m: tuple[float, float, float] = (0.042, 0.042, 0.023)

    def __post_init__(self) -> None:
        for name in ("axial_offset_m", "forward_offset_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= _MAX_MOUNT_OFFSET_M):
                raise ValueError(f"{name} must be in [0, {_MAX_MOUNT_OFFSET_M}] m, got {value}")
        if not math.isfinite(self.azimuth_deg):
            raise ValueError(f"azimuth_deg must be finite, got {self.azimuth_deg}")
        if len(self.housing_size_m) != 3 or not all(
            math.isfinite(s) and s > 0 for s in self.housing_size_m
        ):
            raise ValueError(f"housing_size_m must be 3 positive sizes, got {self.housing_size_m}")
        if self.axial_offset_m < 0.5 * self.housing_size_m[1]:
            raise ValueError(
                f"axial_offset_m ({self.axial_offset_m}) must clear half the housing height "
                f"({0.5 * self.housing_size_m[1]}): the camera would sit inside the flange"
            )


# The camera frame in the flange frame before the azimuth turn: optical axis (camera z) along
# flange x, image down (camera y) along -flange z, camera x = y cross z = -flange y.
_R_FLANGE_CAMERA_0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _rot_z(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def T_flange_camera(mount: CameraMountConfig | None = None) -> np.ndarray:
    """Fixed camera pose in the flange frame.

    Args:
        mount: The camera mount; defaults to :class:`CameraMountConfig()`.

    Returns:
        (4, 4) transform mapping camera-frame points (OpenCV axes) to flange-frame points.
    """
    mount = mount or CameraMountConfig()
    T = np.eye(4)
    T[:3, :3] = _rot_z(math.radians(mount.azimuth_deg)) @ _R_FLANGE_CAMERA_0
    T[:3, 3] = mount.forward_offset_m * T[:3, 2] + np.array([0.0, 0.0, mount.axial_offset_m])
    return T


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

    Args:
        rotation_vector: (3,) axis x angle (rad).

    Returns:
        (3, 3) rotation matrix.
    """
    angle = float(np.linalg.norm(rotation_vector))
    K = np.array(
        [
            [0.0, -rotation_vector[2], rotation_vector[1]],
            [rotation_vector[2], 0.0, -rotation_vector[0]],
            [-rotation_vector[1], rotation_vector[0], 0.0],
        ]
    )
    if angle < 1e-9:
        return np.eye(3) + K
    return np.eye(3) + math.sin(angle) / angle * K + (1.0 - math.cos(angle)) / angle**2 * K @ K


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


def _rpy_from_matrix(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw (R = Rz(yaw) Ry(pitch) Rx(roll)) of a (3, 3) rotation, in radians."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(R[2, 0]) < 1.0 - 1e-9:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: only roll - yaw (or roll + yaw) is defined; put it all in roll
        roll = math.atan2(-R[1, 2], R[1, 1])
        yaw = 0.0
    return roll, pitch, yaw


def _fmt(values: tuple[float, ...] | np.ndarray) -> str:
    return " ".join(f"{float(v):.10g}" for v in values)


def _geometry_xml(geometry: tuple[_Geometry, ...]) -> str:
    parts = []
    for kind, radius_m, length_m, xyz, rpy in geometry:
        shape = f'<{kind} radius="{radius_m:.10g}" length="{length_m:.10g}"/>'
        origin = f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>'
        for tag in ("visual", "collision"):
            parts.append(f"    <{tag}>{origin}<geometry>{shape}</geometry></{tag}>")
    return "\n".join(parts)


def _box_xml(size_m: tuple[float, float, float], xyz: tuple[float, float, float]) -> str:
    origin = f'<origin xyz="{_fmt(xyz)}" rpy="0 0 0"/>'
    shape = f'<box size="{_fmt(size_m)}"/>'
    return "\n".join(
        f"    <{tag}>{origin}<geometry>{shape}</geometry></{tag}>"
        for tag in ("visual", "collision")
    )


def _link_xml(name: str, mass_kg: float, body: str = "") -> str:
    # Inertial frame = link frame (see the module docstring); a small solid-sphere-like inertia.
    inertia = 0.4 * mass_kg * 0.05**2
    inertial = (
        f'    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="{mass_kg:.10g}"/>'
        f'<inertia ixx="{inertia:.6g}" ixy="0" ixz="0" iyy="{inertia:.6g}" iyz="0" '
        f'izz="{inertia:.6g}"/></inertial>'
    )
    lines = [f'  <link name="{name}">', inertial]
    if body:
        lines.append(body)
    lines.append("  </link>")
    return "\n".join(lines)


def _joint_xml(name: str, kind: str, parent: str, child: str, xyz: tuple, rpy: tuple) -> str:
    lines = [
        f'  <joint name="{name}" type="{kind}">',
        f'    <parent link="{parent}"/><child link="{child}"/>',
        f'    <origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>',
    ]
    if kind == "revolute":
        index = JOINT_NAMES.index(name)
        lines.append('    <axis xyz="0 0 1"/>')
        lines.append(
            f'    <limit lower="{-JOINT_LIMIT_RAD:.10g}" upper="{JOINT_LIMIT_RAD:.10g}" '
            f'effort="{JOINT_EFFORT_NM[index]:.10g}" '
            f'velocity="{JOINT_SPEED_LIMIT_RADPS[index]:.10g}"/>'
        )
    lines.append("  </joint>")
    return "\n".join(lines)


def ur5e_urdf_text(
    mount: CameraMountConfig | None = None,
    pedestal_height_m: float = 0.0,
    pedestal_radius_m: float = 0.1,
) -> str:
    """The UR5e URDF with flange and camera links, as text.

    Args:
        mount: The camera mount; defaults to :class:`CameraMountConfig()`.
        pedestal_height_m: Height of a cylindrical column under the base, part of the base link
            (0: no pedestal).
        pedestal_radius_m: Radius of that column.

    Returns:
        URDF XML. Link order (pybullet link index): the 6 arm links (0-5), ``flange`` (6),
        ``camera_optical`` (7); the base is pybullet's link -1.
    """
    mount = mount or CameraMountConfig()
    parts = ['<?xml version="1.0"?>', '<robot name="ur5e">']
    if not (math.isfinite(pedestal_height_m) and pedestal_height_m >= 0):
        raise ValueError(f"pedestal_height_m must be >= 0, got {pedestal_height_m}")
    if not (math.isfinite(pedestal_radius_m) and pedestal_radius_m > 0):
        raise ValueError(f"pedestal_radius_m must be positive, got {pedestal_radius_m}")
    base_geometry = _BASE_GEOMETRY
    if pedestal_height_m > 0:
        pedestal_xyz = (0.0, 0.0, -0.5 * pedestal_height_m)
        pedestal = ("cylinder", pedestal_radius_m, pedestal_height_m, pedestal_xyz, (0, 0, 0))
        base_geometry = (*base_geometry, pedestal)
    parts.append(_link_xml("base_link", BASE_MASS_KG, _geometry_xml(base_geometry)))
    parent = "base_link"
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    for i in range(N_JOINTS):
        link = LINK_NAMES[i]
        parts.append(_link_xml(link, LINK_MASS_KG[i], _geometry_xml(_LINK_GEOMETRY[i])))
        parts.append(_joint_xml(JOINT_NAMES[i], "revolute", parent, link, xyz, rpy))
        # The next joint sits at Tz(d_i) Tx(a_i) Rx(alpha_i) in this link's frame.
        xyz = (float(DH_A_M[i]), 0.0, float(DH_D_M[i]))
        rpy = (float(DH_ALPHA_RAD[i]), 0.0, 0.0)
        parent = link
    bracket_xyz = (0.5 * _BRACKET_SIZE_M[0] - 0.01, 0.0, 0.5 * _BRACKET_SIZE_M[2])
    parts.append(_link_xml(FLANGE_LINK, 0.05, _box_xml(_BRACKET_SIZE_M, bracket_xyz)))
    parts.append(_joint_xml("flange_joint", "fixed", parent, FLANGE_LINK, xyz, rpy))
    housing_xyz = (0.0, 0.0, -0.5 * mount.housing_size_m[2])
    parts.append(_link_xml(CAMERA_LINK, 0.05, _box_xml(mount.housing_size_m, housing_xyz)))
    T_camera = T_flange_camera(mount)
    parts.append(
        _joint_xml(
            "camera_joint",
            "fixed",
            FLANGE_LINK,
            CAMERA_LINK,
            tuple(T_camera[:3, 3]),
            _rpy_from_matrix(T_camera[:3, :3]),
        )
    )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def write_ur5e_urdf(
    mount: CameraMountConfig | None = None,
    pedestal_height_m: float = 0.0,
    pedestal_radius_m: float = 0.1,
    directory: Path | None = None,
) -> Path:
    """Write the URDF once to a cache file and return its path.

    The file name carries a hash of the text, so different models never clash, and the write is
    atomic (temp file + rename), so parallel test workers can share the cache.

    Args:
        mount: The camera mount; defaults to :class:`CameraMountConfig()`.
        pedestal_height_m: See :func:`ur5e_urdf_text`.
        pedestal_radius_m: See :func:`ur5e_urdf_text`.
        directory: Where to write; a ``branch_gym_urdf`` folder in the system temp dir if None.

    Returns:
        Path of the URDF file.
    """
    text = ur5e_urdf_text(mount, pedestal_height_m, pedestal_radius_m)
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    directory = directory or Path(tempfile.gettempdir()) / "branch_gym_urdf"
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"ur5e_{digest}.urdf"
    if not path.exists():
        fd, tmp_name = tempfile.mkstemp(dir=directory, suffix=".urdf.tmp")
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
        os.replace(tmp_name, path)
    return path
