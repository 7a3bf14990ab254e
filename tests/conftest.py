"""Shared pytest configuration."""

import os

# One BLAS/torch thread per test process: the suite runs with pytest-xdist on 2 cores.
os.environ.setdefault("OMP_NUM_THREADS", "1")
