"""How many trees a benchmark needs: the power computation behind its test split.

Two policies scan the same trees, so the difference of their missed % is paired tree by tree. The
difference pooled over ``N`` trees is a ratio, ``D = sum(d_i) / sum(g_i)`` with ``d_i`` the
difference of the two policies' misses on tree ``i`` and ``g_i`` its in-scope side branches. By
the delta method its standard error is ``s / (mean(g) sqrt(N))`` with ``s`` the standard
deviation of ``d_i - D g_i``, so the 95 % interval that :func:`paired_comparison
<branch_gym.evaluation.statistics.paired_comparison>` draws by bootstrap has a half-width of
about ``z s / (mean(g) sqrt(N))`` (``z`` = 1.96), in points when multiplied by 100. From a pilot
sample of pairs, :func:`trees_for_half_width` solves that for ``N``;
:func:`simulated_half_width` checks the answer by drawing ``N`` trees from the pilot and
bootstrapping them as the benchmark will.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from branch_gym.evaluation.statistics import PERCENT, BootstrapConfig


@dataclass(frozen=True)
class PairedSample:
    """Per-tree outcomes of two policies on the same trees.

    Attributes:
        missed_a: (T,) side branches policy a missed on each tree.
        missed_b: (T,) side branches policy b missed on each tree.
        n_gt: (T,) in-scope side branches of each tree.
    """

    missed_a: np.ndarray
    missed_b: np.ndarray
    n_gt: np.ndarray

    def __post_init__(self) -> None:
        arrays = [np.asarray(v, float) for v in (self.missed_a, self.missed_b, self.n_gt)]
        if len({a.shape for a in arrays}) != 1 or arrays[0].ndim != 1 or len(arrays[0]) < 2:
            raise ValueError("PairedSample needs three 1-D arrays of the same length >= 2")
        if arrays[2].sum() <= 0:
            raise ValueError("PairedSample: the trees hold no in-scope side branch")
        if (
            np.any(arrays[0] > arrays[2])
            or np.any(arrays[1] > arrays[2])
            or np.any(np.concatenate(arrays) < 0)
        ):
            raise ValueError("PairedSample: misses must lie in [0, n_gt] on every tree")
        for name, value in zip(("missed_a", "missed_b", "n_gt"), arrays, strict=True):
            object.__setattr__(self, name, value)

    @property
    def difference_pct(self) -> float:
        """a's missed % minus b's, pooled over the trees (points)."""
        return PERCENT * float((self.missed_a - self.missed_b).sum() / self.n_gt.sum())

    @property
    def spread(self) -> float:
        """``s``: the standard deviation of ``d_i - D g_i`` (branches per tree; module doc)."""
        d = self.missed_a - self.missed_b
        ratio = d.sum() / self.n_gt.sum()
        return float(np.std(d - ratio * self.n_gt, ddof=1))


def predicted_half_width(sample: PairedSample, n_trees: int, level: float = 0.95) -> float:
    """Half-width (points) of the ``level`` interval of the paired difference on ``n_trees``
    trees like the pilot's (delta method, module docstring)."""
    if n_trees < 1:
        raise ValueError(f"n_trees must be >= 1, got {n_trees}")
    z = float(norm.ppf(0.5 + level / 2.0))
    return PERCENT * z * sample.spread / (float(sample.n_gt.mean()) * math.sqrt(n_trees))


def trees_for_half_width(sample: PairedSample, half_width_pct: float, level: float = 0.95) -> int:
    """The fewest trees whose ``level`` interval of the paired difference is at most
    +-``half_width_pct`` points (delta method, module docstring); at least 2."""
    if not half_width_pct > 0.0:
        raise ValueError(f"half_width_pct must be positive, got {half_width_pct}")
    z = float(norm.ppf(0.5 + level / 2.0))
    needed = (PERCENT * z * sample.spread / (float(sample.n_gt.mean()) * half_width_pct)) ** 2
    return max(2, math.ceil(needed))


def simulated_half_width(
    sample: PairedSample,
    n_trees: int,
    rng: np.random.Generator,
    draws: int = 20,
    config: BootstrapConfig | None = None,
) -> float:
    """Median half-width (points) of the bootstrap interval over ``draws`` benchmarks of
    ``n_trees`` trees drawn from the pilot with replacement (the benchmark's own bootstrap)."""
    config = config or BootstrapConfig()
    tail = PERCENT * (1.0 - config.level) / 2.0
    d = sample.missed_a - sample.missed_b
    widths = []
    for _ in range(draws):
        trees = rng.integers(0, len(d), n_trees)
        index = trees[rng.integers(0, n_trees, size=(config.resamples, n_trees))]
        totals = sample.n_gt[index].sum(axis=1)
        valid = totals > 0
        diffs = PERCENT * d[index].sum(axis=1)[valid] / totals[valid]
        low, high = np.percentile(diffs, [tail, PERCENT - tail])
        widths.append((high - low) / 2.0)
    return float(np.median(widths))
