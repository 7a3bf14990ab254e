"""Association of lifted secondaries: the box test that skips most overlap distances.

``_boxes_apart`` lets ``SecondaryBranches`` skip the k-d-tree overlap distance of two branches
whose bounding boxes lie at least the merge distance apart. It must never change a decision:
wherever it says "apart", the overlap distance is at least that distance.
"""

from __future__ import annotations

import numpy as np
import pytest

from recon.config import ModelerConfig
from recon.model import BranchModel
from recon.model3d.secondary import (
    SecondaryBranches,
    SecondaryDetection,
    _boxes_apart,
    _overlap_distance,
)


def _branch(start: np.ndarray, direction: np.ndarray, length_m: float, n: int = 12) -> np.ndarray:
    return start + np.linspace(0.0, length_m, n)[:, None] * direction


@pytest.mark.parametrize("seed", range(5))
def test_boxes_apart_only_where_the_overlap_distance_is_at_least_the_distance(seed: int) -> None:
    rng = np.random.default_rng(seed)
    distance_m = 0.01
    apart = 0
    for _ in range(400):
        a = rng.normal(0.0, 0.01, (int(rng.integers(1, 20)), 3))
        b = rng.normal(0.0, 0.01, (int(rng.integers(1, 20)), 3)) + rng.normal(0.0, 0.02, 3)
        if _boxes_apart(a, b, distance_m):
            apart += 1
            assert _overlap_distance(a, b) >= distance_m
    assert 0 < apart < 400  # both outcomes exercised


def test_boxes_touching_at_the_distance_are_not_apart() -> None:
    # Two points exactly 1 cm apart along x: the boxes' gap equals the distance; the slack keeps
    # the exact test (the overlap distance is 1 cm, not below it) to the k-d tree.
    a = np.array([[0.0, 0.0, 0.0]])
    b = np.array([[0.01, 0.0, 0.0]])
    assert not _boxes_apart(a, b, 0.01)
    assert _boxes_apart(a, b + np.array([0.001, 0.0, 0.0]), 0.01)
    assert not _boxes_apart(a, np.empty((0, 3)), 0.01)


def test_a_redetection_joins_its_branch_and_a_distant_one_starts_another() -> None:
    config = ModelerConfig()
    branches = SecondaryBranches(config, np.random.default_rng(0))
    primary = BranchModel(
        _branch(np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.4, 40), np.full(40, 0.01)
    )
    out = np.array([1.0, 0.0, 0.0])
    first = _branch(np.array([0.0, 0.0, 0.2]), out, 0.12)
    assert branches.add_detections([SecondaryDetection(first, np.full(12, 0.004))], primary) == 1
    again = first + np.array([0.0, 0.002, 0.0])  # 2 mm off: the same branch
    elsewhere = _branch(np.array([0.0, 0.0, 0.3]), out, 0.12)  # 10 cm higher: another
    created = branches.add_detections(
        [
            SecondaryDetection(again, np.full(12, 0.004)),
            SecondaryDetection(elsewhere, np.full(12, 0.004)),
        ],
        primary,
    )
    assert created == 1
    assert len(branches._branches) == 2
    assert branches._branches[0].detections == 2
