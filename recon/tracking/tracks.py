"""What every point tracker returns and accepts (paper section IV-C): :class:`Tracks`, the
:class:`PointTracker` interface, and :func:`check_window`, the shared check of a tracking window
and its query pixels (implementations: see ``recon/tracking/__init__.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from recon.frame import Frame


@dataclass
class Tracks:
    """Where the queried pixels appear in each frame of the tracking window.

    Attributes:
        pixels: (M, N, 2) pixel coordinates (u, v), frames oldest to newest; NaN where not valid
            (enforced: invalid entries are overwritten with NaN).
        valid: (M, N) boolean, True where the track is reliable in that frame.
    """

    pixels: np.ndarray
    valid: np.ndarray

    def __post_init__(self) -> None:
        pixels = np.array(self.pixels, dtype=float)
        valid = np.asarray(self.valid)
        if pixels.ndim != 3 or pixels.shape[2] != 2:
            raise ValueError(f"pixels must have shape (M, N, 2), got {pixels.shape}")
        if valid.shape != pixels.shape[:2]:
            raise ValueError(f"valid must have shape {pixels.shape[:2]}, got {valid.shape}")
        if valid.dtype != bool:
            raise ValueError(f"valid must be boolean, got dtype {valid.dtype}")
        if not np.all(np.isfinite(pixels[valid])):
            raise ValueError("pixels must be finite wherever valid is True")
        pixels[~valid] = np.nan
        self.pixels, self.valid = pixels, valid


class PointTracker(Protocol):
    """Anything that tracks query pixels of the newest frame through the tracking window."""

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Track the queries.

        Args:
            frames: The M tracking frames, oldest first; the queries live in ``frames[-1]``.
            query_px: (N, 2) pixels (u, v) in the newest frame.

        Returns:
            Tracks with ``pixels`` (M, N, 2) and ``valid`` (M, N).
        """
        ...


def check_window(frames: Sequence[Frame], query_px: np.ndarray) -> tuple[list[Frame], np.ndarray]:
    """Validate a tracking window and its queries; return a list of frames and (N, 2) floats."""
    frames = list(frames)
    if not frames:
        raise ValueError("frames is empty: a tracking window needs at least one frame")
    query = np.asarray(query_px, dtype=float)
    if query.ndim != 2 or query.shape[1] != 2:
        raise ValueError(f"query_px must have shape (N, 2), got {query.shape}")
    if not np.all(np.isfinite(query)):
        raise ValueError("query_px contains NaN or infinite values")
    size = (frames[-1].intrinsics.width, frames[-1].intrinsics.height)
    for i, frame in enumerate(frames):
        if (frame.intrinsics.width, frame.intrinsics.height) != size:
            raise ValueError(f"frame {i} image size differs from the newest frame's {size}")
    return frames, query
