"""Tracing a one-pixel skeleton into a :class:`~recon.curve2d.skeleton_graph.SkeletonGraph`.

Junction pixels (crossing number >= 3) are merged into junction nodes and endpoints become
endpoint nodes; walks along line pixels between nodes become edges. Closed loops are split,
short terminal spurs at junctions pruned, junctions left with two edges dissolved, and the
result re-indexed (:func:`build_graph`, called by ``recon/curve2d/skeleton.py``).
"""

from __future__ import annotations

from itertools import chain

import numpy as np

from recon.curve2d.skeleton_graph import SkeletonEdge, SkeletonGraph

# 8-neighbour offsets (drow, dcol) clockwise from north; the cyclic order gives crossing numbers.
_OFFSETS = np.array([(-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1)])
# Walking prefers 4-neighbours so that staircase corners are not skipped.
_WALK_ORDER = [0, 2, 4, 6, 1, 3, 5, 7]
# A crossing number (0->1 transitions around a pixel) of 3 or more marks a junction pixel.
_JUNCTION_CROSSINGS = 3
# So do 4 or more neighbours: where two thick branches cross, skeletonize can leave a 2x2 block
# whose pixels all have crossing number 2 (the arms meet diagonally), which would otherwise split
# the crossing into two unconnected arcs (measured on rendered masks after a camera rotation).
_JUNCTION_NEIGHBOURS = 4
# A walk must leave its start node by this many pixels before it may close a loop on it.
_MIN_LOOP_PIXELS = 4


def build_graph(
    skel: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    pixels_uv: np.ndarray,
    radii: np.ndarray,
    at_cut: np.ndarray,
    spur_prune_factor: float,
) -> SkeletonGraph:
    """Graph of a one-pixel skeleton that does not touch the array border.

    ``at_cut`` (M,) marks pixels whose terminal edges are never pruned as spurs.
    """
    index = np.full(skel.shape, -1, dtype=np.int32)
    index[rows, cols] = np.arange(len(rows))
    neighbours = index[rows[:, None] + _OFFSETS[:, 0], cols[:, None] + _OFFSETS[:, 1]]  # (M, 8)
    present = neighbours >= 0
    count = present.sum(axis=1)
    crossings = (~present & np.roll(present, -1, axis=1)).sum(axis=1)
    # Flat list, 8 entries per pixel in walking order, -1 for none: one container keeps the
    # garbage collector's work small.
    nb = neighbours[:, _WALK_ORDER].ravel().tolist()

    node_of = [-1] * len(rows)
    node_pixels: list[list[int]] = []
    kinds: list[str] = []
    is_junction = (crossings >= _JUNCTION_CROSSINGS) | (count >= _JUNCTION_NEIGHBOURS)
    for p in np.flatnonzero(is_junction):  # merge touching junction pixels
        if node_of[p] < 0:
            _flood_junction(int(p), len(kinds), nb, is_junction, node_of, node_pixels)
            kinds.append("junction")
    # Endpoints: one neighbour, or two that touch each other (the tip of a staircase).
    for p in np.flatnonzero((count == 1) | ((count == 2) & (crossings == 1))):
        node_of[p] = len(kinds)
        node_pixels.append([int(p)])
        kinds.append("endpoint")

    edges: list[list] = []  # [start_node, end_node, pixel index list]
    visited = bytearray(len(rows))
    seen_direct: set[tuple[int, int]] = set()
    node, scan = 0, 0
    while True:  # the node list grows when walks dead-end or closed loops need a node
        if node == len(kinds):
            while scan < len(rows) and (visited[scan] or node_of[scan] >= 0 or count[scan] == 0):
                scan += 1
            if scan == len(rows):
                break
            node_of[scan] = len(kinds)  # a closed loop without nodes: give it one
            node_pixels.append([scan])
            kinds.append("loop")
        for p in node_pixels[node]:
            for q in nb[8 * p : 8 * p + 8]:
                if q < 0 or node_of[q] == node:
                    continue
                if node_of[q] >= 0:
                    key = (min(p, q), max(p, q))
                    if key not in seen_direct:
                        seen_direct.add(key)
                        edges.append([node, node_of[q], [p, q]])
                elif not visited[q]:
                    edges.append(_walk(node, p, q, nb, node_of, visited, node_pixels, kinds))
        node += 1

    edges = _split_loops(edges, node_of, node_pixels, kinds)
    if spur_prune_factor > 0:
        edges = _prune_spurs(edges, node_pixels, kinds, radii, pixels_uv, at_cut, spur_prune_factor)
    edges = _dissolve_degree_two(edges, kinds)
    return _compact(edges, node_pixels, kinds, pixels_uv, radii)


def _flood_junction(
    seed: int,
    node: int,
    nb: list[int],
    is_junction: np.ndarray,
    node_of: list[int],
    node_pixels: list[list[int]],
) -> None:
    """Assign ``node`` to the 8-connected cluster of junction pixels containing ``seed``."""
    cluster, stack = [], [seed]
    node_of[seed] = node
    while stack:
        p = stack.pop()
        cluster.append(p)
        for q in nb[8 * p : 8 * p + 8]:
            if q >= 0 and node_of[q] < 0 and is_junction[q]:
                node_of[q] = node
                stack.append(q)
    node_pixels.append(cluster)


def _walk(
    node: int,
    start: int,
    first: int,
    nb: list[int],
    node_of: list[int],
    visited: bytearray,
    node_pixels: list[list[int]],
    kinds: list[str],
) -> list:
    """Follow line pixels from ``start`` (in ``node``) through ``first`` to the next node.

    A node pixel next to the current pixel ends the edge. Otherwise the walk continues to an
    unvisited line pixel, preferring one that does not touch the previous pixel: where a
    junction's arms meet diagonally, the pixel touching both belongs to another arm.
    """
    path = [start, first]
    visited[first] = 1
    prev, cur = start, first
    while True:
        closes_loop = len(path) > _MIN_LOOP_PIXELS
        behind = nb[8 * prev : 8 * prev + 8]
        nxt = fallback = -1
        for r in nb[8 * cur : 8 * cur + 8]:
            if r < 0:
                continue
            k = node_of[r]
            if k >= 0:
                if r != prev and (k != node or closes_loop):
                    path.append(r)
                    return [node, k, path]
            elif not visited[r]:
                if nxt < 0 and r not in behind:
                    nxt = r
                elif fallback < 0:
                    fallback = r
        nxt = nxt if nxt >= 0 else fallback
        if nxt < 0:  # dead end inside a thick blob: end the edge with a new endpoint node
            node_of[cur] = len(kinds)
            node_pixels.append([cur])
            kinds.append("endpoint")
            return [node, node_of[cur], path]
        visited[nxt] = 1
        path.append(nxt)
        prev, cur = cur, nxt


def _split_loops(
    edges: list[list], node_of: list[int], node_pixels: list[list[int]], kinds: list[str]
) -> list[list]:
    """Split each edge that starts and ends on the same node at its middle pixel."""
    out = []
    for start, end, path in edges:
        if start != end or len(path) < 3:
            out.append([start, end, path])
            continue
        mid = len(path) // 2
        node_of[path[mid]] = len(kinds)
        node_pixels.append([path[mid]])
        kinds.append("loop")
        out += [[start, len(kinds) - 1, path[: mid + 1]], [len(kinds) - 1, end, path[mid:]]]
    return out


def _degrees(edges: list[list], n_nodes: int) -> list[int]:
    degree = [0] * n_nodes
    for start, end, _ in edges:
        degree[start] += 1
        degree[end] += 1
    return degree


def _path_lengths(paths: list[list[int]], pixels_uv: np.ndarray) -> list[float]:
    """Polyline length in pixels of each path of pixel indices (each path has >= 2 pixels)."""
    if not paths:
        return []
    flat = pixels_uv[list(chain.from_iterable(paths))].astype(float)
    steps = np.append(np.linalg.norm(np.diff(flat, axis=0), axis=1), 0.0)
    ends = np.cumsum([len(path) for path in paths]) - 1
    steps[ends] = 0.0  # the step from one path's last pixel to the next path's first
    return np.add.reduceat(steps, np.concatenate([[0], ends[:-1] + 1])).tolist()


def _prune_spurs(
    edges: list[list],
    node_pixels: list[list[int]],
    kinds: list[str],
    radii: np.ndarray,
    pixels_uv: np.ndarray,
    at_cut: np.ndarray,
    factor: float,
) -> list[list]:
    """Remove short terminal edges at junctions, keeping at least two edges per junction and
    every edge that ends on a cut (``at_cut``)."""
    degree = _degrees(edges, len(kinds))
    lengths = _path_lengths([path for _, _, path in edges], pixels_uv)
    spurs_at: dict[int, list[tuple[float, int]]] = {}
    for i, (start, end, _) in enumerate(edges):
        for node, other in ((start, end), (end, start)):
            if kinds[node] == "junction" and degree[node] >= _JUNCTION_CROSSINGS:
                if degree[other] == 1 and not at_cut[node_pixels[other]].any():
                    spurs_at.setdefault(node, []).append((lengths[i], i))
    removed: set[int] = set()
    for node, terminal in spurs_at.items():
        limit = factor * float(radii[node_pixels[node]].max())
        spurs = [(length, i) for length, i in terminal if length < limit]
        if len(spurs) == degree[node]:  # all spurs: a tiny blob, keep its two longest arms
            spurs = sorted(spurs)[:-2]
        removed.update(i for _, i in spurs)
    return [e for i, e in enumerate(edges) if i not in removed]


def _dissolve_degree_two(edges: list[list], kinds: list[str]) -> list[list]:
    """Merge the two edges through every junction left with degree 2 (after spur pruning)."""
    live = dict(enumerate(edges))
    incident: dict[int, set[int]] = {}
    for i, (start, end, _) in live.items():
        incident.setdefault(start, set()).add(i)
        incident.setdefault(end, set()).add(i)
    next_id = len(edges)
    for node, kind in enumerate(kinds):
        touching = incident.get(node, set())
        if kind != "junction" or len(touching) != 2:
            continue
        i1, i2 = sorted(touching)
        (s1, e1, p1), (s2, e2, p2) = live[i1], live[i2]
        a, path_a = (s1, p1) if e1 == node else (e1, p1[::-1])  # a -> node
        b, path_b = (e2, p2) if s2 == node else (s2, p2[::-1])  # node -> b
        if a == b:
            continue  # merging would close a loop on one node
        del live[i1], live[i2]
        live[next_id] = [a, b, path_a + path_b[1:]]
        incident[node] = set()
        incident[a] = (incident[a] - {i1}) | {next_id}
        incident[b] = (incident[b] - {i2}) | {next_id}
        next_id += 1
    return list(live.values())


def _compact(
    edges: list[list],
    node_pixels: list[list[int]],
    kinds: list[str],
    pixels_uv: np.ndarray,
    radii: np.ndarray,
) -> SkeletonGraph:
    """Re-index nodes and pixels to those used by the remaining edges."""
    degree = _degrees(edges, len(kinds))
    kept_nodes = [n for n in range(len(kinds)) if degree[n] > 0]
    node_id = {n: i for i, n in enumerate(kept_nodes)}
    used = np.zeros(len(radii), dtype=bool)
    used[list(chain.from_iterable(path for _, _, path in edges))] = True
    groups = [node_pixels[n] for n in kept_nodes]
    counts = np.array([len(g) for g in groups], dtype=float)
    flat = pixels_uv[list(chain.from_iterable(groups))]
    starts = np.concatenate([[0], np.cumsum(counts[:-1])]).astype(int)
    node_uv = (
        np.add.reduceat(flat, starts, axis=0) / counts[:, None] if groups else np.zeros((0, 2))
    )
    out_edges = tuple(
        SkeletonEdge(node_id[s], node_id[e], pixels_uv[path], radii[path]) for s, e, path in edges
    )
    return SkeletonGraph(
        pixels_uv=pixels_uv[used],
        radii_px=radii[used],
        node_uv=node_uv.astype(float),
        node_kind=tuple("endpoint" if degree[n] == 1 else kinds[n] for n in kept_nodes),
        edges=out_edges,
    )
