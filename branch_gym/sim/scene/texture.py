"""Procedural, seamlessly tiling textures: bark for branches, foliage and ground for the background.

A plain-coloured branch cannot be tracked by Lucas-Kanade: it needs surface features of 1.5-4 mm,
stretched about x4 along the branch (reference.md, "Tracking on rendered images"); finer ones
(0.5 mm) alias in TinyRenderer, which samples textures without filtering. Each texture is
band-limited noise (white noise filtered in the Fourier domain, hence periodic: no seams when it
wraps) mapped through a colour palette. Image rows run along the branch (texture ``v``), columns
around it (``u``).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.special import ndtr

from branch_gym.sim.scene.tree_mesh import TILE_WIDTH_M
from branch_gym.sim.validation import require_positive

_COARSE_FACTOR = 4.0  # the shading layer's features are this much larger (our choice)
_COARSE_WEIGHT = 0.5  # and this much weaker than the pattern (our choice)
_EDGE_OCTAVES = 0.5  # width of the pass band's soft edges (our choice)
_PALETTE_LEVELS = 256  # colour look-up table size (one per uint8 step)
# Uncompressed, unfiltered PNG: 3 ms for 512x512 against 15 ms at level 1 (measured); it is read
# once by pybullet and deleted.
_PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 0, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]

Palette = tuple[tuple[float, tuple[int, int, int]], ...]
"""Colour stops: (position in [0, 1] of the noise value's rank, RGB), positions increasing."""

# Grey-brown bark, dark furrows to light ridges (our choice: contrast for the tracker).
BARK_PALETTE: Palette = (
    (0.0, (48, 38, 32)),
    (0.35, (92, 76, 62)),
    (0.65, (138, 122, 104)),
    (1.0, (196, 184, 164)),
)
# Leaves with a little sky between them, and grass on soil (our choice: coarse, muted).
FOLIAGE_PALETTE: Palette = (
    (0.0, (22, 44, 20)),
    (0.45, (58, 96, 40)),
    (0.8, (112, 146, 70)),
    (0.9, (150, 170, 110)),
    (0.93, (178, 196, 214)),
    (1.0, (196, 212, 230)),
)
GROUND_PALETTE: Palette = (
    (0.0, (72, 60, 44)),
    (0.4, (96, 92, 58)),
    (0.75, (92, 122, 56)),
    (1.0, (128, 150, 84)),
)


@dataclass(frozen=True)
class TextureConfig:
    """One procedural texture.

    Attributes:
        size_px: Square image size; a power of two keeps the FFT fast.
        texel_m: Size of one texel on the surface in metres.
        feature_min_m: Smallest feature (half a noise wavelength) across, in metres.
        feature_max_m: Largest feature across, in metres.
        stretch_along: Features are this many times longer along the rows (along the branch).
        palette: Colour stops over the noise value's rank.
    """

    size_px: int
    texel_m: float
    feature_min_m: float
    feature_max_m: float
    stretch_along: float
    palette: Palette

    def __post_init__(self) -> None:
        if self.size_px < 8:
            raise ValueError(f"size_px must be at least 8, got {self.size_px}")
        require_positive(self, "texel_m", "feature_min_m", "feature_max_m", "stretch_along")
        if self.feature_max_m < self.feature_min_m:
            raise ValueError(
                f"feature_max_m ({self.feature_max_m}) must be >= feature_min_m "
                f"({self.feature_min_m})"
            )
        if self.feature_min_m < 2.0 * self.texel_m:
            raise ValueError(
                f"feature_min_m ({self.feature_min_m}) must span at least two texels "
                f"(texel_m = {self.texel_m})"
            )
        positions = [stop[0] for stop in self.palette]
        if len(positions) < 2 or positions[0] != 0.0 or positions[-1] != 1.0:
            raise ValueError("palette must have at least two stops, from position 0 to 1")
        if any(b <= a for a, b in itertools.pairwise(positions)):
            raise ValueError("palette positions must increase")


# Bark: 512 texels once around a 5 mm radius branch (~0.06 mm each), features 1.5-4 mm stretched
# x4 along the branch (reference.md, "Tracking on rendered images").
BARK = TextureConfig(
    size_px=512,
    texel_m=TILE_WIDTH_M / 512,
    feature_min_m=1.5e-3,
    feature_max_m=4e-3,
    stretch_along=4.0,
    palette=BARK_PALETTE,
)
# Background: 1 cm texels, 4-30 cm features (our choice: seen from 1-3 m, a pixel covers 2.5-7 mm
# of a wall facing the camera, and far more of the ground at a grazing angle).
FOLIAGE = TextureConfig(
    size_px=256,
    texel_m=0.01,
    feature_min_m=0.04,
    feature_max_m=0.3,
    stretch_along=1.0,
    palette=FOLIAGE_PALETTE,
)
GROUND = replace(FOLIAGE, feature_min_m=0.05, palette=GROUND_PALETTE)


def band_limited_noise(
    rng: np.random.Generator, config: TextureConfig, coarse_weight: float = 0.0
) -> np.ndarray:
    """Periodic noise whose features span ``feature_min_m``..``feature_max_m``.

    White noise filtered in the Fourier domain. The amplitude weight is a raised cosine over log
    frequency, flat between the wavelengths ``2 * feature_max_m`` and ``2 * feature_min_m`` and
    falling to zero half an octave beyond each end; frequencies along the rows are multiplied by
    ``stretch_along``. With ``coarse_weight > 0`` a second band, ``_COARSE_FACTOR`` times larger
    (capped by the tile size), is added with that relative amplitude.

    Returns:
        (size_px, size_px) float array with zero mean and unit standard deviation.

    Raises:
        ValueError: no frequency of the image falls in the band (tile too small for the features).
    """
    size = config.size_px
    spectrum = np.fft.rfft2(rng.standard_normal((size, size)))
    # The filter does not depend on the palette: cache it without (orchard bark draws palettes).
    filter_key = replace(config, palette=BARK_PALETTE)
    noise = np.fft.irfft2(spectrum * _amplitude(filter_key, coarse_weight), s=(size, size))
    std = float(noise.std())
    if std == 0.0:
        raise ValueError("no frequency of the texture falls in the feature band: enlarge size_px")
    return (noise - noise.mean()) / std


@functools.lru_cache(maxsize=16)
def _amplitude(config: TextureConfig, coarse_weight: float) -> np.ndarray:
    """(size, size // 2 + 1) filter over the ``rfft2`` grid (cached: half the texture's cost)."""
    size = config.size_px
    along = np.fft.fftfreq(size)[:, None] * config.stretch_along  # cycles per texel
    around = np.fft.rfftfreq(size)[None, :]
    with np.errstate(divide="ignore"):
        log_radial = np.log2(np.hypot(along, around) / config.texel_m)  # log2 cycles per metre
    power = _band_weight(log_radial, config.feature_min_m, config.feature_max_m) ** 2
    if coarse_weight > 0:
        tile_m = size * config.texel_m
        coarse_min = min(_COARSE_FACTOR * config.feature_min_m, tile_m / 4.0)
        coarse_max = min(_COARSE_FACTOR * config.feature_max_m, tile_m / 2.0)
        power += (coarse_weight * _band_weight(log_radial, coarse_min, coarse_max)) ** 2
    amplitude = np.sqrt(power)
    amplitude.flags.writeable = False
    return amplitude


def _band_weight(log2_frequency: np.ndarray, feature_min_m: float, feature_max_m: float):
    """Raised-cosine pass band over log2 frequency (cycles per metre), edges half an octave wide."""
    low, high = np.log2(0.5 / feature_max_m), np.log2(0.5 / feature_min_m)
    rising = np.clip((log2_frequency - low) / _EDGE_OCTAVES + 1.0, 0.0, 1.0)
    falling = np.clip((high - log2_frequency) / _EDGE_OCTAVES + 1.0, 0.0, 1.0)
    return np.sin(0.5 * np.pi * rising) * np.sin(0.5 * np.pi * falling)


def make_texture(rng: np.random.Generator, config: TextureConfig) -> np.ndarray:
    """A seamlessly tiling colour texture.

    The noise is the band set by ``config`` plus a weaker band of larger features that shades
    broad patches, so the surface is not uniformly busy. The noise is Gaussian, so its normal CDF
    is uniform over [0, 1]: the palette positions are value ranks.

    Returns:
        (size_px, size_px, 3) uint8 RGB image; rows run along the branch.
    """
    rank = ndtr(band_limited_noise(rng, config, coarse_weight=_COARSE_WEIGHT))
    level = np.minimum((rank * _PALETTE_LEVELS).astype(np.intp), _PALETTE_LEVELS - 1)
    return _palette_table(config.palette)[level]


@functools.lru_cache(maxsize=16)
def _palette_table(palette: Palette) -> np.ndarray:
    """(_PALETTE_LEVELS, 3) uint8 colours, interpolated between the stops at level centres."""
    ranks = (np.arange(_PALETTE_LEVELS) + 0.5) / _PALETTE_LEVELS
    positions = [stop[0] for stop in palette]
    table = np.stack([np.interp(ranks, positions, [s[1][c] for s in palette]) for c in range(3)])
    table = np.round(table.T).astype(np.uint8)
    table.flags.writeable = False
    return table


def write_png(image: np.ndarray, path: Path) -> Path:
    """Write an (H, W, 3) uint8 RGB image as an uncompressed PNG and return ``path``."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    path = Path(path)
    if not cv2.imwrite(str(path), image[:, :, ::-1], _PNG_FAST):
        raise ValueError(f"could not write PNG to {path}")
    return path


# Dormant apple bark in an orchard (reference.md, "Real close-up frames": trunk mean sRGB
# ~(72, 59, 43), from near-black to ~(125, 112, 104)); each scan draws a base colour in this
# range and builds the palette around it.
ORCHARD_BARK_BASE_RANGE: tuple[tuple[int, int, int], tuple[int, int, int]] = (
    (56, 46, 36),
    (120, 108, 98),
)
_FURROW_SHADE = 0.55  # furrows this fraction of the base colour (our choice)
_RIDGE_SHADE = 1.45  # ridges this much brighter (our choice)
# Lenticels: small light dashes across the branch (our choice: 0.5-1 mm x 1.5-3 mm, a few per
# square centimetre on young apple wood).
_LENTICELS_PER_CM2 = 1.5
_LENTICEL_COLOUR = (176, 160, 136)
# Lichen: grey-green patches on older wood (our choice: up to 15 % of the surface).
_LICHEN_COLOUR = (138, 142, 124)
_LICHEN_COVER_RANGE = (0.0, 0.1)
_LICHEN_GRID = 12  # patch grid across a tile (~3 mm patches on a 5 mm radius branch)
# Orchard ground in the dormant season: dry straw, soil and a little green (our choice).
ORCHARD_GROUND_PALETTE: Palette = (
    (0.0, (48, 40, 32)),
    (0.35, (84, 72, 54)),
    (0.7, (112, 100, 70)),
    (0.9, (96, 104, 64)),
    (1.0, (140, 128, 96)),
)
ORCHARD_GROUND = replace(GROUND, feature_min_m=0.03, palette=ORCHARD_GROUND_PALETTE)


def orchard_bark(rng: np.random.Generator, config: TextureConfig = BARK) -> np.ndarray:
    """Dormant apple bark: a drawn base colour, furrows, lenticels and lichen patches.

    Keeps the trackable 1.5-4 mm features of ``config`` (module docstring).

    Returns:
        (size_px, size_px, 3) uint8 RGB image, rows along the branch, tiling.
    """
    low, high = (np.array(c, dtype=float) for c in ORCHARD_BARK_BASE_RANGE)
    base = low + rng.random() * (high - low) + rng.normal(0.0, 4.0, 3)
    palette = tuple(
        (position, tuple(int(np.clip(round(c * shade), 0, 255)) for c in base))
        for position, shade in ((0.0, _FURROW_SHADE), (0.5, 1.0), (1.0, _RIDGE_SHADE))
    )
    image = make_texture(rng, replace(config, palette=palette)).astype(np.float32)
    size = config.size_px
    cover = rng.uniform(*_LICHEN_COVER_RANGE)
    coarse = rng.standard_normal((_LICHEN_GRID, _LICHEN_GRID)).astype(np.float32)
    if cover > 0:  # a smooth field (patches ~1/_LICHEN_GRID of the tile), thresholded by cover
        field = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
        lichen = field > np.quantile(field, 1.0 - cover)
        image[lichen] = 0.4 * image[lichen] + 0.6 * np.array(_LICHEN_COLOUR, np.float32)
    area_cm2 = (size * config.texel_m * 100.0) ** 2
    for _ in range(rng.poisson(_LENTICELS_PER_CM2 * area_cm2)):
        centre = (int(rng.integers(0, size)), int(rng.integers(0, size)))
        axes = (
            max(1, round(rng.uniform(0.75e-3, 1.5e-3) / config.texel_m)),  # across the branch
            max(1, round(rng.uniform(0.25e-3, 0.5e-3) / config.texel_m)),  # along it
        )
        cv2.ellipse(image, centre, axes, 0.0, 0.0, 360.0, _LENTICEL_COLOUR, -1)
    return np.clip(image, 0, 255).astype(np.uint8)
