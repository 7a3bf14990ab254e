"""A tree built into a pybullet world: textured branch meshes, clutter, and a cheap background.

:class:`TreeScene` turns a ``TreeGT`` into pybullet bodies and remembers which body and link is
which branch, so that rendered segmentation becomes instance labels (0 background, 1 primary,
2 + i secondary i, 100 + k clutter object k). The caller calls ``bullet.reset()`` before building
the next tree: removing every body is the only leak-free way (reference.md, "Costs measured").

Layout: one multi-link body for the scanned tree (base = primary, link i = secondary i) and one
for the clutter (base = clutter 0, link k - 1 = clutter k); each link has its own mesh, so the
segmentation buffer (body + link) tells the branches apart. Measured against one body per branch
(7 tree branches + 10 clutter objects, TinyRenderer, medians over a scan): the render times agree
within noise (~0.1 ms) and building is a little faster, so the fewer bodies win.

Memory: the OBJ and PNG files exist only while the bodies are created (pybullet reads them then,
for TinyRenderer and EGL alike), in one fixed folder per process with fixed file names. pybullet
caches meshes and textures by path for the life of the process: with the cache on, a rewritten
file at a known path shows the *old* mesh and texture; with fresh paths every scene, memory
grows ~1.6 MB per build. So the build turns file caching off (``enableFileCaching=0``, a
process-wide pybullet setting) and reuses the same paths: 200 rebuilds then stay flat under
TinyRenderer. The EGL plugin never frees its GL textures: ~1.4 MB per build (measured); long EGL
runs should recreate the Bullet client every few hundred scenes.

The background (:class:`PlanarBackground`) is not made of pybullet bodies: TinyRenderer's cost
follows covered pixels (a full-screen textured plane costs ~12 ms a frame, reference.md), so a
ground plane (z = 0) and a foliage wall behind the clutter are drawn by homography warps of their
textures into the pixels no body covers (~1 ms), with the exact depth of each plane: true
parallax, and the planes never hide a body (nothing may stand below the ground or behind the wall).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
import pybullet

from branch_gym.sim.bullet import Bullet
from branch_gym.sim.camera import (
    CameraImages,
    CameraSpec,
    check_pose,
    pixel_grid,
    render_camera,
)
from branch_gym.sim.texture import BARK, FOLIAGE, GROUND, TextureConfig, make_texture, write_png
from branch_gym.sim.tree_mesh import TubeMeshConfig, tube_mesh, write_obj

PRIMARY_LABEL = 1
FIRST_SECONDARY_LABEL = 2
FIRST_CLUTTER_LABEL = 100
# Background textures are tiled this many times per axis before warping (see PlanarBackground).
_PRETILE = 4


class Branch(Protocol):
    """What the scene reads of a ``trees.BranchGT``."""

    points: np.ndarray  # (N, 3) centerline in metres, world frame, base -> tip
    radii: np.ndarray  # (N,) radius in metres


class Tree(Protocol):
    """What the scene reads of a ``trees.TreeGT``."""

    primary: Branch
    secondaries: list[Branch]
    clutter: list[Branch]


@dataclass(frozen=True)
class BackgroundConfig:
    """The ground and the backdrop wall, painted where no body is.

    Attributes:
        enabled: Paint a background at all (off: the renderer's clear colour, depth inf).
        ground: Draw the ground plane z = 0.
        backdrop: Draw a vertical foliage wall facing the camera (normal -y).
        backdrop_y_m: World y of the wall (our choice: behind clutter, which stands 0.3-1.0 m
            behind the tree near y = 0).
        sky_rgb: Colour where neither plane is hit within the far clip distance.
        foliage: Wall texture (texel size in metres on the wall).
        ground_texture: Ground texture.
    """

    enabled: bool = True
    ground: bool = True
    backdrop: bool = True
    backdrop_y_m: float = 2.0
    sky_rgb: tuple[int, int, int] = (196, 212, 230)
    foliage: TextureConfig = FOLIAGE
    ground_texture: TextureConfig = GROUND

    def __post_init__(self) -> None:
        if not math.isfinite(self.backdrop_y_m):
            raise ValueError(f"backdrop_y_m must be finite, got {self.backdrop_y_m}")
        if len(self.sky_rgb) != 3 or not all(0 <= c <= 255 for c in self.sky_rgb):
            raise ValueError(f"sky_rgb must be three values in [0, 255], got {self.sky_rgb}")


@dataclass(frozen=True)
class SceneConfig:
    """How a tree is turned into bodies.

    Attributes:
        tree_mesh: Tessellation of the scanned tree (primary and secondaries).
        clutter_mesh: Tessellation of clutter (our choice: 8 sides and 0.5 mm chord error; it
            stands 0.3 m or more farther away, and every triangle costs render time).
        bark: Bark texture of all branches (one image per scene).
        background: Ground and backdrop.
        collision: Give the tree bodies triangle-mesh collision shapes (for robot contact checks).
    """

    tree_mesh: TubeMeshConfig = field(default_factory=TubeMeshConfig)
    clutter_mesh: TubeMeshConfig = field(
        default_factory=lambda: TubeMeshConfig(sides=8, max_chord_error_m=5e-4)
    )
    bark: TextureConfig = BARK
    background: BackgroundConfig = field(default_factory=BackgroundConfig)
    collision: bool = True


@dataclass(frozen=True)
class _Plane:
    """A textured plane ``{x : normal . x = offset}`` seen from the side ``normal`` points to.

    Texel (i, j) of ``texture`` lies at ``corner + texel_m * (i * axis_u + j * axis_v)``.
    """

    texture: np.ndarray  # (S, S, 3) uint8 RGB, tiling
    texel_m: float
    normal: np.ndarray  # (3,) unit
    offset: float
    corner: np.ndarray  # (3,) world point of texel (0, 0), metres
    axis_u: np.ndarray  # (3,) unit, along texture columns
    axis_v: np.ndarray  # (3,) unit, along texture rows


def _plane(
    rng: np.random.Generator,
    texture_config: TextureConfig,
    normal: np.ndarray,
    centre: np.ndarray,
    axes: tuple[np.ndarray, np.ndarray],
) -> _Plane:
    """A plane through ``centre`` whose (pre-tiled) texture is centred there."""
    texture = np.tile(make_texture(rng, texture_config), (_PRETILE, _PRETILE, 1))
    half_m = 0.5 * len(texture) * texture_config.texel_m
    corner = centre - half_m * (axes[0] + axes[1])
    return _Plane(
        texture, texture_config.texel_m, normal, float(normal @ centre), corner, axes[0], axes[1]
    )


def scene_folder() -> Path:
    """Where scene files are written during a build: one fixed folder per process.

    Fixed names matter: pybullet keeps a few hundred kB per distinct mesh or texture path for
    the life of the process (~1.6 MB per scene with fresh names, measured), but nothing when the
    same paths are written again. One build at a time per process.
    """
    return Path(tempfile.gettempdir()) / f"branch_gym_scene_{os.getpid()}"


class PlanarBackground:
    """Ground plane and backdrop wall drawn into empty pixels by homography (see module doc).

    Warping is fast only where the texel coordinates fall inside the texture image (OpenCV's
    wrap-around border is a slow per-pixel path: ~1 ms a plane, measured), so each texture is
    tiled ``_PRETILE`` times per axis (10 m at 1 cm texels) around the part the scanning camera
    sees, and only the image rows a plane shows are warped.
    """

    def __init__(self, config: BackgroundConfig, rng: np.random.Generator) -> None:
        self.config = config
        x, y, z = np.eye(3)
        self._planes: list[_Plane] = []
        if config.ground:  # centred on the ground the scanning camera sees (1-2 m ahead)
            ground_centre = np.array([0.0, 0.5 * config.backdrop_y_m, 0.0])
            self._planes.append(_plane(rng, config.ground_texture, z, ground_centre, (x, y)))
        if config.backdrop:  # centred at the scan heights (0.275-0.75 m, reference.md)
            wall_centre = np.array([0.0, config.backdrop_y_m, 0.5])
            self._planes.append(_plane(rng, config.foliage, -y, wall_centre, (x, -z)))

    def paint(
        self,
        rgb: np.ndarray,
        depth_m: np.ndarray,
        empty: np.ndarray,
        T_world_camera: np.ndarray,
        spec: CameraSpec,
    ) -> None:
        """Write the nearest plane's colour and depth into the ``empty`` pixels, in place.

        Args:
            rgb: (H, W, 3) uint8 image, C-contiguous.
            depth_m: (H, W) float32 z-depth in metres.
            empty: (H, W) bool, True where no body was drawn.
            T_world_camera: (4, 4) camera pose.
            spec: Camera intrinsics and clip planes.
        """
        if not empty.any():
            return
        T = check_pose(T_world_camera)
        rays = T[:3, :3] @ np.linalg.inv(spec.K)  # world ray (camera z = 1) = rays @ (u, v, 1)
        u, v = pixel_grid(spec)
        nearest_inverse_depth = np.full(empty.shape, 1.0 / spec.far_m, dtype=np.float32)
        nearest_plane = np.full(empty.shape, -1, dtype=np.int8)
        for index, plane in enumerate(self._planes):
            height_m = float(plane.normal @ T[:3, 3]) - plane.offset
            if height_m <= 0:  # the camera is behind the plane, which faces away from it
                continue
            # On the plane n . (c + z r) = offset, so 1 / z = -(n . r) / height: affine in (u, v).
            q = ((plane.normal @ rays) / -height_m).astype(np.float32)
            inverse_depth = q[0] * u + q[1] * v + q[2]
            nearer = inverse_depth > nearest_inverse_depth
            np.copyto(nearest_inverse_depth, inverse_depth, where=nearer)
            np.copyto(nearest_plane, np.int8(index), where=nearer)
        for index, plane in enumerate(self._planes):
            mask = (nearest_plane == index) & empty
            rows = np.flatnonzero(mask.any(axis=1))
            if len(rows) == 0:
                continue
            top, bottom = int(rows[0]), int(rows[-1]) + 1
            warped = self._warp(plane, T, spec, top, bottom)
            cv2.copyTo(warped, mask[top:bottom].view(np.uint8), rgb[top:bottom])
        sky = (nearest_plane < 0) & empty
        if sky.any():
            rgb[sky] = self.config.sky_rgb
        depth = np.divide(
            1.0, nearest_inverse_depth, where=nearest_plane >= 0, out=np.full_like(depth_m, np.inf)
        )
        np.copyto(depth_m, depth, where=empty)

    @staticmethod
    def _warp(
        plane: _Plane, T_world_camera: np.ndarray, spec: CameraSpec, top: int, bottom: int
    ) -> np.ndarray:
        """Image rows ``top:bottom`` of the plane's texture seen by the camera (nearest texel)."""
        R, centre = T_world_camera[:3, :3], T_world_camera[:3, 3]
        texels_to_camera = R.T @ np.stack(
            [plane.axis_u * plane.texel_m, plane.axis_v * plane.texel_m, plane.corner - centre],
            axis=1,
        )  # maps homogeneous texel (i, j, 1) to a camera-frame point on the plane's ray
        rows_to_pixels = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, top], [0.0, 0.0, 1.0]])
        return cv2.warpPerspective(
            plane.texture,
            np.linalg.inv(spec.K @ texels_to_camera) @ rows_to_pixels,
            (spec.width, bottom - top),
            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_WRAP,
        )


class TreeScene:
    """One tree, its clutter and the background, built into a :class:`Bullet`.

    Attributes:
        bullet: The world the bodies live in.
        config: The scene settings.
        tree_body_ids: Bodies of the scanned tree (primary and secondaries), for contact checks.
        clutter_body_ids: Bodies of the clutter (empty without clutter).
        label_of: Instance label per (body unique id, link index); link -1 is a body's base.
        background: The painter of the empty pixels, or None when the background is off.
    """

    def __init__(
        self,
        bullet: Bullet,
        tree: Tree,
        rng: np.random.Generator,
        config: SceneConfig | None = None,
    ) -> None:
        """Create the bodies; the caller has called ``bullet.reset()`` (no leftover bodies).

        Args:
            bullet: The world.
            tree: The tree (a ``trees.TreeGT``).
            rng: Draws the textures.
            config: Scene settings.

        Raises:
            ValueError: more secondaries than labels 2..99 allow, or a malformed branch.
            RuntimeError: pybullet refused a mesh.
        """
        if len(tree.secondaries) > FIRST_CLUTTER_LABEL - FIRST_SECONDARY_LABEL:
            raise ValueError(
                f"too many secondaries ({len(tree.secondaries)}): labels 2 + i must stay below 100"
            )
        self.bullet = bullet
        self.config = config or SceneConfig()
        self.label_of: dict[tuple[int, int], int] = {}
        # Fresh file contents behind fixed file names (module docstring, "Memory").
        bullet.p.setPhysicsEngineParameter(enableFileCaching=0)
        folder = scene_folder()
        folder.mkdir(parents=True, exist_ok=True)
        try:
            bark_png = write_png(make_texture(rng, self.config.bark), folder / "bark.png")
            tree_id = self._add_body(
                [tree.primary, *tree.secondaries], PRIMARY_LABEL, self.config.tree_mesh,
                bark_png, self.config.collision,
            )  # fmt: skip
            self.tree_body_ids: tuple[int, ...] = (tree_id,)
            self.clutter_body_ids: tuple[int, ...] = ()
            if tree.clutter:
                clutter_id = self._add_body(
                    list(tree.clutter), FIRST_CLUTTER_LABEL, self.config.clutter_mesh,
                    bark_png, collision=False,
                )  # fmt: skip
                self.clutter_body_ids = (clutter_id,)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        background = self.config.background
        self.background = PlanarBackground(background, rng) if background.enabled else None

    def render(self, T_world_camera: np.ndarray, spec: CameraSpec | None = None) -> CameraImages:
        """RGB, metric depth and instance labels from a camera pose (see ``render_camera``)."""
        return render_camera(
            self.bullet, T_world_camera, spec, label_of=self.label_of, background=self.background
        )

    def _add_body(
        self,
        branches: list[Branch],
        first_label: int,
        mesh_config: TubeMeshConfig,
        texture_png: Path,
        collision: bool,
    ) -> int:
        """One static multi-link body: base = ``branches[0]``, link k - 1 = ``branches[k]``."""
        p = self.bullet.p
        folder = texture_png.parent
        visuals, collisions = [], []
        for k, branch in enumerate(branches):
            mesh = tube_mesh(branch.points, branch.radii, mesh_config)
            obj = str(write_obj(mesh, folder / f"label_{first_label + k}.obj", texture_png))
            visuals.append(p.createVisualShape(pybullet.GEOM_MESH, fileName=obj))
            collisions.append(
                p.createCollisionShape(
                    pybullet.GEOM_MESH, fileName=obj, flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH
                )
                if collision
                else -1
            )
            if visuals[-1] < 0 or (collision and collisions[-1] < 0):
                raise RuntimeError(
                    f"pybullet could not load the mesh of branch label {first_label + k}"
                )
        n_links = len(branches) - 1
        body = p.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=collisions[0],
            baseVisualShapeIndex=visuals[0],
            linkMasses=[0.0] * n_links,
            linkCollisionShapeIndices=collisions[1:],
            linkVisualShapeIndices=visuals[1:],
            linkPositions=[[0.0, 0.0, 0.0]] * n_links,
            linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * n_links,
            linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n_links,
            linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n_links,
            linkParentIndices=[0] * n_links,
            linkJointTypes=[pybullet.JOINT_FIXED] * n_links,
            linkJointAxis=[[0.0, 0.0, 1.0]] * n_links,
        )
        for k in range(len(branches)):
            self.label_of[(body, k - 1)] = first_label + k  # k = 0 is the base (link -1)
        return body
