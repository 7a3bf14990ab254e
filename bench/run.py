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
    "bench.bench_benchmark",
]
DEFAULT_OUT = Path(__file__).with_name("results.json")
TRAIN_CORES = 2
# Issue 14: ratios only from figures of the same run (machines differ by 2x), each
# (name, numerator, denominator, cores): numerator / (cores x denominator). The training rates
# over twice the one-core rate of the same steps (bench_train replays the training run's trees
# and action mix); what the machine allows two processes side by side, and what training keeps of
# it; the earlier denominator, the mix on bench_env's trees.
RATIOS = (
    ("train_over_env_fast", "train_steps_per_s_fast", "env_steps_per_s_train_trees", TRAIN_CORES),
    ("train_over_env_fast_lockstep", "train_steps_per_s_fast_lockstep",
     "env_steps_per_s_train_trees", TRAIN_CORES),
    ("env_parallel_efficiency", "env_steps_per_s_side_by_side", "env_steps_per_s_train_trees",
     TRAIN_CORES),
    ("train_over_side_by_side", "train_steps_per_s_fast", "env_steps_per_s_side_by_side", 1),
    ("train_over_env_fast_mix_seeds", "train_steps_per_s_fast", "env_steps_per_s_mix", TRAIN_CORES),
    ("render_orchard_over_clean", "render_frame_orchard_ms", "render_frame_ms", 1),
    ("render_orchard_fast_over_clean", "render_frame_orchard_fast_ms", "render_frame_ms", 1),
    ("train_fast_clean_over_orchard", "train_steps_per_s_fast",
     "train_steps_per_s_fast_orchard_learned", 1),
)  # fmt: skip


def derived_figures(measured: dict[str, float]) -> dict[str, float]:
    """The :data:`RATIOS` whose two figures were measured in this run (and are finite):
    ``train_over_env_fast`` has the target >= 0.8."""
    ratios = {}
    for name, numerator_key, denominator_key, cores in RATIOS:
        numerator, denominator = measured.get(numerator_key), measured.get(denominator_key)
        if numerator is None or denominator is None:
            continue
        if math.isfinite(numerator) and math.isfinite(denominator) and denominator > 0:
            ratios[name] = numerator / (cores * denominator)
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
