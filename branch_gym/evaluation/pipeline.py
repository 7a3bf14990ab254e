"""The whole evaluation: check the output folder, run what is missing, report, draw.

Everything written at the end (``summary.json``, ``table.md``, ``trials.csv``, ``branches.csv``,
figures) is
rebuilt from the saved trial files, so a resumed run and a fresh one give the same outputs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
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
from branch_gym.evaluation.trials import TrialRecord, code_version, remove_partial_writes

logger = logging.getLogger(__name__)

DEFAULT_PLOT_TREES = 2


@dataclass
class EvalOutcome:
    """What :func:`run_evaluation` did.

    Attributes:
        summary: The content of ``summary.json``.
        records: All trials, policy order then seed.
        computed: The trials run this time (the others were loaded), in completion order.
        files: Every output file written (trial files aside).
        other_code: The loaded trials that another version of the code ran, or one that did not
            record its version (:func:`other_code_trials`).
    """

    summary: dict
    records: list[TrialRecord]
    computed: list[TrialKey]
    files: list[Path]
    other_code: list[TrialKey] = field(default_factory=list)


def default_plot_seeds(config: EvalConfig) -> list[int]:
    """The first tree seeds (up to :data:`DEFAULT_PLOT_TREES`)."""
    return list(config.seeds[:DEFAULT_PLOT_TREES])


def run_evaluation(
    config: EvalConfig,
    out: Path,
    plot_seeds: Sequence[int] | None = None,
    on_start: Callable[[int, int], None] | None = None,
    on_done: Callable[[TrialKey], None] | None = None,
    rerun: bool = False,
) -> EvalOutcome:
    """Run (or resume) an evaluation into ``out`` and write its outputs.

    Saved trials of the same configuration are loaded, not run again; those that another
    version of the code ran are reused too, with a warning (``rerun`` runs them all again).

    Args:
        config: Policies, trees, workers, scan configuration.
        out: Output folder (created).
        plot_seeds: Tree seeds to draw; the first two by default.
        on_start: Called once with (all trials, trials already saved) before running any.
        on_done: Called after each trial run is saved.
        rerun: Run every trial again, replacing the saved ones (e.g. after a code change).

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
    todo = list(config.keys) if rerun else pending_trials(config, out)
    if on_start is not None:
        on_start(len(config.keys), len(config.keys) - len(todo))
    computed = run_trials(config, out, todo, on_done)
    records = load_records(config, out)
    version = code_version()
    other_code = other_code_trials(records, version)
    if other_code:
        theirs = sorted({str(r.code_version) for r in records if r.code_version != version})
        logger.warning(
            "%d of %d trials loaded from %s were run by other code (%s; now %s): they are "
            "reused as saved; run again with --rerun (or another --out) to refresh them",
            len(other_code),
            len(records),
            out,
            ", ".join(theirs),
            version,
        )
    summary = write_report(out, config, records)
    files = [out / name for name in ("summary.json", "table.md", "trials.csv", "branches.csv")]
    files += write_figures(out, summary, records, plot_seeds, config.policy_factory)
    return EvalOutcome(summary, records, computed, files, other_code)


def other_code_trials(records: Sequence[TrialRecord], version: str | None) -> list[TrialKey]:
    """The trials whose recorded code version is not ``version`` (None: not recorded).

    >>> from types import SimpleNamespace as Trial
    >>> trials = [Trial(policy="none", seed=0, code_version="git:a"),
    ...           Trial(policy="none", seed=1, code_version=None)]
    >>> other_code_trials(trials, "git:a")
    [('none', 1)]
    """
    return [(r.policy, r.seed) for r in records if r.code_version != version]
