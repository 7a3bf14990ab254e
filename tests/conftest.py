"""Shared pytest configuration."""

# One BLAS/torch thread per test process (the suite runs with pytest-xdist on 2 cores): importing
# branch_gym pins it, before anything loads numpy.
from hypothesis import settings

import branch_gym  # noqa: F401

# Property-based tests draw their examples from a fixed seed: CI runs are reproducible.
settings.register_profile("deterministic", derandomize=True)
settings.load_profile("deterministic")
