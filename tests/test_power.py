"""The power computation that sizes a benchmark's test split, on constructed paired samples."""

from __future__ import annotations

import numpy as np
import pytest

from branch_gym.evaluation.power import (
    PairedSample,
    predicted_half_width,
    simulated_half_width,
    trees_for_half_width,
)


def _sample(p: float, branches: int = 10, trees: int = 2000) -> PairedSample:
    """Trees of ``branches`` side branches; on each, a misses one more than b with probability
    ``p``, one fewer with probability ``p``, else the same: the difference has mean 0 and
    variance 2p branches^2 per tree."""
    rng = np.random.default_rng(0)
    u = rng.random(trees)
    b = rng.integers(1, branches, trees).astype(float)
    a = b + (u < p) - ((u >= p) & (u < 2 * p))
    return PairedSample(a, b, np.full(trees, float(branches)))


def test_trees_for_one_point_match_the_closed_form() -> None:
    sample = _sample(0.05)
    # s^2 = 2p = 0.1 per tree, mean(g) = 10: N = (100 * 1.96 * sqrt(0.1) / (10 * 1))^2 = 38.4.
    assert sample.spread == pytest.approx(np.sqrt(0.1), rel=0.05)
    assert trees_for_half_width(sample, 1.0) in range(36, 42)
    assert trees_for_half_width(sample, 0.5) == pytest.approx(4 * 38.4, rel=0.1)
    assert predicted_half_width(sample, 39) == pytest.approx(1.0, rel=0.05)


def test_the_bootstrap_on_that_many_trees_gives_the_half_width() -> None:
    sample = _sample(0.05)
    n_trees = trees_for_half_width(sample, 1.0)
    width = simulated_half_width(sample, n_trees, np.random.default_rng(1), draws=40)
    assert width == pytest.approx(1.0, abs=0.2)
    assert simulated_half_width(sample, 4 * n_trees, np.random.default_rng(2)) < 0.65


def test_identical_policies_need_the_fewest_trees_and_bad_samples_are_refused() -> None:
    same = PairedSample(np.ones(5), np.ones(5), np.full(5, 3.0))
    assert same.difference_pct == 0.0 and trees_for_half_width(same, 1.0) == 2
    with pytest.raises(ValueError, match="same length"):
        PairedSample(np.ones(5), np.ones(4), np.ones(5))
    with pytest.raises(ValueError, match="no in-scope"):
        PairedSample(np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"\[0, n_gt\]"):
        PairedSample(np.array([4.0, 0.0]), np.zeros(2), np.full(2, 3.0))
    with pytest.raises(ValueError, match="positive"):
        trees_for_half_width(same, 0.0)
