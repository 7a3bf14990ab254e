"""A learned point tracker (PIPs-class: M RGB images in, tracks and visibility out) behind the
:class:`~recon.tracking.tracks.PointTracker` interface."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from recon.frame import Frame
from recon.tracking.tracks import Tracks, check_window

# A learned tracker: (M, H, W, 3) uint8 images and (N, 2) query pixels -> (M, N, 2) tracks and
# (M, N) visibility.
LearnedTrackFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


class LearnedTrackerAdapter:
    """Puts a learned tracker (PIPs-class) behind the :class:`PointTracker` interface.

    Args:
        track_fn: ``(images (M, H, W, 3) uint8, query_px (N, 2)) -> (tracks (M, N, 2), visible
            (M, N))``. By default the images are ordered oldest to newest and the queries live in
            the last image.
        queries_in_first_image: Set for models that query the first image (PIPs does): the images
            are then passed newest first and the outputs flipped back.
    """

    def __init__(self, track_fn: LearnedTrackFn, queries_in_first_image: bool = False) -> None:
        self.track_fn = track_fn
        self.queries_in_first_image = queries_in_first_image

    def track(self, frames: Sequence[Frame], query_px: np.ndarray) -> Tracks:
        """Run the learned tracker; see :class:`PointTracker`.

        Tracks outside the image or not finite are marked invalid.

        Raises:
            ValueError: the model's outputs have the wrong shape.
        """
        frames, query = check_window(frames, query_px)
        images = np.stack([frame.rgb for frame in frames])
        if self.queries_in_first_image:
            images = images[::-1]
        tracks, visible = self.track_fn(images, query.copy())
        tracks = np.asarray(tracks, dtype=float)
        visible = np.asarray(visible)
        expected = (len(frames), len(query))
        if tracks.shape != (*expected, 2):
            raise ValueError(
                f"learned tracker returned tracks {tracks.shape}, expected {(*expected, 2)}"
            )
        if visible.shape != expected:
            raise ValueError(
                f"learned tracker returned visible {visible.shape}, expected {expected}"
            )
        if self.queries_in_first_image:
            tracks, visible = tracks[::-1], visible[::-1]
        in_image = np.stack([f.intrinsics.in_image(t) for f, t in zip(frames, tracks, strict=True)])
        valid = visible.astype(bool) & np.all(np.isfinite(tracks), axis=2) & in_image
        return Tracks(np.where(valid[..., None], tracks, np.nan), valid)
