"""The view-coverage memory (branch_gym/env/coverage.py) after a scripted sequence of views."""

from __future__ import annotations

import numpy as np
import pytest

from branch_gym.env.coverage import CoverageConfig, CoverageMemory, rows_to_heights_m

CONFIG = CoverageConfig(height_bins=5, sector_angles_deg=(-22.5, 0.0, 22.5), count_scale=10.0)


def test_scripted_views_fill_the_table() -> None:
    memory = CoverageMemory(CONFIG, 0.3, 0.8)  # bins of 10 cm: centres 0.35 .. 0.75
    memory.update(0.30, 0.42, 0.0, np.array([0.36, 0.37]), np.zeros(0), None)
    memory.update(0.40, 0.52, 22.5, np.zeros(0), np.array([0.45]), 0.46)
    memory.update(0.40, 0.52, 1.0, np.array([0.45]), np.array([0.45, 0.47]), None)  # ~0 deg
    table = memory.as_array()
    assert table.shape == (5, CONFIG.n_channels) and table.dtype == np.float32
    seen = table[:, :3]
    np.testing.assert_array_equal(seen[:, 1], [1, 1, 0, 0, 0])  # from 0 deg: bins 0 and 1
    np.testing.assert_array_equal(seen[:, 2], [0, 1, 0, 0, 0])  # from +22.5: bin 1
    assert not seen[:, 0].any()  # never from -22.5
    unconfirmed, found, disagreement = table[:, 3], table[:, 4], table[:, 5]
    assert unconfirmed[0] == pytest.approx(0.2)  # two candidates, bin 0 not viewed again
    assert unconfirmed[1] == pytest.approx(0.1)  # the latest view of bin 1 holds one
    assert found[1] == pytest.approx(0.2) and found.sum() == pytest.approx(0.2)
    assert disagreement[1] == pytest.approx(0.1) and disagreement.sum() == pytest.approx(0.1)
    memory.reset()
    assert not memory.as_array().any()


def test_heights_outside_the_band_are_dropped_and_rows_map_to_heights() -> None:
    memory = CoverageMemory(CONFIG, 0.3, 0.8)
    np.testing.assert_array_equal(memory.bins_of(np.array([0.1, 0.3, 0.8, 0.9])), [-1, 0, 4, -1])
    heights = rows_to_heights_m(np.array([120.0, 0.0]), 0.5, 120.0, 400.0, 0.2)
    np.testing.assert_allclose(heights, [0.5, 0.56])
    with pytest.raises(ValueError, match="band_low_m"):
        CoverageMemory(CONFIG, 0.8, 0.3)


def test_points_in_front_of_the_primary_accumulate_in_their_height_bins() -> None:
    """v2's IN_FRONT channel: counts of every step add up; v1's layout stays 3 + A channels."""
    config = CoverageConfig(
        height_bins=5, sector_angles_deg=(-22.5, 0.0, 22.5), in_front_channel=True
    )
    assert config.n_channels == CONFIG.n_channels + 1
    memory = CoverageMemory(config, 0.3, 0.8)
    memory.update(0.30, 0.42, 0.0, np.zeros(0), np.zeros(0), None, np.array([0.36, 0.37, 0.95]))
    memory.update(0.40, 0.52, 22.5, np.zeros(0), np.zeros(0), None, np.array([0.38]))
    memory.update(0.50, 0.62, 22.5, np.zeros(0), np.zeros(0), None)
    in_front = memory.as_array()[:, -1]
    np.testing.assert_allclose(in_front, [0.3, 0, 0, 0, 0])  # 0.95 m lies above the band
    v1 = CoverageMemory(CONFIG, 0.3, 0.8)
    v1.update(0.30, 0.42, 0.0, np.zeros(0), np.zeros(0), None, np.array([0.36]))
    assert v1.as_array().shape == (5, CONFIG.n_channels)
