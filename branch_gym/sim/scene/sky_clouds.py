"""The sky's clouds: periodic fractal noise on a curved cloud layer, thresholded at a cover.

Clouds are periodic fractal noise (white noise shaped in the Fourier domain, like
:func:`branch_gym.sim.scene.texture.band_limited_noise` but with a power-law spectrum: that one's
flat band gives uniform blobs, not cloud masses with detail) laid on a curved cloud layer, so
their features are larger at the zenith than near the horizon, thresholded at the drawn cover
(by solid angle) with soft edges, and faded into the haze at the horizon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from branch_gym.sim.scene.sky_config import SkyConfig
from branch_gym.sim.scene.sky_map import texel_directions

__all__ = ["Clouds", "cloud_fields", "draw_clouds"]

# Clouds (our choices).
_CLOUD_TILE_MIN_PX = 64  # smallest and largest noise tile
_CLOUD_TILE_MAX_PX = 1024
_TEXELS_PER_MIN_FEATURE = 3.0  # the smallest cloud feature spans this many noise texels
# Amplitude spectrum ~ f^-1.4 (power ~ f^-2.8): broad masses dominate, detail rides on them;
# within the -2..-3 power slopes commonly measured for cloud fields.
_CLOUD_SPECTRAL_SLOPE = 1.4
_BAND_EDGE_OCTAVES = 0.5  # soft low-frequency edge of the noise's band
_MAX_CLOUD_STRETCH = 1.6  # clouds are 1-1.6x longer along a random direction (rolls, wind)
_CALIBRATION_GRID = (64, 256)  # rows, columns sampled to set the cover threshold
_THICKNESS_QUANTILE = 0.99  # noise quantile at which a cloud is fully thick
_MIN_THICK_SPAN = 2.0  # ... but thickness takes at least 2 noise std to build up
_HORIZON_HAZE_DEG = 3.0  # clouds fade into the horizon haze below about this elevation
_TINY = 1e-9  # guards divisions by a vanishing norm


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 (x <= 0) to 1 (x >= 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class Clouds:
    """A drawn cloud field on the curved cloud layer."""

    noise: np.ndarray  # (S, S) float32 periodic noise, zero mean, unit std
    texel_rad: float  # noise texel on the layer, in radians of arc at the zenith
    threshold: float  # noise value of the cloud edge (cover)
    thick_span: float  # noise above the threshold at which a cloud is fully thick
    softness: float  # edge width, noise units
    perspective: float  # SkyConfig.cloud_perspective


def draw_clouds(rng: np.random.Generator, config: SkyConfig, cover: float) -> Clouds:
    """Draw the cloud layer's noise and set its threshold to give ``cover`` by solid angle."""
    feature_min = math.radians(config.cloud_feature_min_deg)
    feature_max = math.radians(config.cloud_feature_max_deg)
    texel_rad = feature_min / _TEXELS_PER_MIN_FEATURE
    layer_radius = math.tan(0.5 * math.pi * config.cloud_perspective) / config.cloud_perspective
    needed = 2.0 * max(layer_radius, 2.0 * feature_max) / texel_rad  # texels across the tile
    size = 1 << max(0, math.ceil(math.log2(needed)))
    size = int(np.clip(size, _CLOUD_TILE_MIN_PX, _CLOUD_TILE_MAX_PX))
    stretch = rng.uniform(1.0, _MAX_CLOUD_STRETCH)
    stretch_angle = rng.uniform(0.0, math.pi)
    noise = _cloud_noise(rng, size, texel_rad, feature_min, feature_max, stretch, stretch_angle)
    clouds = Clouds(
        noise=noise,
        texel_rad=texel_rad,
        threshold=0.0,  # set below
        thick_span=1.0,
        softness=config.cloud_edge_softness,
        perspective=config.cloud_perspective,
    )

    # Calibrate the threshold on the upper hemisphere, weighting each sample by its solid angle.
    directions = texel_directions(*_CALIBRATION_GRID, 1)
    upper = directions[..., 2] > 0.0
    values = _layer_noise(clouds, directions)[upper]
    weights = np.hypot(directions[..., 0], directions[..., 1])[upper]  # sin(zenith)
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order]) / weights.sum()
    sorted_values = values[order]

    def quantile(q: float) -> float:
        return float(sorted_values[min(int(np.searchsorted(cumulative, q)), len(order) - 1)])

    threshold = quantile(1.0 - cover) if cover < 1.0 else float(sorted_values[0]) - clouds.softness
    thick_span = max(quantile(_THICKNESS_QUANTILE) - threshold, _MIN_THICK_SPAN)
    return replace(clouds, threshold=threshold, thick_span=thick_span)


def _cloud_noise(
    rng: np.random.Generator,
    size: int,
    texel_rad: float,
    feature_min_rad: float,
    feature_max_rad: float,
    stretch: float,
    stretch_angle: float,
) -> np.ndarray:
    """Periodic fractal noise for clouds: white noise shaped in the Fourier domain.

    The amplitude falls as ``frequency ** -_CLOUD_SPECTRAL_SLOPE`` from the wavelength
    ``2 * feature_max_rad`` (a raised-cosine edge ``_BAND_EDGE_OCTAVES`` wide) and rolls off as a
    Gaussian of sigma ``1 / (2 * feature_min_rad)`` (no ringing around strong peaks, which
    thickness shading would show as rings), so broad masses carry fine detail; features are
    ``stretch`` times longer along the direction at ``stretch_angle`` (rolls, wind).

    Returns:
        (size, size) float32, zero mean, unit standard deviation, periodic.
    """
    along = np.fft.fftfreq(size)[:, None] / texel_rad  # cycles per radian
    across = np.fft.rfftfreq(size)[None, :] / texel_rad
    cos_a, sin_a = math.cos(stretch_angle), math.sin(stretch_angle)
    stretched = (cos_a * across + sin_a * along) * stretch
    frequency = np.hypot(stretched, cos_a * along - sin_a * across)
    with np.errstate(divide="ignore"):
        log_frequency = np.log2(frequency)
        power_law = np.where(frequency > 0.0, frequency**-_CLOUD_SPECTRAL_SLOPE, 0.0)
    lowest = math.log2(0.5 / feature_max_rad)  # log2 cycles per radian of the largest feature
    rising = np.clip((log_frequency - lowest) / _BAND_EDGE_OCTAVES + 1.0, 0.0, 1.0)
    high_cut = np.exp(-0.5 * (frequency * 2.0 * feature_min_rad) ** 2)
    amplitude = power_law * np.sin(0.5 * np.pi * rising) * high_cut
    spectrum = np.fft.rfft2(rng.standard_normal((size, size))) * amplitude
    noise = np.fft.irfft2(spectrum, s=(size, size))
    noise -= noise.mean()
    return (noise / max(float(noise.std()), _TINY)).astype(np.float32)


def _layer_noise(clouds: Clouds, directions: np.ndarray) -> np.ndarray:
    """(H, W) noise of the cloud layer seen along (H, W, 3) unit directions (upper hemisphere)."""
    zenith = np.arccos(np.clip(directions[..., 2], 0.0, 1.0))
    radius = np.tan(clouds.perspective * zenith) / clouds.perspective
    azimuth = np.arctan2(directions[..., 1], directions[..., 0])
    size = clouds.noise.shape[0]
    u = np.mod(radius * np.cos(azimuth) / clouds.texel_rad, size).astype(np.float32)
    v = np.mod(radius * np.sin(azimuth) / clouds.texel_rad, size).astype(np.float32)
    return cv2.remap(clouds.noise, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def cloud_fields(clouds: Clouds, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cloud opacity and thickness, each (H, W) in [0, 1], along (H, W, 3) unit directions.

    Opacity rises smoothly over ``softness`` around the threshold and fades to 0 at the horizon
    (haze); thickness grows from the threshold to the ``_THICKNESS_QUANTILE`` of the noise.
    """
    excess = _layer_noise(clouds, directions).astype(np.float64) - clouds.threshold
    if clouds.softness > 0.0:
        alpha = _smoothstep(excess / clouds.softness + 0.5)
    else:
        alpha = (excess > 0.0).astype(np.float64)
    elevation_deg = np.degrees(np.arcsin(np.clip(directions[..., 2], 0.0, 1.0)))
    alpha = alpha * (1.0 - np.exp(-elevation_deg / _HORIZON_HAZE_DEG))
    thick = _smoothstep(excess / clouds.thick_span)
    return alpha, thick
