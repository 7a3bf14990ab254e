"""How many test trees a benchmark needs: the power computation on a pilot of its validation split.

Reads a pilot's trials (``eval.py --benchmark NAME --split validation --trees N ...``: its
``OUT/rows.jsonl``, or the trial files under ``OUT/<stratum>/trials`` of a run that kept no rows)
and prints, for each policy against the reference (the paper's controller), the pilot's paired
difference, its spread and the test trees that a +-1 point 95 % interval takes
(``branch_gym.evaluation.power``), checked by simulating benchmarks of that size from the pilot.

Usage::

    python research/benchmark_power.py runs/orchard_v1_pilot --benchmark orchard-v1
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from branch_gym.evaluation.benchmark import TrialRow, benchmark, load_rows
from branch_gym.evaluation.power import (
    PairedSample,
    simulated_half_width,
    trees_for_half_width,
)
from branch_gym.evaluation.trials import TRIALS_DIR, load_trial

TARGET_HALF_WIDTH_PCT = 1.0  # issue 60


def pilot_rows(out: Path, name: str) -> list[TrialRow]:
    """The pilot's rows: ``OUT/rows.jsonl`` when there is one, else its trial files as saved."""
    bench = benchmark(name)
    rows = load_rows(out, bench)
    if rows:
        return list(rows.values())
    found = []
    for stratum in bench.strata:
        for path in sorted((out / stratum.name / TRIALS_DIR).glob("*/[0-9]*.json")):
            found.append(TrialRow.of(load_trial(path), stratum.name))
    return found


def power_table(rows: list[TrialRow], reference: str, seed: int = 0) -> str:
    """The Markdown table: each policy against ``reference``."""
    by_policy: dict[str, dict[tuple[str, int], TrialRow]] = defaultdict(dict)
    for row in rows:
        by_policy[row.policy][row.stratum, row.seed] = row
    if reference not in by_policy:
        raise ValueError(f"the pilot has no trials of the reference policy {reference!r}")
    lines = [
        f"| policy | trees | side branches | missed % minus `{reference}`'s | spread s "
        "(branches a tree) | trees for +-1 point | simulated half-width there |",
        "|---|---|---|---|---|---|---|",
    ]
    for policy, trials in by_policy.items():
        if policy == reference:
            continue
        keys = sorted(set(trials) & set(by_policy[reference]))
        sample = PairedSample(
            np.array([trials[k].n_missed for k in keys], float),
            np.array([by_policy[reference][k].n_missed for k in keys], float),
            np.array([trials[k].n_gt for k in keys], float),
        )
        needed = trees_for_half_width(sample, TARGET_HALF_WIDTH_PCT)
        check = simulated_half_width(sample, needed, np.random.default_rng(seed))
        lines.append(
            f"| `{policy}` | {len(keys)} | {int(sample.n_gt.sum())} | "
            f"{sample.difference_pct:+.1f} | {sample.spread:.2f} | {needed} | {check:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("out", type=Path, help="the pilot's output folder")
    parser.add_argument("--benchmark", required=True, help="the benchmark's name")
    args = parser.parse_args(argv)
    rows = pilot_rows(args.out, args.benchmark)
    if not rows:
        parser.error(f"no trials under {args.out}")
    print(power_table(rows, benchmark(args.benchmark).reference_policy))
    return 0


if __name__ == "__main__":
    sys.exit(main())
