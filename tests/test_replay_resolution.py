"""research/replay_resolution.py: its table of the replays found in the work folder."""

from __future__ import annotations

import json
from pathlib import Path

from research.replay_resolution import VARIANTS, table


def _summary(folder: Path, width: int, missed: int, residuals: list[float]) -> None:
    folder.mkdir(parents=True)
    metrics = {"n_gt": 3, "n_missed": missed, "n_spurious": 1, "pb_residuals_m": residuals}
    summary = {"camera": {"width": width, "height": width * 3 // 4}, "wall_time_s": 4.0}
    (folder / "summary.json").write_text(json.dumps({**summary, "metrics": metrics}))


def test_the_table_pools_the_trees_of_each_replay(tmp_path: Path) -> None:
    for seed in (0, 1):
        _summary(tmp_path / f"replay0_{seed}", 320, 0, [0.001, 0.003])
        _summary(tmp_path / f"replay1_{seed}", 640, seed + 1, [0.006])
    lines = table(tmp_path, [0, 1, 2]).splitlines()  # tree 2 not there: left out
    names = list(VARIANTS)
    assert lines[2] == f"| {names[0]} | 2 | 320x240 | 0 of 6 | 2 | 2.0 | 4 |"
    assert lines[3] == f"| {names[1]} | 2 | 640x480 | 3 of 6 | 2 | 6.0 | 4 |"
    assert len(lines) == 4  # the third replay has no tree yet
