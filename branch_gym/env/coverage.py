"""A view-coverage memory of the scan band: what the pipeline has seen, and from where.

A feed-forward policy cannot plan coverage from the latest image alone. :class:`CoverageMemory`
keeps, for height bins of the scan band, a small table the policy observes as one
``(height_bins, n_channels)`` float32 array in [0, 1]:

=============================  ==============================================================
channel                        meaning (per height bin)
=============================  ==============================================================
``0 .. A-1`` (``seen_from``)   1 once the bin was in view with the camera in rotation sector a
                               (sectors centred on ``sector_angles_deg``)
``A`` (``UNCONFIRMED``)        2D side-branch candidates whose base lies in the bin and that no
                               3D secondary explains, latest count / ``count_scale``
``A + 1`` (``FOUND``)          3D model secondaries with their base in the bin / ``count_scale``
                               (siblings often share a height)
``A + 2`` (``DISAGREEMENT``)   modeling iterations in the bin whose mask disagreed with the model
                               (inconsistent / restart: often a branch crossing the primary or
                               pointing at the lens) / ``count_scale``
``A + 3`` (``IN_FRONT``, v2)   tracked primary points that triangulated in front of the model
                               (``IterationReport.points_in_front``: something between the
                               camera and the primary, e.g. a branch pointing at the lens),
                               all iterations so far / ``count_scale``; only with
                               ``CoverageConfig.in_front_channel``
=============================  ==============================================================

Heights come from image rows through the camera's vertical field of view at the follow distance
``z_target`` (the image is kept level: row v maps to ``z_camera - (v - cy) z_target / fy``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from branch_gym.sim.validation import require_int, require_positive


@dataclass(frozen=True)
class CoverageConfig:
    """Layout of the coverage memory.

    Attributes:
        height_bins: Bins over the scan band (our choice: 16, ~3 cm over the paper's 0.275-0.75 m
            band, a quarter of the vertical FoV at z_target).
        sector_angles_deg: Centres of the rotation sectors (the discrete env's angles: the
            paper's +-22.5 and +-45 deg and 0); an angle counts for the nearest centre.
        count_scale: Counts are divided by this and clipped to 1 (the observation's count scale).
        in_front_channel: Add the ``IN_FRONT`` channel (the v2 observation).
    """

    height_bins: int = 16
    sector_angles_deg: tuple[float, ...] = (-45.0, -22.5, 0.0, 22.5, 45.0)
    count_scale: float = 10.0
    in_front_channel: bool = False

    def __post_init__(self) -> None:
        require_int(self, "height_bins", minimum=1)
        require_positive(self, "count_scale")
        if not self.sector_angles_deg:
            raise ValueError("CoverageConfig.sector_angles_deg must not be empty")

    @property
    def n_channels(self) -> int:
        return len(self.sector_angles_deg) + 3 + int(self.in_front_channel)


class CoverageMemory:
    """The coverage table of one scan (see the module docstring).

    Args:
        config: Layout.
        band_low_m, band_high_m: The scan band's bottom and top heights (m).
    """

    def __init__(self, config: CoverageConfig, band_low_m: float, band_high_m: float) -> None:
        if not band_low_m < band_high_m:
            raise ValueError(f"band_low_m ({band_low_m}) must be below band_high_m ({band_high_m})")
        self.config = config
        self.edges_m = np.linspace(band_low_m, band_high_m, config.height_bins + 1)
        self.reset()

    @property
    def unconfirmed_channel(self) -> int:
        return len(self.config.sector_angles_deg)

    def reset(self) -> None:
        """Forget everything (a new scan)."""
        sectors = len(self.config.sector_angles_deg)
        self.seen_from = np.zeros((self.config.height_bins, sectors), bool)
        self.unconfirmed = np.zeros(self.config.height_bins)
        self.found = np.zeros(self.config.height_bins)
        self.disagreement = np.zeros(self.config.height_bins)
        self.in_front = np.zeros(self.config.height_bins)

    def bins_of(self, heights_m: np.ndarray) -> np.ndarray:
        """Bin index of each height; -1 outside the band."""
        heights = np.asarray(heights_m, float)
        index = np.searchsorted(self.edges_m, heights, side="right") - 1
        index[heights == self.edges_m[-1]] = self.config.height_bins - 1
        index[(index < 0) | (index >= self.config.height_bins)] = -1
        return index

    def update(
        self,
        view_low_m: float,
        view_high_m: float,
        angle_deg: float,
        unconfirmed_heights_m: np.ndarray,
        found_heights_m: np.ndarray,
        disagreed_at_m: float | None,
        in_front_heights_m: np.ndarray | None = None,
    ) -> None:
        """Record one modeling iteration (or the iterations of one env step).

        Args:
            view_low_m, view_high_m: Heights at the bottom and top of the image at z_target.
            angle_deg: The camera's rotation about the branch (deg).
            unconfirmed_heights_m: Base heights of the 2D candidates no 3D secondary explains.
            found_heights_m: Base heights of all model secondaries (replaces the earlier ones).
            disagreed_at_m: The camera height if the iteration's mask disagreed with the model.
            in_front_heights_m: Heights of new points found in front of the model (added to the
                ``IN_FRONT`` counts).
        """
        centres = (self.edges_m[:-1] + self.edges_m[1:]) / 2.0
        in_view = (centres >= view_low_m) & (centres <= view_high_m)
        sector = int(np.argmin(np.abs(np.asarray(self.config.sector_angles_deg) - angle_deg)))
        self.seen_from[in_view, sector] = True
        self.unconfirmed[in_view] = 0.0  # the latest view of these bins is what counts
        self.found[:] = 0.0
        in_front = np.zeros(0) if in_front_heights_m is None else in_front_heights_m
        for counts, heights in (
            (self.unconfirmed, unconfirmed_heights_m),
            (self.found, found_heights_m),
            (self.in_front, in_front),
        ):
            index = self.bins_of(np.asarray(heights, float))
            np.add.at(counts, index[index >= 0], 1.0)
        if disagreed_at_m is not None:
            index = self.bins_of(np.array([disagreed_at_m]))
            if index[0] >= 0:
                self.disagreement[index[0]] += 1.0

    def as_array(self) -> np.ndarray:
        """(height_bins, n_channels) float32 in [0, 1]."""
        scale = self.config.count_scale
        columns = [self.unconfirmed, self.found, self.disagreement]
        if self.config.in_front_channel:
            columns.append(self.in_front)
        counts = np.column_stack(columns) / scale
        return np.concatenate(
            [self.seen_from.astype(np.float32), np.clip(counts, 0.0, 1.0).astype(np.float32)],
            axis=1,
        )


def rows_to_heights_m(
    rows_px: np.ndarray, camera_height_m: float, cy_px: float, fy_px: float, z_target_m: float
) -> np.ndarray:
    """World heights of image rows at the follow distance (the image is kept level)."""
    return camera_height_m - (np.asarray(rows_px, float) - cy_px) * z_target_m / fy_px
