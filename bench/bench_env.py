"""Environment throughput: ``env_steps_per_s`` (real LK tracking) and ``env_steps_per_s_oracle``.

Whole episodes of ``BranchScan-v0`` at the paper's settings (0.275 -> 0.75 m at 2.5 cm/s, paper
trees, ground-truth segmentation) with the no-rotation baseline, resets included, on one core
(the process is pinned to one CPU and OpenCV to one thread for the measurement). A step is one
modeling iteration: ~10 mm of travel, ~8 rendered frames, the pipeline, scoring and the
observation. ``env_overhead_ms`` is the env's own share per step (scoring against ground truth +
observation). Targets (issue "Gymnasium environment"): >= 15 and >= 50 steps/s.
``env_steps_per_s_oracle_fast`` is the oracle's fast training mode (``render_tracking_frames=
False``: only the frames an iteration runs on are rendered).
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager

import cv2
import gymnasium
import numpy as np

import branch_gym
from agents.baselines import NoRotationAgent

SEEDS = (0, 1, 2)
WARMUP_SEED = 100


@contextmanager
def _one_core():
    """Pin this process to one CPU and OpenCV to one thread; restore both afterwards."""
    threads = cv2.getNumThreads()
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    cv2.setNumThreads(1)
    if affinity:
        os.sched_setaffinity(0, {min(affinity)})
    try:
        yield
    finally:
        cv2.setNumThreads(threads)
        if affinity:
            os.sched_setaffinity(0, affinity)


def _steps_per_s(tracker: str, **kwargs: object) -> tuple[float, float]:
    """(env steps per second over whole episodes, median env overhead per step in ms)."""
    env = gymnasium.make(branch_gym.ENV_ID, tracker=tracker, info_timings=True, **kwargs)
    agent = NoRotationAgent()
    overhead_ms: list[float] = []

    def episode(seed: int) -> int:
        obs, _ = env.reset(seed=seed)
        steps, done = 0, False
        while not done:
            action, _ = agent.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            timings = info["timings_ms"]
            overhead_ms.append(timings["metrics_ms"] + timings["observation_ms"])
            steps, done = steps + 1, terminated or truncated
        return steps

    episode(WARMUP_SEED)
    overhead_ms.clear()
    start = time.perf_counter()
    steps = sum(episode(seed) for seed in SEEDS)
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed, float(np.median(overhead_ms))


def run() -> dict[str, float]:
    with _one_core():
        lk, lk_overhead = _steps_per_s("lk")
        oracle, _ = _steps_per_s("oracle")
        oracle_fast, _ = _steps_per_s("oracle", render_tracking_frames=False)
    return {
        "env_steps_per_s": lk,
        "env_steps_per_s_oracle": oracle,
        "env_steps_per_s_oracle_fast": oracle_fast,
        "env_overhead_ms": lk_overhead,
    }
