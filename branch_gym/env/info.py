"""The ``info`` dicts of :class:`branch_gym.env.BranchScanEnv`: flat, JSON-able, comparable.

Undefined metrics (NaN in :mod:`recon.metrics`, e.g. a residual before any match) appear as
``None``: NaN never equals itself, so infos holding it could not be compared for determinism.
Wall-clock measurements live only under ``timings_ms`` (see ``EnvConfig.info_timings``).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence

from branch_gym.scan import ScanSession
from branch_gym.scoring import ScanResult
from recon.metrics import TreeMetrics
from recon.modeler import IterationReport

# ScanResult.to_row() columns that are wall-clock measurements, not scan results.
_WALL_CLOCK_KEYS = ("wall_time_s",)
_STAGE_PREFIX = "stage_"


def plain(value: object) -> object:
    """NaN -> None; other values unchanged."""
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def metrics_dict(metrics: TreeMetrics) -> dict[str, object]:
    """The metrics so far as a flat dict (:meth:`TreeMetrics.to_dict`, NaN -> None)."""
    return {key: plain(value) for key, value in metrics.to_dict().items()}


def final_metrics(result: ScanResult, with_timings: bool) -> dict[str, object]:
    """The scan's final row (:meth:`ScanResult.to_row`, NaN -> None).

    Args:
        result: The scored scan.
        with_timings: Keep the wall-clock columns (``wall_time_s``, ``stage_*`` medians).
    """
    row = result.to_row()
    if not with_timings:
        row = {
            k: v
            for k, v in row.items()
            if k not in _WALL_CLOCK_KEYS and not k.startswith(_STAGE_PREFIX)
        }
    return {key: plain(value) for key, value in row.items()}


def step_info(
    session: ScanSession,
    seed: int | None,
    metrics: TreeMetrics,
    last_report: IterationReport | None,
    reports: Sequence[IterationReport],
    rotated: bool,
) -> dict[str, object]:
    """The deterministic part of a reset / step info (see ``BranchScanEnv``'s docstring).

    Args:
        session: The scan after the step.
        seed: The episode's tree seed.
        metrics: The model scored after the step.
        last_report: The latest modeling iteration so far (None before the first).
        reports: The iterations this step ran.
        rotated: The step performed a rotation.
    """
    return {
        "seed": seed,
        "metrics": metrics_dict(metrics),
        "failure": session.failure or "",
        "stop_reason": session.stop_reason or "",
        "scan_time_s": float(session.scan_time_s),
        "rotations": int(session.rotations),
        "angle_deg": float(session.angle_deg),
        "camera_height_m": session.camera_height_m,
        "progress": session.progress,
        "outcome": "" if last_report is None else last_report.outcome.value,
        "iterations": len(reports),
        "n_iterations": len(session.reports),
        "rotated": bool(rotated),
    }


def step_timings(reports: Sequence[IterationReport], env_ms: Mapping[str, float]) -> dict:
    """Per-stage milliseconds of one env step.

    Args:
        reports: The modeling iterations the step ran; their stage timings are summed
            (``curve2d_ms``, ``tracking_ms``, ..., ``total_ms``).
        env_ms: The env's own stages (e.g. ``scan_step_ms``, ``metrics_ms``, ``observation_ms``).

    Returns:
        Flat ``{stage: ms}``; modeler stages are prefixed ``modeler_``.
    """
    totals: dict[str, float] = defaultdict(float)
    for report in reports:
        for stage, ms in report.timings_ms.items():
            totals[f"modeler_{stage}"] += float(ms)
    out = dict(totals)
    out.update({k: float(v) for k, v in env_ms.items()})
    return out
