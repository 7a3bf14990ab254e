"""Does a learned policy dominate each fixed schedule? Issue 34's check, from saved trials.

Reads the trials of one or more ``eval.py --out`` folders (the same trees and scan configuration)
and, for every periodic and ``ftl`` point, looks for a learned policy (a ``ppo:`` spec) that
dominates it: fewer missed branches at no more scan time, or no more missed at no more than
``TIME_FACTOR`` of its scan time; spurious no more than ``SPURIOUS_SLACK_POINTS`` above; no more
failures. Each point's row names the learned policy with the fewest misses among those within
its time budget, with the paired difference on the same trees (points, paired-bootstrap
interval, wins / losses / ties, sign test), and says which condition fails. It then checks the
cheap end (at least ``CHEAP_END_FEWER`` fewer misses than no rotation within ``CHEAP_END_TIME``
x its scan time) and the gap to the privileged bound.

    python research/dominance.py results/orchard_pixels_v2 results/orchard_pixels_v2_shipped

``--learned SPEC ...`` counts only those learned policies (e.g. the shipped ones) where the folders
hold others too.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from agents.ppo import PPO_SPEC_PREFIX
from branch_gym.evaluation.report import summarise_policy
from branch_gym.evaluation.statistics import paired_comparison
from branch_gym.evaluation.trials import TRIALS_DIR, TrialRecord, load_trial

# Issue 34's must-show: the conditions of "dominates".
TIME_FACTOR = 0.8
SPURIOUS_SLACK_POINTS = 1.0
CHEAP_END_TIME = 1.3
CHEAP_END_FEWER = 0.25
FIXED_PREFIXES = ("periodic:", "ftl:")
RESAMPLE_SEED = 0  # paired-bootstrap draws


def load_folders(folders: list[Path]) -> dict[str, list[TrialRecord]]:
    """Every trial of the folders, by policy.

    Raises:
        ValueError: trials of different scan configurations, or a policy with two trials of
            one tree.
    """
    records: dict[str, list[TrialRecord]] = defaultdict(list)
    hashes = set()
    for folder in folders:
        for path in sorted((folder / TRIALS_DIR).glob("*/*.json")):
            if not path.stem.isdigit():  # config.json, model.json, segmenter.json
                continue
            record = load_trial(path)
            hashes.add(record.config_hash)
            if any(r.seed == record.seed for r in records[record.policy]):
                raise ValueError(f"{record.policy} has two trials of tree {record.seed}")
            records[record.policy].append(record)
    if len(hashes) > 1:
        raise ValueError(f"the folders hold trials of {len(hashes)} scan configurations")
    return dict(records)


def figures(records: list[TrialRecord]) -> dict[str, float]:
    """Pooled missed and spurious %, mean scan time (s), failures."""
    summary = summarise_policy(records)
    return {
        "missed": summary["missed_pct"],
        "spurious": summary["spurious_pct"],
        "time": summary["scan_time_s"]["mean"],
        "failures": summary["failures"],
    }


def dominance_failure(learned: dict[str, float], fixed: dict[str, float]) -> str:
    """ "" when ``learned`` dominates ``fixed``, else the condition it fails."""
    fewer = learned["missed"] < fixed["missed"] and learned["time"] <= fixed["time"]
    cheaper = (
        learned["missed"] <= fixed["missed"] and learned["time"] <= TIME_FACTOR * fixed["time"]
    )
    if not (fewer or cheaper):
        return "misses"
    if learned["spurious"] > fixed["spurious"] + SPURIOUS_SLACK_POINTS:
        return "spurious"
    if learned["failures"] > fixed["failures"]:
        return "failures"
    return ""


def _paired(a: list[TrialRecord], b: list[TrialRecord]) -> str:
    comparison = paired_comparison(a, b, np.random.default_rng(RESAMPLE_SEED))
    low, high = comparison["missed_pct_diff_ci"]
    return (
        f"{comparison['missed_pct_diff']:+.1f} [{low:+.1f}, {high:+.1f}], "
        f"{comparison['wins']}/{comparison['losses']}/{comparison['ties']}, "
        f"p = {comparison['sign_test_p']:.2f}"
    )


def _cell(f: dict[str, float]) -> str:
    return f"{f['missed']:.1f} % / {f['time']:.1f} s / {f['spurious']:.0f} % / {f['failures']}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="eval.py --out folders")
    parser.add_argument(
        "--learned", nargs="+", help="count only these ppo: policies (default: every one)"
    )
    args = parser.parse_args()
    records = load_folders(args.folders)
    stats = {policy: figures(trials) for policy, trials in records.items()}
    learned = [p for p in records if p.startswith(PPO_SPEC_PREFIX)]
    if args.learned:
        unknown = sorted(set(args.learned) - set(learned))
        if unknown:
            raise SystemExit(f"--learned: no trials of {', '.join(unknown)} in the folders")
        learned = [p for p in learned if p in args.learned]
    fixed = [p for p in records if p.startswith(FIXED_PREFIXES)]
    if not learned or not fixed:
        raise SystemExit("need trials of at least one ppo: policy and one periodic/ftl point")
    print("missed / scan time / spurious / failures; paired: learned minus fixed, missed points")
    print("[95 % CI], wins/losses/ties of the learned policy, sign test\n")
    header = ("fixed point", "its figures", "best learned in its time", "figures", "paired")
    print("| " + " | ".join((*header, "dominates")) + " |")
    print("|---|---|---|---|---|---|")
    for point in fixed:
        within = [p for p in learned if stats[p]["time"] <= stats[point]["time"]]
        if not within:
            print(f"| {point} | {_cell(stats[point])} | none as fast | | | no: time |")
            continue
        best = min(within, key=lambda p: (stats[p]["missed"], stats[p]["time"]))
        failed = dominance_failure(stats[best], stats[point])
        verdict = "**yes**" if not failed else f"no: {failed}"
        print(
            f"| {point} | {_cell(stats[point])} | {best} | {_cell(stats[best])} | "
            f"{_paired(records[best], records[point])} | {verdict} |"
        )
    if "none" in stats:
        budget = CHEAP_END_TIME * stats["none"]["time"]
        print(f"\nWithin {CHEAP_END_TIME}x the no-rotation scan time ({budget:.1f} s):")
        for p in learned:
            if stats[p]["time"] > budget:
                continue
            fewer = 1.0 - stats[p]["missed"] / stats["none"]["missed"]
            verdict = "meets" if fewer >= CHEAP_END_FEWER else "misses"
            print(
                f"- {p}: {100 * abs(fewer):.0f} % {'fewer' if fewer >= 0 else 'more'} misses "
                f"than none at "
                f"{stats[p]['time'] / stats['none']['time']:.2f}x ({verdict} the "
                f"{100 * CHEAP_END_FEWER:.0f} % target); vs none "
                f"{_paired(records[p], records['none'])}"
            )
    for bound in sorted(b for b in stats if b.split(":")[0] == "privileged"):
        print(f"\nAgainst the privileged bound {bound} ({_cell(stats[bound])}):")
        for p in learned:
            print(f"- {p}: {_paired(records[p], records[bound])}")


if __name__ == "__main__":
    main()
