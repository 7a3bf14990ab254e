"""Path search on a skeleton graph, for the 2D curve fitting (``recon/curve2d/fit.py``).

:class:`SearchGraph` walks the graph by half-edges (id 2e walks edge e forward, 2e + 1 backward)
and gathers a path's pixels and radii; :func:`enumerate_paths` lists the simple paths extending
given starts over an adjacency: :func:`oriented_adjacency` (every edge along the motion
direction but level edges between junctions: primary search) or :func:`undirected_adjacency`
(secondary search).
:func:`component_reach` bounds the path length per connected component.
"""

from __future__ import annotations

import math

import numpy as np

from recon.curve2d.skeleton_graph import SkeletonGraph


class SearchGraph:
    """The skeleton graph as half-edges: id 2e walks edge e forward, 2e + 1 backward."""

    def __init__(self, graph: SkeletonGraph) -> None:
        self.graph = graph
        self._pixels: dict[int, np.ndarray] = {}

    def head(self, half_edge: int) -> int:
        edge = self.graph.edges[half_edge // 2]
        return edge.start if half_edge % 2 else edge.end

    def tail(self, half_edge: int) -> int:
        return self.head(half_edge ^ 1)

    def half_edge_pixels(self, half_edge: int) -> np.ndarray:
        """(P, 2) float pixels of a half-edge in walking order (cached)."""
        pixels = self._pixels.get(half_edge)
        if pixels is None:
            pixels = self.graph.edges[half_edge // 2].pixels_uv.astype(float)
            pixels = pixels[::-1] if half_edge % 2 else pixels
            self._pixels[half_edge] = pixels
        return pixels

    def path_pixels(self, path: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(P, 2) pixels and (P,) radii of a half-edge path; shared node pixels appear once."""
        pix = [self.half_edge_pixels(path[0])]
        pix += [self.half_edge_pixels(h)[1:] for h in path[1:]]
        rad = [self._radii(path[0])] + [self._radii(h)[1:] for h in path[1:]]
        return np.concatenate(pix), np.concatenate(rad)

    def _radii(self, half_edge: int) -> np.ndarray:
        radii = self.graph.edges[half_edge // 2].radii_px
        return radii[::-1] if half_edge % 2 else radii

    def path_nodes(self, path: tuple[int, ...]) -> list[int]:
        return [self.tail(path[0])] + [self.head(h) for h in path]

    def edge_progress_ranges(self, direction: np.ndarray) -> tuple[list[float], list[float]]:
        """Per edge, the lowest and highest pixel progress along ``direction``."""
        edges = self.graph.edges
        if not edges:
            return [], []
        lengths = np.array([len(e.pixels_uv) for e in edges])
        progress = np.concatenate([e.pixels_uv for e in edges]) @ direction
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        low = np.minimum.reduceat(progress, starts)
        high = np.maximum.reduceat(progress, starts)
        return low.tolist(), high.tolist()


def enumerate_paths(
    adjacency: list[list[tuple[int, int]]],
    starts: list[tuple[int, ...]],
    sg: SearchGraph,
    blocked: set[int],
    max_paths: int,
) -> tuple[list[tuple[int, ...]], bool]:
    """All simple half-edge paths extending the ``starts`` (each start is itself a path).

    Returns:
        The paths (at most ``max_paths``) and whether more were left unexplored.
    """
    paths: list[tuple[int, ...]] = []
    stack = [(start, set(sg.path_nodes(start))) for start in reversed(starts)]
    while stack:
        path, visited = stack.pop()
        if len(paths) == max_paths:
            return paths, True
        paths.append(path)
        for half_edge, nxt in reversed(adjacency[sg.head(path[-1])]):
            if nxt not in visited and nxt not in blocked:
                stack.append(((*path, half_edge), visited | {nxt}))
    return paths, False


def oriented_adjacency(
    sg: SearchGraph, direction: np.ndarray, crossing_level_px: float = 0.0
) -> list[list[tuple[int, int]]]:
    """Outgoing half-edges per node, each edge oriented along ``direction``.

    Args:
        sg: The graph.
        direction: (2,) unit motion direction (u, v).
        crossing_level_px: An edge joining two junctions whose ends' progress along
            ``direction`` differs by at most this gets both half-edges (the split junction of a
            crossing, ``Curve2DConfig.crossing_level_px``); 0 gives a DAG.
    """
    graph = sg.graph
    progress = graph.node_uv @ direction
    junction = np.array([kind == "junction" for kind in graph.node_kind], dtype=bool)
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(graph.n_nodes)]
    for e, edge in enumerate(graph.edges):
        # Ties in progress break by node index, so every edge gets one consistent orientation.
        forward = (progress[edge.start], edge.start) < (progress[edge.end], edge.end)
        half_edge = 2 * e if forward else 2 * e + 1
        adjacency[sg.tail(half_edge)].append((half_edge, sg.head(half_edge)))
        level = abs(progress[edge.start] - progress[edge.end]) <= crossing_level_px
        if crossing_level_px > 0.0 and level and junction[edge.start] and junction[edge.end]:
            adjacency[sg.head(half_edge)].append((half_edge ^ 1, sg.tail(half_edge)))
    return adjacency


def undirected_adjacency(sg: SearchGraph, skip_edges: set[int]) -> list[list[tuple[int, int]]]:
    adjacency: list[list[tuple[int, int]]] = [[] for _ in range(sg.graph.n_nodes)]
    for e, edge in enumerate(sg.graph.edges):
        if e not in skip_edges:
            adjacency[edge.start].append((2 * e, edge.end))
            adjacency[edge.end].append((2 * e + 1, edge.start))
    return adjacency


def component_reach(graph: SkeletonGraph) -> tuple[np.ndarray, np.ndarray]:
    """Connected component of each node, and per component an upper bound of any path's length
    in pixels (a diagonal step, sqrt(2) px, for every pixel step of its edges)."""
    parent = list(range(graph.n_nodes))

    def root(node: int) -> int:
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    for edge in graph.edges:
        parent[root(edge.start)] = root(edge.end)
    component = np.array([root(node) for node in range(graph.n_nodes)], dtype=int)
    steps = [len(edge.pixels_uv) - 1 for edge in graph.edges]
    reach = np.zeros(graph.n_nodes)
    np.add.at(reach, component[[edge.start for edge in graph.edges]], steps)
    return component, reach * math.sqrt(2.0)
