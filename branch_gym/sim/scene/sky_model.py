"""The sky's model: the parameters one sky draws and the radiance they give each direction.

:func:`draw_sky_parameters` draws a kind of sky, its sun, colours and brightness from a
:class:`~branch_gym.sim.scene.sky_config.SkyConfig`; the radiance functions below turn them into
linear radiance along unit directions (the clouds' shapes are in
:mod:`branch_gym.sim.scene.sky_clouds`, the baking into a map in
:mod:`branch_gym.sim.scene.sky_bake`). Conventions: :mod:`branch_gym.sim.scene.sky`.

Sky light follows the CIE standard skies (CIE S 011/E:2003): the overcast sky's gradation
``(1 + b sin(elevation)) / (1 + b)`` (b = 2 for the standard overcast sky) and the Perez form
``(1 + a exp(b / cos zeta)) (1 + c exp(d gamma) + e cos^2 gamma)`` of the standard clear sky,
with zeta the zenith angle and gamma the angle to the sun.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from branch_gym.sim.scene.sky_config import SKY_KINDS, SkyConfig

__all__ = [
    "RAYLEIGH_RGB",
    "SkyParameters",
    "blackbody_rgb",
    "clear_radiance",
    "cloud_radiance",
    "draw_sky_parameters",
    "overcast_radiance",
    "unit_luminance",
]

# Linear sRGB luminance weights (IEC 61966-2-1).
LUMA = np.array([0.2126, 0.7152, 0.0722])
# CIE XYZ -> linear sRGB (IEC 61966-2-1).
_XYZ_TO_RGB = np.array(
    [[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]]
)
_WHITE_POINT_K = 6504.0  # D65's correlated colour temperature: the camera's white balance
# Rayleigh-scattered daylight: lambda^-4 at the sRGB primaries' dominant wavelengths
# (612, 549, 465 nm), relative to blue.
RAYLEIGH_RGB = np.array([(465.0 / 612.0) ** 4, (465.0 / 549.0) ** 4, 1.0])

# CIE standard clear sky (CIE S 011/E:2003, type 12): Perez coefficients a..e.
_PEREZ_A, _PEREZ_B, _PEREZ_C, _PEREZ_D, _PEREZ_E = -1.0, -0.32, 10.0, -3.0, 0.45
_MIN_COS_ZENITH = 0.01  # keeps exp(b / cos zeta) finite at the horizon

# Sky colour (our choices).
_HORIZON_WHITENING = 0.7  # the horizon keeps 30 % of the zenith's blue purity (haze)
_HORIZON_WHITENING_POWER = 3.0  # how fast the whitening fades with elevation
_AUREOLE_MIX = 0.6  # the sky next to the sun takes this much of the sun's colour
_AUREOLE_WIDTH_DEG = 20.0  # e-folding angle of that colour mix
_LOW_SUN_HORIZON_WARMTH = 0.8  # a low sun tints the horizon band on its side this much
_LOW_SUN_BAND_POWER = 6.0  # thinness of that warm band over elevation
_OVERCAST_SUN_GLOW = 0.35  # a hidden sun brightens the overcast around it by up to 35 %
_OVERCAST_GLOW_WIDTH_DEG = 25.0  # e-folding angle of that brightening

# Cloud light (our choices).
_FORWARD_GAIN = 3.0  # thin cloud next to the sun glows (forward scattering), per sun_radiance
_FORWARD_WIDTH_DEG = 10.0  # e-folding angle of that glow
_CLOUD_SKY_MIX = 0.3  # clear/low-sun clouds take this much of the zenith sky's colour
_LOW_SUN_CLOUD_AMBIENT = 3.0  # low-sun clouds lit by the sky: this many x the zenith radiance
_LOW_SUN_LIT_WIDTH_DEG = 40.0  # e-folding angle from a low sun of the clouds it lights
_TINY = 1e-9  # guards divisions by a vanishing norm


@dataclass(frozen=True)
class SkyParameters:
    """What one sky drew: its kind, sun, colours and brightness (radiance relative, linear).

    Attributes:
        kind: One of ``SKY_KINDS``.
        sun_elevation_deg: Sun elevation, degrees.
        sun_azimuth_rad: Sun azimuth, radians from +x towards +y.
        sun_direction: (3,) float64 unit world vector towards the sun.
        cover: Fraction of the sky covered by cloud (by solid angle).
        temperature_k: Colour temperature of the sun (of the overcast for an overcast sky).
        zenith_radiance: Radiance of the sky at the zenith.
        gradient: The overcast's gradation ``b`` (0 for a clear or low sun).
        sun_radiance: Direct sun before the clouds in front of it (0 for overcast).
        purity: Blue purity of the clear zenith (0 for overcast).
        brightness: Sunlit cloud radiance relative to ``sun_radiance`` (0 for overcast).
        darkening: How much darker the thickest cloud is than the thinnest.
        tint: Green (+) / magenta (-) cast of the white balance.
    """

    kind: str
    sun_elevation_deg: float
    sun_azimuth_rad: float
    sun_direction: np.ndarray
    cover: float
    temperature_k: float
    zenith_radiance: float
    gradient: float
    sun_radiance: float
    purity: float
    brightness: float
    darkening: float
    tint: float


def draw_sky_parameters(config: SkyConfig, rng: np.random.Generator) -> SkyParameters:
    """Draw one sky's parameters from ``config`` with ``rng`` (the clouds' noise is drawn next).

    Args:
        config: The distribution to draw from.
        rng: Source of every draw, in a fixed order: the same seed gives the same sky.

    Returns:
        The drawn parameters.
    """
    weights = np.asarray(config.kind_weights, dtype=np.float64)
    kind = SKY_KINDS[int(rng.choice(len(SKY_KINDS), p=weights / weights.sum()))]

    sun_elevation_deg = _uniform(rng, _SUN_ELEVATION_FIELD[kind](config))
    sun_azimuth = rng.uniform(0.0, 2.0 * math.pi)
    sun_elevation = math.radians(sun_elevation_deg)
    sun_direction = np.array(
        [
            math.cos(sun_elevation) * math.cos(sun_azimuth),
            math.cos(sun_elevation) * math.sin(sun_azimuth),
            math.sin(sun_elevation),
        ]
    )
    if kind == "overcast":
        cover = _uniform(rng, config.overcast_cloud_cover_range)
        temperature_k = _uniform(rng, config.overcast_temperature_range_k)
        zenith = _uniform(rng, config.overcast_zenith_radiance_range)
        gradient = _uniform(rng, config.overcast_gradient_range)
        sun_radiance, purity, brightness = 0.0, 0.0, 0.0
    else:
        clear = kind == "clear"
        cover = _uniform(rng, config.cloud_cover_range)
        cover *= config.clear_cloud_cover_scale if clear else 1.0
        temperature_k = _uniform(
            rng,
            config.clear_sun_temperature_range_k if clear else config.low_sun_temperature_range_k,
        )
        zenith = _uniform(
            rng,
            config.clear_zenith_radiance_range if clear else config.low_sun_zenith_radiance_range,
        )
        sun_radiance = _uniform(
            rng,
            config.clear_sun_radiance_range if clear else config.low_sun_sun_radiance_range,
        )
        purity = _uniform(rng, config.sky_purity_range)
        brightness = _uniform(rng, config.cloud_brightness_range)
        gradient = 0.0
    darkening = _uniform(rng, config.cloud_darkening_range)
    tint = _uniform(rng, config.tint_range)
    return SkyParameters(
        kind=kind,
        sun_elevation_deg=sun_elevation_deg,
        sun_azimuth_rad=float(sun_azimuth),
        sun_direction=sun_direction,
        cover=cover,
        temperature_k=temperature_k,
        zenith_radiance=zenith,
        gradient=gradient,
        sun_radiance=sun_radiance,
        purity=purity,
        brightness=brightness,
        darkening=darkening,
        tint=tint,
    )


_SUN_ELEVATION_FIELD = {
    "overcast": lambda config: config.overcast_sun_elevation_range_deg,
    "clear": lambda config: config.clear_sun_elevation_range_deg,
    "low_sun": lambda config: config.low_sun_elevation_range_deg,
}


def _uniform(rng: np.random.Generator, value_range: tuple[float, float]) -> float:
    """One uniform draw from a (min, max) range (a draw is made even when min == max)."""
    return float(rng.uniform(value_range[0], value_range[1]))


def blackbody_rgb(temperature_k: float) -> np.ndarray:
    """Colour of a blackbody, white-balanced for daylight, in linear sRGB of luminance 1.

    The chromaticity follows Krystek's fit of the Planckian locus (1985, valid 1000-15000 K); the
    result is divided by that of 6504 K (D65's temperature), so daylight is neutral.

    Args:
        temperature_k: Colour temperature, kelvin, in [1000, 15000].

    Returns:
        (3,) float64 linear RGB, non-negative, luminance (Rec. 709 weights) 1.
    """
    rgb = _planck_rgb(temperature_k) / _planck_rgb(_WHITE_POINT_K)
    rgb = np.maximum(rgb, 0.0)
    return rgb / float(LUMA @ rgb)


def _planck_rgb(temperature_k: float) -> np.ndarray:
    """Linear sRGB (unbalanced, Y = 1) of a blackbody from Krystek's Planckian-locus fit."""
    t = float(temperature_k)
    u = (0.860117757 + 1.54118254e-4 * t + 1.28641212e-7 * t * t) / (
        1.0 + 8.42420235e-4 * t + 7.08145163e-7 * t * t
    )
    v = (0.317398726 + 4.22806245e-5 * t + 4.20481691e-8 * t * t) / (
        1.0 - 2.89741816e-5 * t + 1.61456053e-7 * t * t
    )
    denominator = 2.0 * u - 8.0 * v + 4.0
    x, y = 3.0 * u / denominator, 2.0 * v / denominator
    return _XYZ_TO_RGB @ np.array([x / y, 1.0, (1.0 - x - y) / y])


def unit_luminance(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) colours scaled to luminance 1."""
    return rgb / (rgb @ LUMA)[..., None]


def overcast_radiance(
    directions: np.ndarray,
    sun_direction: np.ndarray,
    zenith_radiance: float,
    gradient: float,
    colour: np.ndarray,
) -> np.ndarray:
    """(H, W, 3) radiance of the bright (thin) overcast deck: CIE gradation, hidden-sun glow."""
    sin_elevation = np.clip(directions[..., 2], 0.0, 1.0)
    gradation = (1.0 + gradient * sin_elevation) / (1.0 + gradient)
    gamma_deg = np.degrees(np.arccos(np.clip(directions @ sun_direction, -1.0, 1.0)))
    glow = 1.0 + _OVERCAST_SUN_GLOW * np.exp(-gamma_deg / _OVERCAST_GLOW_WIDTH_DEG)
    return (zenith_radiance * gradation * glow)[..., None] * colour


def _perez(cos_zenith: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """CIE standard clear sky relative luminance (Perez form) at zenith cosine and sun angle."""
    cos_zenith = np.maximum(cos_zenith, _MIN_COS_ZENITH)
    gradation = 1.0 + _PEREZ_A * np.exp(_PEREZ_B / cos_zenith)
    indicatrix = 1.0 + _PEREZ_C * np.exp(_PEREZ_D * gamma) + _PEREZ_E * np.cos(gamma) ** 2
    return gradation * indicatrix


def clear_radiance(
    directions: np.ndarray,
    sun_direction: np.ndarray,
    zenith_radiance: float,
    purity: float,
    sun_colour: np.ndarray,
    kind: str,
) -> np.ndarray:
    """(H, W, 3) radiance of a cloudless sky under a clear or low sun.

    CIE clear-sky luminance; Rayleigh blue, whitening towards the horizon; the sun's colour in
    the aureole and, for a low sun, in the horizon band on its side.
    """
    sin_elevation = np.clip(directions[..., 2], 0.0, 1.0)
    gamma = np.arccos(np.clip(directions @ sun_direction, -1.0, 1.0))
    sun_zenith = math.acos(min(max(float(sun_direction[2]), -1.0), 1.0))
    luminance = _perez(sin_elevation, gamma) / _perez(np.array(1.0), np.array(sun_zenith))

    horizon = (1.0 - sin_elevation) ** _HORIZON_WHITENING_POWER
    local_purity = purity * (1.0 - _HORIZON_WHITENING * horizon)
    colour = unit_luminance(RAYLEIGH_RGB ** local_purity[..., None])
    mix = _AUREOLE_MIX * np.exp(-np.degrees(gamma) / _AUREOLE_WIDTH_DEG)
    if kind == "low_sun":
        sun_side = 0.5 * (1.0 + _horizontal_cos(directions, sun_direction))
        band = (1.0 - sin_elevation) ** _LOW_SUN_BAND_POWER
        mix = mix + _LOW_SUN_HORIZON_WARMTH * band * sun_side**2
    mix = np.clip(mix, 0.0, 1.0)[..., None]
    colour = colour + mix * (sun_colour - colour)
    return (zenith_radiance * luminance)[..., None] * colour


def _horizontal_cos(directions: np.ndarray, sun_direction: np.ndarray) -> np.ndarray:
    """Cosine of the azimuth difference between each direction and the sun."""
    horizontal = np.hypot(directions[..., 0], directions[..., 1])
    sun_horizontal = math.hypot(sun_direction[0], sun_direction[1])
    dot = directions[..., 0] * sun_direction[0] + directions[..., 1] * sun_direction[1]
    return dot / np.maximum(horizontal * sun_horizontal, _TINY)


def cloud_radiance(
    directions: np.ndarray,
    sun_direction: np.ndarray,
    thick: np.ndarray,
    sun_colour: np.ndarray,
    sky_colour: np.ndarray,
    kind: str,
    zenith_radiance: float,
    sun_radiance: float,
    brightness: float,
    darkening: float,
) -> np.ndarray:
    """(H, W, 3) radiance of clouds under a clear or low sun, darker where thicker.

    A high sun lights every cloud (its colour mixed with the sky's). A low sun lights clouds
    orange only on its side of the sky; elsewhere they are grey, lit by the sky. Thin cloud near
    the sun adds forward-scattered sun (silver linings); backlit cores stay dark against the glow.
    """
    shade = 1.0 - darkening * thick
    gamma_deg = np.degrees(np.arccos(np.clip(directions @ sun_direction, -1.0, 1.0)))
    if kind == "low_sun":
        grey = unit_luminance(1.0 + _CLOUD_SKY_MIX * (sky_colour - 1.0))
        sky_lit = brightness * _LOW_SUN_CLOUD_AMBIENT * zenith_radiance * shade
        # Only the thinner parts pass the low sun's light: a thick deck stays grey.
        sun_lit = (
            brightness * sun_radiance * (1.0 - thick) * np.exp(-gamma_deg / _LOW_SUN_LIT_WIDTH_DEG)
        )
        radiance = sky_lit[..., None] * grey + sun_lit[..., None] * sun_colour
    else:
        lit_colour = unit_luminance(sun_colour + _CLOUD_SKY_MIX * (sky_colour - sun_colour))
        radiance = (brightness * sun_radiance * shade)[..., None] * lit_colour
    forward = _FORWARD_GAIN * sun_radiance * np.exp(-gamma_deg / _FORWARD_WIDTH_DEG) * (1 - thick)
    return radiance + forward[..., None] * sun_colour
