"""Shared pytest configuration."""

import os

# One BLAS/torch thread per test process: the suite runs with pytest-xdist on 2 cores.
os.environ.setdefault("OMP_NUM_THREADS", "1")

from hypothesis import settings

# Property-based tests draw their examples from a fixed seed: CI runs are reproducible.
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")
