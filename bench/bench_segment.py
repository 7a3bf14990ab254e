"""Learned segmenter cost on one core: one 320x240 frame, rendering excluded.

Frames of straight-up scans of a few paper-default trees are rendered first (each with the frame
1 cm of climb before it); then the shipped segmenter (``load_segmenter("learned")``) segments
each frame, timed alone. Figures (medians, milliseconds):

* ``segment_ms``: ``LearnedSegmenter.segment(rgb, previous_rgb)``: the whole call, DIS optical
  flow included when the network takes flow. Target: <= 10 ms on one core (issue 15; the paper's
  GAN took 37 ms on a laptop GPU).
* ``segment_no_previous_ms``: the same without a previous frame (a scan's first frame: no flow).
* ``segment_cpu_ms``: CPU time of the ``segment_ms`` call (``time.thread_time``): what the call
  costs one core when other processes share the machine (wall time then grows, CPU time not).
* ``segment_torch_ms``: ``segment_ms`` with the network on PyTorch instead of ONNX Runtime
  (``load_segmenter("learned", runtime="torch")``, the runtime before; same masks), same run.
* ``segment_rgb_clean_ms``: ``segment_ms`` of the clean world's RGB-only network
  (``learned:.../rgb_clean.pt``, the default before issue 32), in the same run: the reference
  for machines that differ.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import torch

from branch_gym.segmenter_training.evaluate import EvaluateConfig, render_eval_frames
from recon.segmentation import load_segmenter
from recon.segmentation.segmenter import RGB_CLEAN_WEIGHTS

SEEDS = (0, 1, 2)  # fixed paper-default trees
FRAMES_PER_TREE = 8
WARMUP_CALLS = 3
REPEATS = 3  # each frame is segmented this many times


def bench_segment(spec: str = "learned", runtime: str = "auto") -> dict[str, float]:
    """Median milliseconds of one 320x240 frame on one core.

    Args:
        spec: Segmenter spec (``"learned"`` or ``"learned:PATH"``).
        runtime: What runs the network (``load_segmenter``'s ``runtime``).

    Returns:
        ``{"segment_ms": ..., "segment_no_previous_ms": ..., "segment_cpu_ms": ...}``.
    """
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    segmenter = load_segmenter(spec, runtime)
    config = EvaluateConfig(trees=len(SEEDS), frames_per_tree=FRAMES_PER_TREE)
    frames = [
        (previous, rgb)
        for seed in SEEDS
        for previous, rgb, *_ in render_eval_frames("paper", seed, config)
    ]
    for _ in range(WARMUP_CALLS):
        segmenter.segment(frames[0][1], frames[0][0])
    results = {}
    for key, with_previous in (("segment_ms", True), ("segment_no_previous_ms", False)):
        times, cpu_times = [], []
        for _ in range(REPEATS):
            for previous, rgb in frames:
                t0, c0 = time.perf_counter(), time.thread_time()
                segmenter.segment(rgb, previous if with_previous else None)
                cpu_times.append(1000.0 * (time.thread_time() - c0))
                times.append(1000.0 * (time.perf_counter() - t0))
        results[key] = float(np.median(times))
        if with_previous:
            results["segment_cpu_ms"] = float(np.median(cpu_times))
    return results


def run() -> dict[str, float]:
    """Entry point of ``bench/run.py``: :func:`bench_segment` of the shipped and the RGB network."""
    figures = bench_segment()
    figures["segment_torch_ms"] = bench_segment(runtime="torch")["segment_ms"]
    reference = bench_segment(f"learned:{RGB_CLEAN_WEIGHTS}")
    figures["segment_rgb_clean_ms"] = reference["segment_ms"]
    return figures


if __name__ == "__main__":
    print(bench_segment())
