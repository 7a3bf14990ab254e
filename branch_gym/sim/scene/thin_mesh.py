"""Merged low-polygon tube meshes for the many thin branches of an orchard row, built in one pass.

The scanned tree is tessellated finely, branch by branch (``sim/scene/tree_mesh.py``: ring
selection, rotation-minimising frames, 16 sides). The row around it holds hundreds of twigs a few
millimetres thick, seen from 0.3 m or more, where that care buys nothing and its per-branch
Python cost would dominate a reset. This module tessellates every polyline of a batch at once
(numpy over all of them): each is resampled to the same number of rings, each ring gets
``sides`` vertices around a frame built from the segment tangent and a fixed helper axis (a twist
along a 2-6 mm twig is invisible), and all tubes are merged into one :class:`TubeMesh`, one OBJ
file, one pybullet visual shape. That is the renderers' level-of-detail practice: few triangles
for what is thin or far (TinyRenderer's cost grows with every triangle, on screen or not:
``sim/scene/tree_mesh.py``).

Triangles wind counter-clockwise seen from outside (back faces are culled); the tip is closed by
a fan, the base left open (it sits inside the parent branch).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from branch_gym.sim.scene.tree_mesh import TubeMesh

__all__ = ["merge_meshes", "thin_tubes_mesh"]

# Helper axes for the ring frames: world z unless the tangent is nearly vertical, then world x.
_NEARLY_VERTICAL = 0.9
_TEXTURE_TILE_M = 0.03  # one bark tile per 3 cm along a twig (our choice: features of 1-4 mm)


def _resample(points: np.ndarray, radii: np.ndarray, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """(rings, 3) points and (rings,) radii at equal arc-length steps along one polyline."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    if arc[-1] <= 0:
        raise ValueError("a thin branch has zero length")
    s = np.linspace(0.0, arc[-1], rings)
    out = np.stack([np.interp(s, arc, points[:, k]) for k in range(3)], axis=1)
    return out, np.interp(s, arc, radii)


def thin_tubes_mesh(
    branches: Sequence[tuple[np.ndarray, np.ndarray]], rings: int = 4, sides: int = 4
) -> TubeMesh:
    """One merged mesh of many thin tubes.

    Args:
        branches: (points (N, 3) metres world frame base -> tip, radii (N,) metres) per branch.
        rings: Rings per branch (resampled at equal arc length; at least 2).
        sides: Vertices per ring (at least 3).

    Returns:
        The merged mesh: side walls plus a fan closing each tip.

    Raises:
        ValueError: no branch, too few rings or sides, or a malformed branch.
    """
    if not branches:
        raise ValueError("thin_tubes_mesh needs at least one branch")
    if rings < 2 or sides < 3:
        raise ValueError(f"need rings >= 2 and sides >= 3, got rings={rings}, sides={sides}")
    centres = np.empty((len(branches), rings, 3))
    radii = np.empty((len(branches), rings))
    for index, (points, branch_radii) in enumerate(branches):
        points = np.asarray(points, dtype=float)
        branch_radii = np.asarray(branch_radii, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
            raise ValueError(f"branch {index}: points must be (N >= 2, 3), got {points.shape}")
        if branch_radii.shape != (len(points),) or np.any(branch_radii <= 0):
            raise ValueError(f"branch {index}: radii must be ({len(points)},) positive values")
        centres[index], radii[index] = _resample(points, branch_radii, rings)

    tangents = np.gradient(centres, axis=1)
    tangents /= np.linalg.norm(tangents, axis=2, keepdims=True)
    helper = np.where(
        np.abs(tangents[..., 2:3]) > _NEARLY_VERTICAL, np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    )
    normals = np.cross(helper, tangents)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    binormals = np.cross(tangents, normals)
    angles = 2.0 * math.pi * np.arange(sides) / sides
    radial = (
        np.cos(angles)[None, None, :, None] * normals[:, :, None, :]
        + np.sin(angles)[None, None, :, None] * binormals[:, :, None, :]
    )  # (B, R, S, 3), counter-clockwise about the tangent
    wall = centres[:, :, None, :] + radii[:, :, None, None] * radial
    n_branches, per_branch = len(branches), rings * sides + 1  # + the tip centre
    arc = np.concatenate(
        [np.zeros((n_branches, 1)), np.cumsum(np.linalg.norm(np.diff(centres, axis=1), axis=2), 1)],
        axis=1,
    )
    u = np.broadcast_to(np.arange(sides) / sides, (n_branches, rings, sides))
    v = np.broadcast_to(arc[:, :, None] / _TEXTURE_TILE_M, (n_branches, rings, sides))
    vertices = np.concatenate([wall.reshape(n_branches, -1, 3), centres[:, -1:, :]], axis=1)
    vertex_normals = np.concatenate(
        [radial.reshape(n_branches, -1, 3), tangents[:, -1:, :]], axis=1
    )
    uvs = np.concatenate(
        [
            np.stack([u, v], axis=-1).reshape(n_branches, -1, 2),
            np.stack([np.full(n_branches, 0.5), arc[:, -1] / _TEXTURE_TILE_M], 1)[:, None, :],
        ],
        axis=1,
    )
    ring, side = np.meshgrid(np.arange(rings - 1), np.arange(sides), indexing="ij")
    a = (ring * sides + side).ravel()
    b = (ring * sides + (side + 1) % sides).ravel()
    c, d = a + sides, b + sides
    tip_ring = (rings - 1) * sides + np.arange(sides)
    tip_next = (rings - 1) * sides + (np.arange(sides) + 1) % sides
    tip_centre = np.full(sides, rings * sides)
    local = np.concatenate(
        [
            np.stack([a, b, c], 1),
            np.stack([b, d, c], 1),
            np.stack([tip_ring, tip_next, tip_centre], 1),
        ]
    )
    faces = (np.arange(n_branches)[:, None, None] * per_branch + local[None]).reshape(-1, 3)
    return TubeMesh(
        vertices=vertices.reshape(-1, 3),
        normals=vertex_normals.reshape(-1, 3),
        uvs=uvs.reshape(-1, 2),
        faces=faces.astype(np.int64),
    )


def merge_meshes(meshes: Sequence[TubeMesh]) -> TubeMesh:
    """One mesh holding every triangle of ``meshes`` (vertex indices offset)."""
    if not meshes:
        raise ValueError("merge_meshes needs at least one mesh")
    offsets = np.cumsum([0] + [len(mesh.vertices) for mesh in meshes[:-1]])
    return TubeMesh(
        vertices=np.vstack([mesh.vertices for mesh in meshes]),
        normals=np.vstack([mesh.normals for mesh in meshes]),
        uvs=np.vstack([mesh.uvs for mesh in meshes]),
        faces=np.vstack(
            [mesh.faces + offset for mesh, offset in zip(meshes, offsets, strict=True)]
        ),
    )
