"""research/miss_overlap.py: which policies miss the same side branches."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from research.miss_overlap import load_matches, report

FIELDS = ("seed", "policy", "branch", "in_scope", "matched", "miss")


def _write_branches(folder: Path, rows: list[tuple]) -> None:
    with (folder / "branches.csv").open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(FIELDS)
        writer.writerows(rows)


def test_counts_shared_and_own_misses(tmp_path: Path) -> None:
    # tree 0 branch 0: missed by a and b; branch 1: missed by a alone; branch 2: found by all;
    # branch 3 is out of scope and missed by everyone: not counted
    rows = []
    for policy in ("a", "b", "c"):
        rows.append((0, policy, 0, True, policy == "c", "" if policy == "c" else "seen"))
        rows.append((0, policy, 1, True, policy != "a", "never_seen" if policy == "a" else ""))
        rows.append((0, policy, 2, True, True, ""))
        rows.append((0, policy, 3, False, False, "seen"))
    _write_branches(tmp_path, rows)
    matches = load_matches(tmp_path)
    assert set(matches) == {("0", "0"), ("0", "1"), ("0", "2")}
    text = report(matches)
    assert "3 policies; 2 branches missed by at least one" in text
    assert "| 1 | 1 |" in text and "| 2 | 1 |" in text  # one branch missed alone, one by two
    assert "| a | 2 | 1 | 2 |" in text
    assert "| b | 1 | 0 | 1 |" in text
    assert "| c | 0 | 0 | 0 |" in text


def test_missing_folder_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"branches\.csv"):
        load_matches(tmp_path / "nowhere")
