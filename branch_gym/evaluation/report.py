"""Aggregate saved trials into the paper's table: ``summary.json``, ``table.md``, ``trials.csv``,
and one row per ground-truth branch, ``branches.csv`` (why each miss happened).

Per policy (recon.metrics.aggregate): the PB residual is pooled over the points of all trials (as
the paper); PB and SB radius RMSEs are per trial, then mean (std) over the trials that have one;
the SB residual is pooled over matched samples; spurious / missed / duplicate percentages are
totals over trials divided by all in-scope ground-truth branches. Two rows keep the paper's
definitions for its Table I beside ours: its spurious % counts every reconstruction that matches
no side branch (the tree's spurs, a neighbour's branch and a wire included) and its missed %
scores up to the height each scan reached; ours counts only reconstructions with nothing there
and every branch up to the planned end height (a failed scan misses those above where it
stopped; recon.metrics). Scan time and rotations are
mean (std) over trials. Failed scans count in "failures" and still contribute what they
reconstructed. Standard deviations are population (ddof=0). Undefined values are ``null`` in
JSON and ``n/a`` in tables.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from branch_gym.attribution import MISS_NEVER_SEEN, MISS_SEEN
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.statistics import bootstrap_ci, paired_comparison
from branch_gym.evaluation.trials import TrialRecord
from recon.metrics import BRANCH_CLASSES, aggregate

MM_PER_M = 1000.0
MISSING = "n/a"  # an undefined value of ours
NOT_REPORTED = "-"  # a value the paper does not report

# Table rows: (label, summary key), the paper's layout and then ours.
# The paper's Table I value for a row: its spurious and missed % are by its own definitions.
PAPER_KEYS = {
    "spurious_paper_pct": "spurious_pct",
    "missed_paper_pct": "missed_pct",
    "spurious_pct": None,
    "missed_pct": None,
}
TABLE_ROWS: tuple[tuple[str, str], ...] = (
    ("PB residual (mm)", "pb_residual_mm"),
    ("PB radius RMSE (mm)", "pb_radius_rmse_mm"),
    ("SB residual (mm)", "sb_residual_mm"),
    ("SB radius (mm)", "sb_radius_mm"),
    ("Spurious % (paper's definition)", "spurious_paper_pct"),
    ("Missed % (paper's scope)", "missed_paper_pct"),
    ("Spurious %, nothing there", "spurious_pct"),
    ("Missed %, unreached included", "missed_pct"),
    ("Precision %", "precision_pct"),
    ("Missed, seen %", "missed_seen_pct"),
    ("Missed, never seen %", "missed_never_seen_pct"),
    ("Duplicates %", "duplicate_pct"),
    ("SB completeness %", "sb_completeness_pct"),
    ("Scan time (s)", "scan_time_s"),
    ("Rotations", "rotations"),
    ("Trials", "trials"),
    ("Failures", "failures"),
)


# Misses broken down by the branch's angle to the home optical axis (deg; 0 = pointing toward or
# away from the camera): the bins of the issue's finding that misses lie within 45 deg of it.
AXIS_ANGLE_BINS_DEG = (0.0, 15.0, 30.0, 45.0, 90.0)
BRANCH_COLUMNS = (
    "seed",
    "policy",
    "branch",
    "axis_angle_deg",
    "elevation_deg",
    "length_m",
    "base_height_m",
    "peak_visible_px",
    "peak_view_angle_deg",
    "in_scope",
    "matched",
    "completeness",
    "residual_mm",
    "miss",
)


def summarise_policy(records: Sequence[TrialRecord]) -> dict:
    """One policy's summary entry (the shape of ``summary.json["policies"][NAME]``).

    Raises:
        ValueError: no records.
    """
    stats = aggregate([r.metrics for r in records])
    scan_times = np.array([r.scan_time_s for r in records], dtype=float)
    rotations = np.array([r.rotations for r in records], dtype=float)
    return {
        "trials": len(records),
        "failures": sum(r.failure is not None for r in records),
        "pb_residual_mm": _mean_std(
            stats["pb_residual_mean_m"], stats["pb_residual_std_m"], MM_PER_M
        ),
        "pb_radius_rmse_mm": _mean_std(
            stats["pb_radius_rmse_mean_m"], stats["pb_radius_rmse_std_m"], MM_PER_M
        ),
        "sb_residual_mm": _mean_std(
            stats["sb_residual_mean_m"], stats["sb_residual_std_m"], MM_PER_M
        ),
        "sb_radius_mm": _mean_std(
            stats["sb_radius_rmse_mean_m"], stats["sb_radius_rmse_std_m"], MM_PER_M
        ),
        "spurious_pct": _finite_or_none(stats["spurious_pct"]),
        "missed_pct": _finite_or_none(stats["missed_pct"]),
        "spurious_paper_pct": _finite_or_none(stats["spurious_paper_pct"]),
        "missed_paper_pct": _finite_or_none(stats["missed_paper_pct"]),
        "precision_pct": _finite_or_none(stats["precision_pct"]),
        "classes": {name: stats[f"n_class_{name}"] for name in BRANCH_CLASSES},
        "duplicate_pct": _finite_or_none(stats["duplicate_pct"]),
        **_miss_kinds(records, stats["n_gt"]),
        "sb_completeness_pct": _finite_or_none(stats["sb_completeness_pct"]),
        "misses_by_axis_angle": _misses_by_axis_angle(records),
        "scan_time_s": _mean_std(float(np.mean(scan_times)), float(np.std(scan_times))),
        "rotations": _mean_std(float(np.mean(rotations)), float(np.std(rotations))),
    }


def _miss_kinds(records: Sequence[TrialRecord], n_gt: int) -> dict[str, float | None]:
    """Missed branches a frame showed well ("seen") and ones none did, in % of in-scope GT.

    None when a trial has no branch rows (saved before the attribution existed).
    """
    if n_gt == 0 or any(r.metrics.n_gt and not r.branches for r in records):
        return {"missed_seen_pct": None, "missed_never_seen_pct": None}
    rows = [row for r in records for row in r.branches]
    return {
        f"missed_{kind}_pct": 100.0 * sum(row["miss"] == kind for row in rows) / n_gt
        for kind in (MISS_SEEN, MISS_NEVER_SEEN)
    }


def _misses_by_axis_angle(records: Sequence[TrialRecord]) -> dict[str, dict[str, int]]:
    """Per bin of ``AXIS_ANGLE_BINS_DEG``: in-scope GT branches, missed, and missed but seen."""
    bins: dict[str, dict[str, int]] = {}
    edges = AXIS_ANGLE_BINS_DEG
    for low, high in itertools.pairwise(edges):
        rows = [
            row
            for r in records
            for row in r.branches
            if row["in_scope"] and low <= float(row["axis_angle_deg"]) < high + (high == edges[-1])
        ]
        bins[f"{low:g}-{high:g}"] = {
            "gt": len(rows),
            "missed": sum(bool(row["miss"]) for row in rows),
            "missed_seen": sum(row["miss"] == MISS_SEEN for row in rows),
        }
    return bins


def build_summary(config: EvalConfig, records: Sequence[TrialRecord]) -> dict:
    """``summary.json``: one entry per policy, keyed by its spec as given, the paired
    comparisons of every two policies, and the run config.

    Each policy's bootstrap and each pair's starts a fresh generator seeded by the first tree
    seed (``config.seed``): every interval resamples the same trees, and none depends on which
    other policies share the run or on their order.
    """
    by_policy = {policy: [r for r in records if r.policy == policy] for policy in config.policies}
    empty = [policy for policy, rs in by_policy.items() if not rs]
    if empty:
        raise ValueError(f"no trials for policies {empty}")
    policies = {}
    for policy, rs in by_policy.items():
        rng = np.random.default_rng(config.seed)
        policies[policy] = {**summarise_policy(rs), **bootstrap_ci(rs, rng)}
    paired = [
        {
            "policy": a,
            "against": b,
            **paired_comparison(by_policy[a], by_policy[b], np.random.default_rng(config.seed)),
        }
        for i, a in enumerate(config.policies)
        for b in config.policies[:i]
    ]
    return {"policies": policies, "paired": paired, "config": config.to_json_dict()}


def format_cell(value: object) -> str:
    """``{"mean", "std"}`` -> "mean (std)"; a float -> 1 decimal; an int as is; None -> n/a."""
    if isinstance(value, dict):
        mean, std = value["mean"], value["std"]
        if mean is None:
            return MISSING
        return f"{mean:.1f}" if std is None else f"{mean:.1f} ({std:.1f})"
    if value is None:
        return MISSING
    if isinstance(value, int):
        return str(value)
    return f"{value:.1f}"


def format_table(summary: dict) -> str:
    """The paper's table layout in Markdown: one column per policy, in the given order."""
    policies = summary["policies"]
    header = ["", *(_escape(p) for p in policies)]
    rows = [
        [label, *(format_cell(entry[key]) for entry in policies.values())]
        for label, key in TABLE_ROWS
    ]
    return _markdown([header, *rows])


def format_comparison(summary: dict, paper_column: Callable[[str], dict | None]) -> str:
    """Our table with the paper's Table I value beside each column (``-``: not reported).

    Args:
        summary: The content of ``summary.json``.
        paper_column: A policy spec -> the paper's column for it (summary-shaped), or None
            where the paper has none (``agents.paper.paper_column``).
    """
    policies = summary["policies"]
    header = [""]
    for policy in policies:
        header += [_escape(policy), "paper"]
    rows = []
    for label, key in TABLE_ROWS:
        row = [label]
        for policy, entry in policies.items():
            paper = paper_column(policy) or {}
            paper_key = PAPER_KEYS.get(key, key)
            value = format_cell(paper[paper_key]) if paper_key in paper else "-"
            row += [format_cell(entry[key]), value]
        rows.append(row)
    return _markdown([header, *rows])


def write_report(out: Path, config: EvalConfig, records: Sequence[TrialRecord]) -> dict:
    """Write ``summary.json``, ``table.md`` and ``trials.csv`` into ``out``.

    Returns:
        The summary.
    """
    summary = build_summary(config, records)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    (out / "table.md").write_text(_table_document(summary, records))
    write_trials_csv(out / "trials.csv", records)
    write_branches_csv(out / "branches.csv", records)
    return summary


def write_branches_csv(path: Path, records: Sequence[TrialRecord]) -> None:
    """One row per ground-truth secondary per trial (``BRANCH_COLUMNS``), in the records' order."""
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(BRANCH_COLUMNS), restval="")
        writer.writeheader()
        for record in records:
            for row in record.branches:
                writer.writerow({"seed": record.seed, "policy": record.policy, **row})


def write_trials_csv(path: Path, records: Sequence[TrialRecord]) -> None:
    """One row per trial (``ScanResult.to_row()``), in the records' order; columns in first-seen
    order over all rows (a cell is empty where a row lacks the column)."""
    columns: dict[str, None] = {}
    for record in records:
        columns.update(dict.fromkeys(record.row))
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns), restval="")
        writer.writeheader()
        writer.writerows(record.row for record in records)


def _table_document(summary: dict, records: Sequence[TrialRecord]) -> str:
    config = summary["config"]
    seeds = config["seeds"]
    return (
        "# Simulated scans, mean (std) per policy\n\n"
        f"Trees: seeds {seeds[0]}..{seeds[-1]}; scan configuration {config['scan_config_hash']} "
        "(summary.json). PB residual pooled over points; radius RMSEs per trial; percentages of "
        "in-scope ground-truth secondaries, totals over trials.\n\n"
        f"{format_table(summary)}\n\n"
        "Misses by the branch's angle to the home optical axis (0 deg: pointing toward or away "
        "from the camera), missed / in-scope (of which seen):\n\n"
        f"{format_angle_breakdown(summary)}\n\n"
        "Missed % with 95 % bootstrap intervals over trees, and paired comparisons on the same "
        "trees (difference in missed %, points, with its paired-bootstrap interval; per-tree "
        "wins / losses / ties and the two-sided sign test):\n\n"
        f"{format_paired(summary)}\n\n"
        f"Failure reasons: {failure_reasons(records, config['policies'])}\n"
    )


def format_paired(summary: dict) -> str:
    """Markdown: each policy's missed % [95 % CI], then one line per paired comparison."""
    lines = []
    for policy, entry in summary["policies"].items():
        ci = entry.get("missed_pct_ci")
        interval = MISSING if ci is None else f"[{ci[0]:.1f}, {ci[1]:.1f}]"
        lines.append(f"- {policy}: missed {format_cell(entry['missed_pct'])} % {interval}")
    for row in summary.get("paired", []):
        ci = row["missed_pct_diff_ci"]
        interval = MISSING if ci is None else f"[{ci[0]:+.1f}, {ci[1]:+.1f}]"
        diff = MISSING if row["missed_pct_diff"] is None else f"{row['missed_pct_diff']:+.1f}"
        lines.append(
            f"- {row['policy']} vs {row['against']}: {diff} pts {interval}, "
            f"{row['scan_time_s_diff']:+.1f} s; trees {row['wins']}/{row['losses']}/{row['ties']}"
            f", sign test p = {row['sign_test_p']:.3f}"
        )
    return "\n".join(lines)


def format_angle_breakdown(summary: dict) -> str:
    """Markdown: one row per axis-angle bin, one column per policy, "missed / gt (seen)"."""
    policies = summary["policies"]
    bins = list(next(iter(policies.values()))["misses_by_axis_angle"])
    header = ["axis angle (deg)", *(_escape(p) for p in policies)]
    rows = []
    for name in bins:
        row = [name]
        for entry in policies.values():
            cell = entry["misses_by_axis_angle"][name]
            row.append(f"{cell['missed']} / {cell['gt']} ({cell['missed_seen']})")
        rows.append(row)
    return _markdown([header, *rows])


def failure_reasons(records: Sequence[TrialRecord], policies: Sequence[str]) -> str:
    """E.g. "none: lost_branch 1; periodic:45:1.5: joint_limit 2, singularity 1" (or "none")."""
    parts = []
    for policy in policies:
        reasons = Counter(r.failure for r in records if r.policy == policy and r.failure)
        if reasons:
            counts = ", ".join(f"{reason} {n}" for reason, n in sorted(reasons.items()))
            parts.append(f"{policy}: {counts}")
    return "; ".join(parts) or "none"


def _mean_std(mean: float, std: float, scale: float = 1.0) -> dict[str, float | None]:
    return {"mean": _finite_or_none(mean * scale), "std": _finite_or_none(std * scale)}


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _escape(text: str) -> str:
    return text.replace("|", "\\|")


def _markdown(rows: list[list[str]]) -> str:
    """A Markdown table with padded columns (first row is the header)."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = [
        "| " + " | ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) + " |"
        for row in rows
    ]
    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([lines[0], rule, *lines[1:]])
