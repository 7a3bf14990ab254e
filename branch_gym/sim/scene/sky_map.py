"""The sky's radiance map: its equirectangular layout and its lookup (painting frames).

A :class:`SkyMap` holds a baked HDR map (float32, linear RGB) and samples it with
``cv2.remap`` for every sky pixel of a frame. Map column ``j`` holds azimuth ``j * 360 / width``;
row ``i`` holds zenith angle ``i * 100 / (height - 1)`` deg, i.e. elevation 90 deg (row 0) down
to -10 deg (last row). Below the horizon the map repeats the horizon (the ground covers it).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["MAX_ZENITH_DEG", "MIN_ELEVATION_DEG", "SkyMap", "texel_directions"]

MIN_ELEVATION_DEG = -10.0  # lowest elevation the map holds; below it the lookup clamps
MAX_ZENITH_DEG = 90.0 - MIN_ELEVATION_DEG  # zenith angle of the map's last row
_MAP_CHANNELS = 4  # RGB and a zero pad channel
_REMAP_MAX_SIDE = 32767  # cv2.remap's limit on each side of its output (SHRT_MAX)
_RADIANCE_GRID_COLS = 1024  # radiance() looks up flat inputs as rows of this many directions


def texel_directions(height: int, width: int, samples: int) -> np.ndarray:
    """(height * samples, width * samples, 3) unit directions of the sub-texel samples.

    Sub-samples sit symmetrically around each texel's centre, so the mean of each
    ``samples x samples`` block belongs to texel (row, column) as the module docstring places it.
    """
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    columns = (np.arange(width)[:, None] + offsets[None, :]).ravel()
    rows = (np.arange(height)[:, None] + offsets[None, :]).ravel()
    azimuth = np.radians(columns * 360.0 / width)
    zenith = np.radians(rows * MAX_ZENITH_DEG / (height - 1))
    sin_zenith = np.sin(zenith)[:, None]
    return np.stack(
        [
            sin_zenith * np.cos(azimuth)[None, :],
            sin_zenith * np.sin(azimuth)[None, :],
            np.broadcast_to(np.cos(zenith)[:, None], (len(rows), len(columns))),
        ],
        axis=-1,
    )


class SkyMap:
    """A baked sky radiance map and its bilinear lookup (wrapping in azimuth)."""

    def __init__(self, sky_map: np.ndarray) -> None:
        """Hold ``sky_map`` for lookups.

        Args:
            sky_map: (H, W, 3) linear radiance in the module's layout (H >= 2).
        """
        height, width = sky_map.shape[:2]
        # One wrapped column so that bilinear lookups across azimuth 360 -> 0 need no border, and
        # a fourth (zero) channel: cv2.remap is ~3x faster on 4-channel float images (measured).
        padded = np.zeros((height, width + 1, _MAP_CHANNELS), np.float32)
        padded[:, :width, :3] = sky_map
        padded[:, width, :3] = sky_map[:, 0]
        padded.flags.writeable = False
        self._map = padded
        self._x_scale = np.float32(width / 360.0)  # map columns per degree of azimuth
        self._y_scale = np.float32((height - 1) / MAX_ZENITH_DEG)  # map rows per degree

    @property
    def radiance_map(self) -> np.ndarray:
        """(map_height_px, map_width_px, 3) float32 read-only HDR map (see module conventions)."""
        return self._map[:, :-1, :3]

    def radiance(self, directions_world: np.ndarray) -> np.ndarray:
        """Sky radiance towards world directions (bilinear in the map, wrapping in azimuth).

        Args:
            directions_world: (N, 3) or (H, W, 3) world directions; need not be unit length.

        Returns:
            (N, 3) or (H, W, 3) float32 linear radiance (1.0 ~ a white surface in full light).
        """
        directions = np.asarray(directions_world)
        if directions.ndim not in (2, 3) or directions.shape[-1] != 3:
            raise ValueError(f"directions must be (N, 3) or (H, W, 3), got {directions.shape}")
        if directions.ndim == 3 and max(directions.shape[:2]) < _REMAP_MAX_SIDE:
            return cv2.cvtColor(self._lookup(*_planes(directions)), cv2.COLOR_RGBA2RGB)
        # cv2.remap needs both sides of its output < 32767: look up a padded (rows, cols) grid.
        flat = directions.reshape(-1, 3)
        count = len(flat)
        if count == 0:
            return np.zeros(directions.shape, np.float32)
        cols = min(count, _RADIANCE_GRID_COLS)
        rows = -(-count // cols)
        grid = np.zeros((rows * cols, 3), np.float32)
        grid[:count] = flat
        values = cv2.cvtColor(
            self._lookup(*_planes(grid.reshape(rows, cols, 3))), cv2.COLOR_RGBA2RGB
        )
        return values.reshape(-1, 3)[:count].reshape(directions.shape)

    def paint(self, out: np.ndarray, rays_world: np.ndarray, where: np.ndarray) -> None:
        """Write the sky's radiance into ``out[where]``; other pixels are left untouched.

        Args:
            out: (H, W, 3) float32 C-contiguous image, written in place.
            rays_world: (H, W, 3) world ray direction of each pixel (need not be unit length).
            where: (H, W) bool, the pixels to paint (those that see the sky).
        """
        if out.dtype != np.float32 or out.ndim != 3 or not out.flags.c_contiguous:
            raise ValueError(f"out must be C-contiguous (H, W, 3) float32, got {out.dtype}")
        if rays_world.shape != out.shape or where.shape != out.shape[:2]:
            raise ValueError(
                f"rays_world {rays_world.shape} and where {where.shape} must match out {out.shape}"
            )
        if where.dtype != np.bool_:
            raise ValueError(f"where must be bool, got {where.dtype}")
        self.paint_planes(out, *_planes(rays_world), where)

    def paint_planes(
        self, out: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, where: np.ndarray
    ) -> None:
        """:meth:`paint` with the ray directions given as three (H, W) float32 planes."""
        values = cv2.cvtColor(self._lookup(x, y, z), cv2.COLOR_RGBA2RGB)
        cv2.copyTo(values, where.view(np.uint8), out)

    def _lookup(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Direction planes (H, W) -> (H, W, 4) float32 radiance (4th channel 0) by remap."""
        horizontal, azimuth = cv2.cartToPolar(x, y, angleInDegrees=True)  # azimuth in [0, 360)
        zenith = cv2.phase(z, horizontal, angleInDegrees=True)  # zenith angle in [0, 180]
        np.multiply(azimuth, self._x_scale, out=azimuth)
        np.multiply(zenith, self._y_scale, out=zenith)
        return cv2.remap(
            self._map, azimuth, zenith, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )


def _planes(directions: np.ndarray) -> np.ndarray:
    """(H, W, 3) directions -> (3, H, W) float32 planes (one transposing copy: ~3x faster than
    cv2.split, measured)."""
    return np.ascontiguousarray(np.moveaxis(directions, -1, 0), dtype=np.float32)
