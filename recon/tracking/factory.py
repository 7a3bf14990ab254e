"""Point trackers by name: the one place a ``--tracker`` / ``ScanConfig.tracker`` name is read.

=========  ==========================================================================
name       tracker
=========  ==========================================================================
``lk``     :class:`LucasKanadeTracker`, on the images (what a real robot runs)
``oracle`` :class:`DepthOracleTracker`, exact tracks from the frames' depth (the renderer's
           or an RGB-D camera's): ablations and fast training
=========  ==========================================================================
"""

from __future__ import annotations

from recon.tracking.depth_oracle import DepthOracleTracker
from recon.tracking.lucas_kanade import LucasKanadeTracker
from recon.tracking.tracks import PointTracker

TRACKERS = ("lk", "oracle")
"""The tracker names :func:`make_tracker` knows (module docstring)."""


def make_tracker(name: str, names: tuple[str, ...] = TRACKERS) -> PointTracker:
    """The point tracker called ``name``, with its default settings.

    Args:
        name: One of ``names``.
        names: The trackers the caller accepts (a subset of :data:`TRACKERS`; a recording has no
            depth, so the replay takes ``("lk",)``).

    Raises:
        ValueError: a name not in ``names``, listing them.
    """
    if name not in names:
        raise ValueError(f"unknown tracker {name!r}: expected one of {names}")
    if name == "lk":
        return LucasKanadeTracker()
    return DepthOracleTracker()
