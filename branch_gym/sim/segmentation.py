"""Segmentation models: instance label image (+ RGB) -> binary branch mask.

The paper's masks come from a learned segmenter (paper section III, a GAN on RGB + optical
flow) that "fails fairly regularly" (section VIII): ragged boundaries, lost thin branches,
spurious blobs, background trunks and trellis wires leaking in. :class:`NoisySegmenter`
imitates those failures on top of the renderer's exact instance labels, reproducibly from the
``rng`` it is given; :class:`GroundTruthSegmenter` is the oracle.

Instance label image convention (renderer output, segmenter input): int32 (H, W) with
0 = background / ground / backdrop, 1 = primary, 2 + i = secondary i, 100 + k = clutter object k;
the orchard world's sky, ground, trellis and row have labels of their own
(``branch_gym/sim/scene/labels.py``). Clutter that leaks into a mask is anything but the sky and
the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Protocol

import cv2
import numpy as np

from branch_gym.sim.scene.labels import (  # the label convention (module docstring)
    BACKGROUND_LABEL,
    is_occluding_clutter,
    is_scanned_tree,
)
from branch_gym.sim.validation import require_non_negative

PRESET_NAMES = ("mild", "moderate", "severe")
SEGMENTER_NAMES = ("gt", *(f"noisy:{preset}" for preset in PRESET_NAMES))
_FULL_TURN_DEG = 360.0


class Segmenter(Protocol):
    """Anything that turns a rendered frame into a branch mask."""

    def segment(self, rgb: np.ndarray, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Segment one frame.

        Args:
            rgb: (H, W, 3) uint8 colour image.
            labels: (H, W) int32 instance labels (module docstring convention).
            rng: Source of every random draw.

        Returns:
            (H, W) bool mask, True on (what the model believes is) the scanned tree.
        """
        ...


def _check_frame(rgb: np.ndarray, labels: np.ndarray) -> None:
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(
            f"labels must be an integer (H, W) image, got {labels.dtype} {labels.shape}"
        )
    if rgb.shape != (*labels.shape, 3) or rgb.dtype != np.uint8:
        raise ValueError(
            f"rgb must be uint8 with shape {(*labels.shape, 3)}, got {rgb.dtype} {rgb.shape}"
        )
    if labels.size and labels.min() < BACKGROUND_LABEL:
        raise ValueError(f"labels must be non-negative, got minimum {labels.min()}")


def _is_branch(label_ids: np.ndarray) -> np.ndarray:
    return is_scanned_tree(label_ids)


class GroundTruthSegmenter:
    """The oracle: exactly the primary and secondary pixels (1 <= label < 100)."""

    def segment(self, rgb: np.ndarray, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        _check_frame(rgb, labels)
        return _is_branch(labels)


@dataclass(frozen=True)
class NoisySegmenterConfig:
    """Failure model of a learned segmenter. Defaults are the "moderate" preset.

    The paper gives no error rates for its segmenter; these values are this project's choice,
    scaled to the paper's image (320x240, branches 10-30 px wide at 0.20 m).

    Attributes:
        boundary_jitter_px: Standard deviation in px of a smooth random field that moves the
            mask boundary outward (positive) or inward (negative); 0 disables.
        boundary_jitter_cell_px: Correlation length of that field in px (its grid spacing).
        thin_width_px: Branch instances whose apparent width (diameter of the largest disc that
            fits inside) is below this are "thin".
        thin_drop_prob: Probability that a thin instance is missing from the mask in a frame.
        blob_rate: Mean number (Poisson) of false-positive ellipses per frame.
        blob_axis_range_px: (low, high) semi-axis lengths of those ellipses in px.
        clutter_leak_prob: Probability that a visible clutter object (label >= 100: background
            trees, wires) is segmented as branch in a frame.
        chunk_rate: Mean number (Poisson) of missing discs cut out of the branch mask per frame.
        chunk_radius_range_px: (low, high) radius of those discs in px.
    """

    # All values: project choice (no segmenter error rates in the paper). At 0.20 m with
    # fx = 416.8 px (reference.md, camera) one pixel spans 0.48 mm.
    boundary_jitter_px: float = 1.0  # ragged edges about one pixel deep
    boundary_jitter_cell_px: int = 24  # raggedness varies over ~1 cm along a branch
    thin_width_px: float = 6.0  # ~2.9 mm thick branches at 0.20 m are at risk
    thin_drop_prob: float = 0.3
    blob_rate: float = 0.5  # one spurious blob every other frame
    blob_axis_range_px: tuple[float, float] = (2.0, 8.0)
    clutter_leak_prob: float = 0.2  # paper VI-C: background trunks were hard to remove
    chunk_rate: float = 0.3
    chunk_radius_range_px: tuple[float, float] = (3.0, 10.0)

    def __post_init__(self) -> None:
        ranges = [f.name for f in fields(self) if f.name.endswith("_range_px")]
        require_non_negative(self, *(f.name for f in fields(self) if f.name not in ranges))
        for name in ranges:
            value = getattr(self, name)
            if len(value) != 2 or not value[0] <= value[1]:
                raise ValueError(f"{name} must be a (low, high) pair, got {value}")
            if value[0] < 0:
                raise ValueError(f"{name} must be non-negative, got {value}")
        for name in ("thin_drop_prob", "clutter_leak_prob"):
            if getattr(self, name) > 1:
                raise ValueError(f"{name} is a probability in [0, 1], got {getattr(self, name)}")
        if self.boundary_jitter_cell_px < 1:
            raise ValueError(
                f"boundary_jitter_cell_px must be >= 1, got {self.boundary_jitter_cell_px}"
            )

    @classmethod
    def preset(cls, name: str) -> NoisySegmenterConfig:
        """A named severity: "mild", "moderate" (the defaults) or "severe"."""
        if name == "mild":
            return cls(
                boundary_jitter_px=0.5,
                thin_width_px=4.0,
                thin_drop_prob=0.1,
                blob_rate=0.1,
                clutter_leak_prob=0.05,
                chunk_rate=0.05,
            )
        if name == "moderate":
            return cls()
        if name == "severe":
            return cls(
                boundary_jitter_px=2.5,
                thin_width_px=10.0,
                thin_drop_prob=0.5,
                blob_rate=1.5,
                blob_axis_range_px=(3.0, 14.0),
                clutter_leak_prob=0.5,
                chunk_rate=1.0,
                chunk_radius_range_px=(5.0, 16.0),
            )
        raise ValueError(f"unknown segmenter preset {name!r}; valid presets: {PRESET_NAMES}")


class NoisySegmenter:
    """Ground truth corrupted by a learned segmenter's typical failures (see the config).

    Order per frame: choose the instances (drop thin branches, leak clutter), jitter the
    boundary, cut missing chunks, add false blobs. Every draw comes from the given ``rng``;
    the segmenter holds no state, so each frame's failures are independent.
    """

    def __init__(self, config: NoisySegmenterConfig | None = None) -> None:
        self.config = config or NoisySegmenterConfig()

    def segment(self, rgb: np.ndarray, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        _check_frame(rgb, labels)
        keep = self._kept_labels(labels, rng)
        mask = keep[labels].astype(np.uint8)
        if self.config.boundary_jitter_px > 0 and mask.any():
            mask = self._jitter_boundary(mask, rng)
        self._cut_chunks(mask, rng)
        self._add_blobs(mask, rng)
        return mask.astype(bool)

    def _kept_labels(self, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(max label + 1,) bool lookup table: which instances appear in the mask."""
        present = np.flatnonzero(np.bincount(labels.ravel()))
        keep = np.zeros(int(present.max(initial=0)) + 1, dtype=bool)
        branch_ids = present[_is_branch(present)]
        keep[branch_ids] = True
        cfg = self.config
        if cfg.thin_drop_prob > 0 and cfg.thin_width_px > 0 and len(branch_ids):
            widths = _apparent_widths_px(labels, branch_ids)
            thin = branch_ids[widths < cfg.thin_width_px]
            keep[thin[rng.random(len(thin)) < cfg.thin_drop_prob]] = False
        clutter_ids = present[is_occluding_clutter(present)]
        if cfg.clutter_leak_prob > 0 and len(clutter_ids):
            keep[clutter_ids[rng.random(len(clutter_ids)) < cfg.clutter_leak_prob]] = True
        return keep

    def _jitter_boundary(self, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Move the boundary by a smooth random offset field (px, positive = outward)."""
        height, width = mask.shape
        cell = self.config.boundary_jitter_cell_px
        coarse = rng.standard_normal((height // cell + 2, width // cell + 2)).astype(np.float32)
        coarse *= self.config.boundary_jitter_px
        offset_px = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_LINEAR)
        # Pixels farther from the mask than the largest offset cannot change: work in a crop.
        window = _crop_around(mask, margin_px=math.ceil(float(np.abs(offset_px).max())) + 1)
        crop, offset_px = mask[window], offset_px[window]
        # Distance to the boundary, which lies half a pixel beyond the edge pixels' centres.
        distance_px = _distance_to_edges(crop) + 0.5
        grown = distance_px < offset_px  # outside pixels the boundary moves past
        kept = distance_px > -offset_px  # inside pixels the boundary does not move past
        jittered = np.zeros_like(mask)
        jittered[window] = np.where(crop > 0, kept, grown)
        return jittered

    def _cut_chunks(self, mask: np.ndarray, rng: np.random.Generator) -> None:
        """Erase discs centred on random mask pixels, in place."""
        count = rng.poisson(self.config.chunk_rate)
        if count == 0:
            return
        on = np.flatnonzero(mask)
        if len(on) == 0:
            return
        width = mask.shape[1]
        for index in on[rng.integers(0, len(on), size=count)]:
            radius = round(rng.uniform(*self.config.chunk_radius_range_px))
            cv2.circle(mask, (int(index % width), int(index // width)), radius, 0, thickness=-1)

    def _add_blobs(self, mask: np.ndarray, rng: np.random.Generator) -> None:
        """Draw filled false-positive ellipses at random places, in place."""
        height, width = mask.shape
        for _ in range(rng.poisson(self.config.blob_rate)):
            center = (int(rng.integers(0, width)), int(rng.integers(0, height)))
            axes = tuple(round(a) for a in rng.uniform(*self.config.blob_axis_range_px, size=2))
            angle = float(rng.uniform(0.0, _FULL_TURN_DEG / 2))
            cv2.ellipse(mask, center, axes, angle, 0.0, _FULL_TURN_DEG, 1, thickness=-1)


def _distance_to_edges(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 distance in px from each pixel to the nearest edge pixel.

    Edge pixels are those whose right or lower neighbour has a different value, and those
    neighbours: both sides of every change. The image border is not an edge.
    """
    differs_right = image[:, :-1] != image[:, 1:]
    differs_below = image[:-1, :] != image[1:, :]
    not_edge = np.ones(image.shape, dtype=np.uint8)
    not_edge[:, :-1][differs_right] = 0
    not_edge[:, 1:][differs_right] = 0
    not_edge[:-1, :][differs_below] = 0
    not_edge[1:, :][differs_below] = 0
    # distanceTransform measures to the nearest zero pixel: the edge pixels.
    return cv2.distanceTransform(not_edge, cv2.DIST_L2, cv2.DIST_MASK_3)


def _apparent_widths_px(labels: np.ndarray, instance_ids: np.ndarray) -> np.ndarray:
    """(K,) apparent width in px of each instance: the diameter of its largest inscribed disc.

    Distances are to the nearest pixel of any other label, so a secondary's width is measured
    on its own pixels even where it touches the primary.
    """
    window = _crop_around(_is_branch(labels).astype(np.uint8), margin_px=1)
    crop = labels[window]
    depth_px = _distance_to_edges(crop)
    widths = np.empty(len(instance_ids))
    for k, instance_id in enumerate(instance_ids):
        # An instance w px wide has edge pixels on both sides and its centre (w - 1) / 2 inside.
        widths[k] = 2.0 * depth_px[crop == instance_id].max() + 1.0
    return widths


def _crop_around(mask: np.ndarray, margin_px: int) -> tuple[slice, slice]:
    """(rows, cols) slices of the bounding box of the non-zero (H, W) uint8 mask plus a margin."""
    x, y, w, h = cv2.boundingRect(mask)
    height, width = mask.shape
    rows = slice(max(y - margin_px, 0), min(y + h + margin_px, height))
    cols = slice(max(x - margin_px, 0), min(x + w + margin_px, width))
    return rows, cols


def make_segmenter(name: str) -> Segmenter:
    """Build a segmenter by name: "gt", "noisy:mild", "noisy:moderate" or "noisy:severe"."""
    if name == "gt":
        return GroundTruthSegmenter()
    kind, _, preset = name.partition(":")
    if kind == "noisy" and preset in PRESET_NAMES:
        return NoisySegmenter(NoisySegmenterConfig.preset(preset))
    raise ValueError(f"unknown segmenter {name!r}; valid names: {SEGMENTER_NAMES}")
