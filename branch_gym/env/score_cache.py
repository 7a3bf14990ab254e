"""Scoring against the ground truth only when the score can have changed.

:func:`recon.metrics.evaluate` depends on the model's branch arrays (points and radii, in order)
and, through the scanned height, only on which ground-truth secondaries are in scope (those whose
base lies below ``scanned_top_z_m + gt_base_margin_m``, recon/metrics.py). A step that leaves both
unchanged (an Inconsistent iteration, most rotation steps) gets the previous score with the new
height. The model-changed signal is computed here, from the arrays themselves: ``recon`` keeps no
version counter.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from branch_gym.sim.tree.ground_truth import TreeGT
from branch_gym.surroundings import Surroundings
from recon.metrics import MetricsConfig, TreeMetrics, TruthIndex, evaluate, index_truth
from recon.model import BranchModel, TreeModel

_Fingerprint = tuple[tuple[np.ndarray, np.ndarray], ...]


def _fingerprint(model: TreeModel) -> _Fingerprint:
    """Copies of every branch's (points, radii), primary first (a missing primary is empty)."""
    branches: list[BranchModel | None] = [model.primary, *model.secondaries]
    return tuple(
        (np.zeros((0, 3)), np.zeros(0))
        if branch is None
        else (np.array(branch.points, float), np.array(branch.radii, float))
        for branch in branches
    )


def _same(a: _Fingerprint, b: _Fingerprint) -> bool:
    return len(a) == len(b) and all(
        np.array_equal(pa, pb) and np.array_equal(ra, rb)
        for (pa, ra), (pb, rb) in zip(a, b, strict=True)
    )


class ScoreCache:
    """``evaluate(model, tree, scanned_top_z_m=top)``, recomputed only when it can change.

    Args:
        enabled: False scores every call (the reference path).
        config: The metrics configuration :func:`recon.metrics.evaluate` uses (its default).
    """

    def __init__(self, enabled: bool = True, config: MetricsConfig | None = None) -> None:
        self.enabled = enabled
        self.config = config or MetricsConfig()
        self.evaluations = 0
        self.reset()

    def reset(self) -> None:
        """Forget the cached score and the prepared ground truth (a new episode)."""
        self._truth: TreeGT | None = None
        self._truth_index: TruthIndex | None = None
        self._key: tuple[int, int] | None = None
        self._fingerprint: _Fingerprint = ()
        self._metrics: TreeMetrics | None = None

    def score(
        self,
        model: TreeModel,
        tree: TreeGT,
        scanned_top_z_m: float,
        surroundings: Surroundings | None = None,
        planned_top_z_m: float | None = None,
    ) -> TreeMetrics:
        """The model's metrics against ``tree`` with the camera at ``scanned_top_z_m``.

        Args:
            model: The reconstruction.
            tree: The ground truth.
            scanned_top_z_m: The height the scan reached (m).
            surroundings: The structures around ``tree`` (read once per tree).
            planned_top_z_m: The height the scan is to reach (m; ``recon.metrics.evaluate``).
        """
        base_z = np.array([branch.points[0][2] for branch in tree.secondaries])
        in_scope = int(np.sum(base_z <= scanned_top_z_m + self.config.gt_base_margin_m))
        key = (id(tree), in_scope)
        fingerprint = _fingerprint(model) if self.enabled else ()
        if (
            self.enabled
            and self._metrics is not None
            and key == self._key
            and _same(fingerprint, self._fingerprint)
        ):
            return replace(self._metrics, scanned_top_z_m=float(scanned_top_z_m))
        self.evaluations += 1
        if self._truth is not tree:  # the ground truth is prepared once per tree
            index = index_truth(tree, self.config, surroundings)
            self._truth, self._truth_index = tree, index
        metrics = evaluate(
            model,
            tree,
            self.config,
            scanned_top_z_m,
            truth_index=self._truth_index,
            planned_top_z_m=planned_top_z_m,
        )
        self._key, self._fingerprint, self._metrics = key, fingerprint, metrics
        return metrics
