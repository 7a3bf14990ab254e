"""Do the policies of one table miss the same side branches? A study for issue 34.

The dominance figure compares policies whose misses differ by one or two branches of ~155. This
script reads the ``branches.csv`` of an ``eval.py --out`` folder (one row per in-scope ground-truth
side branch and policy) and asks how much of a policy's misses are the tree's (branches every
policy misses) and how much are the scan's own (a branch one policy misses and the others find).

    python research/miss_overlap.py results/orchard_pixels_v6

Prints how many branches are missed by exactly k of the folder's policies, and for each policy
its misses, how many of them no other policy shares and how many at most one other does.
"""

from __future__ import annotations

import argparse
import csv
from collections import Counter, defaultdict
from pathlib import Path


def load_matches(folder: Path) -> dict[tuple[str, str], dict[str, bool]]:
    """(seed, branch) -> {policy: matched} over the in-scope branches of ``folder/branches.csv``."""
    path = folder / "branches.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist: give an eval.py --out folder")
    matches: dict[tuple[str, str], dict[str, bool]] = defaultdict(dict)
    with path.open(newline="") as file:
        for row in csv.DictReader(file):
            if row["in_scope"] == "True":
                matches[(row["seed"], row["branch"])][row["policy"]] = row["matched"] == "True"
    return matches


def report(matches: dict[tuple[str, str], dict[str, bool]]) -> str:
    """The two tables of the module docstring, as Markdown."""
    policies = sorted({policy for by_policy in matches.values() for policy in by_policy})
    missed_by = {
        key: {policy for policy, matched in by_policy.items() if not matched}
        for key, by_policy in matches.items()
    }
    sharing = Counter(len(who) for who in missed_by.values() if who)
    lines = [
        f"{len(policies)} policies; {sum(sharing.values())} branches missed by at least one",
        "",
        "| missed by k policies | branches |",
        "|---|---|",
        *(f"| {k} | {sharing[k]} |" for k in sorted(sharing)),
        "",
        "| policy | missed | missed by no other policy | by at most one other |",
        "|---|---|---|---|",
    ]
    for policy in policies:
        own = [len(who) for who in missed_by.values() if policy in who]
        lines.append(
            f"| {policy} | {len(own)} | {sum(n == 1 for n in own)} | {sum(n <= 2 for n in own)} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder", type=Path, help="an eval.py --out folder")
    print(report(load_matches(parser.parse_args().folder)))


if __name__ == "__main__":
    main()
