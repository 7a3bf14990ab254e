"""What one policy on ``orchard-v2``'s test split costs on this machine's 2 cores.

A timed sample: the paper's controller (the benchmark's reference policy) scans the first
:data:`SAMPLE_TREES` test trees of each stratum from pixels, :data:`WORKERS` trials at once on the
process pool (as ``eval.py --benchmark orchard-v2 --workers 2`` runs them). The figures:

- ``benchmark_trial_s``: the sample's wall time per trial on 2 workers (s);
- ``benchmark_policy_minutes_2cores``: that times the split's trees, in minutes (issue 60: at
  most 30): one policy's whole test split extrapolated from the sample.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from agents.factory import AGENTS
from branch_gym.evaluation.benchmark import benchmark
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.runner import run_trials

BENCHMARK = "orchard-v2"
SAMPLE_TREES = 4  # per stratum: two rounds of the two workers
WORKERS = 2  # the machine's cores


def run() -> dict[str, float]:
    bench = benchmark(BENCHMARK)
    wall_s, trials, split_trees = 0.0, 0, 0
    for stratum in bench.strata:
        first, count = stratum.seeds("test")
        split_trees += count
        config = EvalConfig(
            (bench.reference_policy,),
            SAMPLE_TREES,
            first,
            WORKERS,
            bench.scan_config(stratum),
            policy_factory=AGENTS,
        )
        with tempfile.TemporaryDirectory(prefix="bench_benchmark_") as out:
            start = time.perf_counter()
            run_trials(config, Path(out), config.keys)
            wall_s += time.perf_counter() - start
        trials += len(config.keys)
    trial_s = wall_s / trials
    return {
        "benchmark_trial_s": trial_s,
        "benchmark_policy_minutes_2cores": trial_s * split_trees / 60.0,
    }
