"""What lies around the scanned tree, by kind, for scoring (simulation only).

A reconstructed side branch that matches no ground-truth side branch is put down to the structure
it lies on (:func:`recon.metrics.evaluate`, ``surroundings``): the tree's own spurs, stubs and
buds, a neighbour's branch (or a UFO tree's other uprights and cordon), a trellis wire, clip or
post, the clean world's clutter; only what lies on none of them is spurious. This module reads
those structures from the world's ground truth near the scanned primary, as centerlines, and
turns them to and from JSON (a saved trial carries them, so it re-scores without a re-run).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from branch_gym.sim.scene.orchard_row import OrchardRow
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from recon.metrics import SURROUNDING_KINDS

Surroundings = dict[str, list[BranchGT]]

# Structures are kept within this distance of the scanned primary (our choice: a reconstructed
# side branch starts within 3 cm of the primary, the paper's connection rule, and the trees'
# side branches reach at most ~0.3 m: 0.5 m keeps everything one can lie on).
KEEP_WITHIN_M = 0.5
# Kept structures are resampled at this step before clipping (our choice: a quarter of the 2 cm
# matching distance the classes are decided at; the files stay small).
SAMPLE_STEP_M = 0.005
_JSON_DECIMALS = 5  # 10 um: far below the matching distance


def surroundings_of(tree: TreeGT, row: OrchardRow | None = None) -> Surroundings:
    """The structures around ``tree`` by kind (:data:`recon.metrics.SURROUNDING_KINDS`).

    Args:
        tree: The scanned tree's ground truth (its ``details`` and ``clutter`` are read).
        row: The orchard row around it (neighbours, the UFO cordon, wires, clips, posts), None in
            the clean world.

    Returns:
        Kind -> centerlines (metres, world frame) within :data:`KEEP_WITHIN_M` of the primary,
        resampled every :data:`SAMPLE_STEP_M`; kinds with nothing near are left out.
    """
    candidates: dict[str, list[BranchGT]] = {
        "detail": list(tree.details),
        "clutter": list(tree.clutter),
    }
    if row is not None:
        neighbours = [BranchGT(b.points, b.radii) for t in row.trees for b in t.branches]
        if row.cordon is not None:
            neighbours.append(row.cordon)
        posts = [
            BranchGT(
                np.array([[p.x_m, p.y_m, 0.0], [p.x_m, p.y_m, p.height_m]]), np.full(2, p.radius_m)
            )
            for p in row.posts
        ]
        candidates["neighbour"] = neighbours
        candidates["trellis"] = [*row.wires, *row.clips, *posts]
    primary = cKDTree(np.asarray(tree.primary.points, float))
    kept: Surroundings = {}
    for kind, structures in candidates.items():
        near = [part for b in structures for part in _clip(b, primary)]
        if near:
            kept[kind] = near
    return kept


def surroundings_to_json(surroundings: Surroundings) -> dict[str, list[dict]]:
    """JSON-able form (coordinates rounded to 10 um)."""
    return {
        kind: [
            {
                "points": np.round(b.points, _JSON_DECIMALS).tolist(),
                "radii": np.round(b.radii, _JSON_DECIMALS).tolist(),
            }
            for b in structures
        ]
        for kind, structures in surroundings.items()
    }


def surroundings_from_json(data: dict[str, list[dict]]) -> Surroundings:
    """Inverse of :func:`surroundings_to_json`.

    Raises:
        ValueError: an unknown kind or a malformed structure.
    """
    unknown = sorted(set(data) - set(SURROUNDING_KINDS))
    if unknown:
        raise ValueError(f"unknown surrounding kinds {unknown}; expected {SURROUNDING_KINDS}")
    return {kind: [BranchGT.from_dict(b) for b in structures] for kind, structures in data.items()}


def _clip(branch: BranchGT, primary: cKDTree) -> list[BranchGT]:
    """The runs of ``branch``, resampled, that lie within :data:`KEEP_WITHIN_M` of the primary."""
    points, radii = _resampled(branch)
    near = primary.query(points, distance_upper_bound=KEEP_WITHIN_M)[0] < KEEP_WITHIN_M
    runs, start = [], None
    for k, inside in enumerate([*near.tolist(), False]):
        if inside and start is None:
            start = k
        elif not inside and start is not None:
            # A run of one sample keeps its neighbour sample too (a centerline needs two points).
            lo, hi = (start, k) if k - start >= 2 else (max(start - 1, 0), min(k + 1, len(near)))
            if hi - lo >= 2:
                runs.append(BranchGT(points[lo:hi], radii[lo:hi]))
            start = None
    return runs


def _resampled(branch: BranchGT) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) points and (N,) radii every :data:`SAMPLE_STEP_M` along ``branch`` (ends kept)."""
    points, radii = np.asarray(branch.points, float), np.asarray(branch.radii, float)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    count = max(int(np.ceil(arc[-1] / SAMPLE_STEP_M)) + 1, 2)
    positions = np.linspace(0.0, arc[-1], count)
    if arc[-1] == 0.0:
        return points[[0, -1]], radii[[0, -1]]
    resampled = np.column_stack([np.interp(positions, arc, c) for c in points.T])
    return resampled, np.interp(positions, arc, radii)
