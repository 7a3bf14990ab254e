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

Sky light follows the CIE standard skies (CIE S 011/E:2003): the overcast sky's gradation
``(1 + b sin(elevation)) / (1 + b)`` (b = 2 for the standard overcast sky) and the Perez form
``(1 + a exp(b / cos zeta)) (1 + c exp(d gamma) + e cos^2 gamma)`` of the standard clear sky,
with zeta the zenith angle and gamma the angle to the sun. Clouds are periodic fractal noise
(white noise shaped in the Fourier domain, like
:func:`branch_gym.sim.scene.texture.band_limited_noise` but with a power-law spectrum: that one's
flat band gives uniform blobs, not cloud masses with detail) laid on a curved cloud layer, so
their features are larger at the zenith than near the horizon, thresholded at the drawn cover
(by solid angle) with soft edges, and faded into the haze at the horizon.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from branch_gym.config_utils import is_number
from branch_gym.sim.validation import require_int, require_non_negative, require_positive

__all__ = ["SKY_KINDS", "Sky", "SkyConfig", "blackbody_rgb"]

logger = logging.getLogger(__name__)

SKY_KINDS = ("overcast", "clear", "low_sun")
"""The kinds of sky, in the order of :attr:`SkyConfig.kind_weights`."""

MIN_ELEVATION_DEG = -10.0  # lowest elevation the map holds; below it the lookup clamps
_MAX_ZENITH_DEG = 90.0 - MIN_ELEVATION_DEG  # zenith angle of the map's last row

# Linear sRGB luminance weights (IEC 61966-2-1).
_LUMA = np.array([0.2126, 0.7152, 0.0722])
# CIE XYZ -> linear sRGB (IEC 61966-2-1).
_XYZ_TO_RGB = np.array(
    [[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]]
)
_WHITE_POINT_K = 6504.0  # D65's correlated colour temperature: the camera's white balance
_TEMPERATURE_RANGE_K = (1000.0, 15000.0)  # validity of Krystek's Planckian-locus fit
# Rayleigh-scattered daylight: lambda^-4 at the sRGB primaries' dominant wavelengths
# (612, 549, 465 nm), relative to blue.
_RAYLEIGH_RGB = np.array([(465.0 / 612.0) ** 4, (465.0 / 549.0) ** 4, 1.0])

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

# The sun disc and the camera's glare around it, at map resolution (our choice: the 0.5 deg disc
# is smaller than a map texel; what a camera shows is a blown-out patch a few degrees wide).
_SUN_GLARE_GAIN = 20.0  # peak glare radiance per unit of sun_radiance
_SUN_GLARE_WIDTH_DEG = 1.5  # its Gaussian sigma

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
_FORWARD_GAIN = 3.0  # thin cloud next to the sun glows (forward scattering), per sun_radiance
_FORWARD_WIDTH_DEG = 10.0  # e-folding angle of that glow
_THIN_CLOUD_TRANSMITTANCE = 0.4  # direct sun through the thinnest cloud (none through thick)
_CLOUD_SKY_MIX = 0.3  # clear/low-sun clouds take this much of the zenith sky's colour
_LOW_SUN_CLOUD_AMBIENT = 3.0  # low-sun clouds lit by the sky: this many x the zenith radiance
_LOW_SUN_LIT_WIDTH_DEG = 40.0  # e-folding angle from a low sun of the clouds it lights
_MAP_CHANNELS = 4  # RGB and a zero pad channel
_REMAP_MAX_SIDE = 32767  # cv2.remap's limit on each side of its output (SHRT_MAX)
_RADIANCE_GRID_COLS = 1024  # radiance() looks up flat inputs as rows of this many directions
_TINY = 1e-9  # guards divisions by a vanishing norm
_SUPERSAMPLE = 2  # the map is baked at this many samples per texel and axis, then averaged


def _require_range(obj: object, name: str, low: float = -math.inf, high: float = math.inf) -> None:
    """``obj.name`` is a (min, max) pair of finite numbers, min <= max, inside [low, high]."""
    value = getattr(obj, name)
    ok = (
        isinstance(value, tuple)
        and len(value) == 2
        and all(is_number(v) and math.isfinite(v) for v in value)
        and low <= value[0] <= value[1] <= high
    )
    if not ok:
        raise ValueError(
            f"{type(obj).__name__}.{name} must be a (min, max) tuple of finite numbers with "
            f"{low} <= min <= max <= {high}, got {value!r}"
        )


@dataclass(frozen=True)
class SkyConfig:
    """The distribution :class:`Sky` draws from. Ranges are (min, max), drawn uniformly.

    Attributes:
        kind_weights: Probabilities of ``SKY_KINDS`` (normalised; non-negative, not all zero).
        cloud_cover_range: Fraction of the sky covered by broken clouds under a clear or low sun
            (by solid angle); a clear sky multiplies its draw by ``clear_cloud_cover_scale``.
        clear_cloud_cover_scale: Factor on the cover drawn for a clear sky, in [0, 1].
        overcast_cloud_cover_range: Cover of an overcast sky: its darker, thicker cloud masses.
        clear_sun_elevation_range_deg: Sun elevation under a clear sky, degrees.
        low_sun_elevation_range_deg: Sun elevation of a low-sun sky, degrees.
        overcast_sun_elevation_range_deg: Elevation of the hidden sun of an overcast sky, degrees
            (it only brightens the overcast around it).
        clear_zenith_radiance_range: Radiance of the clear sky at the zenith.
        low_sun_zenith_radiance_range: Radiance of the low-sun sky at the zenith.
        overcast_zenith_radiance_range: Radiance of the (thin) overcast at the zenith.
        overcast_gradient_range: The overcast's gradation ``b``: the horizon has
            ``1 / (1 + b)`` of the zenith's radiance.
        clear_sun_radiance_range: Direct sun on a white surface facing it, clear sky.
        low_sun_sun_radiance_range: The same for a low sun.
        clear_sun_temperature_range_k: Colour temperature of a high sun, kelvin.
        low_sun_temperature_range_k: Colour temperature of a low sun, kelvin.
        overcast_temperature_range_k: Colour temperature of the overcast, kelvin.
        tint_range: Green (+) / magenta (-) cast of the camera's white balance: relative gain on
            the green channel.
        sky_purity_range: Blue purity of the clear zenith: exponent on the Rayleigh colour
            (0 white, 1 pure Rayleigh scattering, more a deeper blue).
        cloud_brightness_range: Sunlit cloud radiance relative to ``sun_radiance``.
        cloud_darkening_range: How much darker the thickest cloud is than the thinnest, in [0, 1].
        cloud_feature_min_deg: Smallest cloud feature (half a noise wavelength) at the zenith,
            degrees of arc.
        cloud_feature_max_deg: Largest cloud feature at the zenith, degrees of arc.
        cloud_edge_softness: Width of the clouds' soft edges, in noise standard deviations.
        cloud_perspective: Curvature of the cloud layer in (0, 1): a feature at the horizon is
            ``1 / cos^2(90 deg * cloud_perspective)`` times thinner than at the zenith.
        map_width_px: Columns of the radiance map over azimuth 0..360 deg.
        map_height_px: Rows of the radiance map over elevation 90..-10 deg.
    """

    # The real frames are all overcast (reference.md): most skies are, the rest randomise.
    kind_weights: tuple[float, float, float] = (0.6, 0.2, 0.2)
    # Broken clouds up to mostly cloudy (our choice; low-sun scenes in the real frames are
    # heavily clouded).
    cloud_cover_range: tuple[float, float] = (0.0, 0.9)
    # A clear sky holds scattered clouds at most (our choice: 0..36 % cover).
    clear_cloud_cover_scale: float = 0.4
    # Overcast: the darker masses cover most of the deck (our choice, from the real frames).
    overcast_cloud_cover_range: tuple[float, float] = (0.7, 1.0)
    # A high sun in the dormant season at mid latitudes: noon elevation ~22 deg (winter solstice)
    # to ~50 deg (spring) at 40-45 deg N.
    clear_sun_elevation_range_deg: tuple[float, float] = (15.0, 50.0)
    # Low sun: morning/evening, just above the horizon (task brief).
    low_sun_elevation_range_deg: tuple[float, float] = (0.0, 15.0)
    # Hidden sun anywhere a dormant-season day puts it (our choice).
    overcast_sun_elevation_range_deg: tuple[float, float] = (5.0, 45.0)
    # Clear zenith ~2500-6000 cd/m^2 against ~30000 cd/m^2 of a white surface in full sun.
    clear_zenith_radiance_range: tuple[float, float] = (0.08, 0.2)
    # Relative to a sun weakened by its long air path, the zenith stays about as bright as under
    # a high sun (our choice); the glow at the sun is ~40x the zenith (CIE clear sky, sun on the
    # horizon): a strongly backlit view.
    low_sun_zenith_radiance_range: tuple[float, float] = (0.08, 0.16)
    # Bright overcast, fitted: a level 60 deg camera's sky pixels average ~(181, 182, 181) over 40
    # seeds at the preview exposure 255 clip(0.6 x) ** (1 / 2.2); real frames ~(180, 182, 178).
    overcast_zenith_radiance_range: tuple[float, float] = (1.0, 1.9)
    # CIE standard overcast b = 2 (horizon 1/3 of zenith); the real frames' skies are flatter,
    # often lighter near the horizon (our choice).
    overcast_gradient_range: tuple[float, float] = (0.3, 1.5)
    # A clear high sun gives ~85 % of the global light on a surface facing it.
    clear_sun_radiance_range: tuple[float, float] = (0.7, 0.95)
    # A low sun is attenuated by 10-40 air masses (our choice of the relative strength).
    low_sun_sun_radiance_range: tuple[float, float] = (0.3, 0.7)
    # Direct sun at 15-50 deg elevation: ~4500-5800 K.
    clear_sun_temperature_range_k: tuple[float, float] = (4500.0, 5800.0)
    # Sun within 15 deg of the horizon: ~2000-3500 K (golden hour).
    low_sun_temperature_range_k: tuple[float, float] = (2000.0, 3500.0)
    # Overcast daylight ~6500-7500 K; a camera's white balance leaves it near neutral (real
    # sky mean (180, 182, 178)): D65 shifted +22 (warm) to -15 (blue) mired (our choice).
    overcast_temperature_range_k: tuple[float, float] = (5700.0, 7200.0)
    # Small casts of auto white balance (our choice; the real sky is a touch green).
    tint_range: tuple[float, float] = (-0.02, 0.04)
    # Pale (hazy) to deep blue zeniths (our choice).
    sky_purity_range: tuple[float, float] = (0.7, 1.4)
    # Sunlit cumulus are about as bright as a white surface in the sun (our choice).
    cloud_brightness_range: tuple[float, float] = (0.6, 1.1)
    # Dark cloud masses at 30-75 % below the bright gaps, as in the real frames (our estimate).
    cloud_darkening_range: tuple[float, float] = (0.3, 0.75)
    # Cloud features 4-60 deg overhead: from the cells of stratocumulus to whole cloud masses
    # (our choice); ~5x thinner near the horizon, where they fade into haze.
    cloud_feature_min_deg: float = 4.0
    cloud_feature_max_deg: float = 60.0
    # Soft cloud edges (our choice: a fuzzy edge a few degrees wide).
    cloud_edge_softness: float = 0.5
    # Horizon features ~5x thinner than at the zenith, never sub-texel (our choice).
    cloud_perspective: float = 0.7
    # 0.70 x 0.79 deg per texel: the sky is smooth and the clouds' soft edges span several
    # texels; a larger map only costs baking time (paint's cost does not depend on it).
    map_width_px: int = 256
    map_height_px: int = 64

    def __post_init__(self) -> None:
        weights = self.kind_weights
        if not (
            isinstance(weights, tuple)
            and len(weights) == len(SKY_KINDS)
            and all(is_number(w) and math.isfinite(w) and w >= 0 for w in weights)
            and sum(weights) > 0
        ):
            raise ValueError(
                f"SkyConfig.kind_weights must be {len(SKY_KINDS)} finite non-negative numbers, "
                f"not all zero, got {weights!r}"
            )
        for name in ("cloud_cover_range", "overcast_cloud_cover_range"):
            _require_range(self, name, 0.0, 1.0)
        if not (
            is_number(self.clear_cloud_cover_scale) and 0.0 <= self.clear_cloud_cover_scale <= 1.0
        ):
            raise ValueError(
                "SkyConfig.clear_cloud_cover_scale must be in [0, 1], got "
                f"{self.clear_cloud_cover_scale!r}"
            )
        for name in (
            "clear_sun_elevation_range_deg",
            "low_sun_elevation_range_deg",
            "overcast_sun_elevation_range_deg",
        ):
            _require_range(self, name, 0.0, 90.0)
        for name in (
            "clear_zenith_radiance_range",
            "low_sun_zenith_radiance_range",
            "overcast_zenith_radiance_range",
            "overcast_gradient_range",
            "clear_sun_radiance_range",
            "low_sun_sun_radiance_range",
            "sky_purity_range",
            "cloud_brightness_range",
        ):
            _require_range(self, name, 0.0)
        for name in (
            "clear_sun_temperature_range_k",
            "low_sun_temperature_range_k",
            "overcast_temperature_range_k",
        ):
            _require_range(self, name, *_TEMPERATURE_RANGE_K)
        _require_range(self, "tint_range", -0.5, 0.5)
        _require_range(self, "cloud_darkening_range", 0.0, 1.0)
        require_positive(self, "cloud_feature_min_deg", "cloud_feature_max_deg")
        if not self.cloud_feature_min_deg <= self.cloud_feature_max_deg <= 90.0:
            raise ValueError(
                "SkyConfig.cloud_feature_max_deg must be in [cloud_feature_min_deg, 90], got "
                f"{self.cloud_feature_max_deg!r} (min {self.cloud_feature_min_deg!r})"
            )
        require_non_negative(self, "cloud_edge_softness")
        if not (is_number(self.cloud_perspective) and 0.0 < self.cloud_perspective < 1.0):
            raise ValueError(
                f"SkyConfig.cloud_perspective must be in (0, 1), got {self.cloud_perspective!r}"
            )
        require_int(self, "map_width_px", minimum=8)
        require_int(self, "map_height_px", minimum=4)


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
    return rgb / float(_LUMA @ rgb)


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


def _unit_luminance(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) colours scaled to luminance 1."""
    return rgb / (rgb @ _LUMA)[..., None]


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 (x <= 0) to 1 (x >= 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class _Clouds:
    """A drawn cloud field on the curved cloud layer."""

    noise: np.ndarray  # (S, S) float32 periodic noise, zero mean, unit std
    texel_rad: float  # noise texel on the layer, in radians of arc at the zenith
    threshold: float  # noise value of the cloud edge (cover)
    thick_span: float  # noise above the threshold at which a cloud is fully thick
    softness: float  # edge width, noise units
    perspective: float  # SkyConfig.cloud_perspective


class Sky:
    """One drawn sky: kind, sun, clouds, colours and its baked HDR radiance map.

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
        weights = np.asarray(config.kind_weights, dtype=np.float64)
        self.kind: str = SKY_KINDS[int(rng.choice(len(SKY_KINDS), p=weights / weights.sum()))]
        kind = self.kind

        sun_elevation_deg = _uniform(rng, _SUN_ELEVATION_FIELD[kind](config))
        sun_azimuth = rng.uniform(0.0, 2.0 * math.pi)
        sun_elevation = math.radians(sun_elevation_deg)
        self.sun_direction = np.array(
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
                config.clear_sun_temperature_range_k
                if clear
                else config.low_sun_temperature_range_k,
            )
            zenith = _uniform(
                rng,
                config.clear_zenith_radiance_range
                if clear
                else config.low_sun_zenith_radiance_range,
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
        self.cloud_cover = float(cover)
        colour = blackbody_rgb(temperature_k)
        white_balance = _unit_luminance(np.array([1.0, 1.0 + tint, 1.0]))
        clouds = _draw_clouds(rng, config, cover)

        # Bake at _SUPERSAMPLE x the map's resolution, then average each block into one texel.
        height, width = config.map_height_px, config.map_width_px
        directions = _texel_directions(height, width, _SUPERSAMPLE)
        horizon = directions.copy()
        horizon[..., 2] = np.maximum(horizon[..., 2], 0.0)  # below the horizon: the horizon
        horizon /= np.linalg.norm(horizon, axis=-1, keepdims=True)
        alpha, thick = _cloud_fields(clouds, horizon)
        if kind == "overcast":
            sky = _overcast_radiance(horizon, self.sun_direction, zenith, gradient, colour)
            # The deck's thin parts are the bright gaps; thick cloud darkens it.
            radiance = sky * (1.0 - darkening * (alpha * thick))[..., None]
            transmittance = 0.0
        else:
            sky_colour = _unit_luminance(_RAYLEIGH_RGB**purity)
            sky = _clear_radiance(horizon, self.sun_direction, zenith, purity, colour, kind)
            cloud = _cloud_radiance(
                horizon,
                self.sun_direction,
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
            sun_alpha, sun_thick = _cloud_fields(clouds, self.sun_direction[None, None, :])
            transmittance = float(
                1.0 - sun_alpha[0, 0] * (1.0 - _THIN_CLOUD_TRANSMITTANCE * (1.0 - sun_thick[0, 0]))
            )
        radiance = radiance * white_balance
        sky_map = _block_mean(radiance, _SUPERSAMPLE)
        self.ambient_rgb = _cosine_mean(sky_map).astype(np.float32)

        self.sun_radiance = float(sun_radiance * transmittance)
        if self.sun_radiance > 0.0:
            cos_gamma = np.clip(horizon @ self.sun_direction, -1.0, 1.0)
            gamma_deg = np.degrees(np.arccos(cos_gamma))
            glare = _SUN_GLARE_GAIN * np.exp(-0.5 * (gamma_deg / _SUN_GLARE_WIDTH_DEG) ** 2)
            glare = _block_mean(glare[..., None], _SUPERSAMPLE) * self.sun_radiance
            sky_map = sky_map + glare * (colour * white_balance)
        self.sun_rgb = _unit_luminance(colour * white_balance).astype(np.float32)

        # One wrapped column so that bilinear lookups across azimuth 360 -> 0 need no border, and
        # a fourth (zero) channel: cv2.remap is ~3x faster on 4-channel float images (measured).
        padded = np.zeros((height, width + 1, _MAP_CHANNELS), np.float32)
        padded[:, :width, :3] = sky_map
        padded[:, width, :3] = sky_map[:, 0]
        padded.flags.writeable = False
        self._map = padded
        self._x_scale = np.float32(width / 360.0)  # map columns per degree of azimuth
        self._y_scale = np.float32((height - 1) / _MAX_ZENITH_DEG)  # map rows per degree
        logger.debug(
            "sky %s: sun elevation %.1f deg azimuth %.1f deg radiance %.2f, cover %.2f, "
            "%.0f K, ambient %s",
            kind,
            sun_elevation_deg,
            math.degrees(sun_azimuth),
            self.sun_radiance,
            cover,
            temperature_k,
            np.round(self.ambient_rgb, 3),
        )

    @property
    def radiance_map(self) -> np.ndarray:
        """(map_height_px, map_width_px, 3) float32 read-only HDR map (see module conventions)."""
        return self._map[:, :-1, :3]

    def radiance(self, directions_world: np.ndarray) -> np.ndarray:
        """Sky radiance towards world directions (bilinear in the map, wrapping in azimuth).

        Args:
            directions_world: (N, 3) or (H, W, 3) world directions; need not be unit length.

        Returns:
            (N, 3) or (H, W, 3) float32 linear radiance (1.0 ~ a white surface in full light).
        """
        directions = np.asarray(directions_world)
        if directions.ndim not in (2, 3) or directions.shape[-1] != 3:
            raise ValueError(f"directions must be (N, 3) or (H, W, 3), got {directions.shape}")
        if directions.ndim == 3 and max(directions.shape[:2]) < _REMAP_MAX_SIDE:
            return cv2.cvtColor(self._lookup(*_planes(directions)), cv2.COLOR_RGBA2RGB)
        # cv2.remap needs both sides of its output < 32767: look up a padded (rows, cols) grid.
        flat = directions.reshape(-1, 3)
        count = len(flat)
        if count == 0:
            return np.zeros(directions.shape, np.float32)
        cols = min(count, _RADIANCE_GRID_COLS)
        rows = -(-count // cols)
        grid = np.zeros((rows * cols, 3), np.float32)
        grid[:count] = flat
        values = cv2.cvtColor(
            self._lookup(*_planes(grid.reshape(rows, cols, 3))), cv2.COLOR_RGBA2RGB
        )
        return values.reshape(-1, 3)[:count].reshape(directions.shape)

    def paint(self, out: np.ndarray, rays_world: np.ndarray, where: np.ndarray) -> None:
        """Write the sky's radiance into ``out[where]``; other pixels are left untouched.

        Args:
            out: (H, W, 3) float32 C-contiguous image, written in place.
            rays_world: (H, W, 3) world ray direction of each pixel (need not be unit length).
            where: (H, W) bool, the pixels to paint (those that see the sky).
        """
        if out.dtype != np.float32 or out.ndim != 3 or not out.flags.c_contiguous:
            raise ValueError(f"out must be C-contiguous (H, W, 3) float32, got {out.dtype}")
        if rays_world.shape != out.shape or where.shape != out.shape[:2]:
            raise ValueError(
                f"rays_world {rays_world.shape} and where {where.shape} must match out {out.shape}"
            )
        if where.dtype != np.bool_:
            raise ValueError(f"where must be bool, got {where.dtype}")
        self.paint_planes(out, *_planes(rays_world), where)

    def paint_planes(
        self, out: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, where: np.ndarray
    ) -> None:
        """:meth:`paint` with the ray directions given as three (H, W) float32 planes."""
        values = cv2.cvtColor(self._lookup(x, y, z), cv2.COLOR_RGBA2RGB)
        cv2.copyTo(values, where.view(np.uint8), out)

    def _lookup(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Direction planes (H, W) -> (H, W, 4) float32 radiance (4th channel 0) by remap."""
        horizontal, azimuth = cv2.cartToPolar(x, y, angleInDegrees=True)  # azimuth in [0, 360)
        zenith = cv2.phase(z, horizontal, angleInDegrees=True)  # zenith angle in [0, 180]
        np.multiply(azimuth, self._x_scale, out=azimuth)
        np.multiply(zenith, self._y_scale, out=zenith)
        return cv2.remap(
            self._map, azimuth, zenith, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )


def _planes(directions: np.ndarray) -> np.ndarray:
    """(H, W, 3) directions -> (3, H, W) float32 planes (one transposing copy: ~3x faster than
    cv2.split, measured)."""
    return np.ascontiguousarray(np.moveaxis(directions, -1, 0), dtype=np.float32)


_SUN_ELEVATION_FIELD = {
    "overcast": lambda config: config.overcast_sun_elevation_range_deg,
    "clear": lambda config: config.clear_sun_elevation_range_deg,
    "low_sun": lambda config: config.low_sun_elevation_range_deg,
}


def _uniform(rng: np.random.Generator, value_range: tuple[float, float]) -> float:
    """One uniform draw from a (min, max) range (a draw is made even when min == max)."""
    return float(rng.uniform(value_range[0], value_range[1]))


def _texel_directions(height: int, width: int, samples: int) -> np.ndarray:
    """(height * samples, width * samples, 3) unit directions of the sub-texel samples.

    Sub-samples sit symmetrically around each texel's centre, so the mean of each
    ``samples x samples`` block belongs to texel (row, column) as the module docstring places it.
    """
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    columns = (np.arange(width)[:, None] + offsets[None, :]).ravel()
    rows = (np.arange(height)[:, None] + offsets[None, :]).ravel()
    azimuth = np.radians(columns * 360.0 / width)
    zenith = np.radians(rows * _MAX_ZENITH_DEG / (height - 1))
    sin_zenith = np.sin(zenith)[:, None]
    return np.stack(
        [
            sin_zenith * np.cos(azimuth)[None, :],
            sin_zenith * np.sin(azimuth)[None, :],
            np.broadcast_to(np.cos(zenith)[:, None], (len(rows), len(columns))),
        ],
        axis=-1,
    )


def _block_mean(image: np.ndarray, samples: int) -> np.ndarray:
    """Average ``samples x samples`` blocks of an (H*s, W*s, C) image."""
    height, width, channels = image.shape
    blocks = image.reshape(height // samples, samples, width // samples, samples, channels)
    return blocks.mean(axis=(1, 3))


def _cosine_mean(sky_map: np.ndarray) -> np.ndarray:
    """Cosine-weighted mean radiance over the upper hemisphere: E / pi on a horizontal surface."""
    height = sky_map.shape[0]
    elevation = np.radians(90.0 - np.arange(height) * _MAX_ZENITH_DEG / (height - 1))
    weight = np.where(elevation >= 0.0, np.sin(elevation) * np.cos(elevation), 0.0)
    return np.einsum("i,ijc->c", weight, sky_map) / (weight.sum() * sky_map.shape[1])


def _draw_clouds(rng: np.random.Generator, config: SkyConfig, cover: float) -> _Clouds:
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
    clouds = _Clouds(
        noise=noise,
        texel_rad=texel_rad,
        threshold=0.0,  # set below
        thick_span=1.0,
        softness=config.cloud_edge_softness,
        perspective=config.cloud_perspective,
    )

    # Calibrate the threshold on the upper hemisphere, weighting each sample by its solid angle.
    directions = _texel_directions(*_CALIBRATION_GRID, 1)
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


def _layer_noise(clouds: _Clouds, directions: np.ndarray) -> np.ndarray:
    """(H, W) noise of the cloud layer seen along (H, W, 3) unit directions (upper hemisphere)."""
    zenith = np.arccos(np.clip(directions[..., 2], 0.0, 1.0))
    radius = np.tan(clouds.perspective * zenith) / clouds.perspective
    azimuth = np.arctan2(directions[..., 1], directions[..., 0])
    size = clouds.noise.shape[0]
    u = np.mod(radius * np.cos(azimuth) / clouds.texel_rad, size).astype(np.float32)
    v = np.mod(radius * np.sin(azimuth) / clouds.texel_rad, size).astype(np.float32)
    return cv2.remap(clouds.noise, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def _cloud_fields(clouds: _Clouds, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _overcast_radiance(
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


def _clear_radiance(
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
    colour = _unit_luminance(_RAYLEIGH_RGB ** local_purity[..., None])
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


def _cloud_radiance(
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
        grey = _unit_luminance(1.0 + _CLOUD_SKY_MIX * (sky_colour - 1.0))
        sky_lit = brightness * _LOW_SUN_CLOUD_AMBIENT * zenith_radiance * shade
        # Only the thinner parts pass the low sun's light: a thick deck stays grey.
        sun_lit = (
            brightness * sun_radiance * (1.0 - thick) * np.exp(-gamma_deg / _LOW_SUN_LIT_WIDTH_DEG)
        )
        radiance = sky_lit[..., None] * grey + sun_lit[..., None] * sun_colour
    else:
        lit_colour = _unit_luminance(sun_colour + _CLOUD_SKY_MIX * (sky_colour - sun_colour))
        radiance = (brightness * sun_radiance * shade)[..., None] * lit_colour
    forward = _FORWARD_GAIN * sun_radiance * np.exp(-gamma_deg / _FORWARD_WIDTH_DEG) * (1 - thick)
    return radiance + forward[..., None] * sun_colour
