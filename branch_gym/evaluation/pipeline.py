"""The whole evaluation: check the output folder, run what is missing, report, draw.

Everything written at the end (``summary.json``, ``table.md``, ``trials.csv``, ``branches.csv``,
figures) is
rebuilt from the saved trial files, so a resumed run and a fresh one give the same outputs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from branch_gym.evaluation.config import EvalConfig, TrialKey
from branch_gym.evaluation.plots import write_figures
from branch_gym.evaluation.report import write_report
from branch_gym.evaluation.runner import (
    check_output_folder,
    load_records,
    pending_trials,
    run_trials,
)
from branch_gym.evaluation.trials import TrialRecord, remove_partial_writes

DEFAULT_PLOT_TREES = 2


@dataclass
class EvalOutcome:
    """What :func:`run_evaluation` did.

    Attributes:
        summary: The content of ``summary.json``.
        records: All trials, policy order then seed.
        computed: The trials run this time (the others were loaded), in completion order.
        files: Every output file written (trial files aside).
    """

    summary: dict
    records: list[TrialRecord]
    computed: list[TrialKey]
    files: list[Path]


def default_plot_seeds(config: EvalConfig) -> list[int]:
    """The first tree seeds (up to :data:`DEFAULT_PLOT_TREES`)."""
    return list(config.seeds[:DEFAULT_PLOT_TREES])


def run_evaluation(
    config: EvalConfig,
    out: Path,
    plot_seeds: Sequence[int] | None = None,
    on_start: Callable[[int, int], None] | None = None,
    on_done: Callable[[TrialKey], None] | None = None,
) -> EvalOutcome:
    """Run (or resume) an evaluation into ``out`` and write its outputs.

    Args:
        config: Policies, trees, workers, scan configuration.
        out: Output folder (created).
        plot_seeds: Tree seeds to draw; the first two by default.
        on_start: Called once with (all trials, trials already saved) before running any.
        on_done: Called after each trial run is saved.

    Raises:
        ValueError: a seed to plot is not among the evaluated ones.
        ConfigMismatchError: ``out`` holds trials of another scan configuration, or of a
            ``ppo:PATH`` model file that has changed since.
    """
    plot_seeds = default_plot_seeds(config) if plot_seeds is None else list(plot_seeds)
    outside = [s for s in plot_seeds if s not in config.seeds]
    if outside:
        raise ValueError(
            f"trees to plot {outside} are not among the evaluated seeds "
            f"{config.seeds.start}..{config.seeds.stop - 1}"
        )
    out.mkdir(parents=True, exist_ok=True)
    check_output_folder(config, out)
    remove_partial_writes(out)
    todo = pending_trials(config, out)
    if on_start is not None:
        on_start(len(config.keys), len(config.keys) - len(todo))
    computed = run_trials(config, out, todo, on_done)
    records = load_records(config, out)
    summary = write_report(out, config, records)
    files = [out / name for name in ("summary.json", "table.md", "trials.csv", "branches.csv")]
    files += write_figures(out, summary, records, plot_seeds)
    return EvalOutcome(summary, records, computed, files)
