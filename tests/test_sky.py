"""Tests of the photometric sky dome (branch_gym/sim/scene/sky.py)."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest

from branch_gym.sim.scene.sky import SKY_KINDS, Sky, SkyConfig, blackbody_rgb

LUMA = np.array([0.2126, 0.7152, 0.0722])
ONE_HOT = {kind: tuple(float(k == kind) for k in SKY_KINDS) for kind in SKY_KINDS}
SEEDS = (0, 1, 2)
NO_CLOUDS = {"cloud_cover_range": (0.0, 0.0)}


@functools.lru_cache(maxsize=32)
def make_sky(kind: str | None = None, seed: int = 0, cloudless: bool = False) -> Sky:
    """A sky of ``kind`` (None: the default mix), cached: baking takes ~0.1-0.3 s."""
    overrides: dict = {"kind_weights": ONE_HOT[kind]} if kind else {}
    if cloudless:
        overrides.update(NO_CLOUDS)
    return Sky(SkyConfig(**overrides), np.random.default_rng(seed))


def direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """(3,) unit world vector; azimuth from +x towards +y."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def sun_angles(sky: Sky) -> tuple[float, float]:
    """(azimuth, elevation) of the sun, degrees."""
    x, y, z = sky.sun_direction
    return math.degrees(math.atan2(y, x)), math.degrees(math.asin(z))


def map_directions(sky: Sky) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) unit directions of the map's texels and (H,) their elevations in degrees."""
    height, width = sky.radiance_map.shape[:2]
    elevation = 90.0 - np.arange(height) * 100.0 / (height - 1)
    azimuth = np.arange(width) * 360.0 / width
    e, a = np.radians(elevation)[:, None], np.radians(azimuth)[None, :]
    grid = np.stack(np.broadcast_arrays(np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)))
    return np.moveaxis(grid, 0, -1), elevation


def camera_rays(yaw_deg: float = 90.0, width: int = 320, height: int = 240) -> np.ndarray:
    """(height, width, 3) float32 rays of a level 60 deg camera looking along azimuth yaw."""
    focal = 0.5 * width / math.tan(math.radians(30.0))
    u, v = np.meshgrid(np.arange(width) + 0.5 - width / 2, np.arange(height) + 0.5 - height / 2)
    forward, right = direction(yaw_deg, 0.0), direction(yaw_deg - 90.0, 0.0)
    rays = focal * forward + u[..., None] * right - v[..., None] * np.array([0.0, 0.0, 1.0])
    return rays.astype(np.float32)


def test_same_seed_same_map_and_pixels():
    config = SkyConfig()
    a, b = Sky(config, np.random.default_rng(11)), Sky(config, np.random.default_rng(11))
    assert a.kind == b.kind
    np.testing.assert_array_equal(a.radiance_map, b.radiance_map)
    np.testing.assert_array_equal(a.sun_direction, b.sun_direction)
    np.testing.assert_array_equal(a.ambient_rgb, b.ambient_rgb)
    assert a.sun_radiance == b.sun_radiance
    rays = camera_rays()
    where = np.ones(rays.shape[:2], bool)
    out_a, out_b = np.zeros(rays.shape, np.float32), np.zeros(rays.shape, np.float32)
    a.paint(out_a, rays, where)
    b.paint(out_b, rays, where)
    np.testing.assert_array_equal(out_a, out_b)
    other = Sky(config, np.random.default_rng(12))
    assert not np.array_equal(a.radiance_map, other.radiance_map)


@pytest.mark.parametrize("kind", SKY_KINDS)
def test_each_kind_can_be_drawn(kind):
    sky = make_sky(kind)
    assert sky.kind == kind
    height, width = SkyConfig().map_height_px, SkyConfig().map_width_px
    assert sky.radiance_map.shape == (height, width, 3)
    assert sky.radiance_map.dtype == np.float32
    assert np.isfinite(sky.radiance_map).all() and (sky.radiance_map >= 0).all()
    assert np.linalg.norm(sky.sun_direction) == pytest.approx(1.0)
    assert sky.ambient_rgb.shape == (3,) and sky.ambient_rgb.dtype == np.float32
    assert (sky.ambient_rgb > 0).all()
    assert float(LUMA @ sky.sun_rgb) == pytest.approx(1.0, rel=1e-5)


def test_default_mix_draws_every_kind():
    config = SkyConfig(map_width_px=32, map_height_px=8)  # small: quick to bake
    kinds = {Sky(config, np.random.default_rng(seed)).kind for seed in range(30)}
    assert kinds == set(SKY_KINDS)


@pytest.mark.parametrize("seed", SEEDS)
def test_overcast_is_grey_sunless_and_bright(seed):
    sky = make_sky("overcast", seed)
    assert sky.sun_radiance == 0.0
    _, elevation = map_directions(sky)
    upper = sky.radiance_map[elevation >= 0.0]
    # HSV saturation after the camera's gamma: near grey (the real sky: (180, 182, 178)).
    saturation = 1.0 - (upper.min(-1) / upper.max(-1)) ** (1 / 2.2)
    assert saturation.mean() < 0.1
    luminance = upper @ LUMA
    assert luminance.max() < 3.0 * np.median(luminance)  # no sun, only soft structure
    assert luminance.std() > 0.03 * luminance.mean()  # but cloud structure
    # Bright: the level camera's sky is ~(180, 182, 178) in the real frames at the preview
    # exposure clip(0.6 x) ** (1 / 2.2); it is well above mid-grey here.
    rays = camera_rays()
    pixels = sky.radiance(rays)[rays[..., 2] > 0]
    srgb = 255.0 * np.clip(0.6 * pixels.mean(0), 0.0, 1.0) ** (1 / 2.2)
    assert (srgb > 120).all()


@pytest.mark.parametrize("seed", SEEDS)
def test_clear_sky_is_blue_and_brighter_at_horizon_and_sun(seed):
    sky = make_sky("clear", seed, cloudless=True)
    sun_azimuth, sun_elevation = sun_angles(sky)
    config = SkyConfig()
    assert config.clear_sun_elevation_range_deg[0] <= sun_elevation
    assert sun_elevation <= config.clear_sun_elevation_range_deg[1]
    assert sky.sun_radiance > 0.5
    zenith = sky.radiance(direction(0.0, 90.0)[None])[0]
    assert zenith[2] > 1.5 * zenith[0]  # blue overhead
    away = sun_azimuth + 180.0
    horizon = sky.radiance(direction(away, 2.0)[None])[0]
    assert horizon @ LUMA > zenith @ LUMA
    near_sun = sky.radiance(direction(sun_azimuth, sun_elevation + 5.0)[None])[0]
    assert near_sun @ LUMA > 2.0 * (horizon @ LUMA)
    assert sky.ambient_rgb[2] > sky.ambient_rgb[0]


def test_clear_sky_with_clouds_stays_blue_overall():
    for seed in SEEDS:
        sky = make_sky("clear", seed)
        _, elevation = map_directions(sky)
        upper = sky.radiance_map[elevation > 30.0].reshape(-1, 3).mean(0)
        assert upper[2] > upper[0]


@pytest.mark.parametrize("seed", SEEDS)
def test_low_sun_glows_brightest_at_the_sun_near_the_horizon(seed):
    sky = make_sky("low_sun", seed, cloudless=True)
    sun_azimuth, sun_elevation = sun_angles(sky)
    assert 0.0 <= sun_elevation <= 15.0
    directions, elevation = map_directions(sky)
    upper = elevation >= 0.0
    luminance = sky.radiance_map[upper] @ LUMA
    brightest = directions[upper].reshape(-1, 3)[np.argmax(luminance)]
    assert math.degrees(math.acos(min(1.0, brightest @ sky.sun_direction))) < 3.0
    assert luminance.max() > 3.0  # HDR
    # Warm glow at the horizon towards the sun; strongly backlit against the opposite sky.
    glow = sky.radiance(direction(sun_azimuth + 10.0, 1.0)[None])[0]
    assert glow[0] > glow[2]
    opposite = sky.radiance(direction(sun_azimuth + 180.0, sun_elevation)[None])[0]
    assert glow @ LUMA > 3.0 * (opposite @ LUMA)


def test_low_sun_with_clouds_keeps_the_sun_low():
    for seed in SEEDS:
        sky = make_sky("low_sun", seed)
        assert 0.0 <= sun_angles(sky)[1] <= 15.0
        assert sky.sun_radiance >= 0.0


def test_radiance_is_continuous_across_the_azimuth_seam():
    sky = make_sky(None, 3)
    tiny = 1e-4  # degrees either side of azimuth 0 (= 360)
    for elevation in (0.5, 10.0, 30.0, 60.0):
        left = sky.radiance(direction(-tiny, elevation)[None])[0]
        right = sky.radiance(direction(tiny, elevation)[None])[0]
        np.testing.assert_allclose(left, right, rtol=1e-3, atol=1e-4)
    # The map's last column continues into its first like any two neighbouring columns.
    rays = sky.radiance_map
    seam = np.abs(rays[:, 0] - rays[:, -1]).max()
    neighbours = np.abs(np.diff(rays, axis=1)).max()
    assert seam <= neighbours + 1e-6


def test_below_the_horizon_repeats_the_horizon():
    sky = make_sky("clear", 0)
    low = sky.radiance(np.stack([direction(a, e) for a in (10.0, 200.0) for e in (-1, -10, -60)]))
    np.testing.assert_allclose(low[:3], low[0:1].repeat(3, 0), rtol=1e-5)
    np.testing.assert_allclose(low[3:], low[3:4].repeat(3, 0), rtol=1e-5)


@pytest.mark.parametrize("kind", SKY_KINDS)
def test_paint_equals_radiance_and_leaves_other_pixels(kind):
    sky = make_sky(kind, 4)
    rng = np.random.default_rng(0)
    rays = (rng.standard_normal((60, 80, 3)) * rng.uniform(0.1, 10.0, (60, 80, 1))).astype(
        np.float32
    )
    where = rng.random((60, 80)) < 0.6
    out = np.full((60, 80, 3), -7.0, np.float32)
    sky.paint(out, rays, where)
    expected = sky.radiance(rays)
    np.testing.assert_array_equal(out[where], expected[where])
    assert (out[~where] == -7.0).all()
    # Flat (N, 3) input and unnormalised directions give the same values.
    np.testing.assert_array_equal(sky.radiance(rays.reshape(-1, 3)), expected.reshape(-1, 3))
    np.testing.assert_allclose(sky.radiance(rays * 3.0), expected, rtol=1e-4, atol=1e-5)


def test_radiance_shapes_and_errors():
    sky = make_sky("overcast", 0)
    assert sky.radiance(np.zeros((0, 3))).shape == (0, 3)
    assert sky.radiance(np.ones((40000, 3))).shape == (40000, 3)  # above cv2.remap's side limit
    assert sky.radiance(np.ones((2, 5, 3))).dtype == np.float32
    with pytest.raises(ValueError, match="directions"):
        sky.radiance(np.ones((3,)))
    out = np.zeros((4, 5, 3), np.float32)
    with pytest.raises(ValueError, match="out"):
        sky.paint(out.astype(np.float64), np.ones((4, 5, 3)), np.ones((4, 5), bool))
    with pytest.raises(ValueError, match="where"):
        sky.paint(out, np.ones((4, 5, 3)), np.ones((4, 5), np.uint8))
    with pytest.raises(ValueError, match="must match"):
        sky.paint(out, np.ones((4, 6, 3)), np.ones((4, 5), bool))


def test_blackbody_colours():
    np.testing.assert_allclose(blackbody_rgb(6504.0), np.ones(3), atol=1e-6)
    warm, cool = blackbody_rgb(2500.0), blackbody_rgb(12000.0)
    assert warm[0] > warm[1] > warm[2] >= 0.0
    assert cool[2] > cool[0]
    assert float(LUMA @ warm) == pytest.approx(1.0)


BAD_VALUES = {
    "kind_weights": [(0.0, 0.0, 0.0), (1.0, -1.0, 1.0), (1.0, 1.0), [1.0, 0.0, 0.0]],
    "cloud_cover_range": [(0.5, 0.2), (0.0, 1.5), (-0.1, 0.5)],
    "clear_cloud_cover_scale": [1.5, -0.1, True],
    "overcast_cloud_cover_range": [(0.9, 1.1)],
    "clear_sun_elevation_range_deg": [(10.0, 95.0), (-5.0, 10.0)],
    "low_sun_elevation_range_deg": [(15.0, 0.0)],
    "overcast_sun_elevation_range_deg": [(5.0, math.nan)],
    "clear_zenith_radiance_range": [(-0.1, 0.2)],
    "low_sun_zenith_radiance_range": [(0.1, math.inf)],
    "overcast_zenith_radiance_range": [(1.0,)],
    "overcast_gradient_range": [(-1.0, 2.0)],
    "clear_sun_radiance_range": [("a", 1.0)],
    "low_sun_sun_radiance_range": [(0.7, 0.3)],
    "clear_sun_temperature_range_k": [(500.0, 5000.0)],
    "low_sun_temperature_range_k": [(2000.0, 20000.0)],
    "overcast_temperature_range_k": [(7000.0, 6000.0)],
    "tint_range": [(-1.0, 0.0)],
    "sky_purity_range": [(-0.5, 1.0)],
    "cloud_brightness_range": [(-1.0, 1.0)],
    "cloud_darkening_range": [(0.5, 1.5)],
    "cloud_feature_min_deg": [0.0, -1.0],
    "cloud_feature_max_deg": [2.0, 120.0],
    "cloud_edge_softness": [-0.1, math.nan],
    "cloud_perspective": [0.0, 1.0],
    "map_width_px": [4, 64.0],
    "map_height_px": [2, True],
}


@pytest.mark.parametrize(
    ("field", "value"), [(f, v) for f, values in BAD_VALUES.items() for v in values]
)
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=f"SkyConfig.{field} "):
        SkyConfig(**{field: value})


def test_every_config_field_is_checked():
    assert set(BAD_VALUES) == {f.name for f in dataclasses.fields(SkyConfig)}
    SkyConfig()  # the defaults are valid
