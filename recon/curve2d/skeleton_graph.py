"""The skeleton graph of a branch mask: nodes are endpoints and junctions, edges carry the
ordered pixel path between them with a radius per pixel (``recon/curve2d/skeleton.py`` builds it).

All pixel coordinates are ``(u, v)`` = (column, row), as in ``recon.camera``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class SkeletonEdge:
    """A run of skeleton pixels between two graph nodes.

    Attributes:
        start: Node index at ``pixels_uv[0]``.
        end: Node index at ``pixels_uv[-1]`` (never equal to ``start``: loops are split).
        pixels_uv: (P, 2) int pixel path (u, v), ordered from ``start`` to ``end``, P >= 2.
        radii_px: (P,) radius in pixels at each path pixel.
    """

    start: int
    end: int
    pixels_uv: np.ndarray
    radii_px: np.ndarray

    @property
    def length_px(self) -> float:
        """Polyline length of the pixel path in pixels."""
        return float(np.linalg.norm(np.diff(self.pixels_uv, axis=0), axis=1).sum())


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class SkeletonGraph:
    """Skeleton pixels and the graph of endpoints, junctions and the paths between them.

    Attributes:
        pixels_uv: (M, 2) int skeleton pixels (u, v) that lie on some edge.
        radii_px: (M,) radius in pixels of each skeleton pixel.
        node_uv: (n, 2) float node positions (mean of the node's pixels).
        node_kind: Per node ``"endpoint"``, ``"junction"`` or ``"loop"`` (a node inserted to
            split a closed loop into two edges).
        edges: The graph's edges.
        bridge_uv: (B, 2) int pixels (u, v) drawn to bridge gaps between skeleton components
            (``recon/curve2d/skeleton_bridge.py``); they lie off the mask.
    """

    pixels_uv: np.ndarray
    radii_px: np.ndarray
    node_uv: np.ndarray
    node_kind: tuple[str, ...]
    edges: tuple[SkeletonEdge, ...]
    bridge_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=int))
    _incident: tuple[tuple[int, ...], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        incident: list[list[int]] = [[] for _ in self.node_kind]
        for i, edge in enumerate(self.edges):
            incident[edge.start].append(i)
            incident[edge.end].append(i)
        object.__setattr__(self, "_incident", tuple(tuple(x) for x in incident))

    @property
    def n_nodes(self) -> int:
        return len(self.node_kind)

    def incident_edges(self, node: int) -> tuple[int, ...]:
        """Indices of the edges touching ``node``."""
        return self._incident[node]

    def nearest_pixel(self, points_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest skeleton pixel of each (N, 2) point (u, v).

        Returns:
            dist_px: (N,) distance in pixels (inf when the skeleton is empty); index: (N,) row of
            ``pixels_uv`` (-1 when empty).
        """
        points_uv = np.asarray(points_uv, dtype=float).reshape(-1, 2)
        if len(self.pixels_uv) == 0:
            return np.full(len(points_uv), np.inf), np.full(len(points_uv), -1)
        dist, index = cKDTree(self.pixels_uv).query(points_uv)
        return dist, index
