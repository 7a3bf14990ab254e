"""Full scans: ``scan_s``, median wall seconds per no-rotation scan of one tree, real LK tracking.

The scan includes the world reset (new tree), every render, segmentation, tracking, modeling and
control step, from the home pose to the end height (0.275 -> 0.75 m at 2.5 cm/s). Target: <= 4 s
on one core (issue "Follow-the-leader scans").
"""

from __future__ import annotations

import time

import numpy as np

from agents.factory import AGENTS
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig

SEEDS = (0, 1, 2, 3, 4)


def run() -> dict[str, float]:
    config = ScanConfig()
    run_trial(100, "none", config, AGENTS)  # warm-up: process start, first world, caches
    seconds = []
    for seed in SEEDS:
        start = time.perf_counter()
        run_trial(seed, "none", config, AGENTS)
        seconds.append(time.perf_counter() - start)
    return {"scan_s": float(np.median(seconds))}
