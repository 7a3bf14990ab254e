"""Threads per process, set in one place.

``import branch_gym`` pins ``OMP_NUM_THREADS`` (BLAS, OpenMP) to :data:`branch_gym.BLAS_THREADS`
before numpy and torch load, for this process and the processes it starts. A worker process
(training env, DAgger labeller) also sets the thread pools of OpenCV and torch, which do not read
that variable once loaded, with :func:`pin_worker_threads`: workers run side by side, one per
core.
"""

from __future__ import annotations

import cv2
import torch

from branch_gym import BLAS_THREADS


def pin_worker_threads(threads: int = BLAS_THREADS) -> None:
    """Give this process's OpenCV and torch ``threads`` threads each."""
    cv2.setNumThreads(threads)
    torch.set_num_threads(threads)
