"""Bootstrap intervals over trees and paired comparisons (branch_gym/evaluation/statistics.py)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from branch_gym.evaluation.statistics import bootstrap_ci, paired_comparison


def _trials(missed: list[int], n_gt: int = 3, time_s: float = 20.0) -> list[SimpleNamespace]:
    return [
        SimpleNamespace(
            seed=seed, scan_time_s=time_s, metrics=SimpleNamespace(n_missed=m, n_gt=n_gt)
        )
        for seed, m in enumerate(missed)
    ]


def test_the_interval_holds_the_estimate_and_narrows_with_more_trees() -> None:
    rng = np.random.default_rng(0)
    few = bootstrap_ci(_trials([0, 1, 0, 2, 1] * 2), rng)
    many = bootstrap_ci(_trials([0, 1, 0, 2, 1] * 12), rng)
    estimate = 100.0 * 4 / 15
    for ci in (few["missed_pct_ci"], many["missed_pct_ci"]):
        assert ci[0] <= estimate <= ci[1]
    assert many["missed_pct_ci"][1] - many["missed_pct_ci"][0] < (
        few["missed_pct_ci"][1] - few["missed_pct_ci"][0]
    )
    assert few["scan_time_s_ci"] == pytest.approx([20.0, 20.0])


def test_same_seed_same_intervals() -> None:
    trials = _trials([0, 1, 0, 2, 1, 0, 0, 3])
    assert bootstrap_ci(trials, np.random.default_rng(5)) == bootstrap_ci(
        trials, np.random.default_rng(5)
    )


def test_a_consistent_win_is_significant_and_a_tie_is_not() -> None:
    rng = np.random.default_rng(1)
    better, worse = _trials([0] * 12, time_s=30.0), _trials([1] * 12)
    win = paired_comparison(better, worse, rng)
    assert win["wins"] == 12 and win["losses"] == 0
    assert win["missed_pct_diff"] == pytest.approx(-100.0 / 3)
    assert win["missed_pct_diff_ci"][1] < 0.0 and win["sign_test_p"] < 0.001
    assert win["scan_time_s_diff"] == pytest.approx(10.0)
    assert win["missed_ratio"] == 0.0 and win["missed_ratio_ci"] == [0.0, 0.0]
    tie = paired_comparison(worse, worse, rng)
    assert tie["ties"] == 12 and tie["sign_test_p"] == 1.0 and tie["missed_pct_diff"] == 0.0
    assert tie["missed_ratio"] == 1.0 and tie["missed_ratio_ci"] == [1.0, 1.0]
    assert paired_comparison(worse, better, rng)["missed_ratio"] is None  # b missed none


def test_the_ratio_of_misses_carries_its_interval() -> None:
    """Half the misses on every other tree: ratio 0.5, an interval around it from resampling."""
    a = _trials([1, 0] * 20)
    b = _trials([1, 1] * 20)
    comparison = paired_comparison(a, b, np.random.default_rng(3))
    assert comparison["missed_ratio"] == pytest.approx(0.5)
    low, high = comparison["missed_ratio_ci"]
    assert 0.3 < low < 0.5 < high < 0.7


def test_different_trees_are_refused() -> None:
    a, b = _trials([0, 1]), _trials([0, 1, 2])
    with pytest.raises(ValueError, match="same tree seeds"):
        paired_comparison(a, b, np.random.default_rng(0))
