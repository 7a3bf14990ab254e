"""Wall-clock stage timings: ``with stage_timer(timings, "curve2d_ms"): ...``.

The pipeline reports where its time goes as a dict of stage name -> milliseconds
(``IterationReport.timings_ms``, the env's ``info["timings_ms"]``). :func:`stage_timer` is the
one way those numbers are taken.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, MutableMapping
from contextlib import contextmanager

__all__ = ["stage_timer"]


@contextmanager
def stage_timer(timings: MutableMapping[str, float], key: str) -> Iterator[None]:
    """Add the wall-clock milliseconds the block takes to ``timings[key]`` (0 if absent).

    The time is added also when the block raises or returns early.

    Args:
        timings: Stage name -> milliseconds; updated in place.
        key: The stage's name (by convention ending in ``_ms``).
    """
    start = time.perf_counter()
    try:
        yield
    finally:
        timings[key] = timings.get(key, 0.0) + (time.perf_counter() - start) * 1e3
