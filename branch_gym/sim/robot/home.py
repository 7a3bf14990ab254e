"""Where the robot stands and where a scan starts: base placement and home pose.

World frame: z up, ground at z = 0; the primary branch passes (0, 0) at the scan start height and
the camera scans from the -y side looking along +y (see ``branch_gym/sim/tree/generator.py``).

Base placement, found by a sweep (our choice, measured). The camera rides on top of the flange
(``camera_mount.py``, :class:`CameraMountConfig`), so the scan holds the flange pointing up
and wrist 2 stays at -90 deg, far from the wrist singularity, whatever the camera's yaw. What
remains is reach and the elbow/shoulder singularities. The sweep solved IK over camera heights
0.275-0.75 m x rotations about the branch of -45..45 deg x branch offsets (x +-0.10 m; y +-0.02 m at
the start growing to +-0.10 m at the top, the generated trees' 99th percentile) for bases at
y = -0.45..-1.05 m, x = -0.35..0.35 m, pedestal 0-0.3 m, in every elbow-up IK family, and scored
the worst manipulability ``|det J|`` of the camera Jacobian (:func:`sweep_scan_workspace` re-runs
this check for one placement; ``tests/test_home.py`` does so for the default):

* A camera looking along the flange normal (the UR tool axis) failed everywhere: rotating about the
  branch turns wrist 2 by 45 deg plus the arm's own swing, reaching its singularity (|sin q5| < 0.1)
  or the end of reach for every placement.
* Camera on top of the flange: the best worst case lies 0.75-0.85 m behind the branch. Closer bases
  lose manipulability (shoulder), farther ones lose reach (0.85 m fails with x offsets of 0.2 m);
  a 0.2 m pedestal centres the shoulder on the wrist's height range. The chosen (0, -0.80, 0.20) m
  keeps ``|det J|`` >= 0.077 (median 0.094) over the task's range (x +-0.10 m, y +-0.02 m), >= 0.055
  with y +-0.10 m at every height, and >= 0.042 at the trees' extremes (x +-0.20 m, y +-0.15 m);
  the smallest singular value stays >= 0.16 (0.077 at the extremes).

The arm stays behind and below the camera: the wrist hangs under it and the forearm comes from the
robot's side. Over the scan range every link keeps >= 0.168 m from the branch surface (wrist 2 is
the closest; camera housing 0.19 m), beyond secondary branches (at most 0.15 m long), and >= 0.085 m
above the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from branch_gym.sim.robot.kinematics import dh_joint_frames
from branch_gym.sim.robot.ur5e_spec import JOINT_LIMIT_RAD

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from branch_gym.sim.robot.arm import UR5e

# Scan geometry, reference.md "Simulated world" / "Follow controller": start at tool height
# 0.275 m, end at 0.75 m, camera z_target = 0.20 m from the primary branch.
SCAN_START_HEIGHT_M = 0.275
SCAN_END_HEIGHT_M = 0.75
Z_TARGET_M = 0.20
# A longer scan of a tall-spindle leader at its real height (TreeConfig.tall_spindle_leader,
# docs/worlds.md "A longer stretch"): 0.80 m of the fruiting zone, 0.70 -> 1.50 m, from the arm
# lifted on a platform (BasePlacement.platform).
LEADER_SCAN_START_HEIGHT_M = 0.70
LEADER_SCAN_END_HEIGHT_M = 1.50
# The camera looks along +y at the tree from the -y side (sim/tree/generator.py convention).
VIEW_DIRECTION_WORLD = np.array([0.0, 1.0, 0.0])
_WORLD_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class BasePlacement:
    """The UR5e base pose in the world and the arm posture the scan uses with it.

    Attributes:
        position_m: Base frame origin (x, y, z) in the world. The default is the sweep's choice
            (module docstring): 0.80 m behind the branch on a 0.20 m pedestal.
        yaw_deg: Base rotation about world z. 90 deg: the base x axis points along +y, at the tree.
        pedestal_radius_m: Radius of the cylindrical pedestal under a raised base, our choice: the
            UR5e base is 149 mm across (datasheet), a 100 mm-radius column carries it.
        home_seed_q_deg: Joint angles (deg) near the home pose for this placement and the default
            camera mount, the IK seed that picks the elbow-up, wrist-2 = -90 deg family (measured).
    """

    position_m: tuple[float, float, float] = (0.0, -0.80, 0.20)
    yaw_deg: float = 90.0
    pedestal_radius_m: float = 0.10
    home_seed_q_deg: tuple[float, ...] = (13.8, -156.9, -105.3, -7.8, -90.0, -13.8)

    def __post_init__(self) -> None:
        if len(self.position_m) != 3 or not all(math.isfinite(v) for v in self.position_m):
            raise ValueError(f"position_m must be 3 finite numbers, got {self.position_m}")
        if self.position_m[2] < 0:
            raise ValueError(f"position_m z (pedestal height) must be >= 0, got {self.position_m}")
        if not math.isfinite(self.yaw_deg):
            raise ValueError(f"yaw_deg must be finite, got {self.yaw_deg}")
        if not (math.isfinite(self.pedestal_radius_m) and self.pedestal_radius_m > 0):
            raise ValueError(f"pedestal_radius_m must be positive, got {self.pedestal_radius_m}")
        if len(self.home_seed_q_deg) != 6 or not all(
            math.isfinite(v) for v in self.home_seed_q_deg
        ):
            raise ValueError(f"home_seed_q_deg must be 6 finite angles, got {self.home_seed_q_deg}")

    @classmethod
    def platform(cls) -> BasePlacement:
        """The arm lifted on an orchard platform for the leader scan (0.70 -> 1.50 m).

        Same place behind the branch as the default, 0.60 m higher: the scan's heights sit
        where the default's do relative to the shoulder, extended 0.175 m below and above
        (the default scans 0.075-0.55 m above its base, this one -0.10-0.70 m). Measured with
        :func:`sweep_scan_workspace` (``tests/test_long_leader.py``): over 0.70-1.50 m x
        rotations -45..45 deg x branch offsets x +-0.10 m, y +-0.05 m every pose is reachable,
        elbow-up and contact-free with ``|det J|`` >= 0.069 (the default's >= 0.055 over its
        range); the generated leaders stray at most 4 cm from the start's vertical. The home
        seed is the IK solution at 0.70 m from the default seed (measured). A platform deck at
        0.60 m with the default 0.20 m column: orchard platforms carry pickers and pruners at
        deck heights of ~0.5-2 m (our choice within that).
        """
        return cls(
            position_m=(0.0, -0.80, 0.80),
            home_seed_q_deg=(13.8, -180.7, -86.5, -2.8, -90.0, -13.8),
        )

    @property
    def T_world_base(self) -> np.ndarray:
        """(4, 4) pose of the robot base frame in the world."""
        c, s = math.cos(math.radians(self.yaw_deg)), math.sin(math.radians(self.yaw_deg))
        T = np.eye(4)
        T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        T[:3, 3] = self.position_m
        return T

    @property
    def home_seed_q(self) -> np.ndarray:
        """(6,) :attr:`home_seed_q_deg` in radians."""
        return np.radians(np.asarray(self.home_seed_q_deg, dtype=float))


def camera_pose_facing_branch(
    branch_point_world: np.ndarray,
    standoff_m: float = Z_TARGET_M,
    yaw_about_branch_deg: float = 0.0,
) -> np.ndarray:
    """Camera pose looking horizontally at a branch point, image up = world up.

    Args:
        branch_point_world: (3,) point on the branch (m) the optical axis passes through.
        standoff_m: Camera-to-point distance along the optical axis (m).
        yaw_about_branch_deg: Rotation of the camera about the world-vertical axis through the
            point, right-handed about +z: 0 looks along +y (:data:`VIEW_DIRECTION_WORLD`);
            positive turns the optical axis toward -x and moves the camera toward +x.

    Returns:
        (4, 4) ``T_world_camera`` (OpenCV axes: x right, y down, z along the optical axis).
    """
    point = np.asarray(branch_point_world, dtype=float)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise ValueError(f"branch_point_world must be a finite (3,) point, got {point}")
    if not (math.isfinite(standoff_m) and standoff_m > 0):
        raise ValueError(f"standoff_m must be positive, got {standoff_m}")
    if not math.isfinite(yaw_about_branch_deg):
        raise ValueError(f"yaw_about_branch_deg must be finite, got {yaw_about_branch_deg}")
    yaw = math.radians(yaw_about_branch_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    optical_axis = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ VIEW_DIRECTION_WORLD
    image_down = -_WORLD_UP
    image_right = np.cross(image_down, optical_axis)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([image_right, image_down, optical_axis])
    T[:3, 3] = point - standoff_m * optical_axis
    return T


def home_configuration(
    robot: UR5e,
    branch_point_world: np.ndarray | None = None,
    standoff_m: float = Z_TARGET_M,
    yaw_about_branch_deg: float = 0.0,
) -> np.ndarray:
    """Joint angles of the home pose: camera ``standoff_m`` from the branch, level, facing it.

    Solved by IK from the placement's :attr:`BasePlacement.home_seed_q`, which keeps the elbow-up,
    wrist-2 = -90 deg family. The robot is not moved.

    Args:
        robot: The robot (its placement and camera mount define the kinematics).
        branch_point_world: (3,) branch point (m) at the scan start height; defaults to the
            origin at :data:`SCAN_START_HEIGHT_M`, where the generated primary passes.
        standoff_m: Camera-to-branch distance (m), z_target.
        yaw_about_branch_deg: Start rotated about the branch (see
            :func:`camera_pose_facing_branch`).

    Returns:
        (6,) joint angles in radians.

    Raises:
        InverseKinematicsError: The pose is out of reach from the seed (see ``UR5e.solve_ik``).
    """
    if branch_point_world is None:
        branch_point_world = np.array([0.0, 0.0, SCAN_START_HEIGHT_M])
    T_world_camera = camera_pose_facing_branch(branch_point_world, standoff_m, yaw_about_branch_deg)
    return robot.solve_ik(T_world_camera, q_seed=robot.config.base.home_seed_q)


def elbow_up(robot: UR5e, q: np.ndarray) -> bool:
    """Whether the elbow is above the straight line from the shoulder to the wrist.

    Args:
        robot: The robot (for its base pose).
        q: (6,) joint angles in radians.
    """
    frames = robot.T_world_base @ dh_joint_frames(q)
    shoulder, elbow, wrist = frames[1, :3, 3], frames[2, :3, 3], frames[3, :3, 3]
    along = float(
        np.dot(elbow - shoulder, wrist - shoulder) / np.dot(wrist - shoulder, wrist - shoulder)
    )
    return bool(elbow[2] > shoulder[2] + along * (wrist[2] - shoulder[2]))


@dataclass
class WorkspaceReport:
    """What :func:`sweep_scan_workspace` found.

    Attributes:
        n_poses: Camera poses solved.
        min_manipulability: Smallest ``sqrt(det(J J^T))`` over the solved poses.
        min_joint_margin_deg: Smallest distance of any joint to its +-360 deg limit.
        failures: One line per pose that was unreachable, elbow-down or in contact.
    """

    n_poses: int = 0
    min_manipulability: float = math.inf
    min_joint_margin_deg: float = math.inf
    failures: list[str] = field(default_factory=list)


def sweep_scan_workspace(
    robot: UR5e,
    heights_m: Sequence[float],
    angles_deg: Sequence[float],
    branch_offsets_m: Sequence[tuple[float, float]],
    place_branch: Callable[[float, float], None] | None = None,
    standoff_m: float = Z_TARGET_M,
) -> WorkspaceReport:
    """Solve the scan's camera poses by IK continuation and check each one.

    For every branch offset (x, y) and rotation angle, the camera starts at the home pose, turns
    about the branch at the start height and climbs through ``heights_m``; each pose is solved
    from the previous solution, as the scan would move. The robot is left at the last pose.

    Args:
        robot: The robot; its obstacles are checked for contact at every pose.
        heights_m: Camera heights, ascending from the scan start (m).
        angles_deg: Rotations about the branch (see :func:`camera_pose_facing_branch`).
        branch_offsets_m: (x, y) positions of a vertical primary branch (m).
        place_branch: Called with (x, y) before the poses of each offset, to move the branch body.
        standoff_m: Camera-to-branch distance (m).

    Returns:
        The report; ``failures`` is empty when every pose is reachable, elbow-up and contact-free.
    """
    report = WorkspaceReport()
    for x_m, y_m in branch_offsets_m:
        if place_branch is not None:
            place_branch(x_m, y_m)
        for angle_deg in angles_deg:
            q = robot.config.base.home_seed_q
            path = [(heights_m[0], angle_deg * f) for f in np.linspace(0.0, 1.0, 5)]
            path += [(h, angle_deg) for h in heights_m[1:]]
            for height_m, yaw_deg in path:
                where = (
                    f"branch ({x_m:+.3f}, {y_m:+.3f}) m, height {height_m:.3f} m, "
                    f"{yaw_deg:+.1f} deg"
                )
                target = camera_pose_facing_branch(
                    np.array([x_m, y_m, height_m]), standoff_m, yaw_deg
                )
                try:
                    q = robot.solve_ik(target, q_seed=q)
                except RuntimeError as error:  # InverseKinematicsError
                    report.failures.append(f"{where}: {error}")
                    break
                robot.set_joint_positions(q)
                report.n_poses += 1
                report.min_manipulability = min(report.min_manipulability, robot.manipulability())
                margin_deg = math.degrees(JOINT_LIMIT_RAD - float(np.max(np.abs(q))))
                report.min_joint_margin_deg = min(report.min_joint_margin_deg, margin_deg)
                if not elbow_up(robot, q):
                    report.failures.append(f"{where}: elbow down")
                contact = robot.check_collision()
                if contact is not None:
                    report.failures.append(f"{where}: {contact}")
    return report
