"""The simulated UR5e with an eye-in-hand camera: state, kinematics, twist control and IK.

Motion is kinematic (no dynamics): a camera-frame twist becomes joint rates by damped least
squares on the pybullet Jacobian of the camera link, integrated with the midpoint rule at a fixed
control step. Each step is checked before it is kept, and a failed step leaves the robot where it
was and says why (:class:`MotionStatus`): singularity, joint limit, joint speed or collision.

Only this class should set the arm's joints: it caches the joint vector, the camera pose and the
Jacobian between steps.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import pybullet

from branch_gym.sim import ur5e
from branch_gym.sim.bullet import Bullet
from branch_gym.sim.home import BasePlacement

logger = logging.getLogger(__name__)

MotionReason = Literal["ok", "singularity", "joint_limit", "joint_speed", "collision", "timeout"]
_ZEROS6 = [0.0] * ur5e.N_JOINTS


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
        base: Base placement and home seed (``branch_gym/sim/home.py``; chosen by a sweep).
        mount: Camera mount on the flange (``branch_gym/sim/ur5e.py``).
        control_time_step_s: Largest integration step; longer commands are split into equal
            sub-steps. Our choice: one sub-step per scan control step (reference.md: ~30 steps per
            10 mm at 2.5 cm/s, i.e. ~13 ms).
        manipulability_threshold: A step whose start or end has ``sqrt(det(J J^T))`` below this
            fails with "singularity". Our choice, measured: the scan workspace stays >= 0.077 with
            the default placement (``branch_gym/sim/home.py``), so 0.01 only stops motions that
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
    """

    base: BasePlacement = field(default_factory=BasePlacement)
    mount: ur5e.CameraMountConfig = field(default_factory=ur5e.CameraMountConfig)
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
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"RobotConfig.{name} must be positive and finite, got {value}")
        for name in ("damping_max", "collision_margin_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"RobotConfig.{name} must be >= 0 and finite, got {value}")
        if self.ground_height_m is not None and not math.isfinite(self.ground_height_m):
            raise ValueError(
                f"RobotConfig.ground_height_m must be finite, got {self.ground_height_m}"
            )
        if not 0 <= self.joint_limit_margin_deg < math.degrees(ur5e.JOINT_LIMIT_RAD):
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


def _check_pose(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name} must be a finite (4, 4) transform, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} rotation part is not a rotation matrix")
    return T


class UR5e:
    """A UR5e with a camera on its flange, loaded into one :class:`Bullet` world.

    ``bullet.reset()`` removes the robot with every other body: build a new ``UR5e`` afterwards.

    Attributes:
        bullet: The world the robot lives in.
        config: Its configuration.
        body_id: pybullet body id of the arm.
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
        self._joint_indices = [names[n] for n in ur5e.LINK_NAMES]
        self._camera_link = names[ur5e.CAMERA_LINK]
        self._flange_link = names[ur5e.FLANGE_LINK]
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
        self._T_base_world = np.linalg.inv(self._T_world_base)
        self._T_flange_camera = ur5e.T_flange_camera(self.config.mount)
        self._limit_rad = ur5e.JOINT_LIMIT_RAD - math.radians(self.config.joint_limit_margin_deg)
        self._obstacle_ids: tuple[int, ...] = ()
        self._obstacle_links: list[tuple[int, range]] = []
        self._q = np.zeros(ur5e.N_JOINTS)
        self._T_world_camera = np.eye(4)
        self._J_world = np.zeros((6, ur5e.N_JOINTS))
        self.set_joint_positions(base.home_seed_q if q is None else q)

    # --- state ---------------------------------------------------------------------------

    @property
    def q(self) -> np.ndarray:
        """(6,) current joint angles in radians (a copy)."""
        return self._q.copy()

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
        get_num_joints = self.bullet.p.getNumJoints
        self._obstacle_links = [(b, range(-1, get_num_joints(b))) for b in ids]

    def set_joint_positions(self, q: np.ndarray) -> None:
        """Teleport the joints (no checks besides shape and finiteness).

        Args:
            q: (6,) joint angles in radians.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (ur5e.N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q must be a finite ({ur5e.N_JOINTS},) vector, got {q}")
        self._apply_q(q, self._world_jacobian(q))

    def _apply_q(self, q: np.ndarray, J_world: np.ndarray) -> None:
        self._bullet_reset_joints(self.body_id, self._joint_indices, [[float(v)] for v in q])
        state = self._bullet_link_state(
            self.body_id, self._camera_link, computeForwardKinematics=True
        )
        self._T_world_camera = _pose_from_pybullet(state[4], state[5])
        self._q = q.copy()
        self._J_world = J_world

    # --- kinematics ----------------------------------------------------------------------

    def T_world_camera(self) -> np.ndarray:
        """(4, 4) camera pose (OpenCV axes) in the world, from pybullet's forward kinematics."""
        return self._T_world_camera.copy()

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
        R_world_base = self._T_world_base[:3, :3]
        return np.vstack([R_world_base @ np.asarray(linear), R_world_base @ np.asarray(angular)])

    def camera_jacobian(self) -> np.ndarray:
        """(6, 6) Jacobian mapping joint rates (rad/s) to the camera twist [v, w] in camera axes."""
        return self._camera_frame(self._J_world, self._T_world_camera[:3, :3])

    @staticmethod
    def _camera_frame(J_world: np.ndarray, R_world_camera: np.ndarray) -> np.ndarray:
        J = np.empty_like(J_world)
        J[:3] = R_world_camera.T @ J_world[:3]
        J[3:] = R_world_camera.T @ J_world[3:]
        return J

    def manipulability(self) -> float:
        """``sqrt(det(J J^T))`` of the camera Jacobian at the current configuration."""
        return abs(float(np.linalg.det(self._J_world)))

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
        closest_points = self._bullet_closest_points
        get_aabb = self._bullet_get_aabb
        margin = self.config.collision_margin_m
        lower, upper = self._link_aabbs()
        moving_lower, moving_upper = lower[1:].min(axis=0) - margin, upper[1:].max(axis=0) + margin
        ground_m = self.config.ground_height_m
        if ground_m is not None and moving_lower[2] < ground_m:
            row = int(np.argmin(lower[1:, 2])) + 1
            return f"{self._link_names[self._all_links[row]]} reaches below the ground"
        for obstacle, links in self._obstacle_links:
            for link in links:
                link_lower, link_upper = get_aabb(obstacle, link)
                if np.any(moving_lower > link_upper) or np.any(moving_upper < link_lower):
                    continue
                for contact in closest_points(self.body_id, obstacle, margin, linkIndexB=link):
                    if contact[3] >= 0:
                        return f"{self._link_names[contact[3]]} touches body {obstacle}"
        if self.config.self_collision:
            a, b = self._pair_rows
            overlap = np.all(lower[a] <= upper[b] + margin, axis=1) & np.all(
                lower[b] <= upper[a] + margin, axis=1
            )
            for k in np.flatnonzero(overlap):
                link_a, link_b = self._self_collision_pairs[k]
                if closest_points(self.body_id, self.body_id, margin, link_a, link_b):
                    return f"{self._link_names[link_a]} touches {self._link_names[link_b]}"
        return None

    # --- motion --------------------------------------------------------------------------

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
        status = MotionStatus(True, "ok", self.manipulability())
        for k in range(n_steps):
            status = self._step(twist, step_s)
            if not status.ok:
                logger.debug("camera twist stopped: %s (%s)", status.reason, status.detail)
                return replace(status, elapsed_s=k * step_s)
        return replace(status, elapsed_s=dt_s)

    def _joint_rates(
        self, J_world: np.ndarray, R_world_camera: np.ndarray, twist: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """Damped least-squares joint rates for a camera-frame twist, and the manipulability."""
        U, sigma, Vt = np.linalg.svd(self._camera_frame(J_world, R_world_camera))
        gains = sigma / (sigma**2 + self._damping_sq(sigma[-1]))
        return Vt.T @ (gains * (U.T @ twist)), float(np.prod(sigma))

    def _step(self, twist: np.ndarray, step_s: float) -> MotionStatus:
        """One checked control step, integrated with the midpoint rule (second order)."""
        config = self.config
        q = self._q
        R_world_camera = self._T_world_camera[:3, :3]
        q_rate, manipulability = self._joint_rates(self._J_world, R_world_camera, twist)
        # Midpoint: the camera's mid-step orientation is known from the commanded body rate.
        q_mid = q + 0.5 * step_s * q_rate
        R_mid = R_world_camera @ ur5e.rotation_exp(0.5 * step_s * twist[3:])
        q_rate, _ = self._joint_rates(self._world_jacobian(q_mid), R_mid, twist)
        q_next = q + q_rate * step_s
        J_next = self._world_jacobian(q_next)
        manipulability_next = abs(float(np.linalg.det(J_next)))
        worst = min(manipulability, manipulability_next)
        if worst < config.manipulability_threshold:
            return MotionStatus(
                False,
                "singularity",
                worst,
                detail=f"manipulability {worst:.4g} < {config.manipulability_threshold}",
            )
        speed_ratio = np.abs(q_rate) / config.max_joint_speed_radps
        if np.any(speed_ratio > 1.0):
            joint = int(np.argmax(speed_ratio))
            return MotionStatus(
                False,
                "joint_speed",
                manipulability,
                detail=f"{ur5e.JOINT_NAMES[joint]} at {math.degrees(q_rate[joint]):.1f} deg/s",
            )
        beyond = (np.abs(q_next) > self._limit_rad) & (np.abs(q_next) > np.abs(q))
        if np.any(beyond):
            joint = int(np.argmax(beyond))
            return MotionStatus(
                False,
                "joint_limit",
                manipulability,
                detail=f"{ur5e.JOINT_NAMES[joint]} would reach "
                f"{math.degrees(q_next[joint]):.1f} deg",
            )
        J_previous = self._J_world
        self._apply_q(q_next, J_next)
        contact = self.check_collision()
        if contact is not None:
            self._apply_q(q, J_previous)
            return MotionStatus(False, "collision", manipulability, detail=contact)
        return MotionStatus(True, "ok", manipulability_next)

    def _damping_sq(self, smallest_sigma: float) -> float:
        """lambda^2 of the variable-damping DLS: 0 above the band, up to damping_max^2 at 0."""
        band = self.config.damping_sigma_band
        if smallest_sigma >= band:
            return 0.0
        return (1.0 - (smallest_sigma / band) ** 2) * self.config.damping_max**2

    def move_camera_to(
        self,
        T_world_camera_target: np.ndarray,
        speed_mps: float,
        angular_speed_radps: float = 0.5,
        max_duration_s: float | None = None,
    ) -> MotionStatus:
        """Move the camera to a pose along a straight line, turning along the shortest rotation.

        Proportional law on the world-frame pose error, saturated so that neither speed exceeds
        its limit; position and rotation errors shrink by the same factor each step, so the
        camera origin stays on the line and both arrive together.

        Args:
            T_world_camera_target: (4, 4) target camera pose.
            speed_mps: Linear speed limit of the camera origin (m/s).
            angular_speed_radps: Angular speed limit (rad/s). Our default: 0.5 rad/s.
            max_duration_s: Give up ("timeout") after this much simulated time; by default twice
                the saturated travel time plus 2 s.

        Returns:
            The status; ``elapsed_s`` is the simulated time the move took.
        """
        T_target = _check_pose(T_world_camera_target, "T_world_camera_target")
        if not (math.isfinite(speed_mps) and speed_mps > 0):
            raise ValueError(f"speed_mps must be positive, got {speed_mps}")
        if not (math.isfinite(angular_speed_radps) and angular_speed_radps > 0):
            raise ValueError(f"angular_speed_radps must be positive, got {angular_speed_radps}")
        config = self.config
        error = ur5e.pose_error(T_target, self._T_world_camera)
        if max_duration_s is None:
            travel_s = max(
                np.linalg.norm(error[:3]) / speed_mps,
                np.linalg.norm(error[3:]) / angular_speed_radps,
            )
            max_duration_s = 2.0 * travel_s + 2.0
        angle_tolerance_rad = math.radians(config.move_angle_tolerance_deg)
        elapsed_s = 0.0
        while True:
            error = ur5e.pose_error(T_target, self._T_world_camera)
            position_error_m = float(np.linalg.norm(error[:3]))
            angle_error_rad = float(np.linalg.norm(error[3:]))
            if (
                position_error_m <= config.move_position_tolerance_m
                and angle_error_rad <= angle_tolerance_rad
            ):
                return MotionStatus(True, "ok", self.manipulability(), elapsed_s)
            if elapsed_s >= max_duration_s:
                return MotionStatus(
                    False,
                    "timeout",
                    self.manipulability(),
                    elapsed_s,
                    detail=f"{position_error_m * 1e3:.2f} mm, "
                    f"{math.degrees(angle_error_rad):.3f} deg left after {elapsed_s:.2f} s",
                )
            command = config.move_gain_per_s * error
            scale = min(
                1.0,
                speed_mps / max(np.linalg.norm(command[:3]), 1e-12),
                angular_speed_radps / max(np.linalg.norm(command[3:]), 1e-12),
            )
            command *= scale
            twist = camera_twist_from_world(self._T_world_camera, command[:3], command[3:])
            status = self.apply_camera_twist(twist, config.control_time_step_s)
            elapsed_s += status.elapsed_s
            if not status.ok:
                return replace(status, elapsed_s=elapsed_s)

    # --- inverse kinematics --------------------------------------------------------------

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
        T_target = _check_pose(T_world_camera_target, "T_world_camera_target")
        q = self.q if q_seed is None else np.asarray(q_seed, dtype=float).copy()
        if q.shape != (ur5e.N_JOINTS,) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_seed must be a finite ({ur5e.N_JOINTS},) vector, got {q_seed}")
        config = self.config
        q, error = ur5e.dh_inverse_kinematics(
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


def _pose_from_pybullet(position: Sequence[float], quaternion: Sequence[float]) -> np.ndarray:
    """(4, 4) pose from a pybullet position and (x, y, z, w) quaternion."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(pybullet.getMatrixFromQuaternion(quaternion)).reshape(3, 3)
    T[:3, 3] = position
    return T
