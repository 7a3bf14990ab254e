"""The simulated world: one procedural tree, the UR5e and its eye-in-hand camera, wired together.

``World.reset(seed)`` rebuilds everything from scratch (``Bullet.reset`` removes every body, the
only leak-free way in pybullet), draws the tree of that seed, and places the camera at the home
pose: z_target in front of the primary at the scan start height, level and facing the branch.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from branch_gym.sim.bullet import Bullet, BulletConfig
from branch_gym.sim.robot.arm import UR5e
from branch_gym.sim.robot.config import MotionStatus, RobotConfig
from branch_gym.sim.robot.home import SCAN_START_HEIGHT_M, Z_TARGET_M, home_configuration
from branch_gym.sim.scene.camera import CameraImages, render_snapshot
from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.scene.orchard_row import ScanView
from branch_gym.sim.scene.orchard_scene import OrchardConfig, OrchardScene
from branch_gym.sim.scene.tree_scene import SceneConfig, TreeScene
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.details import grow_details
from branch_gym.sim.tree.generator import generate_tree
from branch_gym.sim.tree.ground_truth import TreeGT

WORLDS = ("clean", "orchard", "orchard_fast")
# Children of the scan seed's SeedSequence: the tree, the scanned tree's scene, the orchard.
_TREE_STREAM, _SCENE_STREAM, _ORCHARD_STREAM = 0, 1, 2
_VIEW_AXIS_SAMPLES = 5  # heights at which the scanned axis places the culling's orbit

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
        orchard: The orchard around the tree (sky, row, trellis, camera model, dormant bark and
            the tree's spurs, stubs and buds), or None for the clean world.
    """

    tree: TreeConfig = field(default_factory=TreeConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraSpec = field(default_factory=CameraSpec)
    robot: RobotConfig = field(default_factory=RobotConfig)
    bullet: BulletConfig = field(default_factory=BulletConfig)
    scan_start_height_m: float = SCAN_START_HEIGHT_M
    z_target_m: float = Z_TARGET_M
    orchard: OrchardConfig | None = None

    @classmethod
    def preset(cls, name: str, tree: TreeConfig | None = None) -> WorldConfig:
        """The world called ``name`` (:data:`WORLDS`), with ``tree`` (default: the paper's).

        Raises:
            ValueError: an unknown name, listing the valid ones.
        """
        tree = tree or TreeConfig()
        if name == "clean":
            return cls(tree=tree)
        if name == "orchard":
            return cls(tree=tree, orchard=OrchardConfig())
        if name == "orchard_fast":  # the orchard's pixel-changing speed-ups on
            return cls(tree=tree, orchard=OrchardConfig.fast())
        raise ValueError(f"unknown world {name!r}: expected one of {WORLDS}")

    @property
    def name(self) -> str:
        """ "orchard" when the orchard is on, else "clean"."""
        return "clean" if self.orchard is None else "orchard"

    def __post_init__(self) -> None:
        if self.orchard is not None and not isinstance(self.orchard, OrchardConfig):
            raise ValueError(
                f"WorldConfig.orchard must be an OrchardConfig or None, got {self.orchard!r}"
            )
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
        self.scene: TreeScene | OrchardScene | None = None
        self.robot: UR5e | None = None
        self._twist_camera = np.zeros(6)

    def reset(self, seed: int, tree: TreeGT | None = None) -> TreeGT:
        """Build a new scene: the tree of ``seed`` (or the given one) and the robot at home.

        Args:
            seed: Seeds the tree (unless ``tree`` is given) and its textures.
            tree: Use this ground truth instead of drawing one (e.g. loaded from JSON).

        Returns:
            The tree's ground truth.
        """
        orchard = self.config.orchard
        streams = np.random.SeedSequence(seed).spawn(2 if orchard is None else 3)
        if tree is None:
            tree = generate_tree(
                self.config.tree, np.random.default_rng(streams[_TREE_STREAM]), seed=seed
            )
        self.bullet.reset()
        self._twist_camera = np.zeros(6)
        if orchard is None:
            self.scene = TreeScene(
                self.bullet, tree, np.random.default_rng(streams[_SCENE_STREAM]), self.config.scene
            )
        else:
            orchard_rng = np.random.default_rng(streams[_ORCHARD_STREAM])
            if not tree.details:
                tree = replace(tree, details=grow_details(tree, orchard.details, orchard_rng))
            band_m = (
                self.config.scan_start_height_m,
                self.config.tree.secondary_base_height_range_m[1],
            )
            spec = self.config.camera
            axis = [
                self.primary_point_at_height(z, tree)
                for z in np.linspace(*band_m, _VIEW_AXIS_SAMPLES)
            ]
            view = ScanView(
                axis_xy=tuple((float(p[0]), float(p[1])) for p in axis),
                distance_m=self.config.z_target_m,
                band_m=band_m,
                half_fov_deg=(
                    math.degrees(math.atan(0.5 * spec.width / spec.fx)),
                    math.degrees(math.atan(0.5 * spec.height / spec.fy)),
                ),
            )
            self.scene = OrchardScene(
                self.bullet, tree, orchard_rng, self.config.scene, orchard,
                self.config.tree.architecture, band_m, view,
            )  # fmt: skip
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
        """RGB, metric depth and instance labels from the current camera pose.

        In the orchard the RGB comes through the camera model, blurred by the motion of the
        last commanded twist (:meth:`image_motion_px`).
        """
        self._require_reset()
        T = self.robot.T_world_camera()
        if isinstance(self.scene, OrchardScene):
            exposure_s = self.config.orchard.camera.exposure_time_s
            return self.scene.render(T, self.config.camera, self.image_motion_px(exposure_s))
        return self.scene.render(T, self.config.camera)

    def image_motion_px(self, duration_s: float) -> tuple[float, float]:
        """(du, dv) pixels the image centre moves in ``duration_s`` under the last twist.

        For a point on the optical axis at ``z_target_m`` (the scanned branch): with the camera
        twist (v, w), du/dt = fx (-v_x / z - w_y) and dv/dt = fy (-v_y / z + w_x).
        """
        v, w = self._twist_camera[:3], self._twist_camera[3:]
        z, spec = self.config.z_target_m, self.config.camera
        return (
            float(spec.fx * (-v[0] / z - w[1]) * duration_s),
            float(spec.fy * (-v[1] / z + w[0]) * duration_s),
        )

    def apply_camera_twist(self, twist_camera: np.ndarray, dt_s: float) -> MotionStatus:
        """Move the camera by a camera-frame twist [v (m/s), w (rad/s)] for ``dt_s`` seconds."""
        self._require_reset()
        self._twist_camera = np.asarray(twist_camera, dtype=float)
        return self.robot.apply_camera_twist(twist_camera, dt_s)

    def snapshot(self, width: int = 640, height: int = 480) -> np.ndarray:
        """(height, width, 3) uint8 third-person view of the scene at the camera's height."""
        self._require_reset()
        camera = self.robot.T_world_camera()[:3, 3]
        target = (0.0, 0.0, float(camera[2]))
        eye = (0.9, -1.2, float(camera[2]) + 0.35)
        return render_snapshot(
            self.bullet,
            width,
            height,
            eye=eye,
            target=target,
            background=self.scene.background if isinstance(self.scene, TreeScene) else None,
        )

    def close(self) -> None:
        """Disconnect from pybullet."""
        self.bullet.close()

    def _require_reset(self) -> None:
        if self.robot is None or self.scene is None:
            raise RuntimeError("World.reset(seed) must be called before using the world")
