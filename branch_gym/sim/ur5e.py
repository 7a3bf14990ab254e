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


@dataclass(frozen=True)
class CameraMountConfig:
    """Where the camera sits on the tool flange (the fixed ``T_flange_camera``).

    The optical axis is the flange normal (flange z); ``roll_deg`` turns the image about it. With
    the default, the scan's home pose (optical axis horizontal, image up = world up) is reached with
    wrist 3 near 0 deg (see ``branch_gym/sim/home.py``).

    Attributes:
        offset_m: Optical centre in front of the flange face along flange z. Our choice: the depth
            of an Intel RealSense D405 housing (23 mm, Intel datasheet), the paper's lab camera.
        roll_deg: Rotation of the camera frame about the flange z axis. Our choice, measured: flange
            x points along image up (camera -y) at the home pose with q6 = 0.
        housing_size_m: Box (x, y, z) modelled behind the optical centre for contact checks
            (D405: 42 x 42 x 23 mm, Intel datasheet).
    """

    offset_m: float = 0.023
    roll_deg: float = -90.0
    housing_size_m: tuple[float, float, float] = (0.042, 0.042, 0.023)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.offset_m) and 0.0 <= self.offset_m <= 0.5):
            raise ValueError(f"offset_m must be in [0, 0.5] m, got {self.offset_m}")
        if not math.isfinite(self.roll_deg):
            raise ValueError(f"roll_deg must be finite, got {self.roll_deg}")
        if len(self.housing_size_m) != 3 or not all(
            math.isfinite(s) and s > 0 for s in self.housing_size_m
        ):
            raise ValueError(f"housing_size_m must be 3 positive sizes, got {self.housing_size_m}")


def _rot_x(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


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
    T[:3, :3] = _rot_z(math.radians(mount.roll_deg))
    T[2, 3] = mount.offset_m
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


def dh_jacobian(q: np.ndarray, T_flange_tool: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
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
        f"    <{tag}>{origin}<geometry>{shape}</geometry></{tag}>" for tag in ("visual", "collision")
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


def ur5e_urdf_text(mount: CameraMountConfig | None = None) -> str:
    """The UR5e URDF with flange and camera links, as text.

    Args:
        mount: The camera mount; defaults to :class:`CameraMountConfig()`.

    Returns:
        URDF XML. Link order (pybullet link index): the 6 arm links (0-5), ``flange`` (6),
        ``camera_optical`` (7); the base is pybullet's link -1.
    """
    mount = mount or CameraMountConfig()
    parts = ['<?xml version="1.0"?>', '<robot name="ur5e">']
    parts.append(_link_xml("base_link", BASE_MASS_KG, _geometry_xml(_BASE_GEOMETRY)))
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
    parts.append(_link_xml(FLANGE_LINK, 0.01))
    parts.append(_joint_xml("flange_joint", "fixed", parent, FLANGE_LINK, xyz, rpy))
    housing_xyz = (0.0, 0.0, -0.5 * mount.housing_size_m[2])
    parts.append(_link_xml(CAMERA_LINK, 0.05, _box_xml(mount.housing_size_m, housing_xyz)))
    camera_rpy = (0.0, 0.0, math.radians(mount.roll_deg))
    parts.append(
        _joint_xml(
            "camera_joint", "fixed", FLANGE_LINK, CAMERA_LINK, (0.0, 0.0, mount.offset_m), camera_rpy
        )
    )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def write_ur5e_urdf(mount: CameraMountConfig | None = None, directory: Path | None = None) -> Path:
    """Write the URDF once to a cache file and return its path.

    The file name carries a hash of the text, so different mounts never clash, and the write is
    atomic (temp file + rename), so parallel test workers can share the cache.

    Args:
        mount: The camera mount; defaults to :class:`CameraMountConfig()`.
        directory: Where to write; a ``branch_gym`` folder in the system temp dir if None.

    Returns:
        Path of the URDF file.
    """
    text = ur5e_urdf_text(mount)
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
