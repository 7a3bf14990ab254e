"""The orchard world's scene: the scanned tree in a dormant row, under a sky, seen by a real camera.

:class:`OrchardScene` builds on :class:`~branch_gym.sim.scene.tree_scene.TreeScene` (the scanned
tree, now with dormant bark and its spurs, stubs and buds) and adds, all drawn from the scan's
generator:

* the row (``sim/scene/orchard_row.py``): neighbours as real geometry with true depth (one
  multi-link body, a low-polygon merged mesh per tree), the rows behind as depth-correct
  impostors (``sim/scene/impostor.py``), posts, wires and clips;
* the sky (``sim/scene/sky.py``): overcast, clear or low sun; it sets the renderer's light (sun
  direction, direct and ambient strength);
* the camera (``sim/scene/camera_model.py``): motion blur, vignetting, white balance,
  auto-exposure, noise, JPEG.

A frame is rendered in linear radiance: the bodies by pybullet (its 8-bit sRGB output taken to
linear), the empty pixels painted by :class:`~branch_gym.sim.scene.orchard_background.
OrchardBackground`; the camera model then turns radiance into the 8-bit image. Depth and labels
are exact (labels: ``sim/scene/labels.py``).
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pybullet

from branch_gym.config_utils import is_number
from branch_gym.sim.bullet import Bullet
from branch_gym.sim.scene.camera import CameraImages, Lighting, render_camera
from branch_gym.sim.scene.camera_model import CameraConfig, CameraModel
from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.scene.impostor import ImpostorPlane, row_strips
from branch_gym.sim.scene.labels import (
    FIRST_CLUTTER_LABEL,
    FIRST_ROW_TREE_LABEL,
    POST_LABEL,
    WIRE_LABEL,
    own_uprights_label,
)
from branch_gym.sim.scene.orchard_background import OrchardBackground, srgb_to_linear
from branch_gym.sim.scene.orchard_row import (
    OrchardRow,
    OrchardRowConfig,
    RowBranch,
    ScanView,
    generate_row,
)
from branch_gym.sim.scene.sky import Sky, SkyConfig
from branch_gym.sim.scene.texture import (
    ORCHARD_GROUND,
    TextureConfig,
    make_texture,
    orchard_bark,
    write_png,
)
from branch_gym.sim.scene.thin_mesh import merge_meshes, thin_tubes_mesh
from branch_gym.sim.scene.tree_mesh import TubeMesh, write_obj
from branch_gym.sim.scene.tree_scene import (
    SceneConfig,
    TreeScene,
    create_static_body,
    scene_folder,
)
from branch_gym.sim.tree.details import DetailConfig
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT

__all__ = ["OrchardConfig", "OrchardScene"]

# Level of detail of the row's meshes (our choice: twigs 1-6 mm thick seen from 0.3 m or more).
_ROW_RINGS = 3
_ROW_SIDES = 4
_POST_SIDES = 10
_WIRE_SIDES = 4
_THICK_M = 0.006  # branches thicker than this get 6 sides
# Ring spacing of the row's branches (see _lod_mesh): 0.3 times the distance to the nearest
# camera pose (a piece spans at most ~125 px), at least 1 cm; ring counts rounded up to a few
# buckets (one batch each).
_RING_SPACING_PER_M = 0.3
_MIN_RING_SPACING_M = 0.01
_RING_BUCKETS = (3, 5, 9, 17, 33, 65)
_FAR_M = 0.5  # twigs farther than this from every camera pose get 3 sides
_FAR_SIDES = 3
_LOD_ROTATION_DEG = 45.0  # camera poses for the level of detail: the paper's largest rotation
_LOD_ROTATIONS = 7
_THICK_SIDES = 6
# Wire and post colours (our choice: galvanised steel, weathered wood, green-grey steel posts).
_WIRE_RGB = (150, 150, 146)
_WOOD_POST_RGB = (104, 86, 66)
_STEEL_POST_RGB = (92, 104, 96)
_FLAT_TEXTURE_PX = 8
_STEEL_POST_PROBABILITY = 0.3  # our choice: most orchard posts are treated wood
# The renderer's light from the sky (pybullet's lighting is Lambert on the texture colour):
# its coefficients are capped so that a lit white surface stays below the 8-bit ceiling.
_MAX_AMBIENT = 0.85
_MAX_DIFFUSE = 0.8
# OrchardConfig.fast's trellis reach: over twice the ~0.65 m a scan pose can see along the row.
FAST_TRELLIS_REACH_M = 1.5


@dataclass(frozen=True)
class OrchardConfig:
    """What the orchard world adds to the clean one; every part drawn from the scan's seed.

    Attributes:
        row: Neighbours, rows behind and trellis.
        sky: The sky (kind, sun, clouds).
        camera: The photometric camera model.
        ground_texture: Grass and soil.
        details: Spurs, stubs and buds on the scanned tree (``sim/tree/details.py``).
        background_scale: The sky, ground and rows behind are painted at 1/this resolution and
            upsampled (our choice: 2; all of it is 3 m or more away, where a pixel covers 8 mm
            or more, or at infinity; it keeps a frame within twice the clean world's cost).
        trellis_reach_m: Mesh the posts, wires and clips only this far along the row (x) from
            the scanned axis, metres; None: the whole row (the default). The row's geometry
            (``OrchardScene.row``, its ground truth) keeps every part. A scan pose 0.2 m from the
            axis, turned 50 deg, sees a wire ~0.65 m along the row at most; the rest costs
            TinyRenderer its triangles (~0.4 ms a frame) and shows only in third-person views.
    """

    row: OrchardRowConfig = field(default_factory=OrchardRowConfig)
    sky: SkyConfig = field(default_factory=SkyConfig)
    camera: CameraConfig = field(default_factory=CameraConfig.realistic)
    ground_texture: TextureConfig = ORCHARD_GROUND
    details: DetailConfig = field(default_factory=DetailConfig.orchard)
    background_scale: int = 2
    trellis_reach_m: float | None = None

    def __post_init__(self) -> None:
        reach = self.trellis_reach_m
        if reach is not None and not (is_number(reach) and math.isfinite(reach) and reach > 0):
            raise ValueError(
                f"OrchardConfig.trellis_reach_m must be None or a positive number, got {reach!r}"
            )
        if not (isinstance(self.background_scale, int) and self.background_scale in (1, 2, 4)):
            raise ValueError(
                f"OrchardConfig.background_scale must be 1, 2 or 4, got {self.background_scale!r}"
            )
        for name, kind in (
            ("row", OrchardRowConfig),
            ("sky", SkyConfig),
            ("camera", CameraConfig),
            ("ground_texture", TextureConfig),
            ("details", DetailConfig),
        ):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"OrchardConfig.{name} must be a {kind.__name__}, got {getattr(self, name)!r}"
                )

    @classmethod
    def fast(cls) -> OrchardConfig:
        """The orchard with the speed-ups that change its pixels (world ``"orchard_fast"``).

        The sky, ground and rows behind painted at quarter resolution (``background_scale`` 4:
        80x60 at 320x240, a pixel 3 cm or more at 3 m), no JPEG round trip (``camera.jpeg``
        False) and the trellis meshed within ``FAST_TRELLIS_REACH_M`` of the scanned axis. Every
        draw is the default orchard's: a seed gives the same scene in both. Figures:
        ``docs/results/speed.md``.
        """
        return cls(
            background_scale=4,
            camera=replace(CameraConfig.realistic(), jpeg=False),
            trellis_reach_m=FAST_TRELLIS_REACH_M,
        )


class OrchardScene:
    """The scanned tree in its row (module docstring).

    Attributes:
        tree_scene: The scanned tree's bodies (primary, secondaries, details).
        row: The row's geometry.
        sky: The scan's sky.
        camera: The camera model (its exposure state persists over a scan).
        label_of: Instance label per (body, link), the scanned tree's and the row's.
        tree_body_ids: The scanned tree's bodies (robot contact checks).
    """

    def __init__(
        self,
        bullet: Bullet,
        tree: TreeGT,
        rng: np.random.Generator,
        scene_config: SceneConfig,
        config: OrchardConfig,
        architecture: str,
        band_m: tuple[float, float],
        view: ScanView | None = None,
    ) -> None:
        """Build the scene; the caller has called ``bullet.reset()``.

        Args:
            bullet: The world.
            tree: The scanned tree, with its details.
            rng: Source of every draw.
            scene_config: Meshes of the scanned tree.
            config: The orchard.
            architecture: The tree architecture (the row's neighbours follow it).
            band_m: (low, high) scan heights in metres.
            view: The scanning camera's poses (neighbour branches none can see are dropped).
        """
        self.bullet = bullet
        self.config = config
        self._view = view
        bark = orchard_bark(rng, scene_config.bark)
        # The orchard paints its own sky, ground and rows: the clean world's backdrop is off.
        tree_config = replace(
            scene_config, background=replace(scene_config.background, enabled=False)
        )
        self.tree_scene = TreeScene(bullet, tree, rng, tree_config, bark_image=bark)
        self.tree_body_ids = self.tree_scene.tree_body_ids
        self.label_of = dict(self.tree_scene.label_of)
        strips = row_strips(config.row)
        self.row: OrchardRow = generate_row(
            config.row, rng, tree, architecture, band_m, len(strips.strips), view
        )
        self.sky = Sky(config.sky, rng)
        self.camera = CameraModel(config.camera, rng)
        self._noise_rng = rng.spawn(1)[0]  # per-frame sensor noise
        own_uprights = own_uprights_label(len(tree.secondaries))
        if own_uprights >= FIRST_CLUTTER_LABEL:
            raise ValueError(
                f"too many secondaries ({len(tree.secondaries)}) for the orchard's labels: the "
                f"tree's uprights would take label {own_uprights}, which must stay below "
                f"{FIRST_CLUTTER_LABEL}"
            )
        folder = scene_folder()
        folder.mkdir(parents=True, exist_ok=True)
        try:
            self._add_row_body(folder, bark, own_uprights)
            self._add_trellis(folder, rng)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        impostors = [ImpostorPlane(back_row, strips) for back_row in self.row.back_rows]
        ambient, sun_light = self._light_levels()
        self.background = OrchardBackground(
            self.sky,
            make_texture(rng, config.ground_texture),
            config.ground_texture.texel_m,
            impostors,
            [FIRST_ROW_TREE_LABEL + 1 + k for k in range(len(impostors))],
            ambient,
            sun_light,
            scale=config.background_scale,
        )
        sun = self.sky.sun_direction
        self.lighting = Lighting(
            direction=tuple(float(c) for c in sun),
            colour=(1.0, 1.0, 1.0),
            ambient=ambient,
            diffuse=sun_light,
            specular=0.0,
        )

    def _light_levels(self) -> tuple[float, float]:
        """(ambient, direct) light for the renderer, from the sky (capped: module constants)."""
        ambient = float(np.clip(np.mean(self.sky.ambient_rgb), 0.05, _MAX_AMBIENT))
        sun_light = float(np.clip(self.sky.sun_radiance, 0.0, _MAX_DIFFUSE))
        return ambient, sun_light

    def _add_row_body(self, folder: Path, bark: np.ndarray, own_uprights: int) -> None:
        """One multi-link body: link k = row tree k (the UFO cordon joins the scanned tree)."""
        p = self.bullet.p
        bark_png = write_png(bark, folder / "row_bark.png")
        neighbours = [b for tree in self.row.trees if not tree.same_tree for b in tree.branches]
        own = [b for tree in self.row.trees if tree.same_tree for b in tree.branches]
        if self.row.cordon is not None:
            own.append(self.row.cordon)
        parts = [(neighbours, FIRST_ROW_TREE_LABEL), (own, own_uprights)]
        parts = [(branches, label) for branches, label in parts if branches]
        if not parts:
            return
        visuals, labels = [], []
        for k, (branches, label) in enumerate(parts):
            mesh = _lod_mesh(branches, self._view)
            obj = write_obj(mesh, folder / f"row_{k}.obj", bark_png)
            visuals.append(p.createVisualShape(pybullet.GEOM_MESH, fileName=str(obj)))
            labels.append(label)
        self._add_static_body(visuals, labels)

    def _add_trellis(self, folder: Path, rng: np.random.Generator) -> None:
        """Posts (one body) and wires with clips (another), each its own flat texture."""
        p = self.bullet.p
        if self.row.posts:
            steel = rng.random() < _STEEL_POST_PROBABILITY
            colour = _STEEL_POST_RGB if steel else _WOOD_POST_RGB
            texture = write_png(_flat_texture(colour), folder / "post.png")
            posts = [
                BranchGT(
                    np.array([[post.x_m, post.y_m, 0.0], [post.x_m, post.y_m, post.height_m]]),
                    np.full(2, post.radius_m),
                )
                for post in self.row.posts
            ]
            posts = [cut for post in posts if (cut := self._within_reach(post)) is not None]
            if posts:
                mesh = thin_tubes_mesh([(b.points, b.radii) for b in posts], 2, _POST_SIDES)
                obj = write_obj(mesh, folder / "posts.obj", texture)
                self._add_static_body(
                    [p.createVisualShape(pybullet.GEOM_MESH, fileName=str(obj))], [POST_LABEL]
                )
        wires = [*self.row.wires, *self.row.clips]
        wires = [cut for wire in wires if (cut := self._within_reach(wire)) is not None]
        if wires:
            texture = write_png(_flat_texture(_WIRE_RGB), folder / "wire.png")
            mesh = merge_meshes(
                [thin_tubes_mesh([(w.points, w.radii)], len(w.points), _WIRE_SIDES) for w in wires]
            )
            obj = write_obj(mesh, folder / "wires.obj", texture)
            self._add_static_body(
                [p.createVisualShape(pybullet.GEOM_MESH, fileName=str(obj))], [WIRE_LABEL]
            )

    def _within_reach(self, part: BranchGT) -> BranchGT | None:
        """The piece of a trellis part (points ordered along x) to mesh, or None for none of it.

        With ``OrchardConfig.trellis_reach_m`` set, the points within that distance along x of
        the scanned axis, and the next point on each side so that the cut ends outside the
        reach; without it (or without the scan's view), the whole part.
        """
        reach = self.config.trellis_reach_m
        if reach is None or self._view is None:
            return part
        axis_x = float(np.mean([xy[0] for xy in self._view.axis_xy]))
        inside = np.flatnonzero(np.abs(part.points[:, 0] - axis_x) <= reach)
        if len(inside) == 0:
            return None
        first, last = max(int(inside[0]) - 1, 0), min(int(inside[-1]) + 1, len(part.points) - 1)
        return BranchGT(part.points[first : last + 1], part.radii[first : last + 1])

    def _add_static_body(self, visuals: list[int], labels: list[int]) -> int:
        if any(v < 0 for v in visuals):
            raise RuntimeError("pybullet could not load a mesh of the orchard row")
        body = create_static_body(self.bullet, visuals)
        for k, label in enumerate(labels):
            self.label_of[(body, k - 1)] = label
        return body

    def reset_camera(self) -> None:
        """Start a new scan: forget the auto-exposure state."""
        self.camera.reset()

    def render(
        self,
        T_world_camera: np.ndarray,
        spec: CameraSpec | None = None,
        image_motion_px: tuple[float, float] | None = None,
    ) -> CameraImages:
        """RGB through the camera model, exact depth and instance labels.

        Args:
            T_world_camera: (4, 4) camera pose.
            spec: Intrinsics and clip planes.
            image_motion_px: (du, dv) image motion during the exposure (motion blur), or None.
        """
        spec = spec or CameraSpec()
        images = render_camera(
            self.bullet, T_world_camera, spec, label_of=self.label_of, lighting=self.lighting
        )
        empty = np.isinf(images.depth_m)
        radiance = srgb_to_linear(images.rgb)
        self.background.paint(radiance, images.depth_m, images.labels, empty, T_world_camera, spec)
        rgb = self.camera.expose(radiance, image_motion_px, self._noise_rng)
        return CameraImages(rgb=rgb, depth_m=images.depth_m, labels=images.labels)


def _lod_mesh(branches: list[RowBranch], view: ScanView | None) -> TubeMesh:
    """One mesh for the row's trees, the level of detail set by the distance to the camera.

    Rings: a branch is cut into pieces no longer than ``_RING_SPACING_PER_M`` times its
    distance to the nearest camera pose of the scan (at least ``_MIN_RING_SPACING_M``):
    TinyRenderer scans every pixel of a triangle's bounding box, so a long thin triangle crossing
    the image diagonally right in front of the camera costs the whole frame (measured: 11 -> 44
    ms a frame as the camera rose past a crossing branch), while short pieces cost their area.
    Sides: 6 for thick wood, 4 for twigs, 3 for twigs farther than ``_FAR_M`` from the camera.

    Args:
        branches: The branches.
        view: The scan's camera poses (None: the coarsest level everywhere).
    """
    cameras = None if view is None else _camera_positions(view)
    groups: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
    for branch in branches:
        rings, distance = _ROW_RINGS, math.inf
        if cameras is not None:
            gaps = branch.points[:, None, :] - cameras[None, :, :]
            distance = float(np.sqrt(np.min(np.einsum("pck,pck->pc", gaps, gaps))))
            spacing = max(_MIN_RING_SPACING_M, _RING_SPACING_PER_M * distance)
            length = float(np.linalg.norm(np.diff(branch.points, axis=0), axis=1).sum())
            needed = math.ceil(length / spacing) + 1
            rings = next((r for r in _RING_BUCKETS if r >= needed), _RING_BUCKETS[-1])
            rings = max(rings, _ROW_RINGS)
        if branch.radii[0] > _THICK_M:
            sides = _THICK_SIDES
        else:
            sides = _ROW_SIDES if distance < _FAR_M else _FAR_SIDES
        groups.setdefault((rings, sides), []).append((branch.points, branch.radii))
    return merge_meshes(
        [thin_tubes_mesh(group, rings, sides) for (rings, sides), group in sorted(groups.items())]
    )


def _camera_positions(view: ScanView) -> np.ndarray:
    """(C, 3) camera positions of the scan: on the orbit about the axis, at the band's heights."""
    rotations = np.radians(np.linspace(-_LOD_ROTATION_DEG, _LOD_ROTATION_DEG, _LOD_ROTATIONS))
    offsets = view.distance_m * np.stack([np.sin(rotations), -np.cos(rotations)], axis=1)
    heights = np.linspace(*view.band_m, len(view.axis_xy))
    positions = [
        np.column_stack([np.asarray(xy) + offsets, np.full(len(offsets), z)])
        for xy, z in zip(view.axis_xy, heights, strict=True)
    ]
    return np.concatenate(positions)


def _flat_texture(rgb: tuple[int, int, int]) -> np.ndarray:
    """A small uniform texture (flat-coloured materials: wire, posts)."""
    return np.full((_FLAT_TEXTURE_PX, _FLAT_TEXTURE_PX, 3), rgb, np.uint8)
