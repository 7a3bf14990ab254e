"""Swept-tube triangle meshes for branches, written as OBJ files pybullet can render.

A branch is a polyline with a radius per point. :func:`tube_mesh` resamples it to rings (few
where it is straight, more where it bends), orients the rings with rotation-minimising frames (no
twist), and returns vertices, normals, texture coordinates and triangles wound counter-clockwise
seen from outside: back faces are culled, and an inward winding would show the far inner wall, a
plausible image with a +2r depth error (reference.md, "Gotchas"). Flat caps close both ends.

Ring placement and orientation (resampling, ring selection, rotation-minimising frames) live in
``branch_gym/sim/scene/tube_rings.py``; this module builds the triangles and writes OBJ files.

Texture coordinates: ``u`` runs around the circumference and wraps a whole number of times (no
seam); ``v`` is arc length along the branch in units of the same tile width, so one texture tile is
square on the surface and ``v`` is continuous from base to tip.

TinyRenderer transforms every triangle of every body for every image, on screen or not (measured:
about 0.19 us per triangle, 47k off-screen triangles add 9 ms to a 2 ms frame), so triangle counts
matter more than ring spacing along straight stretches: texturing is perspective-correct, so long
rings render the same image (measured: no pixel differs between 5 mm and 200 mm ring spacing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from branch_gym.sim.scene.tube_rings import (
    check_polyline,
    densify,
    ring_tangents,
    rotation_minimising_frames,
    select_rings,
)
from branch_gym.sim.validation import require_positive

__all__ = ["TILE_WIDTH_M", "TubeMesh", "TubeMeshConfig", "tube_mesh", "write_obj"]

# Texture tile width on the surface: 512 texels wrap once around a 5 mm radius branch, i.e.
# ~0.06 mm per texel (reference.md, "Tracking on rendered images").
TILE_WIDTH_M = 2.0 * math.pi * 0.005


@dataclass(frozen=True)
class TubeMeshConfig:
    """How finely a branch is tessellated.

    Attributes:
        sides: Vertices per ring. 16 (our choice, measured) puts the facets at most 0.1 mm inside a
            5 mm radius and the mean silhouette width 0.6% under 2r.
        max_chord_error_m: Largest distance of the dense centerline from the ring-to-ring chords
            (our choice: well under the 0.2-0.3 mm triangulation error in reference.md).
        max_radius_error_m: Largest radius difference between the dense input and the rings.
        max_ring_spacing_m: Longest ring-to-ring distance on straight stretches (our choice).
        tile_width_m: Width of one texture tile on the surface (see :data:`TILE_WIDTH_M`).
        caps: Close both ends with flat discs.
    """

    sides: int = 16
    max_chord_error_m: float = 1e-4
    max_radius_error_m: float = 5e-5
    max_ring_spacing_m: float = 0.05
    tile_width_m: float = TILE_WIDTH_M
    caps: bool = True

    def __post_init__(self) -> None:
        if self.sides < 3:
            raise ValueError(f"sides must be at least 3, got {self.sides}")
        require_positive(
            self, "max_chord_error_m", "max_radius_error_m", "max_ring_spacing_m", "tile_width_m"
        )


@dataclass(frozen=True)
class TubeMesh:
    """A triangle mesh with per-vertex attributes (vertices repeat along the texture seam).

    Attributes:
        vertices: (V, 3) positions in metres, world frame.
        normals: (V, 3) unit outward normals.
        uvs: (V, 2) texture coordinates in tiles (u around, v along the branch).
        faces: (F, 3) int vertex indices, counter-clockwise seen from outside.
    """

    vertices: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray

    @property
    def n_triangles(self) -> int:
        """Number of triangles."""
        return len(self.faces)


def tube_mesh(
    points: np.ndarray, radii: np.ndarray, config: TubeMeshConfig | None = None
) -> TubeMesh:
    """Swept tube around a centerline.

    Args:
        points: (N, 3) centerline in metres, base -> tip (any spacing; N >= 2).
        radii: (N,) radius in metres per point.
        config: Tessellation settings.

    Returns:
        The closed mesh (side wall plus caps when ``config.caps``).

    Raises:
        ValueError: malformed points or radii, a non-positive radius, or a zero-length polyline.
    """
    config = config or TubeMeshConfig()
    dense, dense_radii, arc = densify(*check_polyline(points, radii))
    rings = select_rings(dense, dense_radii, arc, config)
    centres, ring_radii, ring_arc = dense[rings], dense_radii[rings], arc[rings]
    tangents = ring_tangents(centres)
    normals = rotation_minimising_frames(centres, tangents)
    binormals = np.cross(tangents, normals)

    sides, per_ring = config.sides, config.sides + 1  # the last column repeats the seam
    angles = 2.0 * math.pi * np.arange(per_ring) / sides
    radial = (
        np.cos(angles)[None, :, None] * normals[:, None, :]
        + np.sin(angles)[None, :, None] * binormals[:, None, :]
    )  # (R, S+1, 3): counter-clockwise about the tangent
    wall = centres[:, None, :] + ring_radii[:, None, None] * radial
    circumference_m = 2.0 * math.pi * float(np.mean(dense_radii))  # mean over arc length
    wraps = max(1, round(circumference_m / config.tile_width_m))
    u = wraps * np.arange(per_ring) / sides
    v = ring_arc * wraps / circumference_m
    wall_uvs = np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1)

    ring, side = np.meshgrid(np.arange(len(centres) - 1), np.arange(sides), indexing="ij")
    a = (ring * per_ring + side).ravel()
    b, c, d = a + 1, a + per_ring, a + per_ring + 1
    parts = [
        (
            wall.reshape(-1, 3),
            radial.reshape(-1, 3),
            wall_uvs.reshape(-1, 2),
            np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]),
        )
    ]
    if config.caps:
        first = wall.shape[0] * per_ring
        for end, outward in ((0, -tangents[0]), (-1, tangents[-1])):
            parts.append(
                _cap(centres[end], wall[end, :sides], outward, wall_uvs[end, :sides], first)
            )
            first += per_ring
    return TubeMesh(
        vertices=np.vstack([part[0] for part in parts]),
        normals=np.vstack([part[1] for part in parts]),
        uvs=np.vstack([part[2] for part in parts]),
        faces=np.vstack([part[3] for part in parts]).astype(np.int64),
    )


def write_obj(mesh: TubeMesh, path: Path, texture_png: Path | None = None) -> Path:
    """Write ``mesh`` as a Wavefront OBJ with ``vt`` and ``vn`` (and an MTL naming the texture).

    Args:
        mesh: The mesh.
        path: Target ``.obj`` path; the material file goes next to it with suffix ``.mtl``.
        texture_png: Diffuse texture, referenced by file name: it must sit in the same folder.

    Returns:
        ``path``.
    """
    path = Path(path)
    header = []
    if texture_png is not None:
        material = path.with_suffix(".mtl")
        material.write_text(
            f"newmtl bark\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd {texture_png.name}\n"
        )
        header = [f"mtllib {material.name}", "usemtl bark"]
    faces = np.repeat(mesh.faces + 1, 3, axis=1)  # v/vt/vn share one index
    body = [
        _format_rows("v", mesh.vertices, "%.6f"),
        _format_rows("vt", mesh.uvs, "%.6f"),
        _format_rows("vn", mesh.normals, "%.4f"),
        _format_rows("f", faces.reshape(-1, 3, 3), "%d/%d/%d"),
    ]
    path.write_text("\n".join(header + body) + "\n")
    return path


def _cap(
    centre: np.ndarray, ring: np.ndarray, outward: np.ndarray, ring_uvs: np.ndarray, first: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A flat fan closing one end of the tube.

    Args:
        centre: (3,) end point of the centerline.
        ring: (S, 3) end ring, counter-clockwise about the tangent.
        outward: (3,) unit normal of the cap, pointing away from the tube.
        ring_uvs: (S, 2) texture coordinates of the ring (reused: the bark runs onto the cap).
        first: Index the cap's first vertex will have in the final mesh.

    Returns:
        vertices (S+1, 3), normals (S+1, 3), uvs (S+1, 2), faces (S, 3); the centre is last.
    """
    sides = len(ring)
    j = np.arange(sides)
    current, following = first + j, first + (j + 1) % sides
    centre_index = np.full(sides, first + sides)
    counter_clockwise = float(outward @ np.cross(ring[1] - ring[0], centre - ring[0])) > 0
    faces = (
        np.stack([current, following, centre_index], 1)
        if counter_clockwise
        else np.stack([following, current, centre_index], 1)
    )
    return (
        np.vstack([ring, centre[None]]),
        np.repeat(outward[None], sides + 1, axis=0),
        np.vstack([ring_uvs, ring_uvs.mean(axis=0, keepdims=True)]),
        faces,
    )


def _format_rows(tag: str, rows: np.ndarray, fmt: str) -> str:
    """OBJ lines ``tag fmt fmt ...``, one per row of ``rows`` (N, K) or (N, K, ...).

    One C-level ``%`` over the whole array: ~10x faster than formatting row by row.
    """
    line = tag + (" " + fmt) * rows.shape[1]
    return "\n".join([line] * len(rows)) % tuple(rows.ravel().tolist())
