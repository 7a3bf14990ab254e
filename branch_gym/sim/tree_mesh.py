"""Swept-tube triangle meshes for branches, written as OBJ files pybullet can render.

A branch is a polyline with a radius per point. :func:`tube_mesh` resamples it to rings (few
where it is straight, more where it bends), orients the rings with rotation-minimising frames (no
twist), and returns vertices, normals, texture coordinates and triangles wound counter-clockwise
seen from outside: back faces are culled, and an inward winding would show the far inner wall, a
plausible image with a +2r depth error (reference.md, "Gotchas"). Flat caps close both ends.

Texture coordinates: ``u`` runs around the circumference and wraps a whole number of times (no
seam); ``v`` is arc length along the branch in units of the same tile width, so one texture tile is
square on the surface and ``v`` is continuous from base to tip.

TinyRenderer transforms every triangle of every body for every image, on screen or not (measured:
about 0.19 us per triangle, 47k off-screen triangles add 9 ms to a 2 ms frame), so triangle counts
matter more than ring spacing along straight stretches: texturing is perspective-correct, so long
rings render the same image (measured: no pixel differs between 5 mm and 200 mm ring spacing).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Texture tile width on the surface: 512 texels wrap once around a 5 mm radius branch, i.e.
# ~0.06 mm per texel (reference.md, "Tracking on rendered images").
TILE_WIDTH_M = 2.0 * math.pi * 0.005
_DENSE_STEP_M = 0.001  # working resolution of the centerline (the ground truth is 1 mm dense)
_MIN_SEGMENT_M = 1e-9  # shorter steps are duplicate points
_SAME_TANGENT_SQUARED = 1e-18  # |t1 - reflected t0|^2 below this: no second reflection needed


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
        positive = {
            "max_chord_error_m": self.max_chord_error_m,
            "max_radius_error_m": self.max_radius_error_m,
            "max_ring_spacing_m": self.max_ring_spacing_m,
            "tile_width_m": self.tile_width_m,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")


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
    dense, dense_radii, arc = _densify(*_check_polyline(points, radii))
    rings = _select_rings(dense, dense_radii, arc, config)
    centres, ring_radii, ring_arc = dense[rings], dense_radii[rings], arc[rings]
    tangents = _ring_tangents(centres)
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


def rotation_minimising_frames(centres: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Reference normals along a curve by the double-reflection method (Wang et al. 2008).

    Args:
        centres: (R, 3) points on the curve in metres.
        tangents: (R, 3) unit tangents at those points.

    Returns:
        (R, 3) unit normals perpendicular to the tangents, turning as little as possible; the third
        axis of each right-handed frame is ``cross(tangent, normal)``.
    """
    helper = np.eye(3)[int(np.argmin(np.abs(tangents[0])))]
    normals = np.empty_like(centres)
    normals[0] = np.cross(tangents[0], helper)
    normals[0] /= np.linalg.norm(normals[0])
    for i in range(len(centres) - 1):
        v1 = centres[i + 1] - centres[i]
        c1 = float(v1 @ v1)
        reflected_normal = normals[i] - (2.0 / c1) * float(v1 @ normals[i]) * v1
        reflected_tangent = tangents[i] - (2.0 / c1) * float(v1 @ tangents[i]) * v1
        v2 = tangents[i + 1] - reflected_tangent
        c2 = float(v2 @ v2)
        n = (
            reflected_normal - (2.0 / c2) * float(v2 @ reflected_normal) * v2
            if c2 > _SAME_TANGENT_SQUARED
            else reflected_normal
        )
        n = n - float(n @ tangents[i + 1]) * tangents[i + 1]  # remove round-off drift
        normals[i + 1] = n / np.linalg.norm(n)
    return normals


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


def _check_polyline(points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(points, dtype=float)
    radii = np.asarray(radii, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise ValueError(f"points must have shape (N>=2, 3), got {points.shape}")
    if radii.shape != (len(points),):
        raise ValueError(f"radii must have shape ({len(points)},), got {radii.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(radii))):
        raise ValueError("points and radii must be finite")
    if np.any(radii <= 0):
        raise ValueError(f"radii must be positive, got min {radii.min()}")
    return points, radii


def _densify(points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample to equal steps of at most ``_DENSE_STEP_M``: points, radii and arc length (m)."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    keep = np.concatenate([[True], steps > _MIN_SEGMENT_M])
    if keep.sum() < 2:
        raise ValueError("the polyline has zero length")
    points, radii = points[keep], radii[keep]
    arc = np.concatenate([[0.0], np.cumsum(steps[keep[1:]])])
    grid = np.linspace(0.0, arc[-1], max(2, math.ceil(arc[-1] / _DENSE_STEP_M) + 1))
    dense = np.stack([np.interp(grid, arc, points[:, k]) for k in range(3)], axis=1)
    return dense, np.interp(grid, arc, radii), grid


def _select_rings(
    points: np.ndarray, radii: np.ndarray, arc: np.ndarray, config: TubeMeshConfig
) -> np.ndarray:
    """Sorted indices of the dense points that become rings.

    Ramer-Douglas-Peucker on (x, y, z, scaled r) keeps the centerline within
    ``max_chord_error_m`` of the dense one and the radius within ``max_radius_error_m``; then
    stretches longer than ``max_ring_spacing_m`` are split evenly.
    """
    radius_weight = config.max_chord_error_m / config.max_radius_error_m
    augmented = np.hstack([points, radius_weight * radii[:, None]])
    keep = {0, len(points) - 1}
    stack = [(0, len(points) - 1)]
    while stack:
        first, last = stack.pop()
        if last - first < 2:
            continue
        worst, distance = _farthest_from_chord(augmented, first, last)
        if distance > config.max_chord_error_m:
            keep.add(worst)
            stack += [(first, worst), (worst, last)]
    rings = sorted(keep)
    split = [rings[0]]
    for first, last in itertools.pairwise(rings):
        pieces = max(1, math.ceil((arc[last] - arc[first]) / config.max_ring_spacing_m - 1e-9))
        split += np.linspace(first, last, pieces + 1)[1:].round().astype(int).tolist()
    return np.unique(split)


def _farthest_from_chord(points: np.ndarray, first: int, last: int) -> tuple[int, float]:
    """Index and distance of the point of ``points[first:last+1]`` farthest from that chord."""
    chord = points[last] - points[first]
    offsets = points[first : last + 1] - points[first]
    along = np.clip(offsets @ chord / max(float(chord @ chord), _MIN_SEGMENT_M**2), 0.0, 1.0)
    distances = np.linalg.norm(offsets - along[:, None] * chord, axis=1)
    worst = int(np.argmax(distances))
    return first + worst, float(distances[worst])


def _ring_tangents(centres: np.ndarray) -> np.ndarray:
    """(R, 3) unit tangents: bisectors of the adjacent segments, segment direction at the ends."""
    segments = np.diff(centres, axis=0)
    segments /= np.linalg.norm(segments, axis=1, keepdims=True)
    tangents = np.empty_like(centres)
    tangents[0], tangents[-1] = segments[0], segments[-1]
    tangents[1:-1] = segments[:-1] + segments[1:]
    return tangents / np.linalg.norm(tangents, axis=1, keepdims=True)


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
