"""The UR5e's URDF, generated from the official DH table.

The rest of the model lives beside it:

* ``branch_gym/sim/robot/ur5e_spec.py``: DH table, joint and link names, joint limits, masses.
* ``branch_gym/sim/robot/camera_mount.py``: :class:`CameraMountConfig` and :func:`T_flange_camera`.
* ``branch_gym/sim/robot/kinematics.py``: DH forward kinematics, Jacobian, SO(3) log/exp, pose error
  and inverse kinematics in numpy.

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
from pathlib import Path

import numpy as np

from branch_gym.sim.robot.camera_mount import CameraMountConfig, T_flange_camera
from branch_gym.sim.robot.ur5e_spec import (
    BASE_MASS_KG,
    CAMERA_LINK,
    DH_A_M,
    DH_ALPHA_RAD,
    DH_D_M,
    FLANGE_LINK,
    JOINT_EFFORT_NM,
    JOINT_LIMIT_RAD,
    JOINT_NAMES,
    JOINT_SPEED_LIMIT_RADPS,
    LINK_MASS_KG,
    LINK_NAMES,
    N_JOINTS,
)

__all__ = ["ur5e_urdf_text", "write_ur5e_urdf"]

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


# Bracket plate between the flange face and the camera housing (x, y, z in the flange frame), our
# choice: as wide as the flange, spanning from the joint-6 axis to under the camera.
_BRACKET_SIZE_M = (0.07, 0.05, 0.012)


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
