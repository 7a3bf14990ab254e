"""Ray backend of the evaluation: what ``eval.py --backend ray`` costs over the process pool.

The same small evaluation (2 policies x 2 trees, depth-oracle tracker, scans ending at 0.4 m, 2
workers) runs with the process-pool backend and with the Ray backend, each into a fresh output
folder, a few times in alternation; each figure is the median over the repeats.

- ``ray_overhead_ms_per_trial``: (Ray wall time - pool wall time) / trials, the Ray wall time
  being what ``eval.py --backend ray`` spends: start a private local Ray instance, run the trials
  as tasks, shut Ray down. Its fixed part (start + shutdown) dominates a 4-trial evaluation and
  is amortised over a long one.
- ``ray_init_s``: that fixed part alone (``ray.init`` + ``ray.shutdown``).
- ``ray_run_overhead_ms_per_trial``: the per-trial difference without it. It can be negative:
  Ray starts its worker processes during ``ray.init``, the pool spawns its workers in the run.
- ``ray_trial_s``: one trial's wall time on one worker (the pool's wall time x workers / trials).
- ``ray_run_overhead_share_of_trial``: ``ray_run_overhead_ms_per_trial`` over ``ray_trial_s``
  (issue 60: Ray's overhead under 5 % of a trial; these trials are ~5x shorter than an orchard
  trial from pixels, so the share of a benchmark trial is ~5x smaller).
- ``ray_trials_to_amortise_init``: how many trials an evaluation needs before the fixed start
  and shutdown cost less than 5 % of a trial each, with the run overhead (when positive) on top:
  ``ray_init_s / (0.05 ray_trial_s - run overhead)``; infinite when the run overhead alone is
  over 5 %.

Without Ray installed the benchmark logs a warning and reports nothing.
"""

from __future__ import annotations

import logging
import math
import statistics
import tempfile
import time
from pathlib import Path

from agents.factory import AGENTS
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.ray_backend import init_local
from branch_gym.evaluation.runner import run_trials
from branch_gym.scan import ScanConfig

logger = logging.getLogger(__name__)

POLICIES = ("none", "periodic:22.5:1.5")
TREES = 2
WORKERS = 2  # the machine's cores
SCAN = ScanConfig(tracker="oracle", end_height_m=0.4)  # ~2 s of CPU a trial
REPEATS = 3
OVERHEAD_BUDGET = 0.05  # issue 60: Ray's overhead per trial under 5 % of a trial


def _wall_s(config: EvalConfig) -> float:
    """Wall time of running all trials of ``config`` into a fresh folder."""
    with tempfile.TemporaryDirectory(prefix="bench_ray_") as out:
        start = time.perf_counter()
        run_trials(config, Path(out), config.keys)
        return time.perf_counter() - start


def run() -> dict[str, float]:
    try:
        import ray
    except ImportError:
        logger.warning("bench_ray: Ray is not installed (pip install '.[ray]'): skipped")
        return {}
    pool = EvalConfig(POLICIES, TREES, workers=WORKERS, scan=SCAN, policy_factory=AGENTS)
    on_ray = EvalConfig(
        POLICIES, TREES, workers=WORKERS, scan=SCAN, backend="ray", policy_factory=AGENTS
    )
    trials = len(pool.keys)
    total_ms, run_ms, init_s, trial_s = [], [], [], []
    for _ in range(REPEATS):
        pool_s = _wall_s(pool)
        start = time.perf_counter()
        init_local(ray, WORKERS)
        started_s = time.perf_counter() - start
        try:
            ray_s = _wall_s(on_ray)  # uses the running instance
        finally:
            start = time.perf_counter()
            ray.shutdown()
        init_s.append(started_s + time.perf_counter() - start)
        total_ms.append((init_s[-1] + ray_s - pool_s) / trials * 1e3)
        run_ms.append((ray_s - pool_s) / trials * 1e3)
        trial_s.append(pool_s * WORKERS / trials)
        logger.info(
            "%d trials: pool %.2f s, ray %.2f s + %.2f s init", trials, pool_s, ray_s, init_s[-1]
        )
    run_overhead_s = statistics.median(run_ms) / 1e3
    one_trial_s = statistics.median(trial_s)
    budget_left_s = OVERHEAD_BUDGET * one_trial_s - max(run_overhead_s, 0.0)
    return {
        "ray_overhead_ms_per_trial": statistics.median(total_ms),
        "ray_init_s": statistics.median(init_s),
        "ray_run_overhead_ms_per_trial": run_overhead_s * 1e3,
        "ray_trial_s": one_trial_s,
        "ray_run_overhead_share_of_trial": run_overhead_s / one_trial_s,
        "ray_trials_to_amortise_init": (
            statistics.median(init_s) / budget_left_s if budget_left_s > 0 else math.inf
        ),
    }
