"""Tree models as tube meshes: a ring of vertices per centerline point, written as PLY."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.geometry.frames import rotation_minimising_frames
from recon.model import BranchModel, TreeModel

PRIMARY_RGB = (139, 90, 43)
SECONDARY_RGB = (60, 160, 60)


@dataclass(frozen=True)
class TubeMeshConfig:
    """Tube tessellation.

    Attributes:
        sides: Vertices per ring.
        caps: Close both ends with a fan.
    """

    sides: int = 12
    caps: bool = True

    def __post_init__(self) -> None:
        if self.sides < 3:
            raise ValueError("TubeMeshConfig.sides must be >= 3")


def tube_mesh(
    points: np.ndarray, radii: np.ndarray, config: TubeMeshConfig | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube around a polyline (rotation-minimising frames, outward winding).

    The rings follow :func:`recon.geometry.frames.rotation_minimising_frames`, the simulator's
    tree meshes' frames.

    Args:
        points: (N, 3) centerline, metres.
        radii: (N,) radius per point, metres.
        config: Tessellation.

    Returns:
        vertices: (V, 3) float; faces: (F, 3) int vertex indices, counter-clockwise seen from
        outside. Empty arrays for fewer than two distinct points.
    """
    config = config or TubeMeshConfig()
    points = np.asarray(points, float).reshape(-1, 3)
    radii = np.asarray(radii, float).reshape(-1)
    keep = np.ones(len(points), bool)
    keep[1:] = np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9
    points, radii = points[keep], radii[keep]
    if len(points) < 2:
        return np.zeros((0, 3)), np.zeros((0, 3), int)
    tangents = np.gradient(points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = rotation_minimising_frames(points, tangents)
    binormals = np.cross(tangents, normals)
    angles = np.linspace(0.0, 2 * np.pi, config.sides, endpoint=False)
    ring = np.cos(angles)[None, :, None] * normals[:, None] + (
        np.sin(angles)[None, :, None] * binormals[:, None]
    )
    vertices = (points[:, None] + radii[:, None, None] * ring).reshape(-1, 3)
    n, s = len(points), config.sides
    faces = []
    for i in range(n - 1):
        for j in range(s):
            a, b = i * s + j, i * s + (j + 1) % s
            c, d = a + s, b + s
            faces += [(a, b, d), (a, d, c)]
    if config.caps:
        base, tip = len(vertices), len(vertices) + 1
        vertices = np.vstack([vertices, points[0], points[-1]])
        for j in range(s):
            faces.append((base, (j + 1) % s, j))
            faces.append((tip, (n - 1) * s + j, (n - 1) * s + (j + 1) % s))
    return vertices, np.asarray(faces, int)


def tree_mesh(
    model: TreeModel, config: TubeMeshConfig | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All branches of a tree model as one mesh.

    Returns:
        vertices: (V, 3) metres; faces: (F, 3) int; colors: (V, 3) uint8 (primary brown,
        secondaries green).
    """
    parts: list[tuple[BranchModel, tuple[int, int, int]]] = []
    if model.primary is not None:
        parts.append((model.primary, PRIMARY_RGB))
    parts += [(b, SECONDARY_RGB) for b in model.secondaries]
    vertices, faces, colors = [], [], []
    offset = 0
    for branch, rgb in parts:
        v, f = tube_mesh(branch.points, branch.radii, config)
        vertices.append(v)
        faces.append(f + offset)
        colors.append(np.tile(np.array(rgb, np.uint8), (len(v), 1)))
        offset += len(v)
    if not vertices:
        return np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros((0, 3), np.uint8)
    return np.vstack(vertices), np.vstack(faces), np.vstack(colors)


def write_ply(
    path: str | Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None
) -> None:
    """Write an ASCII PLY mesh (opens in MeshLab, Blender, CloudCompare, Open3D)."""
    lines = [
        "ply",
        "format ascii 1.0",
        "comment recon tree model, metres, world frame",
        f"element vertex {len(vertices)}",
        "property float x",
        "property float y",
        "property float z",
    ]
    if colors is not None:
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    lines += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    for i, v in enumerate(vertices):
        row = f"{v[0]:.6f} {v[1]:.6f} {v[2]:.6f}"
        if colors is not None:
            row += " {} {} {}".format(*colors[i])
        lines.append(row)
    lines += [f"3 {a} {b} {c}" for a, b, c in faces]
    Path(path).write_text("\n".join(lines) + "\n")


def read_ply_counts(path: str | Path) -> tuple[int, int]:
    """(vertex count, face count) from a PLY header."""
    counts = {}
    for line in Path(path).read_text().splitlines():
        if line.startswith("element"):
            _, name, count = line.split()
            counts[name] = int(count)
        if line == "end_header":
            break
    return counts.get("vertex", 0), counts.get("face", 0)
