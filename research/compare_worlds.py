"""Side by side: the same policies evaluated in several worlds (``eval.py`` output folders).

Usage::

    python research/compare_worlds.py clean=results/dagger_table orchard=results/orchard_table

Prints one markdown table: a row per policy and world, with missed, spurious and duplicate
percentages, the residuals, failures and scan time from each folder's ``summary.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

COLUMNS = (
    ("missed %", lambda s: f"{s['missed_pct']:.1f}"),
    ("95 % interval", lambda s: "[{:.1f}, {:.1f}]".format(*s["missed_pct_ci"])),
    ("never seen %", lambda s: f"{s['missed_never_seen_pct']:.1f}"),
    ("spurious %", lambda s: f"{s['spurious_pct']:.1f}"),
    ("duplicates %", lambda s: f"{s['duplicate_pct']:.1f}"),
    ("PB residual mm", lambda s: "{mean:.1f} ({std:.1f})".format(**s["pb_residual_mm"])),
    ("SB residual mm", lambda s: "{mean:.1f} ({std:.1f})".format(**s["sb_residual_mm"])),
    ("failures", lambda s: f"{s['failures']} / {s['trials']}"),
    ("scan time s", lambda s: "{mean:.1f}".format(**s["scan_time_s"])),
)


def comparison_table(folders: dict[str, Path]) -> str:
    """Markdown table over every folder's policies (first seen first), a row per (policy, world)."""
    summaries = {
        name: json.loads((folder / "summary.json").read_text())["policies"]
        for name, folder in folders.items()
    }
    header = "| policy | world | " + " | ".join(name for name, _ in COLUMNS) + " |"
    lines = [header, "|" + "---|" * (len(COLUMNS) + 2)]
    policies_seen = dict.fromkeys(p for policies in summaries.values() for p in policies)
    for policy in policies_seen:
        for world, policies in summaries.items():
            if policy in policies:
                cells = " | ".join(cell(policies[policy]) for _, cell in COLUMNS)
                lines.append(f"| {policy} | {world} | {cells} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("folders", nargs="+", metavar="NAME=FOLDER")
    args = parser.parse_args(argv)
    folders = {}
    for item in args.folders:
        name, _, folder = item.partition("=")
        if not folder:
            parser.error(f"expected NAME=FOLDER, got {item!r}")
        if not (Path(folder) / "summary.json").is_file():
            parser.error(f"{folder} holds no summary.json (run eval.py first)")
        folders[name] = Path(folder)
    print(comparison_table(folders))


if __name__ == "__main__":
    main()
