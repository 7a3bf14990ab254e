"""A seeded photometric sky dome at infinity: overcast, clear and low-sun (backlit) skies.

The real close-up frames of the dormant orchard row (reference.md, "Real close-up frames of a
dormant orchard row") show 8-62 % sky, overcast grey-white with darker cloud structure, mean RGB
~(180, 182, 178) after the camera's exposure; in several the sun is low and in front of the camera,
so the trunks are near-black silhouettes against a warm glow. A :class:`Sky` draws one of
:data:`SKY_KINDS`, a sun position, a cloud field, colours and brightness from the ``rng`` it is
given, and bakes them into an HDR equirectangular radiance map (float32, linear RGB) that
:meth:`Sky.paint` samples with ``cv2.remap`` for every sky pixel of a frame.

Conventions:
    * World frame z up; azimuth is measured from +x towards +y (the scanning camera looks along
      +y, azimuth 90 deg), elevation from the horizon.
    * Radiance is relative: 1.0 is about a white diffuse surface in full light. The sky around the
      sun and a bright overcast exceed 1 (HDR); the camera's exposure maps it to pixels.
    * Colours are linear sRGB white-balanced for daylight: a 6504 K source is neutral.
    * Map column ``j`` holds azimuth ``j * 360 / width``; row ``i`` holds zenith angle
      ``i * 100 / (height - 1)`` deg, i.e. elevation 90 deg (row 0) down to -10 deg (last row).
      Below the horizon the map repeats the horizon (the ground covers it).

The sky is built in four steps, one module each: what it draws from
(:mod:`~branch_gym.sim.scene.sky_config`), what it draws and the light that gives
(:mod:`~branch_gym.sim.scene.sky_model`, CIE standard skies; its clouds in
:mod:`~branch_gym.sim.scene.sky_clouds`), the baked map (:mod:`~branch_gym.sim.scene.sky_bake`)
and the map's lookup that paints frames (:mod:`~branch_gym.sim.scene.sky_map`).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from branch_gym.sim.scene.sky_bake import bake_sky
from branch_gym.sim.scene.sky_clouds import draw_clouds
from branch_gym.sim.scene.sky_config import SKY_KINDS, SkyConfig
from branch_gym.sim.scene.sky_map import SkyMap
from branch_gym.sim.scene.sky_model import blackbody_rgb, draw_sky_parameters

__all__ = ["SKY_KINDS", "Sky", "SkyConfig", "blackbody_rgb"]

logger = logging.getLogger(__name__)


class Sky(SkyMap):
    """One drawn sky: kind, sun, clouds, colours and its baked HDR radiance map.

    The map's lookup (:meth:`radiance`, :meth:`paint`, :meth:`paint_planes`) is
    :class:`~branch_gym.sim.scene.sky_map.SkyMap`'s.

    Attributes:
        kind: One of ``SKY_KINDS``.
        sun_direction: (3,) float64 unit world vector towards the sun (hidden behind the deck for
            an overcast sky).
        sun_radiance: Relative strength of direct sun on a white surface facing it (1.0 ~ full
            light), attenuated by the cloud in front of the sun; 0 for overcast.
        sun_rgb: (3,) float32 colour of the direct sun, luminance 1 (direct light =
            ``sun_radiance * sun_rgb``).
        ambient_rgb: (3,) float32 linear sky light on a surface: the radiance of a white,
            upward-facing diffuse surface lit by the sky alone (sun disc excluded).
        cloud_cover: Drawn fraction of the sky covered by cloud.
    """

    def __init__(self, config: SkyConfig, rng: np.random.Generator) -> None:
        """Draw a sky from ``config`` with ``rng`` (every random draw) and bake its map.

        Args:
            config: The distribution to draw from.
            rng: Source of every random draw: the same seed gives the same sky.
        """
        self.config = config
        parameters = draw_sky_parameters(config, rng)
        clouds = draw_clouds(rng, config, parameters.cover)
        baked = bake_sky(parameters, clouds, config.map_height_px, config.map_width_px)
        super().__init__(baked.sky_map)
        self.kind: str = parameters.kind
        self.sun_direction = parameters.sun_direction
        self.cloud_cover = float(parameters.cover)
        self.ambient_rgb = baked.ambient_rgb
        self.sun_radiance = baked.sun_radiance
        self.sun_rgb = baked.sun_rgb
        logger.debug(
            "sky %s: sun elevation %.1f deg azimuth %.1f deg radiance %.2f, cover %.2f, "
            "%.0f K, ambient %s",
            self.kind,
            parameters.sun_elevation_deg,
            math.degrees(parameters.sun_azimuth_rad),
            self.sun_radiance,
            parameters.cover,
            parameters.temperature_k,
            np.round(self.ambient_rgb, 3),
        )
