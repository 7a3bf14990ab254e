"""Run every benchmark, print the medians, write ``bench/results.json`` (one flat key a figure).

Usage: ``python -m bench.run [--only NAME ...] [--out PATH]``. Each benchmark module exposes
``run() -> dict[str, float]``; keys carry their unit (``_ms``, ``_s``, ``_per_s``).
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import math
import os
import platform
from pathlib import Path

# Benchmarks measure one core, as the issues' targets do.
os.environ.setdefault("OMP_NUM_THREADS", "1")

BENCHMARKS = [
    "bench.bench_recon",
    "bench.bench_segment",
    "bench.bench_sim",
    "bench.bench_scan",
    "bench.bench_env",
    "bench.bench_train",
    "bench.bench_ray",
]
DEFAULT_OUT = Path(__file__).with_name("results.json")
# Issue 14: PPO on 2 cores against twice the one-core env rate of the same steps (the training
# run's trees and action mix, bench_train); a ratio only from figures of the same run (machines
# differ by 2x).
TRAIN_KEYS = {
    "train_over_env_fast": "train_steps_per_s_fast",
    "train_over_env_fast_lockstep": "train_steps_per_s_fast_lockstep",
}
SAME_STEPS_KEY = "env_steps_per_s_train_trees"
# The same replays side by side (one process per core): what the machine allows 2 processes.
SIDE_BY_SIDE_KEY = "env_steps_per_s_side_by_side"
# The earlier denominator: the mix on bench_env's trees (not the training run's).
MIX_SEEDS_RATIO = ("train_over_env_fast_mix_seeds", "train_steps_per_s_fast", "env_steps_per_s_mix")
TRAIN_CORES = 2


def derived_figures(measured: dict[str, float]) -> dict[str, float]:
    """Ratios of figures measured in this run: ``train_over_env_fast`` (target >= 0.8).

    Each training rate over twice the single-core rate of the same steps
    (``env_steps_per_s_train_trees``); ``env_parallel_efficiency``: the side-by-side replays'
    rate over that same twice (the machine's ceiling for the ratio); ``train_over_side_by_side``:
    the worker-rollout rate over the side-by-side rate (what training itself loses); and
    ``train_over_env_fast_mix_seeds``: the worker-rollout rate over twice ``env_steps_per_s_mix``
    (bench_env's trees). Figures not measured in this run give no ratio.
    """
    ratios = {}
    env = measured.get(SAME_STEPS_KEY)
    for ratio, key in TRAIN_KEYS.items():
        if env and measured.get(key) is not None:
            ratios[ratio] = measured[key] / (TRAIN_CORES * env)
    side_by_side = measured.get(SIDE_BY_SIDE_KEY)
    if env and side_by_side is not None and math.isfinite(side_by_side):
        ratios["env_parallel_efficiency"] = side_by_side / (TRAIN_CORES * env)
        if measured.get(TRAIN_KEYS["train_over_env_fast"]) is not None:
            ratios["train_over_side_by_side"] = (
                measured[TRAIN_KEYS["train_over_env_fast"]] / side_by_side
            )
    ratio, train_key, mix_key = MIX_SEEDS_RATIO
    if measured.get(train_key) is not None and measured.get(mix_key):
        ratios[ratio] = measured[train_key] / (TRAIN_CORES * measured[mix_key])
    return ratios


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--only", nargs="*", default=None, help="module names to run")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    import cv2

    cv2.setNumThreads(1)  # OpenCV ignores OMP_NUM_THREADS
    results: dict[str, float] = {}
    measured: dict[str, float] = {}
    if args.out.exists():  # keep figures of benchmarks not run this time
        results.update(json.loads(args.out.read_text()))
    for name in BENCHMARKS:
        if args.only and name.split(".")[-1] not in args.only and name not in args.only:
            continue
        figures = importlib.import_module(name).run()
        for key, value in figures.items():
            print(f"{key:40s} {value:10.3f}")
        measured.update(figures)
    for key, value in derived_figures(measured).items():
        print(f"{key:40s} {value:10.3f}")
        measured[key] = value
    results.update(measured)
    results["machine"] = f"{platform.machine()} {os.cpu_count()} cpus"  # type: ignore[assignment]
    args.out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print(f"wrote {args.out}")
    return results


if __name__ == "__main__":
    main()
