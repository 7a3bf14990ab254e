"""Run every benchmark, print the medians, write ``bench/results.json`` (one flat key a figure).

Usage: ``python -m bench.run [--only NAME ...] [--out PATH]``. Each benchmark module exposes
``run() -> dict[str, float]``; keys carry their unit (``_ms``, ``_s``, ``_per_s``).
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
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
# Issue 14: PPO on 2 cores against twice the one-core env rate of the same action mix; a ratio
# only from figures of the same run (machines differ by 2x).
LOCKSTEP_KEY = "train_steps_per_s_fast_lockstep"
TRAIN_RATIO_KEYS = ("train_steps_per_s_fast", "env_steps_per_s_mix")
TRAIN_CORES = 2


def derived_figures(measured: dict[str, float]) -> dict[str, float]:
    """Ratios of figures measured in this run: ``train_over_env_fast`` (target >= 0.8).

    Also ``train_over_env_fast_lockstep``: the same ratio for SB3's lockstep collection.
    """
    train, env = (measured.get(key) for key in TRAIN_RATIO_KEYS)
    if train is None or env is None or env <= 0:
        return {}
    ratios = {"train_over_env_fast": train / (TRAIN_CORES * env)}
    lockstep = measured.get(LOCKSTEP_KEY)
    if lockstep is not None:
        ratios["train_over_env_fast_lockstep"] = lockstep / (TRAIN_CORES * env)
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
