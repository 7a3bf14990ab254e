"""Baking one drawn sky into its HDR radiance map, with its ambient light and direct sun.

The map is baked at ``_SUPERSAMPLE`` samples per texel and axis and averaged; the sun disc and
the camera's glare around it are added at map resolution. Layout:
:mod:`branch_gym.sim.scene.sky_map`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from branch_gym.sim.scene.sky_clouds import Clouds, cloud_fields
from branch_gym.sim.scene.sky_map import MAX_ZENITH_DEG, texel_directions
from branch_gym.sim.scene.sky_model import (
    RAYLEIGH_RGB,
    SkyParameters,
    blackbody_rgb,
    clear_radiance,
    cloud_radiance,
    overcast_radiance,
    unit_luminance,
)

__all__ = ["BakedSky", "bake_sky"]

# The sun disc and the camera's glare around it, at map resolution (our choice: the 0.5 deg disc
# is smaller than a map texel; what a camera shows is a blown-out patch a few degrees wide).
_SUN_GLARE_GAIN = 20.0  # peak glare radiance per unit of sun_radiance
_SUN_GLARE_WIDTH_DEG = 1.5  # its Gaussian sigma
_THIN_CLOUD_TRANSMITTANCE = 0.4  # direct sun through the thinnest cloud (none through thick)
_SUPERSAMPLE = 2  # the map is baked at this many samples per texel and axis, then averaged


@dataclass(frozen=True)
class BakedSky:
    """A baked sky: its map and the light it casts.

    Attributes:
        sky_map: (H, W, 3) float64 linear radiance in :mod:`~branch_gym.sim.scene.sky_map`'s layout.
        ambient_rgb: (3,) float32 radiance of a white, upward-facing surface lit by the sky alone.
        sun_radiance: Direct sun after the cloud in front of it (0 for overcast).
        sun_rgb: (3,) float32 colour of the direct sun, luminance 1.
    """

    sky_map: np.ndarray
    ambient_rgb: np.ndarray
    sun_radiance: float
    sun_rgb: np.ndarray


def bake_sky(parameters: SkyParameters, clouds: Clouds, height: int, width: int) -> BakedSky:
    """Bake a drawn sky and its clouds into a ``height x width`` radiance map.

    Args:
        parameters: The drawn sky.
        clouds: Its drawn cloud layer.
        height: Rows of the map (elevation 90..-10 deg).
        width: Columns of the map (azimuth 0..360 deg).

    Returns:
        The map, the sky's ambient light and its direct sun.
    """
    kind, sun_direction = parameters.kind, parameters.sun_direction
    zenith, gradient = parameters.zenith_radiance, parameters.gradient
    purity, darkening = parameters.purity, parameters.darkening
    sun_radiance, brightness = parameters.sun_radiance, parameters.brightness
    colour = blackbody_rgb(parameters.temperature_k)
    white_balance = unit_luminance(np.array([1.0, 1.0 + parameters.tint, 1.0]))

    # Bake at _SUPERSAMPLE x the map's resolution, then average each block into one texel.
    directions = texel_directions(height, width, _SUPERSAMPLE)
    horizon = directions.copy()
    horizon[..., 2] = np.maximum(horizon[..., 2], 0.0)  # below the horizon: the horizon
    horizon /= np.linalg.norm(horizon, axis=-1, keepdims=True)
    alpha, thick = cloud_fields(clouds, horizon)
    if kind == "overcast":
        sky = overcast_radiance(horizon, sun_direction, zenith, gradient, colour)
        # The deck's thin parts are the bright gaps; thick cloud darkens it.
        radiance = sky * (1.0 - darkening * (alpha * thick))[..., None]
        transmittance = 0.0
    else:
        sky_colour = unit_luminance(RAYLEIGH_RGB**purity)
        sky = clear_radiance(horizon, sun_direction, zenith, purity, colour, kind)
        cloud = cloud_radiance(
            horizon,
            sun_direction,
            thick,
            colour,
            sky_colour,
            kind,
            zenith,
            sun_radiance,
            brightness,
            darkening,
        )
        radiance = sky + alpha[..., None] * (cloud - sky)
        sun_alpha, sun_thick = cloud_fields(clouds, sun_direction[None, None, :])
        transmittance = float(
            1.0 - sun_alpha[0, 0] * (1.0 - _THIN_CLOUD_TRANSMITTANCE * (1.0 - sun_thick[0, 0]))
        )
    radiance = radiance * white_balance
    sky_map = _block_mean(radiance, _SUPERSAMPLE)
    ambient_rgb = _cosine_mean(sky_map).astype(np.float32)

    sun_radiance_seen = float(sun_radiance * transmittance)
    if sun_radiance_seen > 0.0:
        cos_gamma = np.clip(horizon @ sun_direction, -1.0, 1.0)
        gamma_deg = np.degrees(np.arccos(cos_gamma))
        glare = _SUN_GLARE_GAIN * np.exp(-0.5 * (gamma_deg / _SUN_GLARE_WIDTH_DEG) ** 2)
        glare = _block_mean(glare[..., None], _SUPERSAMPLE) * sun_radiance_seen
        sky_map = sky_map + glare * (colour * white_balance)
    sun_rgb = unit_luminance(colour * white_balance).astype(np.float32)

    return BakedSky(
        sky_map=sky_map, ambient_rgb=ambient_rgb, sun_radiance=sun_radiance_seen, sun_rgb=sun_rgb
    )


def _block_mean(image: np.ndarray, samples: int) -> np.ndarray:
    """Average ``samples x samples`` blocks of an (H*s, W*s, C) image."""
    height, width, channels = image.shape
    blocks = image.reshape(height // samples, samples, width // samples, samples, channels)
    return blocks.mean(axis=(1, 3))


def _cosine_mean(sky_map: np.ndarray) -> np.ndarray:
    """Cosine-weighted mean radiance over the upper hemisphere: E / pi on a horizontal surface."""
    height = sky_map.shape[0]
    elevation = np.radians(90.0 - np.arange(height) * MAX_ZENITH_DEG / (height - 1))
    weight = np.where(elevation >= 0.0, np.sin(elevation) * np.cos(elevation), 0.0)
    return np.einsum("i,ijc->c", weight, sky_map) / (weight.sum() * sky_map.shape[1])
