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

The background (:class:`PlanarBackground`, :class:`BackgroundConfig`) is painted, not built of
bodies: it lives in ``branch_gym/sim/scene/background.py``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import pybullet

from branch_gym.sim.bullet import Bullet
from branch_gym.sim.scene.background import BackgroundConfig, PlanarBackground
from branch_gym.sim.scene.camera import CameraImages, render_camera
from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.scene.labels import FIRST_CLUTTER_LABEL, FIRST_SECONDARY_LABEL, PRIMARY_LABEL
from branch_gym.sim.scene.texture import BARK, TextureConfig, make_texture, write_png
from branch_gym.sim.scene.thin_mesh import thin_tubes_mesh
from branch_gym.sim.scene.tree_mesh import TubeMeshConfig, tube_mesh, write_obj

__all__ = [
    "FIRST_CLUTTER_LABEL",
    "FIRST_SECONDARY_LABEL",
    "PRIMARY_LABEL",
    "Branch",
    "SceneConfig",
    "Tree",
    "TreeScene",
    "create_static_body",
    "scene_folder",
]

# Spurs, stubs and buds are millimetres thick: 6 sides, 3 rings each (our choice).
DETAIL_SIDES = 6
DETAIL_RINGS = 3


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


def scene_folder() -> Path:
    """Where scene files are written during a build: one fixed folder per process.

    Fixed names matter: pybullet keeps a few hundred kB per distinct mesh or texture path for
    the life of the process (~1.6 MB per scene with fresh names, measured), but nothing when the
    same paths are written again. One build at a time per process.
    """
    return Path(tempfile.gettempdir()) / f"branch_gym_scene_{os.getpid()}"


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
        bark_image: np.ndarray | None = None,
    ) -> None:
        """Create the bodies; the caller has called ``bullet.reset()`` (no leftover bodies).

        Args:
            bullet: The world.
            tree: The tree (a ``trees.TreeGT``); its ``details`` (spurs, stubs, buds, when it
                has any) become one more link, labelled ``details_label(n_secondaries)``.
            rng: Draws the textures.
            config: Scene settings.
            bark_image: (S, S, 3) uint8 bark texture to use instead of drawing ``config.bark``.

        Raises:
            ValueError: more secondaries than labels 2..99 allow, or a malformed branch.
            RuntimeError: pybullet refused a mesh.
        """
        n_labels = len(tree.secondaries) + (1 if getattr(tree, "details", None) else 0)
        if n_labels > FIRST_CLUTTER_LABEL - FIRST_SECONDARY_LABEL:
            raise ValueError(
                f"too many secondaries ({len(tree.secondaries)}, plus a details label): labels "
                "2 + i must stay below 100"
            )
        self.bullet = bullet
        self.config = config or SceneConfig()
        self.label_of: dict[tuple[int, int], int] = {}
        # Fresh file contents behind fixed file names (module docstring, "Memory").
        bullet.p.setPhysicsEngineParameter(enableFileCaching=0)
        folder = scene_folder()
        folder.mkdir(parents=True, exist_ok=True)
        try:
            if bark_image is None:
                bark_image = make_texture(rng, self.config.bark)
            bark_png = write_png(bark_image, folder / "bark.png")
            details = list(getattr(tree, "details", []))
            tree_id = self._add_body(
                [tree.primary, *tree.secondaries], PRIMARY_LABEL, self.config.tree_mesh,
                bark_png, self.config.collision, details,
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
        details: list[Branch] | None = None,
    ) -> int:
        """One static multi-link body: base = ``branches[0]``, link k - 1 = ``branches[k]``.

        ``details``, if any, are merged into one more link after the branches (thin meshes,
        labelled with the next label; no collision shape: they are millimetres).
        """
        p = self.bullet.p
        folder = texture_png.parent
        meshes = [tube_mesh(branch.points, branch.radii, mesh_config) for branch in branches]
        if details:
            meshes.append(
                thin_tubes_mesh([(d.points, d.radii) for d in details], DETAIL_RINGS, DETAIL_SIDES)
            )
        visuals, collisions = [], []
        for k, mesh in enumerate(meshes):
            collide = collision and k < len(branches)
            obj = str(write_obj(mesh, folder / f"label_{first_label + k}.obj", texture_png))
            visuals.append(p.createVisualShape(pybullet.GEOM_MESH, fileName=obj))
            collisions.append(
                p.createCollisionShape(
                    pybullet.GEOM_MESH, fileName=obj, flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH
                )
                if collide
                else -1
            )
            if visuals[-1] < 0 or (collide and collisions[-1] < 0):
                raise RuntimeError(
                    f"pybullet could not load the mesh of branch label {first_label + k}"
                )
        body = create_static_body(self.bullet, visuals, collisions)
        for k in range(len(meshes)):
            self.label_of[(body, k - 1)] = first_label + k  # k = 0 is the base (link -1)
        return body


def create_static_body(
    bullet: Bullet, visuals: list[int], collisions: list[int] | None = None
) -> int:
    """One static multi-link body: base = the first shape, a fixed link for each other one.

    Args:
        bullet: The world.
        visuals: Visual shape ids, base first.
        collisions: Collision shape ids in the same order (-1 for none); None: no collision.

    Returns:
        The body's unique id; link k - 1 carries ``visuals[k]``.
    """
    collisions = collisions or [-1] * len(visuals)
    n_links = len(visuals) - 1
    return bullet.p.createMultiBody(
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
