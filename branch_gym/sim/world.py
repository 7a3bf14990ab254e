"""The simulated world: one procedural tree, the UR5e and its eye-in-hand camera, wired together.

``World.reset(seed)`` rebuilds everything from scratch (``Bullet.reset`` removes every body, the
only leak-free way in pybullet), draws the tree of that seed, and places the camera at the home
pose: z_target in front of the primary at the scan start height, level and facing the branch.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from branch_gym.sim.bullet import Bullet, BulletConfig
from branch_gym.sim.robot.arm import UR5e
from branch_gym.sim.robot.config import MotionStatus, RobotConfig
from branch_gym.sim.robot.home import SCAN_START_HEIGHT_M, Z_TARGET_M, home_configuration
from branch_gym.sim.scene.camera import CameraImages, render_snapshot
from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.scene.tree_scene import SceneConfig, TreeScene
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.generator import generate_tree
from branch_gym.sim.tree.ground_truth import TreeGT

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class WorldConfig:
    """Everything the world is made of.

    Attributes:
        tree: Tree distribution (the paper's by default, reference.md "Simulated world").
        scene: Meshes, textures and background.
        camera: Camera intrinsics and clipping (authors' 320x240, 42 deg HFOV).
        robot: UR5e placement, camera mount and motion checks.
        bullet: GUI / EGL / time step.
        scan_start_height_m: Camera height of the home pose (paper V-A: 0.275 m).
        z_target_m: Camera-to-branch distance at home (paper V: 0.20 m).
    """

    tree: TreeConfig = field(default_factory=TreeConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraSpec = field(default_factory=CameraSpec)
    robot: RobotConfig = field(default_factory=RobotConfig)
    bullet: BulletConfig = field(default_factory=BulletConfig)
    scan_start_height_m: float = SCAN_START_HEIGHT_M
    z_target_m: float = Z_TARGET_M

    def __post_init__(self) -> None:
        if not self.z_target_m > 0:
            raise ValueError(f"WorldConfig.z_target_m must be positive, got {self.z_target_m}")
        if not 0 < self.scan_start_height_m < 1.0:
            raise ValueError(
                "WorldConfig.scan_start_height_m must be in (0, 1) m, "
                f"got {self.scan_start_height_m}"
            )


class World:
    """One pybullet world holding a tree and the robot.

    Attributes:
        config: The world configuration.
        bullet: The pybullet client owner.
        tree: Ground truth of the current tree (after :meth:`reset`).
        scene: The tree's bodies and background.
        robot: The arm.
    """

    def __init__(self, config: WorldConfig | None = None) -> None:
        self.config = config or WorldConfig()
        self.bullet = Bullet(self.config.bullet)
        self.tree: TreeGT | None = None
        self.scene: TreeScene | None = None
        self.robot: UR5e | None = None

    def reset(self, seed: int, tree: TreeGT | None = None) -> TreeGT:
        """Build a new scene: the tree of ``seed`` (or the given one) and the robot at home.

        Args:
            seed: Seeds the tree (unless ``tree`` is given) and its textures.
            tree: Use this ground truth instead of drawing one (e.g. loaded from JSON).

        Returns:
            The tree's ground truth.
        """
        tree_seq, scene_seq = np.random.SeedSequence(seed).spawn(2)
        if tree is None:
            tree = generate_tree(self.config.tree, np.random.default_rng(tree_seq), seed=seed)
        self.bullet.reset()
        self.scene = TreeScene(
            self.bullet, tree, np.random.default_rng(scene_seq), self.config.scene
        )
        self.robot = UR5e(self.bullet, self.config.robot)
        self.robot.set_obstacles(self.scene.tree_body_ids)
        start = self.primary_point_at_height(self.config.scan_start_height_m, tree)
        home_q = home_configuration(self.robot, start, self.config.z_target_m)
        self.robot.set_joint_positions(home_q)
        self.tree = tree
        return tree

    @staticmethod
    def primary_point_at_height(height_m: float, tree: TreeGT) -> np.ndarray:
        """(3,) point of the primary centerline at ``height_m`` (interpolated; z is monotonic)."""
        pts = tree.primary.points
        return np.array(
            [np.interp(height_m, pts[:, 2], pts[:, 0]), np.interp(height_m, pts[:, 2], pts[:, 1]),
             height_m]
        )  # fmt: skip

    @property
    def T_world_camera(self) -> np.ndarray:
        """(4, 4) current camera pose (OpenCV axes)."""
        self._require_reset()
        return self.robot.T_world_camera()

    def render(self) -> CameraImages:
        """RGB, metric depth and instance labels from the current camera pose."""
        self._require_reset()
        return self.scene.render(self.robot.T_world_camera(), self.config.camera)

    def apply_camera_twist(self, twist_camera: np.ndarray, dt_s: float) -> MotionStatus:
        """Move the camera by a camera-frame twist [v (m/s), w (rad/s)] for ``dt_s`` seconds."""
        self._require_reset()
        return self.robot.apply_camera_twist(twist_camera, dt_s)

    def snapshot(self, width: int = 640, height: int = 480) -> np.ndarray:
        """(height, width, 3) uint8 third-person view of the scene at the camera's height."""
        self._require_reset()
        camera = self.robot.T_world_camera()[:3, 3]
        target = (0.0, 0.0, float(camera[2]))
        eye = (0.9, -1.2, float(camera[2]) + 0.35)
        return render_snapshot(
            self.bullet, width, height, eye=eye, target=target, background=self.scene.background
        )

    def close(self) -> None:
        """Disconnect from pybullet."""
        self.bullet.close()

    def _require_reset(self) -> None:
        if self.robot is None or self.scene is None:
            raise RuntimeError("World.reset(seed) must be called before using the world")
