"""The paper's simulated results, to print next to ours.

You et al., "A real-time, hardware agnostic framework for close-up branch reconstruction using RGB
data", Table I, "Simulated Experiments" columns (60 trials each; mean (std); also in
``shared/spec/reference.md``). The LaTeX source prints the PB radius of the 45 / 2.5 column as
"(0.5) (0.4)"; it is read as 0.5 (0.4). The paper reports no scan time, rotation count, failure
count or duplicate rate.

The authors' experiment script ran ``pan_frequency`` 1 and 2 for the columns labelled 1.5 and
2.5 (``shared/spec/reference.md``): ``ftl:ANGLE:1`` and ``ftl:ANGLE:2`` (:mod:`agents.ftl`) are
the controllers behind those columns, and are printed next to them; ``periodic:ANGLE:FREQ``
follows the paper's words for the same labels.

:func:`paper_column` is what ``branch_gym.evaluation.report.format_comparison`` is handed to
print the paper's column beside ours.
"""

from __future__ import annotations

from agents.baselines import NO_ROTATION_SPEC, parse_periodic_spec
from agents.ftl import parse_ftl_spec

# (rotation angle deg, rotations per vertical FoV) -> summary-shaped values.
PAPER_TABLE_I: dict[tuple[float, float], dict[str, object]] = {
    (0.0, 0.0): {
        "trials": 60,
        "pb_residual_mm": {"mean": 3.5, "std": 4.0},
        "pb_radius_rmse_mm": {"mean": 0.5, "std": 0.1},
        "sb_residual_mm": {"mean": 5.7, "std": 9.3},
        "sb_radius_mm": {"mean": 3.8, "std": 0.9},
        "spurious_pct": 2.3,
        "missed_pct": 7.0,
    },
    (22.5, 1.5): {
        "trials": 60,
        "pb_residual_mm": {"mean": 4.2, "std": 4.9},
        "pb_radius_rmse_mm": {"mean": 0.4, "std": 0.4},
        "sb_residual_mm": {"mean": 11.0, "std": 23.7},
        "sb_radius_mm": {"mean": 3.8, "std": 1.0},
        "spurious_pct": 0.8,
        "missed_pct": 3.4,
    },
    (45.0, 1.5): {
        "trials": 60,
        "pb_residual_mm": {"mean": 4.5, "std": 8.9},
        "pb_radius_rmse_mm": {"mean": 0.4, "std": 0.4},
        "sb_residual_mm": {"mean": 6.1, "std": 10.0},
        "sb_radius_mm": {"mean": 3.9, "std": 0.9},
        "spurious_pct": 4.5,
        "missed_pct": 7.9,
    },
    (22.5, 2.5): {
        "trials": 60,
        "pb_residual_mm": {"mean": 3.8, "std": 3.7},
        "pb_radius_rmse_mm": {"mean": 0.4, "std": 0.3},
        "sb_residual_mm": {"mean": 9.7, "std": 23.6},
        "sb_radius_mm": {"mean": 3.8, "std": 1.0},
        "spurious_pct": 0.3,
        "missed_pct": 4.5,
    },
    (45.0, 2.5): {
        "trials": 60,
        "pb_residual_mm": {"mean": 4.8, "std": 7.5},
        "pb_radius_rmse_mm": {"mean": 0.5, "std": 0.4},
        "sb_residual_mm": {"mean": 7.3, "std": 15.2},
        "sb_radius_mm": {"mean": 3.9, "std": 0.9},
        "spurious_pct": 0.4,
        "missed_pct": 8.5,
    },
}

# pan_frequency the authors' script ran -> the frequency their analysis labels it with.
AUTHORS_RUN_FREQUENCY_LABELS = {1.0: 1.5, 2.0: 2.5}


def paper_column(policy: str) -> dict[str, object] | None:
    """The paper's Table I column for a policy spec, or None when the paper has no such column."""
    if policy == NO_ROTATION_SPEC:
        return PAPER_TABLE_I[(0.0, 0.0)]
    try:
        periodic = parse_periodic_spec(policy)
        ftl = parse_ftl_spec(policy)
    except ValueError:  # not a valid spec: no paper column
        return None
    if ftl is not None:  # the frequency the script ran -> the column's label
        label = AUTHORS_RUN_FREQUENCY_LABELS.get(ftl.pan_frequency)
        return None if label is None else PAPER_TABLE_I.get((ftl.angle_deg, label))
    return None if periodic is None else PAPER_TABLE_I.get(periodic)
