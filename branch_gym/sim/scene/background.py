"""The scene's background: a ground plane and a foliage wall painted into the empty pixels.

The background (:class:`PlanarBackground`) is not made of pybullet bodies: TinyRenderer's cost
follows covered pixels (a full-screen textured plane costs ~12 ms a frame, reference.md), so a
ground plane (z = 0) and a foliage wall behind the clutter are drawn by homography warps of their
textures into the pixels no body covers (~1 ms), with the exact depth of each plane: true
parallax, and the planes never hide a body (nothing may stand below the ground or behind the wall).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from branch_gym.sim.scene.camera_spec import CameraSpec, check_pose, pixel_grid
from branch_gym.sim.scene.texture import FOLIAGE, GROUND, TextureConfig, make_texture

# Background textures are tiled this many times per axis before warping (see PlanarBackground).
_PRETILE = 4


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
            inverse_depth = plane_inverse_depth(plane.normal, plane.offset, T, rays, u, v)
            if inverse_depth is None:
                continue
            nearer = inverse_depth > nearest_inverse_depth
            np.copyto(nearest_inverse_depth, inverse_depth, where=nearer)
            np.copyto(nearest_plane, np.int8(index), where=nearer)
        for index, plane in enumerate(self._planes):
            mask = (nearest_plane == index) & empty
            rows = np.flatnonzero(mask.any(axis=1))
            if len(rows) == 0:
                continue
            top, bottom = int(rows[0]), int(rows[-1]) + 1
            warped = warp_plane_rows(
                plane.texture, plane.texel_m, plane.corner, (plane.axis_u, plane.axis_v), T,
                spec, (top, bottom),
            )  # fmt: skip
            cv2.copyTo(warped, mask[top:bottom].view(np.uint8), rgb[top:bottom])
        sky = (nearest_plane < 0) & empty
        if sky.any():
            rgb[sky] = self.config.sky_rgb
        depth = np.divide(
            1.0, nearest_inverse_depth, where=nearest_plane >= 0, out=np.full_like(depth_m, np.inf)
        )
        np.copyto(depth_m, depth, where=empty)


def plane_inverse_depth(
    normal: np.ndarray,
    offset: float,
    T_world_camera: np.ndarray,
    rays: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
) -> np.ndarray | None:
    """(H, W) float32 inverse z-depth (1/m) of the plane ``normal . x = offset`` per pixel.

    Positive where the pixel's ray meets the plane in front of the camera; None when the camera
    is behind the plane (which faces away from it).

    Args:
        normal: (3,) unit normal, pointing to the side the plane is seen from.
        offset: The plane's offset in metres.
        T_world_camera: (4, 4) camera pose.
        rays: (3, 3) world ray (camera z = 1) per homogeneous pixel: ``R K^-1``.
        u: Pixel columns (broadcastable to (H, W)), float32.
        v: Pixel rows (broadcastable to (H, W)), float32.
    """
    height_m = float(normal @ T_world_camera[:3, 3]) - offset
    if height_m <= 0:
        return None
    # On the plane n . (c + z r) = offset, so 1 / z = -(n . r) / height: affine in (u, v).
    q = ((normal @ rays) / -height_m).astype(np.float32)
    return q[0] * u + q[1] * v + q[2]


def warp_plane_rows(
    texture: np.ndarray,
    texel_m: float,
    corner: np.ndarray,
    axes: tuple[np.ndarray, np.ndarray],
    T_world_camera: np.ndarray,
    spec: CameraSpec,
    rows: tuple[int, int],
    interpolation: int = cv2.INTER_NEAREST,
    border: int = cv2.BORDER_WRAP,
) -> np.ndarray:
    """Image rows ``rows[0]:rows[1]`` of a plane's texture seen by the camera.

    Args:
        texture: (S, T, C) texture; texel (i, j) lies at ``corner + texel_m (j axis_u + i
            axis_v)`` (i: row, j: column).
        texel_m: Texel size in metres.
        corner: (3,) world point of texel (0, 0).
        axes: (3,) unit vectors along the texture's columns and rows.
        T_world_camera: (4, 4) camera pose.
        spec: Intrinsics.
        rows: (top, bottom) image rows to produce.
        interpolation: OpenCV interpolation flag.
        border: OpenCV border mode outside the texture.

    Returns:
        (bottom - top, width, C) warped texture.
    """
    R, centre = T_world_camera[:3, :3], T_world_camera[:3, 3]
    top, bottom = rows
    texels_to_camera = R.T @ np.stack(
        [axes[0] * texel_m, axes[1] * texel_m, corner - centre], axis=1
    )  # maps homogeneous texel (i, j, 1) to a camera-frame point on the plane's ray
    rows_to_pixels = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, top], [0.0, 0.0, 1.0]])
    return cv2.warpPerspective(
        texture,
        np.linalg.inv(spec.K @ texels_to_camera) @ rows_to_pixels,
        (spec.width, bottom - top),
        flags=interpolation | cv2.WARP_INVERSE_MAP,
        borderMode=border,
    )
