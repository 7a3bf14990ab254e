"""Scoring a scan against the ground truth: :class:`ScanResult` and :func:`score_scan`.

Simulation only: it reads the tree's ground truth, which no policy may see. The metrics are the
paper's (:func:`recon.metrics.evaluate`), with every reconstructed side branch classed against the
structures around the tree (:mod:`branch_gym.surroundings`) and, by default, every branch up to
the planned end height in scope (a failed scan misses those above where it stopped).
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from branch_gym.attribution import branch_rows, miss_counts
from branch_gym.scan import ScanConfig, ScanSession
from branch_gym.sim.tree.ground_truth import TreeGT
from branch_gym.surroundings import Surroundings, surroundings_of
from recon.metrics import MetricsConfig, TreeMetrics, evaluate
from recon.model import TreeModel

# Row columns: the iterations per outcome and the median time per modeler stage.
OUTCOME_PREFIX = "outcome_"
STAGE_PREFIX = "stage_"


@dataclass
class ScanResult:
    """One scored scan (see :func:`score_scan`); a saved one is a
    :class:`branch_gym.evaluation.trials.TrialRecord`.

    Attributes:
        seed: Tree seed (-1 for a tree given without one).
        policy: The policy's spec or name.
        metrics: The paper's metrics of the model against the ground truth.
        model: The reconstruction.
        truth: The tree's ground truth.
        scan_time_s: Simulated scan time (s), rotations included.
        rotations: Rotation moves made.
        failure: Failure reason, None for a scan that reached its end height.
        stop_reason: "end_height", the failure reason, or "running".
        n_iterations: Modeling iterations run.
        outcomes: Iterations per outcome ("consistent", ...).
        stage_ms: Median wall-clock time per modeler stage (ms).
        wall_time_s: Wall-clock time of the scan so far (s).
        branches: One row per ground-truth secondary: geometry, visibility, match,
            completeness and why it was missed (:func:`branch_gym.attribution.branch_rows`).
        surroundings: The structures around the tree the metrics classed reconstructions
            against (:func:`branch_gym.surroundings.surroundings_of`).
        planned_top_z_m: The height the scan was to reach (m): the top of the scored scope.
    """

    seed: int
    policy: str
    metrics: TreeMetrics
    model: TreeModel
    truth: TreeGT
    scan_time_s: float
    rotations: int
    failure: str | None
    stop_reason: str
    n_iterations: int
    outcomes: dict[str, int]
    stage_ms: dict[str, float]
    wall_time_s: float
    branches: list[dict[str, object]] = field(default_factory=list)
    surroundings: Surroundings = field(default_factory=dict)
    planned_top_z_m: float = float("nan")

    def to_row(self) -> dict:
        """A flat, CSV-able row."""
        row = {
            "seed": self.seed,
            "policy": self.policy,
            "scan_time_s": self.scan_time_s,
            "rotations": self.rotations,
            "failure": self.failure or "",
            "stop_reason": self.stop_reason,
            "n_iterations": self.n_iterations,
            "wall_time_s": self.wall_time_s,
        }
        row.update({f"{OUTCOME_PREFIX}{k}": v for k, v in sorted(self.outcomes.items())})
        row.update(self.metrics.to_dict())
        row.update(miss_counts(self.branches))
        row.update({f"{STAGE_PREFIX}{k}": v for k, v in self.stage_ms.items()})
        return row


def score_scan(
    session: ScanSession,
    policy: str = "",
    metrics_config: MetricsConfig | None = None,
    surroundings: Surroundings | None = None,
) -> ScanResult:
    """Score a session's current model against its tree's ground truth.

    Args:
        session: A session after ``reset`` (finished or not).
        policy: Recorded in the result.
        metrics_config: The scoring rules; by default the authors' thresholds over the scan's
            band (:func:`scan_metrics_config`), branches up to the planned end height in scope.
        surroundings: The structures around the session's tree, when the caller has them
            (:func:`session_surroundings`, read once per tree); None reads them here.

    Raises:
        RuntimeError: the session has not been reset.
    """
    if session.tree is None:
        raise RuntimeError("ScanSession.reset(seed) must be called before scoring the scan")
    model = session.model
    if surroundings is None:
        surroundings = session_surroundings(session)
    planned_top_m = session.config.end_height_m
    metrics = evaluate(
        model,
        session.tree,
        metrics_config or scan_metrics_config(session.config),
        scanned_top_z_m=session.camera_height_m,
        surroundings=surroundings,
        planned_top_z_m=planned_top_m,
    )
    reports = session.reports
    outcomes = Counter(r.outcome.value for r in reports)
    stages = sorted({k for r in reports for k in r.timings_ms})
    stage_ms = {
        k: float(np.median([r.timings_ms[k] for r in reports if k in r.timings_ms])) for k in stages
    }
    return ScanResult(
        seed=int(session.tree.seed) if session.tree.seed is not None else -1,
        policy=policy,
        metrics=metrics,
        model=model,
        truth=session.tree,
        scan_time_s=session.scan_time_s,
        rotations=session.rotations,
        failure=session.failure,
        stop_reason=session.stop_reason or "running",
        n_iterations=len(reports),
        outcomes=dict(outcomes),
        stage_ms=stage_ms,
        wall_time_s=time.perf_counter() - session.wall_start_s,
        branches=branch_rows(session.tree, metrics, session.sensor.visibility),
        surroundings=surroundings,
        planned_top_z_m=planned_top_m,
    )


# Band heights are rounded to this many decimals (nanometres): 0.275 + 0.05 is 0.325 exactly.
_BAND_DECIMALS = 9


def scan_metrics_config(scan: ScanConfig, **changes: object) -> MetricsConfig:
    """The authors' scoring rules over ``scan``'s band (:attr:`ScanConfig.metrics_band_m`), with
    other :class:`recon.metrics.MetricsConfig` fields as ``changes``."""
    low, high = (round(z, _BAND_DECIMALS) for z in scan.metrics_band_m)
    # A scan ending below the band (a quick test scan) scores an empty band.
    return MetricsConfig(band_min_z_m=low, band_max_z_m=max(high, low), **changes)


def session_surroundings(session: ScanSession) -> Surroundings:
    """The structures around a reset session's tree (its orchard row, if any)."""
    return surroundings_of(session.tree, getattr(session.world.scene, "row", None))
