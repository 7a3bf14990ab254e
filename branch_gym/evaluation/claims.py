"""Does a learned policy beat a fixed schedule? Issue 63's rules, as paired intervals over trees.

A learned policy *beats* a fixed schedule (periodic or ``ftl``) when, on the trees both scanned,
either

* its mean scan time is at most the schedule's, it misses less, and the 95 % paired interval
  of its missed % minus the schedule's ends at or below zero (``faster_fewer``), or
* its scan time is at most ``ClaimRules.cheaper_time_factor`` of the schedule's and that
  interval ends at most ``ClaimRules.cheaper_slack_points`` above zero (``cheaper``).

The *cheap end*: within ``ClaimRules.cheap_end_time_factor`` of no rotation's scan time, the
fraction of no rotation's misses that a learned policy avoids (1 - the ratio of the misses),
with its paired interval.

Every comparison pairs the trees both policies have (a run in progress has fewer trees of some
policies): :func:`on_common_trees`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from branch_gym.evaluation.benchmark import TrialRow
from branch_gym.evaluation.statistics import paired_comparison

LEARNED_PREFIX = "ppo:"
FIXED_PREFIXES = ("periodic:", "ftl:")


@dataclass(frozen=True)
class ClaimRules:
    """The conditions of issue 63's claims.

    Attributes:
        cheaper_time_factor: A policy at most this fraction of a schedule's scan time may miss a
            little more (issue 63: 0.8x).
        cheaper_slack_points: ... with the interval's upper end at most this many points above
            zero (issue 63: +1 point).
        cheap_end_time_factor: The cheap end's time budget, a multiple of no rotation's scan time
            (issue 63: 1.3x).
        cheap_end_fewer: The fraction of no rotation's misses the cheap end avoids (issue 63:
            25 %).
    """

    cheaper_time_factor: float = 0.8
    cheaper_slack_points: float = 1.0
    cheap_end_time_factor: float = 1.3
    cheap_end_fewer: float = 0.25


def on_common_trees(
    a: Sequence[TrialRow], b: Sequence[TrialRow]
) -> tuple[list[TrialRow], list[TrialRow]]:
    """The trials of ``a`` and ``b`` on the (stratum, seed) trees both have, in that order."""
    by_a = {(r.stratum, r.seed): r for r in a}
    by_b = {(r.stratum, r.seed): r for r in b}
    common = sorted(by_a.keys() & by_b.keys())
    return [by_a[k] for k in common], [by_b[k] for k in common]


def compare(a: Sequence[TrialRow], b: Sequence[TrialRow], seed: int = 0) -> dict:
    """:func:`paired_comparison` of ``a`` minus ``b`` on their common trees, with the trees,
    both mean scan times (s) and their ratio.

    Raises:
        ValueError: no common tree.
    """
    a, b = on_common_trees(a, b)
    if not a:
        raise ValueError("the two policies share no tree")
    comparison = paired_comparison(a, b, np.random.default_rng(seed))
    time_a = float(np.mean([r.scan_time_s for r in a]))
    time_b = float(np.mean([r.scan_time_s for r in b]))
    return comparison | {
        "trees": len(a),
        "scan_time_s": time_a,
        "other_scan_time_s": time_b,
        "time_ratio": time_a / time_b if time_b > 0 else None,
    }


def beats(comparison: dict, rules: ClaimRules = ClaimRules()) -> str:
    """``"faster_fewer"``, ``"cheaper"`` or ``""`` (neither) for a :func:`compare` result."""
    interval = comparison["missed_pct_diff_ci"]
    ratio = comparison["time_ratio"]
    if interval is None or ratio is None:
        return ""
    if ratio <= 1.0 and comparison["missed_pct_diff"] < 0.0 and interval[1] <= 0.0:
        return "faster_fewer"
    if ratio <= rules.cheaper_time_factor and interval[1] <= rules.cheaper_slack_points:
        return "cheaper"
    return ""


def fixed_schedule_claims(
    by_policy: dict[str, Sequence[TrialRow]], seed: int = 0, rules: ClaimRules = ClaimRules()
) -> list[dict]:
    """For each fixed schedule, the learned policy that beats it, or the one that comes closest.

    Among the learned policies (``ppo:`` specs) the row names one that beats the schedule (the
    lowest interval upper end among those that do), else the one with the lowest upper end
    among those within the schedule's scan time, else the fastest.

    Returns:
        One dict per schedule: ``fixed``, ``learned`` (None without learned policies), its
        :func:`compare` result against the schedule as ``comparison``, and ``verdict``
        (:func:`beats`).
    """
    learned = [p for p in by_policy if p.startswith(LEARNED_PREFIX)]
    claims = []
    for fixed in (p for p in by_policy if p.startswith(FIXED_PREFIXES)):
        if not learned:
            claims.append({"fixed": fixed, "learned": None, "comparison": None, "verdict": ""})
            continue
        tried = {p: compare(by_policy[p], by_policy[fixed], seed) for p in learned}
        verdicts = {p: beats(c, rules) for p, c in tried.items()}
        upper = {
            p: np.inf if c["missed_pct_diff_ci"] is None else c["missed_pct_diff_ci"][1]
            for p, c in tried.items()
        }
        ratio = {p: c["time_ratio"] or np.inf for p, c in tried.items()}
        winners = [p for p in learned if verdicts[p]]
        within = [p for p in learned if ratio[p] <= 1.0]
        if winners or within:
            pick = min(winners or within, key=upper.__getitem__)
        else:
            pick = min(learned, key=ratio.__getitem__)
        claims.append(
            {
                "fixed": fixed,
                "learned": pick,
                "comparison": tried[pick],
                "verdict": verdicts[pick],
            }
        )
    return claims


def cheap_end_claims(
    by_policy: dict[str, Sequence[TrialRow]],
    baseline: str,
    seed: int = 0,
    rules: ClaimRules = ClaimRules(),
) -> list[dict]:
    """The learned policies within the cheap end's time budget of ``baseline`` (no rotation).

    Returns:
        One dict per such policy: ``learned``, ``comparison`` (:func:`compare` against the
        baseline), ``fewer`` (1 - the ratio of misses), ``fewer_ci`` (from the ratio's
        interval) and ``meets`` (``fewer`` at least ``rules.cheap_end_fewer``).
    """
    claims = []
    for policy in (p for p in by_policy if p.startswith(LEARNED_PREFIX)):
        comparison = compare(by_policy[policy], by_policy[baseline], seed)
        ratio = comparison["time_ratio"]
        if ratio is None or ratio > rules.cheap_end_time_factor:
            continue
        missed_ratio, interval = comparison["missed_ratio"], comparison["missed_ratio_ci"]
        fewer = None if missed_ratio is None else 1.0 - missed_ratio
        claims.append(
            {
                "learned": policy,
                "comparison": comparison,
                "fewer": fewer,
                "fewer_ci": None if interval is None else [1.0 - interval[1], 1.0 - interval[0]],
                "meets": fewer is not None and fewer >= rules.cheap_end_fewer,
            }
        )
    return claims
