"""research/real_frame_errors.py: where the image's edges lie against a mask's outline."""

from __future__ import annotations

import numpy as np

from research.real_frame_errors import OUTLINE_OFFSETS_PX, boundary_contrast, grown


def _bar_frame() -> tuple[np.ndarray, np.ndarray]:
    """A dark vertical bar, columns 20-29, on a bright sky: (rgb, its exact mask)."""
    rgb = np.full((40, 50, 3), 200, np.uint8)
    rgb[:, 20:30] = 40
    exact = np.zeros((40, 50), bool)
    exact[:, 20:30] = True
    return rgb, exact


def test_the_largest_gradient_is_on_the_outline_that_follows_the_edges() -> None:
    rgb, exact = _bar_frame()
    rows = np.zeros_like(exact)
    rows[5:35] = True  # away from the frame's top and bottom, where the bar's ends are cut
    for drawn_inside_px in (0, 1, 2):
        mask = grown(exact, -drawn_inside_px)
        means = [v.mean() for v in boundary_contrast(rgb, mask, rows, OUTLINE_OFFSETS_PX)]
        assert OUTLINE_OFFSETS_PX[int(np.argmax(means))] == drawn_inside_px


def test_grown_shrinks_and_grows_by_whole_pixels() -> None:
    _, exact = _bar_frame()
    assert grown(exact, 0).sum() == exact.sum()
    assert grown(exact, 1)[10].sum() == 12 and grown(exact, -2)[10].sum() == 6
