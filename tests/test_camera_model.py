"""Tests for branch_gym.sim.scene.camera_model: the photometric camera (radiance -> 8-bit RGB)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from branch_gym.sim.scene.camera_model import (
    GREY_WORLD_STRENGTH,
    MANUAL_EXPOSURE_GAIN,
    CameraConfig,
    CameraModel,
    metered_exposure_gain,
    motion_blur_kernel,
    vignetting_map,
)

HEIGHT, WIDTH = 48, 64
GAMMA = 2.2
TARGET_DN = CameraConfig().exposure_target * 255.0

# A camera without the effects a test does not look at: no noise, JPEG, vignetting or
# white-balance error; auto-exposure and (neutral) grey-world AWB stay on.
CLEAN = dataclasses.replace(
    CameraConfig.realistic(),
    noise_shot=0.0,
    noise_read_std=0.0,
    jpeg_quality_range=None,
    vignetting=0.0,
    white_balance_error_range=(1.0, 1.0),
)


def _uniform(value: float | tuple[float, float, float], height: int = HEIGHT, width: int = WIDTH):
    """(height, width, 3) float32 radiance of one colour."""
    rgb = np.broadcast_to(np.asarray(value, dtype=np.float32), (3,))
    return np.ascontiguousarray(np.broadcast_to(rgb, (height, width, 3)))


def _expose(
    config: CameraConfig,
    radiance: np.ndarray,
    motion: tuple[float, float] | None = None,
    seed: int = 0,
) -> np.ndarray:
    """One frame of a fresh camera (per-scan draws from ``seed``, noise from ``seed + 1``)."""
    camera = CameraModel(config, np.random.default_rng(seed))
    return camera.expose(radiance, motion, np.random.default_rng(seed + 1))


def _linear(image: np.ndarray, gamma: float = GAMMA) -> np.ndarray:
    """Undo the gamma encoding: uint8 -> linear float64 in [0, 1]."""
    return (image.astype(np.float64) / 255.0) ** gamma


def _scene(seed: int = 3) -> np.ndarray:
    """A textured frame with a bright (HDR) sky band, a brownish row and a dark trunk."""
    rng = np.random.default_rng(seed)
    radiance = np.empty((HEIGHT, WIDTH, 3), dtype=np.float32)
    radiance[:] = (0.12, 0.10, 0.07)
    radiance[: HEIGHT // 3] = (1.6, 1.65, 1.7)
    radiance[:, 28:36] = (0.05, 0.04, 0.03)
    radiance *= rng.uniform(0.8, 1.2, (HEIGHT, WIDTH, 1)).astype(np.float32)
    return radiance


# --- configuration ---------------------------------------------------------------------------


def test_realistic_is_the_documented_default() -> None:
    config = CameraConfig.realistic()
    assert config == CameraConfig()
    assert config.auto_exposure and config.auto_white_balance and config.jpeg_quality_range


# (field, bad value): at least one per field; a new field without an entry fails the test below.
BAD_VALUES = [
    ("auto_exposure", 1),
    ("auto_exposure", "yes"),
    ("exposure_target", 0.0),
    ("exposure_target", 1.0),
    ("exposure_target", float("nan")),
    ("exposure_percentile", 0.0),
    ("exposure_percentile", 100.5),
    ("exposure_percentile", True),
    ("exposure_gain_range", (2.0, 1.0)),
    ("exposure_gain_range", (0.0, 1.0)),
    ("exposure_gain_range", (0.5, float("inf"))),
    ("exposure_gain_range", (1.0,)),
    ("exposure_gain_range", 1.0),
    ("exposure_adapt_rate", 0.0),
    ("exposure_adapt_rate", 1.5),
    ("adapt_deadband", -0.1),
    ("adapt_deadband", float("nan")),
    ("white_balance_error_range", (1.2, 0.8)),
    ("white_balance_error_range", (-0.1, 1.0)),
    ("white_balance_error_range", None),
    ("auto_white_balance", None),
    ("noise_shot", -0.01),
    ("noise_shot", float("nan")),
    ("noise_read_std", -1e-3),
    ("noise_read_std", "0.01"),
    ("vignetting", -0.1),
    ("vignetting", 1.0),
    ("exposure_time_s", 0.0),
    ("exposure_time_s", -0.008),
    ("jpeg_quality_range", (0, 90)),
    ("jpeg_quality_range", (70, 101)),
    ("jpeg_quality_range", (95, 70)),
    ("jpeg_quality_range", (70.0, 95.0)),
    ("jpeg_quality_range", (True, 95)),
    ("jpeg", 1),
    ("gamma", 0.0),
    ("gamma", float("inf")),
]


@pytest.mark.parametrize(("field", "value"), BAD_VALUES)
def test_config_rejects_a_bad_value_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"CameraConfig\.{field} must be"):
        CameraConfig(**{field: value})


def test_every_config_field_has_a_bad_value_case() -> None:
    fields = {f.name for f in dataclasses.fields(CameraConfig)}
    assert fields == {field for field, _ in BAD_VALUES}


def test_config_accepts_lists_and_edge_values() -> None:
    config = CameraConfig(
        exposure_gain_range=[0.5, 0.5],
        jpeg_quality_range=[1, 100],
        exposure_percentile=100.0,
        exposure_adapt_rate=1.0,
        vignetting=0.0,
        noise_shot=0.0,
        noise_read_std=0.0,
    )
    assert config.exposure_gain_range == (0.5, 0.5)
    assert config.jpeg_quality_range == (1, 100)
    assert CameraConfig(jpeg_quality_range=None).jpeg_quality_range is None
    hash(config)  # frozen and hashable after the list -> tuple conversion


# --- determinism and interface -----------------------------------------------------------------


def test_same_generators_give_the_same_images() -> None:
    radiance = _scene()
    config = CameraConfig.realistic()

    def run(scan_seed: int, frame_seed: int) -> list[np.ndarray]:
        camera = CameraModel(config, np.random.default_rng(scan_seed))
        rng = np.random.default_rng(frame_seed)
        motions = [None, (2.5, -1.0), (0.0, 4.0)]
        return [camera.expose(radiance * (1 + i), m, rng) for i, m in enumerate(motions)]

    first, again = run(7, 8), run(7, 8)
    for a, b in zip(first, again, strict=True):
        assert a.dtype == np.uint8 and a.shape == (HEIGHT, WIDTH, 3)
        np.testing.assert_array_equal(a, b)
    # Another frame generator draws other noise; another scan generator other per-scan draws.
    assert any((a != b).any() for a, b in zip(first, run(7, 9), strict=True))
    cameras = [CameraModel(config, np.random.default_rng(seed)) for seed in range(20)]
    assert len({float(c.white_balance_error[0]) for c in cameras}) == 20
    assert len({c.jpeg_quality for c in cameras}) > 5


def test_per_scan_draws_stay_in_their_ranges() -> None:
    config = dataclasses.replace(CLEAN, white_balance_error_range=(0.9, 1.1))
    config = dataclasses.replace(config, jpeg_quality_range=(80, 84))
    qualities = set()
    for seed in range(50):
        camera = CameraModel(config, np.random.default_rng(seed))
        error = camera.white_balance_error
        assert error.dtype == np.float32 and error[1] == 1.0
        assert 0.9 <= error[0] <= 1.1 and 0.9 <= error[2] <= 1.1
        qualities.add(camera.jpeg_quality)
    assert qualities == {80, 81, 82, 83, 84}  # both ends included
    assert CameraModel(CLEAN, np.random.default_rng(0)).jpeg_quality is None


def test_jpeg_off_keeps_the_quality_draw_and_skips_the_round_trip() -> None:
    radiance = _scene()
    realistic = CameraConfig.realistic()
    images, after = {}, {}
    for name, config in (
        ("jpeg", realistic),
        ("off", dataclasses.replace(realistic, jpeg=False)),
        ("none", dataclasses.replace(realistic, jpeg_quality_range=None)),
    ):
        scan_rng = np.random.default_rng(3)
        camera = CameraModel(config, scan_rng)
        after[name] = scan_rng.random()  # where the scene's next draw lands
        images[name] = camera.expose(radiance, None, np.random.default_rng(4))
        assert (camera.jpeg_quality is None) == (name != "jpeg")
    assert after["off"] == after["jpeg"] != after["none"]
    np.testing.assert_array_equal(images["off"], images["none"])
    assert (images["off"] != images["jpeg"]).any()


def test_expose_checks_shape_and_leaves_the_radiance_alone() -> None:
    camera = CameraModel(CameraConfig.realistic(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="radiance must be"):
        camera.expose(np.zeros((HEIGHT, WIDTH), np.float32), None, np.random.default_rng(0))
    broken = _scene()
    broken[8, 8] = np.nan  # on the metering grid
    with pytest.raises(ValueError, match="finite"):
        camera.expose(broken, None, np.random.default_rng(0))
    assert camera.exposure_gain is None  # the state is not poisoned
    radiance = _scene()
    before = radiance.copy()
    first = camera.expose(radiance, (3.0, 0.0), np.random.default_rng(1))
    np.testing.assert_array_equal(radiance, before)
    # A float64 or non-contiguous input works the same as float32.
    camera.reset()
    second = camera.expose(
        np.asfortranarray(radiance.astype(np.float64)), (3.0, 0.0), np.random.default_rng(1)
    )
    np.testing.assert_array_equal(first, second)
    # Work buffers are reused between frames, the returned images are not.
    third = camera.expose(radiance * 0.5, None, np.random.default_rng(2))
    assert not np.shares_memory(second, third)
    np.testing.assert_array_equal(first, second)


def test_image_motion_is_velocity_times_exposure_time() -> None:
    camera = CameraModel(dataclasses.replace(CLEAN, exposure_time_s=0.01), np.random.default_rng(0))
    assert camera.image_motion_px((300.0, -50.0)) == pytest.approx((3.0, -0.5))


# --- auto-exposure -----------------------------------------------------------------------------


def test_auto_exposure_brings_dark_and_bright_scenes_to_the_target() -> None:
    """Uniform grey scenes 16x apart both come out at the target level.

    Tolerance 1.5 DN: the gain solve is exact for a uniform frame; the realistic noise (sigma
    ~3 DN at the target) averages out over the 3072 pixels to < 0.1 DN, and its bias through the
    concave encoding is ~0.1 DN; JPEG keeps a flat frame's DC within ~0.5 DN; rounding < 0.5 DN.
    """
    config = dataclasses.replace(
        CameraConfig.realistic(), vignetting=0.0, white_balance_error_range=(1.0, 1.0)
    )
    camera = CameraModel(config, np.random.default_rng(0))
    means, gains = [], []
    for level in (0.05, 0.8):
        camera.reset()
        image = camera.expose(_uniform(level), None, np.random.default_rng(1))
        means.append(image.mean())
        gains.append(camera.exposure_gain)
    assert means[0] == pytest.approx(TARGET_DN, abs=1.5)
    assert means[1] == pytest.approx(TARGET_DN, abs=1.5)
    assert abs(means[0] - means[1]) < 1.5
    assert gains[0] / gains[1] == pytest.approx(16.0, rel=1e-3)


def test_auto_exposure_off_uses_the_manual_gain() -> None:
    config = dataclasses.replace(CLEAN, auto_exposure=False)
    for level in (0.05, 0.5):
        camera = CameraModel(config, np.random.default_rng(0))
        image = camera.expose(_uniform(level), None, np.random.default_rng(1))
        assert _linear(image).mean() == pytest.approx(level * MANUAL_EXPOSURE_GAIN, rel=0.02)
        assert camera.exposure_gain == pytest.approx(MANUAL_EXPOSURE_GAIN)


def test_auto_exposure_gain_is_clipped_to_its_range() -> None:
    config = dataclasses.replace(CLEAN, exposure_gain_range=(0.5, 2.0))
    camera = CameraModel(config, np.random.default_rng(0))
    camera.expose(_uniform(0.001), None, np.random.default_rng(1))
    assert camera.exposure_gain == pytest.approx(2.0)
    camera.reset()
    camera.expose(_uniform(50.0), None, np.random.default_rng(1))
    assert camera.exposure_gain == pytest.approx(0.5)
    camera.reset()
    camera.expose(_uniform(0.0), None, np.random.default_rng(1))  # black: no gain reaches it
    assert camera.exposure_gain == pytest.approx(2.0)


def test_auto_exposure_adapts_gradually_and_reset_exposes_directly() -> None:
    rate = 0.4
    config = dataclasses.replace(CLEAN, exposure_adapt_rate=rate, adapt_deadband=0.0)
    camera = CameraModel(config, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    dark, bright = _uniform(0.02), _uniform(0.32)
    first = camera.expose(dark, None, rng)  # first frame after construction: direct
    assert first.mean() == pytest.approx(TARGET_DN, abs=1.0)
    log_dark, log_bright = math.log(camera.exposure_gain), math.log(camera.exposure_gain / 16.0)
    means, log_gains = [], []
    for _ in range(8):  # the scene brightens 16x: the image is too bright, then settles
        means.append(camera.expose(bright, None, rng).mean())
        log_gains.append(math.log(camera.exposure_gain))
    for n, log_gain in enumerate(log_gains, start=1):  # the way left shrinks by (1 - rate)
        remaining = (1.0 - rate) ** n * (log_dark - log_bright)
        assert log_gain - log_bright == pytest.approx(remaining, rel=1e-4)
    assert means[0] > TARGET_DN + 60  # overexposed right after the change
    assert (np.diff(means) < 0).all()  # monotone
    assert means[-1] == pytest.approx(TARGET_DN, abs=6.0)  # 0.6^8 of 4 stops left
    camera.reset()
    assert camera.exposure_gain is None
    assert camera.expose(dark, None, rng).mean() == pytest.approx(TARGET_DN, abs=1.0)


def test_backlit_frame_saturates_the_sky_and_leaves_the_trunk_dark() -> None:
    """A third of HDR sky (radiance 8) over a patch 100x darker, average metering (the default).

    Clipped sky meters as white: 1/3 of the 0.46 target, so the patch gets (0.46 - 1/3) / (2/3)
    = 0.19 encoded, ~48.5 DN (the noise's bias through the concave encoding takes ~1 DN off),
    ~40 % of what it gets alone; the sky saturates.
    """
    config = dataclasses.replace(CameraConfig.realistic(), vignetting=0.0, jpeg_quality_range=None)
    radiance = _uniform(0.08)
    sky_rows = HEIGHT // 3  # a multiple of METER_STRIDE: the metered share is exactly 1/3
    radiance[:sky_rows] = 8.0
    image = _expose(config, radiance)
    sky, patch = image[:sky_rows], image[sky_rows:]
    assert (sky == 255).mean() > 0.99
    assert patch.mean() == pytest.approx(48.5, abs=4.0)
    alone = _expose(config, _uniform(0.08))
    assert alone.mean() == pytest.approx(TARGET_DN, abs=1.5)
    assert patch.mean() < 0.5 * alone.mean()
    # Metering only the darkest 60 % (no sky) exposes the patch to the target instead.
    spot = dataclasses.replace(config, exposure_percentile=60.0)
    image = _expose(spot, radiance)
    assert image[sky_rows:].mean() == pytest.approx(TARGET_DN, abs=1.5)
    assert (image[:sky_rows] == 255).all()


@pytest.mark.parametrize("percentile", [100.0, 70.0, 25.0])
def test_metered_gain_solves_the_metered_level_exactly(percentile: float) -> None:
    rng = np.random.default_rng(4)
    for trial in range(30):
        y = (rng.random(int(rng.integers(1, 400))) ** 3 * 10.0 ** rng.uniform(-2, 1)).astype(
            np.float32
        )
        if trial % 3 == 0:
            y[: y.size // 3] = 0.0
        if trial % 4 == 0:
            y = np.round(y * 8.0) / 8.0  # ties
        target = float(rng.uniform(0.05, 0.95))
        gain = metered_exposure_gain(y, target, GAMMA, percentile)
        metered = np.sort(y.astype(np.float64))[: max(1, math.ceil(percentile / 100 * y.size))]
        if math.isinf(gain):  # only when even all-but-the-zeros clipped stays below the target
            assert np.mean(metered > 0) <= target
            continue
        level = np.mean(np.minimum(gain * metered, 1.0) ** (1.0 / GAMMA))
        assert level == pytest.approx(target, abs=1e-9)
    assert metered_exposure_gain(np.zeros(10, np.float32), 0.5, GAMMA, 100.0) == math.inf


# --- backlit look, white balance, noise --------------------------------------------------------


def test_white_balance_error_and_partial_grey_world() -> None:
    grey = _uniform(0.2)
    fixed = dataclasses.replace(
        CLEAN, auto_white_balance=False, white_balance_error_range=(1.1, 1.1)
    )
    lin = _linear(_expose(fixed, grey)).mean(axis=(0, 1))
    assert lin[0] / lin[1] == pytest.approx(1.1, rel=0.02)
    assert lin[2] / lin[1] == pytest.approx(1.1, rel=0.02)
    # A scene with a warm cast: AWB off keeps it, grey-world AWB removes part of it.
    reddish = _uniform((0.3, 0.2, 0.1))
    off = _linear(_expose(dataclasses.replace(CLEAN, auto_white_balance=False), reddish))
    on = _linear(_expose(CLEAN, reddish))
    for channel, cast in ((0, 1.5), (2, 0.5)):
        ratio_off = off[..., channel].mean() / off[..., 1].mean()
        ratio_on = on[..., channel].mean() / on[..., 1].mean()
        assert ratio_off == pytest.approx(cast, rel=0.02)
        assert ratio_on == pytest.approx(cast ** (1.0 - GREY_WORLD_STRENGTH), rel=0.02)
    # The per-scan error multiplies the AWB gains.
    camera = CameraModel(
        dataclasses.replace(CLEAN, white_balance_error_range=(0.9, 0.9)), np.random.default_rng(0)
    )
    camera.expose(reddish, None, np.random.default_rng(0))
    expected = [0.9 * 1.5**-GREY_WORLD_STRENGTH, 1.0, 0.9 * 0.5**-GREY_WORLD_STRENGTH]
    np.testing.assert_allclose(camera.white_balance_gains, expected, rtol=1e-4)


def test_sensor_noise_follows_shot_plus_read_model() -> None:
    """The spread of a flat frame matches sqrt(shot^2 v + read^2), carried through the gamma."""
    shot, read = 0.03, 0.01
    config = dataclasses.replace(
        CLEAN, auto_exposure=False, noise_shot=shot, noise_read_std=read, auto_white_balance=False
    )
    for level in (0.05, 0.4):
        image = _expose(config, _uniform(level, 96, 128)).astype(np.float64)
        sigma_linear = math.sqrt(shot**2 * level + read**2)
        slope_dn = 255.0 / GAMMA * level ** (1.0 / GAMMA - 1.0)  # d(encoded DN) / d(linear)
        assert image.std() == pytest.approx(sigma_linear * slope_dn, rel=0.1)
        assert image.mean() == pytest.approx(255.0 * level ** (1.0 / GAMMA), abs=1.0)
    # Read noise only; and no noise: a flat frame stays flat.
    read_only = dataclasses.replace(config, noise_shot=0.0)
    image = _expose(read_only, _uniform(0.4, 96, 128)).astype(np.float64)
    slope_dn = 255.0 / GAMMA * 0.4 ** (1.0 / GAMMA - 1.0)
    assert image.std() == pytest.approx(read * slope_dn, rel=0.1)
    flat = _expose(dataclasses.replace(config, noise_read_std=0.0, noise_shot=0.0), _uniform(0.4))
    assert flat.std() == 0.0


def test_negative_noise_clips_to_black_not_bright() -> None:
    config = dataclasses.replace(CLEAN, auto_exposure=False, noise_read_std=0.02)
    image = _expose(config, _uniform(0.0))
    assert (image == 0).mean() > 0.45  # about half the draws are negative
    assert image.mean() < 40  # |x| would make it as bright as the positive half


# --- motion blur -------------------------------------------------------------------------------


def _transition_width(profile: np.ndarray, low: float, high: float) -> int:
    """Samples of a 1D profile strictly between the two levels (2 DN margin)."""
    return int(np.count_nonzero((profile > low + 2.0) & (profile < high - 2.0)))


@pytest.mark.parametrize("length", [4.0, 8.0, 12.0])
def test_motion_blur_along_u_smears_vertical_edges_only(length: float) -> None:
    config = dataclasses.replace(CLEAN, auto_exposure=False)
    vertical = _uniform(0.05)
    vertical[:, WIDTH // 2 :] = 0.5  # an edge between columns
    horizontal = _uniform(0.05)
    horizontal[HEIGHT // 2 :] = 0.5  # an edge between rows
    low, high = 255 * 0.05 ** (1 / GAMMA), 255 * 0.5 ** (1 / GAMMA)
    sharp = _expose(config, vertical)[HEIGHT // 2, :, 1].astype(float)
    assert _transition_width(sharp, low, high) == 0
    blurred = _expose(config, vertical, (length, 0.0))[HEIGHT // 2, :, 1].astype(float)
    assert abs(_transition_width(blurred, low, high) - length) <= 1.5
    # Half the smear on either side of the edge: the image at mid-exposure.
    assert blurred[WIDTH // 2 - 1] < blurred[WIDTH // 2] and blurred[WIDTH // 2 - 1] > low + 2
    column = _expose(config, horizontal, (length, 0.0))[:, WIDTH // 2, 1].astype(float)
    assert _transition_width(column, low, high) == 0
    # Along v the roles swap.
    column = _expose(config, horizontal, (0.0, -length))[:, WIDTH // 2, 1].astype(float)
    assert abs(_transition_width(column, low, high) - length) <= 1.5


def test_motion_below_half_a_pixel_is_not_blurred() -> None:
    radiance = _scene()
    config = CameraConfig.realistic()
    np.testing.assert_array_equal(_expose(config, radiance, (0.3, 0.3)), _expose(config, radiance))
    assert (_expose(config, radiance, (0.6, 0.0)) != _expose(config, radiance)).any()


@pytest.mark.parametrize(("du", "dv"), [(8.0, 0.0), (0.0, 3.3), (5.0, 5.0), (-2.7, 6.1), (0.6, 0)])
def test_motion_blur_kernel_is_a_centred_line_of_unit_sum(du: float, dv: float) -> None:
    kernel = motion_blur_kernel(du, dv)
    assert kernel.dtype == np.float32
    assert kernel.shape[0] % 2 == 1 and kernel.shape[1] % 2 == 1
    assert float(kernel.sum()) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(kernel, kernel[::-1, ::-1], atol=1e-6)  # symmetric about centre
    rows, cols = np.nonzero(kernel > 1e-6)
    cy, cx = kernel.shape[0] // 2, kernel.shape[1] // 2
    # Spread along the motion: the second moment of a uniform segment is L^2 / 12.
    offsets = np.stack([cols - cx, rows - cy], axis=1).astype(float)
    direction = np.array([du, dv]) / math.hypot(du, dv)
    along = offsets @ direction
    across = offsets @ np.array([-direction[1], direction[0]])
    weights = kernel[rows, cols]
    length = math.hypot(du, dv)
    assert np.sqrt(np.sum(weights * along**2)) == pytest.approx(length / math.sqrt(12), abs=0.3)
    assert np.sqrt(np.sum(weights * across**2)) < 0.5
    assert np.abs(along).max() <= length / 2 + 1.0


# --- vignetting --------------------------------------------------------------------------------


@pytest.mark.parametrize("strength", [0.0, 0.25, 0.5])
def test_vignetting_darkens_the_corners_by_the_configured_loss(strength: float) -> None:
    config = dataclasses.replace(CLEAN, auto_exposure=False, vignetting=strength)
    lin = _linear(_expose(config, _uniform(0.5)))[..., 1]
    centre = lin[HEIGHT // 2 - 1 : HEIGHT // 2 + 1, WIDTH // 2 - 1 : WIDTH // 2 + 1].mean()
    corners = np.array([lin[0, 0], lin[0, -1], lin[-1, 0], lin[-1, -1]])
    assert centre == pytest.approx(0.5, rel=0.01)
    np.testing.assert_allclose(corners / centre, 1.0 - strength, atol=0.01)
    # Falls off monotonically from the centre along the diagonal.
    diagonal = lin[np.arange(HEIGHT // 2), (np.arange(HEIGHT // 2) * WIDTH) // HEIGHT]
    assert (np.diff(diagonal) >= -1e-3).all()


def test_vignetting_map_is_cached_and_exact_at_the_corners() -> None:
    gain = vignetting_map(240, 320, 0.25)
    assert gain.shape == (240, 320, 3) and gain.dtype == np.float32
    assert not gain.flags.writeable
    assert vignetting_map(240, 320, 0.25) is gain  # cached per size and strength
    assert vignetting_map(120, 160, 0.25) is not gain
    for corner in (gain[0, 0], gain[0, -1], gain[-1, 0], gain[-1, -1]):
        np.testing.assert_allclose(corner, 0.75, rtol=1e-5)
    assert gain.max() <= 1.0 and gain[119:121, 159:161].min() > 0.9999
    np.testing.assert_array_equal(vignetting_map(8, 8, 0.0), 1.0)


# --- JPEG --------------------------------------------------------------------------------------


def _blocking(image: np.ndarray) -> float:
    """Mean |step| between columns across 8x8 block borders over that within blocks (1: none)."""
    steps = np.abs(np.diff(image.astype(np.float64), axis=1)).mean(axis=(0, 2))
    border = np.arange(7, steps.size, 8)  # between columns 8k - 1 and 8k
    return float(steps[border].mean() / np.delete(steps, border).mean())


def test_jpeg_off_has_no_8x8_blocking_and_low_quality_has() -> None:
    rows, cols = np.mgrid[0:96, 0:128].astype(np.float32)
    ramp = 0.05 + 0.3 * (cols / 128) * (0.5 + 0.5 * rows / 96)
    radiance = np.repeat(ramp[..., None], 3, axis=2)
    noisy = dataclasses.replace(CameraConfig.realistic(), white_balance_error_range=(1.0, 1.0))
    off = _expose(dataclasses.replace(noisy, jpeg_quality_range=None), radiance)
    low = _expose(dataclasses.replace(noisy, jpeg_quality_range=(30, 30)), radiance)
    assert abs(_blocking(off) - 1.0) < 0.1
    assert _blocking(low) > 1.5
    # High quality stays close to the JPEG-free frame (noise-free: 4:2:0 chroma subsampling
    # averages the independent per-channel noise away); the output is RGB, not BGR.
    clean = _expose(CLEAN, radiance).astype(float)
    high = _expose(dataclasses.replace(CLEAN, jpeg_quality_range=(95, 95)), radiance)
    assert 0.0 < np.abs(high - clean).mean() < 1.0
    red = _expose(dataclasses.replace(CLEAN, jpeg_quality_range=(90, 90)), _uniform((0.5, 0, 0)))
    assert red[..., 0].mean() > 200 and red[..., 2].mean() < 20


def test_realistic_scene_looks_like_the_real_frames() -> None:
    """Bright sky, brownish row, dark trunk: ordered as in reference.md's real frames."""
    image = _expose(CameraConfig.realistic(), _scene())
    sky = image[: HEIGHT // 3].mean(axis=(0, 1))
    row = image[HEIGHT // 2 :, :20].mean(axis=(0, 1))
    trunk = image[HEIGHT // 2 :, 29:35].mean(axis=(0, 1))
    assert sky.mean() > 180 and row.mean() < 120 and trunk.mean() < row.mean()
    assert row[0] > row[2] and trunk[0] > trunk[2]  # brown stays brown (partial grey world)
    assert abs(image.mean() - TARGET_DN) < 25  # vignetting and JPEG move it a little


def test_white_balance_follows_a_colour_change_gradually() -> None:
    config = dataclasses.replace(
        CameraConfig.realistic(), white_balance_error_range=(1.0, 1.0), adapt_deadband=0.0
    )
    camera = CameraModel(config, np.random.default_rng(0))
    neutral = np.full((HEIGHT, WIDTH, 3), 0.3, np.float32)
    warm = neutral * np.array([1.6, 1.0, 0.6], np.float32)
    camera.expose(neutral, None, np.random.default_rng(1))
    assert camera.white_balance_gains[0] == pytest.approx(1.0, abs=1e-6)
    reds = []
    for k in range(3):
        camera.expose(warm, None, np.random.default_rng(2 + k))
        reds.append(float(camera.white_balance_gains[0]))
    settled = (1.0 / 1.6) ** GREY_WORLD_STRENGTH  # partial grey world
    # Each frame moves exposure_adapt_rate of the way (in log gain) toward the settled gain.
    for k, red in enumerate(reds, start=1):
        expected = settled ** (1.0 - (1.0 - config.exposure_adapt_rate) ** k)
        assert red == pytest.approx(expected, rel=1e-4)


def test_exposure_holds_within_the_deadband_and_adapts_beyond_it() -> None:
    camera = CameraModel(CLEAN, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    camera.expose(_uniform(0.1), None, rng)
    held = camera.exposure_gain
    camera.expose(_uniform(0.1 * 1.1), None, rng)  # 10 % brighter: within the deadband
    assert camera.exposure_gain == held
    camera.expose(_uniform(0.1 * 2.0), None, rng)  # twice as bright: the AE moves
    assert camera.exposure_gain < held
