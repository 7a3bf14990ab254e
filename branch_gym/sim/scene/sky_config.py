"""What a :class:`~branch_gym.sim.scene.sky.Sky` draws from: the kinds of sky and their ranges.

Every range is (min, max), drawn uniformly; the defaults and their sources are commented field by
field. The sky's conventions (frames, radiance units, the map's layout) are in
:mod:`branch_gym.sim.scene.sky`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from branch_gym.config_utils import is_number
from branch_gym.sim.validation import require_int, require_non_negative, require_positive

__all__ = ["SKY_KINDS", "TEMPERATURE_RANGE_K", "SkyConfig"]

SKY_KINDS = ("overcast", "clear", "low_sun")
"""The kinds of sky, in the order of :attr:`SkyConfig.kind_weights`."""

TEMPERATURE_RANGE_K = (1000.0, 15000.0)  # validity of Krystek's Planckian-locus fit


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
            _require_range(self, name, *TEMPERATURE_RANGE_K)
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
