"""The simulated UR5e with an eye-in-hand camera: state, forward kinematics, contact checks.

The class :class:`UR5e` lives here. It owns two parts that it hands what they need explicitly
(panda-gym style composition) and delegates to:

* :class:`branch_gym.sim.robot.motion.CameraMotion`: camera twists, damped least-squares twist
  control (:meth:`UR5e.apply_camera_twist`) and straight-line moves (:meth:`UR5e.move_camera_to`),
  given the robot's :class:`KinematicState`, its Jacobian provider and a checked commit
  (``motion.py`` also has :func:`camera_twist_from_world` and :func:`orbit_camera_twist`);
* :class:`branch_gym.sim.robot.ik.CameraIK`: camera-pose inverse kinematics
  (:meth:`UR5e.solve_ik`), given the base pose, the camera mount and the joint limits.

Configuration and outcome types (:class:`RobotConfig`, :class:`MotionStatus`,
:class:`InverseKinematicsError`) live in ``branch_gym/sim/robot/config.py``.

Only this class should set the arm's joints: it caches the joint vector, the camera pose and the
Jacobian between steps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pybullet

from branch_gym.sim.bullet import Bullet
from branch_gym.sim.robot import ur5e
from branch_gym.sim.robot.camera_mount import T_flange_camera
from branch_gym.sim.robot.config import MotionStatus, RobotConfig
from branch_gym.sim.robot.ik import CameraIK
from branch_gym.sim.robot.motion import (
    CameraMotion,
    KinematicState,
    camera_frame_jacobian,
    manipulability,
)
from branch_gym.sim.robot.ur5e_spec import (
    CAMERA_LINK,
    FLANGE_LINK,
    JOINT_LIMIT_RAD,
    LINK_NAMES,
    N_JOINTS,
)

__all__ = ["UR5e"]

_ZEROS6 = [0.0] * N_JOINTS


class UR5e:
    """A UR5e with a camera on its flange, loaded into one :class:`Bullet` world.

    ``bullet.reset()`` removes the robot with every other body: build a new ``UR5e`` afterwards.

    Attributes:
        bullet: The world the robot lives in.
        config: Its configuration.
        body_id: pybullet body id of the arm.
        motion: Its camera motion (:class:`CameraMotion`), behind :meth:`apply_camera_twist` and
            :meth:`move_camera_to`.
    """

    def __init__(
        self, bullet: Bullet, config: RobotConfig | None = None, q: np.ndarray | None = None
    ) -> None:
        """Load the arm and set its joints.

        Args:
            bullet: The pybullet world.
            config: Robot configuration; defaults to :class:`RobotConfig()`.
            q: (6,) initial joint angles (rad); the placement's home seed if None.
        """
        self.bullet = bullet
        self.config = config or RobotConfig()
        base = self.config.base
        urdf_path = ur5e.write_ur5e_urdf(
            self.config.mount,
            pedestal_height_m=base.position_m[2],
            pedestal_radius_m=base.pedestal_radius_m,
        )
        half_yaw = 0.5 * math.radians(base.yaw_deg)
        self.body_id: int = bullet.p.loadURDF(
            str(urdf_path),
            basePosition=base.position_m,
            baseOrientation=(0.0, 0.0, math.sin(half_yaw), math.cos(half_yaw)),
            useFixedBase=True,
        )
        names = {
            bullet.p.getJointInfo(self.body_id, j)[12].decode(): j
            for j in range(bullet.p.getNumJoints(self.body_id))
        }
        self._joint_indices = [names[n] for n in LINK_NAMES]
        self._camera_link = names[CAMERA_LINK]
        self._flange_link = names[FLANGE_LINK]
        self._link_names = {index: name for name, index in names.items()} | {-1: "base_link"}
        self._self_collision_pairs = self._non_adjacent_link_pairs()
        self._all_links = [-1, *sorted(names.values())]
        row = {link: i for i, link in enumerate(self._all_links)}
        self._pair_rows = (
            np.array([row[a] for a, _ in self._self_collision_pairs]),
            np.array([row[b] for _, b in self._self_collision_pairs]),
        )
        # pybullet calls made every step, bound once (the client's attribute lookup costs ~1 us).
        self._bullet_closest_points = bullet.p.getClosestPoints
        self._bullet_get_aabb = bullet.p.getAABB
        self._bullet_jacobian = bullet.p.calculateJacobian
        self._bullet_reset_joints = bullet.p.resetJointStatesMultiDof
        self._bullet_link_state = bullet.p.getLinkState
        self._T_world_base = base.T_world_base
        limit_rad = JOINT_LIMIT_RAD - math.radians(self.config.joint_limit_margin_deg)
        self._obstacle_ids: tuple[int, ...] = ()
        self._obstacle_links: list[tuple[int, range]] = []
        self._state = KinematicState(np.zeros(N_JOINTS), np.eye(4), np.zeros((6, N_JOINTS)))
        self.motion = CameraMotion(
            self.config,
            limit_rad,
            state=self._kinematic_state,
            world_jacobian=self._world_jacobian,
            commit=self._commit_checked,
        )
        self._ik = CameraIK(
            self.config, self._T_world_base, T_flange_camera(self.config.mount), limit_rad
        )
        # Contact-check skipping (RobotConfig.contact_query_m): the joint vector of the last full
        # check and how far any point of the arm may move from there before a contact is possible.
        self._checked_q = np.zeros(N_JOINTS)
        self._free_motion_m: np.ndarray | None = None
        self.set_joint_positions(base.home_seed_q if q is None else q)
        self._motion_bounds = self._motion_bound_rows()

    # --- state ---------------------------------------------------------------------------

    @property
    def q(self) -> np.ndarray:
        """(6,) current joint angles in radians (a copy)."""
        return self._state.q.copy()

    @property
    def T_world_base(self) -> np.ndarray:
        """(4, 4) pose of the robot base in the world (a copy)."""
        return self._T_world_base.copy()

    @property
    def obstacle_ids(self) -> tuple[int, ...]:
        """Bodies the arm must not touch (checked after every step)."""
        return self._obstacle_ids

    def set_obstacles(self, body_ids: Sequence[int]) -> None:
        """Declare the bodies to avoid (the tree, the ground, ...); replaces the previous set."""
        ids = tuple(int(b) for b in body_ids)
        if self.body_id in ids:
            raise ValueError("the robot cannot be its own obstacle (self-collision is separate)")
        self._obstacle_ids = ids
        self._free_motion_m = None
        get_num_joints = self.bullet.p.getNumJoints
        self._obstacle_links = [(b, range(-1, get_num_joints(b))) for b in ids]

    def set_joint_positions(self, q: np.ndarray) -> None:
        """Teleport the joints (no checks besides shape and finiteness).

        Args:
            q: (6,) joint angles in radians.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q must be a finite ({N_JOINTS},) vector, got {q}")
        self._apply_q(q, self._world_jacobian(q))
        self._free_motion_m = None  # a teleport: the next step is checked in full

    def _apply_q(self, q: np.ndarray, J_world: np.ndarray) -> None:
        """Set the joints and cache the state at ``q`` (pybullet's camera pose, ``J_world``)."""
        self._bullet_reset_joints(self.body_id, self._joint_indices, q.reshape(-1, 1).tolist())
        link = self._bullet_link_state(
            self.body_id, self._camera_link, computeForwardKinematics=True
        )
        self._state = KinematicState(q.copy(), _pose_from_pybullet(link[4], link[5]), J_world)

    def _kinematic_state(self) -> KinematicState:
        """The cached state (not copied: for the parts the robot owns, which do not mutate it)."""
        return self._state

    def _commit_checked(self, q: np.ndarray, J_world: np.ndarray) -> str | None:
        """Set the joints to ``q``; on contact put the previous state back and describe it."""
        previous = self._state
        self._apply_q(q, J_world)
        if self._free_motion_m is not None:
            moved_m = self._motion_bounds @ np.abs(q - self._checked_q)
            if np.all(moved_m < self._free_motion_m):
                return None  # no link can have closed the clearance measured at the last check
        contact, free_m = self._contact_and_clearance(self.config.contact_query_m)
        if contact is not None:
            self._apply_q(previous.q, previous.J_world)
            self._free_motion_m = None
            return contact
        self._checked_q = q.copy()
        self._free_motion_m = free_m if np.all(free_m > 0.0) else None
        return None

    # --- motion and inverse kinematics (delegated) ---------------------------------------

    def apply_camera_twist(self, twist_camera: np.ndarray, dt_s: float) -> MotionStatus:
        """Move the camera with a constant camera-frame twist for ``dt_s`` seconds.

        See :meth:`branch_gym.sim.robot.motion.CameraMotion.apply_camera_twist`.
        """
        return self.motion.apply_camera_twist(twist_camera, dt_s)

    def move_camera_to(
        self,
        T_world_camera_target: np.ndarray,
        speed_mps: float,
        angular_speed_radps: float = 0.5,
        max_duration_s: float | None = None,
    ) -> MotionStatus:
        """Move the camera to a pose along a straight line, turning along the shortest rotation.

        Proportional law on the world-frame pose error, saturated so that neither speed exceeds
        its limit (:meth:`branch_gym.sim.robot.motion.CameraMotion.move_camera_to`).

        Args:
            T_world_camera_target: (4, 4) target camera pose.
            speed_mps: Linear speed limit of the camera origin (m/s).
            angular_speed_radps: Angular speed limit (rad/s). Our default: 0.5 rad/s.
            max_duration_s: Give up ("timeout") after this much simulated time; by default twice
                the saturated travel time plus 2 s.

        Returns:
            The status; ``elapsed_s`` is the simulated time the move took.
        """
        return self.motion.move_camera_to(
            T_world_camera_target, speed_mps, angular_speed_radps, max_duration_s
        )

    def solve_ik(
        self, T_world_camera_target: np.ndarray, q_seed: np.ndarray | None = None
    ) -> np.ndarray:
        """Joint angles that put the camera at a pose (the robot does not move).

        See :meth:`branch_gym.sim.robot.ik.CameraIK.solve`; ``q_seed`` defaults to the current
        joint angles.
        """
        return self._ik.solve(T_world_camera_target, self._state.q if q_seed is None else q_seed)

    # --- kinematics ----------------------------------------------------------------------

    def T_world_camera(self) -> np.ndarray:
        """(4, 4) camera pose (OpenCV axes) in the world, from pybullet's forward kinematics."""
        return self._state.T_world_camera.copy()

    def T_world_flange(self) -> np.ndarray:
        """(4, 4) tool-flange pose (UR ``tool0``: z out of the flange) in the world."""
        p = self.bullet.p
        state = p.getLinkState(self.body_id, self._flange_link, computeForwardKinematics=True)
        return _pose_from_pybullet(state[4], state[5])

    def _world_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(6, 6) pybullet Jacobian of the camera origin at ``q``, world axes (state untouched).

        pybullet returns a fixed-base Jacobian in the base frame; it is rotated to world axes.
        """
        linear, angular = self._bullet_jacobian(
            self.body_id, self._camera_link, [0.0, 0.0, 0.0], q.tolist(), _ZEROS6, _ZEROS6
        )
        rows = self._T_world_base[:3, :3] @ np.array((linear, angular))  # (2, 3, 6)
        return rows.reshape(6, N_JOINTS)

    def camera_jacobian(self) -> np.ndarray:
        """(6, 6) Jacobian mapping joint rates (rad/s) to the camera twist [v, w] in camera axes."""
        return camera_frame_jacobian(self._state.J_world, self._state.T_world_camera[:3, :3])

    def manipulability(self) -> float:
        """``sqrt(det(J J^T))`` of the camera Jacobian at the current configuration."""
        return manipulability(self._state.J_world)

    # --- checks --------------------------------------------------------------------------

    def _non_adjacent_link_pairs(self) -> list[tuple[int, int]]:
        """Link pairs at least two rigid bodies apart in the chain (flange, camera = wrist 3)."""
        rigid_body = {-1: 0} | {index: i + 1 for i, index in enumerate(self._joint_indices)}
        rigid_body[self._flange_link] = rigid_body[self._joint_indices[-1]]
        rigid_body[self._camera_link] = rigid_body[self._joint_indices[-1]]
        links = sorted(rigid_body)
        return [
            (a, b)
            for i, a in enumerate(links)
            for b in links[i + 1 :]
            if abs(rigid_body[a] - rigid_body[b]) >= 2
        ]

    def _link_aabbs(self) -> tuple[np.ndarray, np.ndarray]:
        """(n_links, 3) lower and upper world AABB corners of every link, base (-1) first."""
        get_aabb = self._bullet_get_aabb
        boxes = [get_aabb(self.body_id, link) for link in self._all_links]
        return np.array([box[0] for box in boxes]), np.array([box[1] for box in boxes])

    def check_collision(self) -> str | None:
        """Describe the first contact of the arm, or None when it touches nothing.

        Checks the moving links (not the base or its pedestal, which stand on the ground) against
        the ground plane (by their bounding boxes, which err on the safe side by ~1 cm) and every
        obstacle link, then non-adjacent links against each other. Axis-aligned bounding boxes
        skip the pairs that cannot touch; pybullet's closest points decide the others.
        """
        return self._contact_and_clearance(self.config.collision_margin_m)[0]

    def _contact_and_clearance(self, query_m: float) -> tuple[str | None, np.ndarray]:
        """The first contact (as :meth:`check_collision`), and the free motion when none.

        Args:
            query_m: Distances are measured up to this (m); at least the collision margin.

        Returns:
            ``(contact, free_m)``: the contact's description or None, and per row of
            :meth:`_motion_bound_rows` how far (m) its motion bound may grow before a contact
            becomes possible: for each moving link its ground gap and obstacle distances, for
            each self-collision pair its distance, less the margin and capped by ``query_m`` less
            the margin (all 0 with a contact).
        """
        closest_points = self._bullet_closest_points
        get_aabb = self._bullet_get_aabb
        margin = self.config.collision_margin_m
        query_m = max(query_m, margin)
        n_moving = len(self._all_links) - 1
        free_m = np.full(n_moving + len(self._self_collision_pairs), query_m - margin)
        no_motion = np.zeros_like(free_m)
        lower, upper = self._link_aabbs()
        moving_lower, moving_upper = lower[1:].min(axis=0), upper[1:].max(axis=0)
        ground_m = self.config.ground_height_m
        if ground_m is not None:
            if moving_lower[2] - margin < ground_m:
                row = int(np.argmin(lower[1:, 2])) + 1
                name = self._link_names[self._all_links[row]]
                return f"{name} reaches below the ground", no_motion
            np.minimum(free_m[:n_moving], lower[1:, 2] - margin - ground_m, out=free_m[:n_moving])
        query_lower, query_upper = moving_lower - query_m, moving_upper + query_m
        row_of = {link: i - 1 for i, link in enumerate(self._all_links)}
        for obstacle, links in self._obstacle_links:
            for link in links:
                link_lower, link_upper = get_aabb(obstacle, link)
                if np.any(query_lower > link_upper) or np.any(query_upper < link_lower):
                    continue
                for contact in closest_points(self.body_id, obstacle, query_m, linkIndexB=link):
                    if contact[3] < 0:
                        continue
                    if contact[8] <= margin:
                        return f"{self._link_names[contact[3]]} touches body {obstacle}", no_motion
                    row = row_of[contact[3]]
                    free_m[row] = min(free_m[row], contact[8] - margin)
        if self.config.self_collision:
            a, b = self._pair_rows
            overlap = np.all(lower[a] <= upper[b] + query_m, axis=1) & np.all(
                lower[b] <= upper[a] + query_m, axis=1
            )
            for k in np.flatnonzero(overlap):
                link_a, link_b = self._self_collision_pairs[k]
                for contact in closest_points(self.body_id, self.body_id, query_m, link_a, link_b):
                    if contact[8] <= margin:
                        name_a, name_b = self._link_names[link_a], self._link_names[link_b]
                        return f"{name_a} touches {name_b}", no_motion
                    free_m[n_moving + k] = min(free_m[n_moving + k], contact[8] - margin)
        return None, free_m

    def _motion_bound_rows(self) -> np.ndarray:
        """(n_moving_links + n_self_pairs, 6): bounds of motion per unit joint rotation (m/rad).

        Row k < n_moving_links: no point of moving link k moves farther than ``row @ |dq|``
        when the joints turn by ``dq``; the rows after it bound how much the distance between the
        links of each self-collision pair can change (only the joints between them count).

        Joint j's child-link origin lies on its axis; a point of link k is within ``extent_k``
        (farthest corner of its bounding box from its origin, measured once: the geometry is
        rigid in the link frame and its box contains it) of that origin, and link origins are
        rigidly spaced along the chain: ``reach[j, k] = path(j -> k) + extent_k`` bounds the
        distance of link k's points to axis j at every configuration.
        """
        p = self.bullet.p
        links = self._all_links[1:]
        origin = {
            link: np.asarray(self._bullet_link_state(self.body_id, link)[4]) for link in links
        }
        origin[-1] = np.asarray(p.getBasePositionAndOrientation(self.body_id)[0])
        parent = {link: p.getJointInfo(self.body_id, link)[16] for link in links}
        extent = {}
        for link in links:
            box = np.array(self._bullet_get_aabb(self.body_id, link))
            corners = np.array([[box[i][0], box[j][1], box[k][2]] for i in (0, 1)
                                for j in (0, 1) for k in (0, 1)])  # fmt: skip
            extent[link] = float(np.max(np.linalg.norm(corners - origin[link], axis=1)))
        reach = {-1: np.zeros(N_JOINTS)}
        for link in links:
            reach[link] = np.zeros(N_JOINTS)
            for j, joint_link in enumerate(self._joint_indices):
                path_m, node = 0.0, link
                while node not in (joint_link, -1):
                    path_m += float(np.linalg.norm(origin[node] - origin[parent[node]]))
                    node = parent[node]
                if node == joint_link:
                    reach[link][j] = path_m + extent[link]
        rows = [reach[link] for link in links]
        for link_a, link_b in self._self_collision_pairs:
            moves_a, moves_b = reach[link_a] > 0, reach[link_b] > 0
            rows.append(
                np.where(moves_a & ~moves_b, reach[link_a], 0.0)
                + np.where(moves_b & ~moves_a, reach[link_b], 0.0)
            )
        return np.array(rows)


def _pose_from_pybullet(position: Sequence[float], quaternion: Sequence[float]) -> np.ndarray:
    """(4, 4) pose from a pybullet position and (x, y, z, w) quaternion."""
    m = pybullet.getMatrixFromQuaternion(quaternion)  # row-major 3x3
    x, y, z = position
    return np.array(
        ((m[0], m[1], m[2], x), (m[3], m[4], m[5], y), (m[6], m[7], m[8], z), (0.0, 0.0, 0.0, 1.0))
    )
