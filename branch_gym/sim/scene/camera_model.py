"""The photometric camera model: linear scene radiance in, the 8-bit RGB image a real camera gives.

The renderer produces linear scene radiance (1.0 ~ a white diffuse surface in full light; a bright
sky may exceed 1). A real consumer RGB camera (e.g. the colour imager of an Intel RealSense D435)
turns that into 8-bit frames that differ from the radiance in ways a segmenter trained in
simulation must survive: motion blur, lens vignetting, white-balance and exposure errors, sensor
noise, clipping (an overcast sky saturates to white, backlit trunks go near-black, as in the real
close-up frames of reference.md) and JPEG artefacts. :class:`CameraModel.expose` applies, in order:

1. motion blur: a line kernel of the image motion during the exposure (``cv2.filter2D``);
2. vignetting: a cached ``cos^4``-like gain map per image size;
3. white balance: a per-scan gain error times grey-world auto-white-balance gains;
4. auto-exposure: the gain that brings the metered level to the target, smoothed over frames;
5. sensor noise: shot (signal-dependent) plus read noise;
6. gamma encoding, 8-bit quantisation with clipping;
7. JPEG encode/decode at the per-scan quality.

Auto-exposure metering (our choice, see :class:`CameraConfig`): like a real ISP, the AE meters
the *output* statistics: the mean of the gamma-encoded, clipped luminance, over the darkest
``exposure_percentile`` % of a decimated pixel grid (100: plain average metering). Clipped pixels
count as 1, so a bright sky cannot pull the exposure down below the point where it saturates:
the rest of a backlit frame stays dark. The gain is solved exactly (the metered level is
piecewise linear in ``gain ** (1 / gamma)``), not iterated.

Noise draws (our choice, for speed): numpy's float32 ``standard_normal`` costs ~2.6 ms for a
320x240x3 frame on the dev machine's core, more than the whole budget. The model takes one byte
per value from the generator's raw 64-bit draws (``rng.bit_generator.random_raw``) and maps it
through a 256-entry table of standard-normal quantiles (rescaled to unit variance, tails at
+-2.9 sigma) with ``cv2.LUT``: ~0.2 ms. At the default noise levels (sigma ~2-4 DN after
encoding) the 8-bit output cannot tell the two apart.

Speed, 320x240, ``CameraConfig.realistic()``, one thread (``timeit``, process time, best of
9 x 200 frames, on the shared 2-core 2.8 GHz Xeon dev machine while other jobs kept its load
average at 5-8): 1.4-1.8 ms a frame without JPEG, 2.3-3.0 ms with JPEG at quality 70-83, 3.1-3.5
ms at 95; a 3 px motion blur adds ~0.1-0.3 ms. At light load (load average < 1) the steps measured
about half that: ~0.9 ms before JPEG, JPEG encode + decode 0.5 ms (q78) to 0.95 ms (q95), so
~1.4-1.9 ms a frame. JPEG of a noisy frame is the largest single cost. All full-frame arrays are
float32 work buffers reused between frames (fresh ones doubled the time); only the 40x30
metering grid uses small float64 temporaries. Motion blur cost grows with the kernel's area
(``cv2.filter2D`` switches to a DFT above ~11x11: ~12 ms at 21x21).
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import cv2
import numpy as np

from branch_gym.config_utils import is_number
from branch_gym.sim.validation import require_non_negative, require_positive

__all__ = [
    "AWB_GAIN_RANGE",
    "GREY_WORLD_STRENGTH",
    "LUMINANCE_WEIGHTS",
    "MANUAL_EXPOSURE_GAIN",
    "METER_STRIDE",
    "MOTION_BLUR_MIN_PX",
    "CameraConfig",
    "CameraModel",
    "metered_exposure_gain",
    "motion_blur_kernel",
    "vignetting_map",
]

logger = logging.getLogger(__name__)

# Rec. 709 / sRGB luminance weights of linear R, G, B (standard).
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)
# Auto-exposure meters every 8th row and column (our choice; ISPs meter on coarse grids too):
# 40x30 = 1200 samples at 320x240, plenty for a mean of the darkest share, and the exact solve's
# sort stays cheap (~40 us). (The AWB's channel means are over the whole frame: cv2.mean is
# cheaper than decimating.)
METER_STRIDE = 8
# Grey-world gains are clipped to +-1 stop (our choice: a sane ISP correction range).
AWB_GAIN_RANGE = (0.5, 2.0)
# Fraction (in log gain) of the grey-world correction the AWB applies (our choice: real AWB
# corrects only part of a scene's own cast; the real orchard frames keep a brown cast, mean RGB
# ~(126, 119, 107) over sky, trunk and row, reference.md). 1 = full grey world.
GREY_WORLD_STRENGTH = 0.5
# Exposure gain with auto_exposure off (our choice): a white diffuse surface in full light
# (radiance 1.0) just reaches full scale.
MANUAL_EXPOSURE_GAIN = 1.0
# Motion blur is applied only when the image moves more than this during the exposure (pixels).
MOTION_BLUR_MIN_PX = 0.5
# Sub-pixel samples per pixel of motion when drawing the blur line into its kernel (our choice).
MOTION_BLUR_SAMPLES_PER_PX = 4
# Levels of the discretised standard normal used for the sensor noise (one random byte each).
_NOISE_LEVELS = 256
_JPEG_QUALITY_LIMITS = (1, 100)
_FULL_SCALE_DN = 255.0
# The noise bytes come from the generator's raw 64-bit draws (~3x faster than rng.bytes).
_BYTES_PER_DRAW = 8
# Negative values (noise) are clipped to the linear level that encodes to this (rounds to 0 DN).
_BLACK_FLOOR_DN = 0.25
_IMREAD_RGB = getattr(cv2, "IMREAD_COLOR_RGB", None)  # OpenCV >= 4.10 decodes straight to RGB


def _normal_table() -> np.ndarray:
    """(1, 256) float32 standard-normal quantiles at the level midpoints, rescaled to unit std."""
    normal = NormalDist()
    levels = np.array(
        [normal.inv_cdf((i + 0.5) / _NOISE_LEVELS) for i in range(_NOISE_LEVELS)], dtype=np.float64
    )
    levels /= levels.std()
    return levels.astype(np.float32).reshape(1, _NOISE_LEVELS)


_NORMAL_TABLE = _normal_table()


def _is_pair(value: object, element_ok: Callable[[object], bool]) -> bool:
    """A 2-tuple (or list) whose elements pass ``element_ok`` and are ordered ``lo <= hi``."""
    return (
        isinstance(value, tuple | list)
        and len(value) == 2
        and all(element_ok(v) for v in value)
        and value[0] <= value[1]
    )


def _positive_finite(value: object) -> bool:
    return is_number(value) and math.isfinite(value) and value > 0


def _jpeg_quality(value: object) -> bool:
    lo, hi = _JPEG_QUALITY_LIMITS
    return isinstance(value, int | np.integer) and not isinstance(value, bool) and lo <= value <= hi


@dataclass(frozen=True)
class CameraConfig:
    """The photometric camera model; the defaults are :meth:`realistic`.

    Attributes:
        auto_exposure: Auto-exposure on; off: the fixed gain ``MANUAL_EXPOSURE_GAIN``.
        exposure_target: Target level of the metered *gamma-encoded* luminance, in (0, 1) (1 =
            255 DN). Our choice of domain: real AE set points are output (encoded) levels.
        exposure_percentile: The AE meters the mean encoded, clipped luminance of the darkest
            ``exposure_percentile`` % of the metering grid, in (0, 100]; 100 = average metering,
            lower values ignore the brightest pixels (e.g. sky) and expose for the rest.
        exposure_gain_range: (min, max) exposure gain on the linear radiance, positive.
        exposure_adapt_rate: Fraction of the way (in log gain) from the current exposure and
            white balance to the metered ones per frame, in (0, 1]; 1 = instant. The first frame
            after a reset is exposed and balanced directly.
        adapt_deadband: The exposure and white balance hold while the metered log gain differs
            from the current one by at most this (hysteresis), >= 0; 0 = always adapt.
        white_balance_error_range: (min, max) of the per-scan multiplicative R and B gain errors
            of the white balance (independent uniform draws), positive.
        auto_white_balance: Grey-world AWB on (partial, ``GREY_WORLD_STRENGTH``); off: only the
            error gains (a fixed preset, wrong by the error).
        noise_shot: Signal-dependent noise: std ``noise_shot * sqrt(value)`` on the exposed
            linear value (1 = full scale), >= 0.
        noise_read_std: Signal-independent noise std on the exposed linear value, >= 0.
        vignetting: Relative light loss at the image corners, in [0, 1) (``cos^4``-like falloff
            with this loss at the corner pixels); 0 = none.
        exposure_time_s: Exposure time, seconds, > 0. Not used by :meth:`CameraModel.expose`:
            the caller turns image velocity into ``image_motion_px`` with it
            (:meth:`CameraModel.image_motion_px`).
        jpeg_quality_range: (min, max) of the per-scan JPEG quality, ints in [1, 100]; None: no
            JPEG.
        jpeg: Apply the JPEG round trip. False skips it (~0.5 ms a 320x240 frame) while the
            per-scan quality is still drawn, so that every later draw of the scene stays where
            it was (the orchard's fast setting, ``OrchardConfig.fast``).
        gamma: Encoding exponent, > 0: ``encoded = linear ** (1 / gamma)`` (sRGB-like power law).
    """

    # Our choice: consumer cameras ship with AE on, and sim lighting varies per scene.
    auto_exposure: bool = True
    # The real close-up frames' mean level, ~118/255 (reference.md: sky 34 % at ~180, trunk 10 %
    # at ~60, the rest at ~90).
    exposure_target: float = 0.46
    # Typical consumer AE: average metering of the whole frame (RealSense: a mean-intensity set
    # point); clipped sky counts as white, so backlit trunks go dark as in the real frames.
    exposure_percentile: float = 100.0
    # Our choice: +-4 stops around unit gain; the renderer's radiance is normalised (a lit white
    # surface is 1), so frames' mean radiance of ~0.01-3 stays within reach.
    exposure_gain_range: tuple[float, float] = (1.0 / 16.0, 16.0)
    # Our choice: a real AE and AWB settle in ~0.3-0.5 s; the simulated camera renders a frame
    # per ~1 mm of travel, ~25 frames a second at 2.5 cm/s, so a tenth of the way per frame.
    # Measured: at half the way per frame the brightness jumps between the tracking window's
    # frames made Lucas-Kanade lose the branch in 16 of 60 orchard scans.
    exposure_adapt_rate: float = 0.1
    # Our choice: consumer AE and AWB hold while the metered error stays within ~+-15 %
    # (hysteresis keeps the exposure stable as a scene drifts; log 1.15 = 0.14).
    adapt_deadband: float = 0.14
    # Our choice: consumer AWB errs by up to ~15 % per channel under overcast or backlit light.
    white_balance_error_range: tuple[float, float] = (0.85, 1.15)
    # Consumer cameras ship with AWB on.
    auto_white_balance: bool = True
    # Typical small-pixel CMOS sensor: ~2 % of full scale at full signal (photon shot noise).
    noise_shot: float = 0.02
    # Typical small-pixel CMOS sensor in daylight after the ISP's denoising: ~0.3 % of linear
    # full scale (the gamma curve multiplies it in the shadows: ~4 DN at a backlit trunk's ~50 DN).
    noise_read_std: float = 0.003
    # Typical small wide-angle lens: a quarter of the light lost at the corners (pure cos^4 at the
    # sim's 42 deg HFOV would lose ~0.34; real lenses compensate part of it).
    vignetting: float = 0.25
    # Typical AE exposure of a consumer camera in overcast daylight at 30 fps (D435 colour:
    # 1-33 ms).
    exposure_time_s: float = 0.008
    # Our choice: recorded or streamed frames (ROS compressed_image_transport defaults to 95;
    # bandwidth-limited pipelines go down to ~70).
    jpeg_quality_range: tuple[int, int] | None = (70, 95)
    # Real frames arrive compressed (above); off only to save time.
    jpeg: bool = True
    # sRGB-like encoding (standard).
    gamma: float = 2.2

    def __post_init__(self) -> None:
        for name in (
            "exposure_gain_range",
            "white_balance_error_range",
            "jpeg_quality_range",
        ):
            value = getattr(self, name)
            if isinstance(value, list):  # configs read from YAML or JSON give lists
                object.__setattr__(self, name, tuple(value))
        for name in ("auto_exposure", "auto_white_balance", "jpeg"):
            self._check(name, isinstance(getattr(self, name), bool), "a bool")
        self._check_interval("exposure_target", 0.0, 1.0, include_lo=False, include_hi=False)
        self._check_interval("exposure_percentile", 0.0, 100.0, include_lo=False, include_hi=True)
        self._check_interval("exposure_adapt_rate", 0.0, 1.0, include_lo=False, include_hi=True)
        require_non_negative(self, "adapt_deadband")
        self._check_interval("vignetting", 0.0, 1.0, include_lo=True, include_hi=False)
        for name in ("exposure_gain_range", "white_balance_error_range"):
            self._check(
                name,
                _is_pair(getattr(self, name), _positive_finite),
                "a pair (lo, hi) of positive finite numbers with lo <= hi",
            )
        self._check(
            "jpeg_quality_range",
            self.jpeg_quality_range is None or _is_pair(self.jpeg_quality_range, _jpeg_quality),
            "None or a pair (lo, hi) of ints in [1, 100] with lo <= hi",
        )
        require_non_negative(self, "noise_shot", "noise_read_std")
        require_positive(self, "exposure_time_s", "gamma")

    def _check(self, name: str, ok: bool, what: str) -> None:
        """Raise ``ValueError`` naming ``CameraConfig.name`` unless ``ok``."""
        if not ok:
            value = getattr(self, name)
            raise ValueError(f"{type(self).__name__}.{name} must be {what}, got {value!r}")

    def _check_interval(
        self, name: str, lo: float, hi: float, *, include_lo: bool, include_hi: bool
    ) -> None:
        """The named field is a real number in the interval from ``lo`` to ``hi``."""
        value = getattr(self, name)
        ok = is_number(value) and math.isfinite(value)
        ok = ok and (lo <= value if include_lo else lo < value)
        ok = ok and (value <= hi if include_hi else value < hi)
        brackets = ("[" if include_lo else "(", "]" if include_hi else ")")
        self._check(name, ok, f"a number in {brackets[0]}{lo}, {hi}{brackets[1]}")

    @classmethod
    def realistic(cls) -> CameraConfig:
        """A consumer RGB camera (RealSense D435 colour class) in an overcast-to-backlit orchard.

        These are the field defaults; each default's comment says where it comes from.
        """
        return cls()


@functools.lru_cache(maxsize=8)
def vignetting_map(height: int, width: int, corner_loss: float) -> np.ndarray:
    """The ``cos^4``-like vignetting gain of each pixel, cached per (height, width, loss).

    ``gain = 1 / (1 + k rho^2)^2`` with ``rho`` the distance from the image centre relative to
    the corner pixels' (the ``cos^4`` law of a lens with an effective focal length set by ``k``),
    and ``k`` chosen so that the corner pixels' gain is exactly ``1 - corner_loss``.

    Args:
        height: Image height in pixels.
        width: Image width in pixels.
        corner_loss: Relative light loss at the corner pixels, in [0, 1).

    Returns:
        (height, width, 3) float32 gain in (0, 1], 1 at the centre, the same for each channel;
        read-only (it is shared).
    """
    k = (1.0 - corner_loss) ** -0.5 - 1.0
    cu, cv = 0.5 * (width - 1), 0.5 * (height - 1)
    corner_sq = max(cu * cu + cv * cv, 1.0)
    u = (np.arange(width, dtype=np.float32) - np.float32(cu)) ** 2
    v = (np.arange(height, dtype=np.float32) - np.float32(cv)) ** 2
    rho_sq = (v[:, None] + u[None, :]) / np.float32(corner_sq)
    gain = (1.0 / (1.0 + np.float32(k) * rho_sq) ** 2).astype(np.float32)
    gain3 = np.ascontiguousarray(np.repeat(gain[:, :, None], 3, axis=2))
    gain3.setflags(write=False)
    return gain3


def motion_blur_kernel(du: float, dv: float) -> np.ndarray:
    """The line kernel of an image motion ``(du, dv)`` during the exposure, centred, sum 1.

    The segment from ``-(du, dv) / 2`` to ``+(du, dv) / 2`` about the kernel centre is sampled
    at its midpoints (``MOTION_BLUR_SAMPLES_PER_PX`` per pixel of length) and each sample is
    splatted bilinearly: an anti-aliased line of the exact length, symmetric about the centre
    (so ``cv2.filter2D``'s correlation equals the convolution).

    Args:
        du: Image motion along u (columns) during the exposure, pixels.
        dv: Image motion along v (rows), pixels.

    Returns:
        (2 ceil(|dv| / 2) + 1, 2 ceil(|du| / 2) + 1) float32 kernel summing to 1.
    """
    half_u, half_v = math.ceil(abs(du) / 2.0), math.ceil(abs(dv) / 2.0)
    kernel = np.zeros((2 * half_v + 1, 2 * half_u + 1), dtype=np.float32)
    count = max(2, math.ceil(math.hypot(du, dv) * MOTION_BLUR_SAMPLES_PER_PX))
    s = (np.arange(count, dtype=np.float64) + 0.5) / count - 0.5
    u, v = half_u + s * du, half_v + s * dv
    u0, v0 = np.floor(u).astype(np.intp), np.floor(v).astype(np.intp)
    fu, fv = (u - u0).astype(np.float32), (v - v0).astype(np.float32)
    u1 = np.minimum(u0 + 1, kernel.shape[1] - 1)  # out of range only with weight 0
    v1 = np.minimum(v0 + 1, kernel.shape[0] - 1)
    np.add.at(kernel, (v0, u0), (1 - fu) * (1 - fv))
    np.add.at(kernel, (v0, u1), fu * (1 - fv))
    np.add.at(kernel, (v1, u0), (1 - fu) * fv)
    np.add.at(kernel, (v1, u1), fu * fv)
    kernel /= kernel.sum()
    return kernel


def metered_exposure_gain(
    luminance: np.ndarray, target: float, gamma: float, percentile: float
) -> float:
    """The gain at which the AE's metered level equals ``target`` (see module doc).

    The metered level is ``mean(min(g * Y, 1) ** (1 / gamma))`` over the darkest ``percentile``
    % of ``luminance``. With ``e = g ** (1 / gamma)`` and ``c = Y ** (1 / gamma)`` it is
    ``mean(min(e * c, 1))``: continuous, non-decreasing and piecewise linear in ``e`` with
    breakpoints at ``e = 1 / c_i``, so the solution is an exact interpolation.

    Args:
        luminance: (N,) linear luminance samples, >= 0.
        target: Target metered level, in (0, 1).
        gamma: Encoding exponent.
        percentile: Share of the darkest samples metered, in (0, 100].

    Returns:
        The gain ``g`` (not clipped); ``inf`` when no gain reaches the target (a black frame);
        NaN when ``luminance`` is empty or holds a NaN.
    """
    y = np.sort(luminance, axis=None)  # a float32 sort is ~2x faster than float64
    if y.size == 0 or math.isnan(y[-1]):  # NaNs sort last
        return math.nan
    n = max(1, math.ceil(percentile / 100.0 * y.size))
    c = y[:n].astype(np.float64)
    np.maximum(c, 0.0, out=c)
    c **= 1.0 / gamma
    first_positive = int(np.searchsorted(c, 0.0, side="right"))
    if first_positive == n:
        return math.inf
    prefix = np.cumsum(c)
    # Level at each breakpoint e_j = 1 / c_j (j >= first_positive): the j samples before c_j
    # unclipped, the rest at 1. Ties need no care: at e = 1 / c_j a sample equal to c_j gives 1,
    # clipped or not. The levels fall with j (e falls).
    c_pos = c[first_positive:]
    j = np.arange(first_positive, n)
    level = ((prefix[first_positive:] - c_pos) / c_pos + (n - j)) / n
    if target >= level[0]:  # the largest breakpoint: only zero samples left unclipped
        return math.inf
    if target <= level[-1]:  # below the smallest breakpoint nothing clips: level = e sum(c) / n
        e = target * n / float(prefix[-1])
    else:
        e = float(np.interp(target, level[::-1], 1.0 / c_pos[::-1]))
    return e**gamma


class CameraModel:
    """One camera for one scan: per-scan draws, auto-exposure state, and :meth:`expose`.

    Not thread-safe: it keeps float32 work buffers between frames (each returned image is new).

    Attributes:
        config: The photometric model.
        white_balance_error: (3,) float32 per-scan multiplicative R, G, B gain errors (G = 1).
        jpeg_quality: The per-scan JPEG quality, or None (no JPEG).
        exposure_gain: The exposure gain of the last frame (None before the first one after a
            reset).
        white_balance_gains: (3,) float32 R, G, B gains of the last frame (AWB times error).
    """

    def __init__(self, config: CameraConfig, rng: np.random.Generator) -> None:
        """Draw the per-scan parameters from ``rng`` (white-balance error R then B, JPEG quality).

        Args:
            config: The photometric model.
            rng: Per-scan draws.
        """
        self.config = config
        lo, hi = config.white_balance_error_range
        error_r, error_b = rng.uniform(lo, hi, size=2)
        self.white_balance_error = np.array([error_r, 1.0, error_b], dtype=np.float32)
        self.jpeg_quality: int | None = None
        if config.jpeg_quality_range is not None:
            q_lo, q_hi = config.jpeg_quality_range
            self.jpeg_quality = int(rng.integers(q_lo, q_hi, endpoint=True))
            if not config.jpeg:  # drawn all the same: the scene's later draws stay in place
                self.jpeg_quality = None
        self.white_balance_gains = self.white_balance_error.copy()
        self._log_gain: float | None = None
        self._log_awb: np.ndarray | None = None  # smoothed log grey-world gains (R, B)
        self._pending_log_awb: np.ndarray | None = None
        self._work: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._luminance = np.asarray(LUMINANCE_WEIGHTS, dtype=np.float32)
        floor = (_BLACK_FLOOR_DN / _FULL_SCALE_DN) ** config.gamma
        self._black_floor = (floor, floor, floor, floor)  # a cv2 Scalar for every channel
        self._inverse_gamma = np.float32(1.0 / config.gamma)
        logger.debug(
            "camera draws: white balance error R %.3f B %.3f, JPEG quality %s",
            error_r,
            error_b,
            self.jpeg_quality,
        )

    @property
    def exposure_gain(self) -> float | None:
        """The exposure gain applied to the last frame; None right after a reset."""
        return None if self._log_gain is None else math.exp(self._log_gain)

    def reset(self) -> None:
        """Forget the auto-exposure state (a new scan): the next frame is exposed directly.

        The per-scan draws (white-balance error, JPEG quality) are kept; make a new model to
        redraw them.
        """
        self._log_gain = None
        self._log_awb = None

    def image_motion_px(self, image_velocity_pxps: tuple[float, float]) -> tuple[float, float]:
        """Image motion during one exposure: ``velocity * exposure_time_s``.

        Args:
            image_velocity_pxps: (du/dt, dv/dt) image velocity, pixels per second.

        Returns:
            (du, dv) pixels, for :meth:`expose`.
        """
        t = self.config.exposure_time_s
        return (image_velocity_pxps[0] * t, image_velocity_pxps[1] * t)

    def expose(
        self,
        radiance: np.ndarray,
        image_motion_px: tuple[float, float] | None,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Turn one frame of linear scene radiance into the camera's 8-bit RGB image.

        Args:
            radiance: (H, W, 3) float32 linear scene radiance, finite and >= 0 (1.0 ~ a white
                diffuse surface in full light; a bright sky may exceed 1). Not modified.
            image_motion_px: (du, dv) image motion in pixels during the exposure (the caller
                computes it from the camera's velocity and the scene depth, e.g. with
                :meth:`image_motion_px`), or None for no motion blur.
            rng: Per-frame noise draws.

        Returns:
            (H, W, 3) uint8 RGB.

        Raises:
            ValueError: ``radiance`` is not (H, W, 3), or (auto-exposure on) has a NaN where the
                auto-exposure meters.
        """
        if radiance.ndim != 3 or radiance.shape[2] != 3:
            raise ValueError(f"radiance must be (H, W, 3), got shape {radiance.shape}")
        config = self.config
        source = np.ascontiguousarray(radiance, dtype=np.float32)
        height, width = source.shape[:2]
        image, spare_a, spare_b = self._buffers(source.shape)

        if image_motion_px is not None and math.hypot(*image_motion_px) > MOTION_BLUR_MIN_PX:
            kernel = motion_blur_kernel(float(image_motion_px[0]), float(image_motion_px[1]))
            cv2.filter2D(source, -1, kernel, dst=image, borderType=cv2.BORDER_REFLECT)
            source = image
        if config.vignetting > 0.0:
            cv2.multiply(source, vignetting_map(height, width, config.vignetting), dst=image)
        elif source is not image:
            np.copyto(image, source)

        gains = self._white_balance_gains(image)
        grid = image[::METER_STRIDE, ::METER_STRIDE].reshape(-1, 3)
        exposure = self._exposure_gain(grid @ (gains * self._luminance))
        if self.config.auto_white_balance:
            self._log_awb = self._pending_log_awb
        total = gains * np.float32(exposure)
        cv2.multiply(image, (float(total[0]), float(total[1]), float(total[2]), 0.0), dst=image)

        self._add_noise(image, spare_a, spare_b, rng)

        # Gamma and 8-bit: x ** (1 / gamma) as exp(log(x) / gamma), ~2.5x faster than cv2.pow
        # (measured). Negatives (noise) are clipped first to a floor that still encodes to 0 DN:
        # log(0) = -inf is a slow path. convertScaleAbs rounds and saturates at 255 (bright skies
        # go white).
        cv2.max(image, self._black_floor, dst=image)
        cv2.log(image, dst=image)
        np.multiply(image, self._inverse_gamma, out=image)
        cv2.exp(image, dst=image)
        rgb = cv2.convertScaleAbs(image, alpha=_FULL_SCALE_DN)

        if self.jpeg_quality is not None:
            rgb = self._jpeg(rgb, self.jpeg_quality)
        return rgb

    def _white_balance_gains(self, image: np.ndarray) -> np.ndarray:
        """(3,) float32 R, G, B gains: partial grey-world AWB (if on) times the per-scan error.

        Args:
            image: (H, W, 3) float32 linear RGB after vignetting.
        """
        gains = self.white_balance_error
        if self.config.auto_white_balance:
            # Scalar Python on cv2.mean's sums: small numpy ops cost ~5-10 us each here.
            mean_r, mean_g, mean_b, _ = cv2.mean(image)
            lo, hi = AWB_GAIN_RANGE
            awb = [1.0, 1.0, 1.0]
            if min(mean_r, mean_g, mean_b) > 0.0:
                awb[0] = min(max((mean_g / mean_r) ** GREY_WORLD_STRENGTH, lo), hi)
                awb[2] = min(max((mean_g / mean_b) ** GREY_WORLD_STRENGTH, lo), hi)
            target = np.log(np.array([awb[0], awb[2]]))
            smoothed = target  # a real AWB moves slowly, like the exposure, and holds within the
            if self._log_awb is not None:  # deadband
                error = target - self._log_awb
                step = np.where(np.abs(error) > self.config.adapt_deadband, error, 0.0)
                smoothed = self._log_awb + self.config.exposure_adapt_rate * step
            self._pending_log_awb = smoothed  # kept once the frame's exposure succeeds
            red, blue = np.exp(smoothed)
            gains = np.array([red, 1.0, blue], dtype=np.float32) * gains
        self.white_balance_gains = gains
        return gains

    def _exposure_gain(self, luminance: np.ndarray) -> float:
        """The exposure gain of this frame; updates the smoothed auto-exposure state.

        Args:
            luminance: (N,) float32 decimated linear luminance after vignetting and white balance.
        """
        config = self.config
        if not config.auto_exposure:
            self._log_gain = math.log(MANUAL_EXPOSURE_GAIN)
            return MANUAL_EXPOSURE_GAIN
        lo, hi = config.exposure_gain_range
        metered = metered_exposure_gain(
            luminance, config.exposure_target, config.gamma, config.exposure_percentile
        )
        if math.isnan(metered):  # would poison the smoothed state until the next reset
            raise ValueError("radiance must be finite (NaN on the auto-exposure grid)")
        log_target = math.log(min(max(metered, lo), hi))
        if self._log_gain is None:
            self._log_gain = log_target
        elif abs(log_target - self._log_gain) > config.adapt_deadband:
            self._log_gain += config.exposure_adapt_rate * (log_target - self._log_gain)
        return math.exp(self._log_gain)

    def _buffers(self, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Three (H, W, 3) float32 work images, kept between frames of the same size.

        Fresh full-frame arrays cost page faults on every frame (~0.1-0.3 ms each, measured):
        reusing them roughly halves ``expose``'s time.
        """
        if self._work is None or self._work[0].shape != shape:
            self._work = tuple(np.empty(shape, dtype=np.float32) for _ in range(3))
        return self._work

    def _add_noise(
        self, image: np.ndarray, z: np.ndarray, std: np.ndarray, rng: np.random.Generator
    ) -> None:
        """Add shot and read noise to the exposed linear ``image``, in place.

        Each value gets ``z * sqrt(noise_shot^2 * value + noise_read_std^2)``, ``z`` from a
        256-level discretised standard normal (one byte of the generator's raw 64-bit
        draws per value; module doc).

        Args:
            image: (H, W, 3) float32 exposed linear image, >= 0; modified.
            z: (H, W, 3) float32 work buffer (overwritten).
            std: (H, W, 3) float32 work buffer (overwritten).
            rng: The per-frame generator.
        """
        shot, read = self.config.noise_shot, self.config.noise_read_std
        if shot == 0.0 and read == 0.0:
            return
        raw = rng.bit_generator.random_raw(-(-image.size // _BYTES_PER_DRAW))
        raw = raw.view(np.uint8)[: image.size].reshape(image.shape)
        cv2.LUT(raw, _NORMAL_TABLE, dst=z)
        if shot == 0.0:
            cv2.scaleAdd(z, read, image, dst=image)
            return
        cv2.addWeighted(image, shot * shot, image, 0.0, read * read, dst=std)
        cv2.sqrt(std, dst=std)
        cv2.accumulateProduct(z, std, image)

    @staticmethod
    def _jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
        """JPEG encode and decode (cv2, 4:2:0 chroma) at ``quality``: (H, W, 3) uint8 RGB."""
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        ok, buffer = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise RuntimeError("cv2.imencode failed to encode the frame as JPEG")
        if _IMREAD_RGB is not None:
            return cv2.imdecode(buffer, _IMREAD_RGB)
        return cv2.cvtColor(cv2.imdecode(buffer, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
