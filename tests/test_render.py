"""Camera rendering: pinhole agreement, metric depth, instance labels, background, determinism."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pybullet
import pytest
from scipy.spatial.transform import Rotation

from branch_gym.sim.bullet import Bullet, BulletConfig
from branch_gym.sim.scene.background import BackgroundConfig, PlanarBackground
from branch_gym.sim.scene.camera import render_camera, render_snapshot
from branch_gym.sim.scene.camera_spec import CameraSpec, check_pose, look_at
from branch_gym.sim.scene.tree_scene import SceneConfig, TreeScene, scene_folder
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT

NO_BACKGROUND = SceneConfig(background=BackgroundConfig(enabled=False), collision=False)


@pytest.fixture(scope="module")
def bullet():
    world = Bullet()
    yield world
    world.close()


def _line(start, end, radius_m: float, spacing_m: float = 0.001) -> BranchGT:
    start, end = np.asarray(start, float), np.asarray(end, float)
    n = int(np.ceil(np.linalg.norm(end - start) / spacing_m)) + 1
    return BranchGT(np.linspace(start, end, n), np.full(n, radius_m))


def _scan_pose(height_m: float, yaw_deg: float = 0.0, distance_m: float = 0.2) -> np.ndarray:
    """Camera on a circle about the z axis, looking at (0, 0, height) from the -y side."""
    yaw = math.radians(yaw_deg)
    eye = [distance_m * math.sin(yaw), -distance_m * math.cos(yaw), height_m]
    return look_at(eye, [0.0, 0.0, height_m])


def _test_tree() -> TreeGT:
    """A bent primary, two secondaries, a background trunk and a trellis wire."""
    z = np.linspace(0.0, 1.0, 1001)
    primary = BranchGT(np.stack([0.02 * np.sin(3 * z), 0.01 * z, z], 1), np.full(1001, 0.005))
    base_a, base_b = primary.points[450], primary.points[560]
    return TreeGT(
        primary=primary,
        secondaries=[
            _line(base_a, np.add(base_a, [-0.09, -0.01, 0.05]), 0.0045),
            _line(base_b, np.add(base_b, [0.08, -0.03, 0.06]), 0.004),
        ],
        clutter=[
            _line([0.07, 0.5, 0.0], [0.09, 0.5, 1.0], 0.01),
            _line([-1, 0.4, 0.53], [1, 0.4, 0.53], 0.0015),
        ],
    )


def test_camera_spec_defaults_and_validation() -> None:
    spec = CameraSpec()
    assert (spec.width, spec.height, spec.cx, spec.cy) == (320, 240, 160.0, 120.0)
    assert spec.fx == pytest.approx(416.8, abs=0.05) and spec.fy == spec.fx
    assert CameraSpec.from_hfov(320, 240, 42.0) == spec
    with pytest.raises(ValueError, match="width"):
        CameraSpec(width=0)
    with pytest.raises(ValueError, match="fx"):
        CameraSpec(fx=-1.0)
    with pytest.raises(ValueError, match="near_m"):
        CameraSpec(near_m=2.0, far_m=1.0)
    with pytest.raises(ValueError, match="rotation"):
        check_pose(np.diag([1.0, 1.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="shape"):
        check_pose(np.eye(3))


def test_scaled_camera_keeps_the_image_edges() -> None:
    spec = CameraSpec(cx=161.3, cy=118.2)
    points = np.array([[0.01, -0.02, 0.3], [-0.05, 0.04, 0.5]])
    pixels, _ = spec.project(points, np.eye(4))
    for factor in (2.0, 0.5, 0.25):
        scaled = spec.scaled(factor)
        assert (scaled.width, scaled.height) == (320 * factor, 240 * factor)
        moved, _ = scaled.project(points, np.eye(4))
        # A pixel edge at u lies at factor * u: centres map as factor * (u + 1/2) - 1/2.
        np.testing.assert_allclose(moved, factor * (pixels + 0.5) - 0.5, atol=1e-9)
    assert spec.scaled(2.0).scaled(0.5) == spec
    assert CameraSpec(width=322, height=243).scaled(0.25).width == 80  # a partial bin dropped
    with pytest.raises(ValueError, match="factor"):
        spec.scaled(0.0)
    with pytest.raises(ValueError, match="empty"):
        spec.scaled(1e-3)


@pytest.mark.parametrize(
    "spec",
    [CameraSpec(), CameraSpec(width=200, height=160, fx=300.0, fy=280.0, cx=93.3, cy=88.7)],
)
def test_small_markers_land_on_their_pinhole_projection(bullet: Bullet, spec: CameraSpec) -> None:
    bullet.reset()
    T = look_at([0.03, -0.3, 0.52], [-0.01, 0.1, 0.47])
    roll = Rotation.from_euler("z", 17, degrees=True).as_matrix()
    T[:3, :3] = T[:3, :3] @ roll
    rng = np.random.default_rng(0)
    quaternion = Rotation.from_matrix(T[:3, :3]).as_quat()  # squares parallel to the image
    shape = bullet.p.createVisualShape(pybullet.GEOM_BOX, halfExtents=[0.004, 0.004, 1e-4])
    centres, bodies = [], []
    grid_u = np.linspace(20, spec.width - 20, 6)
    grid_v = np.linspace(20, spec.height - 20, 5)
    for pixel in np.stack(np.meshgrid(grid_u, grid_v), -1).reshape(-1, 2):
        pixel = pixel + rng.uniform(-3, 3, 2)  # sub-pixel positions all over the image
        depth = rng.uniform(0.25, 0.5)
        ray = np.linalg.inv(spec.K) @ [*pixel, 1.0]
        centre = T[:3, :3] @ (ray * depth) + T[:3, 3]
        centres.append(centre)
        bodies.append(bullet.p.createMultiBody(0, -1, shape, centre, quaternion))
    images = render_camera(bullet, T, spec, label_of={(b, -1): k + 1 for k, b in enumerate(bodies)})
    expected, _ = spec.project(np.array(centres), T)
    errors = []
    for k in range(len(bodies)):
        rows, cols = np.nonzero(images.labels == k + 1)
        assert len(rows) >= 9
        errors.append([cols.mean() - expected[k, 0], rows.mean() - expected[k, 1]])
    errors = np.array(errors)
    assert np.abs(errors).max() <= 0.5
    assert np.abs(errors.mean(axis=0)).max() < 0.1  # no systematic principal-point offset


@pytest.mark.parametrize(
    ("radius_m", "distance_m", "yaw_deg"), [(0.003, 0.2, 0), (0.0075, 0.18, 35)]
)
def test_depth_at_the_centre_is_axis_distance_minus_radius(
    bullet: Bullet, radius_m: float, distance_m: float, yaw_deg: float
) -> None:
    bullet.reset()
    tree = TreeGT(primary=_line([0, 0, 0], [0, 0, 1], radius_m))
    scene = TreeScene(bullet, tree, np.random.default_rng(0), NO_BACKGROUND)
    spec = CameraSpec()
    images = scene.render(_scan_pose(0.5, yaw_deg, distance_m), spec)
    centre = images.depth_m[int(spec.cy), int(spec.cx)]
    assert centre == pytest.approx(distance_m - radius_m, abs=5e-4)
    assert images.labels[int(spec.cy), int(spec.cx)] == 1
    assert np.isinf(images.depth_m[0, 0]) and images.labels[0, 0] == 0


def test_projected_centerlines_land_on_their_branch_labels(bullet: Bullet) -> None:
    bullet.reset()
    tree = _test_tree()
    scene = TreeScene(bullet, tree, np.random.default_rng(0))
    branches = [tree.primary, *tree.secondaries, *tree.clutter]
    labels = [1, 2, 3, 100, 101]
    assert sorted(scene.label_of.values()) == labels
    spec = CameraSpec()
    hits = {label: [0, 0] for label in labels}
    for height, yaw in [(0.47, 0.0), (0.52, -30.0), (0.56, 40.0)]:
        T = _scan_pose(height, yaw)
        images = scene.render(T, spec)
        for branch, label in zip(branches, labels, strict=True):
            pixels, depth = spec.project(branch.points, T)
            inside = np.all((pixels >= 10) & (pixels <= [spec.width - 11, spec.height - 11]), 1)
            # Skip the part of a secondary buried in the primary.
            buried = (
                np.min(
                    np.linalg.norm(branch.points[:, None] - tree.primary.points[None, ::5], axis=2),
                    1,
                )
                < 0.008
            )
            keep = inside & ~buried if label != 1 else inside
            u, v = np.round(pixels[keep]).astype(int).T
            visible = images.depth_m[v, u] > depth[keep] - branch.radii[keep] - 0.002
            hits[label][0] += int(np.sum(images.labels[v, u][visible] == label))
            hits[label][1] += int(np.sum(visible))
    for label, (good, total) in hits.items():
        assert total >= 20, f"label {label} barely visible"
        assert good / total >= 0.9, f"label {label}: {good}/{total}"


def test_same_tree_and_seed_give_identical_images(bullet: Bullet) -> None:
    tree, T = _test_tree(), _scan_pose(0.5, 20.0)
    frames = []
    for seed in (5, 5, 6):
        bullet.reset()
        frames.append(TreeScene(bullet, tree, np.random.default_rng(seed)).render(T))
    first, again, other = frames
    for name in ("rgb", "depth_m", "labels"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    assert not np.array_equal(first.rgb, other.rgb)  # other textures
    np.testing.assert_array_equal(first.labels, other.labels)


def test_rebuilds_show_the_new_tree_not_a_cached_one(bullet: Bullet) -> None:
    """Scene files reuse fixed paths: pybullet must not serve the previous mesh or texture."""
    spec, T = CameraSpec(), _scan_pose(0.5)
    columns, bark = [], []
    for x, seed in ((-0.03, 0), (0.03, 0), (0.03, 1), (0.03, 0)):
        bullet.reset()
        tree = TreeGT(primary=_line([x, 0, 0], [x, 0, 1], 0.005))
        images = TreeScene(bullet, tree, np.random.default_rng(seed), NO_BACKGROUND).render(T, spec)
        columns.append(np.nonzero(images.labels[int(spec.cy)] == 1)[0].mean())
        bark.append(images.rgb[images.labels == 1])
    expected = spec.project(np.array([[-0.03, 0, 0.5], [0.03, 0, 0.5]]), T)[0][:, 0]
    np.testing.assert_allclose(columns[:2], expected, atol=1.0)
    np.testing.assert_array_equal(bark[1], bark[3])
    assert not np.array_equal(bark[1], bark[2])  # the new seed's bark, not the cached one


def test_background_fills_empty_pixels_with_the_planes_depth(bullet: Bullet) -> None:
    bullet.reset()
    config = BackgroundConfig()
    scene = TreeScene(
        bullet, TreeGT(primary=_line([0, 0, 0], [0, 0, 1], 0.005)), np.random.default_rng(1)
    )
    spec = CameraSpec()
    camera_z = 0.3
    images = scene.render(look_at([0, -0.2, camera_z], [0, 1, camera_z]), spec)
    background = images.labels == 0
    assert background.mean() > 0.8 and np.all(np.isfinite(images.depth_m))
    rows, cols = np.nonzero(background)
    wall_depth = config.backdrop_y_m + 0.2
    ground_depth = camera_z * spec.fy / np.maximum(rows - spec.cy, 1e-9)
    expected = np.where((rows > spec.cy) & (ground_depth < wall_depth), ground_depth, wall_depth)
    np.testing.assert_allclose(images.depth_m[rows, cols], expected, rtol=1e-4)
    assert np.any(expected < wall_depth) and np.any(expected == wall_depth)  # both planes seen
    # Colours come from the textures: not the renderer's white, not a flat fill.
    assert images.rgb[background].std(axis=0).min() > 10
    # Nothing within the far plane: sky colour and infinite depth.
    far = CameraSpec(far_m=1.0)
    images = scene.render(look_at([0, -0.2, 0.8], [0, 1, 0.8]), far)
    sky = images.labels == 0
    assert np.all(np.isinf(images.depth_m[sky]))
    assert np.all(images.rgb[sky] == config.sky_rgb)


def test_planes_seen_from_behind_are_not_drawn() -> None:
    painter = PlanarBackground(BackgroundConfig(ground=False), np.random.default_rng(0))
    spec = CameraSpec()
    rgb = np.zeros((spec.height, spec.width, 3), np.uint8)
    depth = np.full((spec.height, spec.width), np.inf, np.float32)
    painter.paint(rgb, depth, np.ones_like(depth, bool), look_at([0, 3, 0.5], [0, 9, 0.5]), spec)
    assert np.all(np.isinf(depth))


def test_without_background_empty_pixels_stay_blank(bullet: Bullet) -> None:
    bullet.reset()
    scene = TreeScene(
        bullet,
        TreeGT(primary=_line([0, 0, 0], [0, 0, 1], 0.005)),
        np.random.default_rng(1),
        NO_BACKGROUND,
    )
    images = scene.render(_scan_pose(0.5))
    empty = np.isinf(images.depth_m)
    assert empty.mean() > 0.8 and np.all(images.labels[empty] == 0)
    assert len(np.unique(images.rgb[empty], axis=0)) == 1  # the renderer's clear colour


def test_unknown_bodies_read_background(bullet: Bullet) -> None:
    bullet.reset()
    scene = TreeScene(
        bullet,
        TreeGT(primary=_line([0, 0, 0], [0, 0, 1], 0.005)),
        np.random.default_rng(1),
        NO_BACKGROUND,
    )
    box = bullet.p.createVisualShape(pybullet.GEOM_BOX, halfExtents=[0.02, 0.001, 0.02])
    bullet.p.createMultiBody(0, -1, box, [0.05, -0.05, 0.5])
    images = scene.render(_scan_pose(0.5))
    assert set(np.unique(images.labels)) == {0, 1}
    covered = np.isfinite(images.depth_m) & (images.labels == 0)
    assert covered.sum() > 100  # the box is drawn, and labelled background
    assert np.all(render_camera(bullet, _scan_pose(0.5)).labels == 0)


def test_tree_bodies_collide_per_branch(bullet: Bullet) -> None:
    bullet.reset()
    tree = _test_tree()
    scene = TreeScene(bullet, tree, np.random.default_rng(0), SceneConfig())
    (tree_id,) = scene.tree_body_ids
    sphere = bullet.p.createCollisionShape(pybullet.GEOM_SPHERE, radius=0.01)
    probe_point = tree.primary.points[300] + [0.0, -0.03, 0.0]
    probe = bullet.p.createMultiBody(0, sphere, -1, probe_point)
    closest = bullet.p.getClosestPoints(probe, tree_id, 0.1)
    distance = min(c[8] for c in closest)
    assert distance == pytest.approx(0.03 - 0.01 - 0.005, abs=5e-4)
    tip = tree.secondaries[1].points[-20]
    bullet.p.resetBasePositionAndOrientation(probe, tip, [0, 0, 0, 1])
    links = {c[4] for c in bullet.p.getClosestPoints(probe, tree_id, 0.0)}
    assert scene.label_of[(tree_id, links.pop())] == 3


def test_snapshot_shows_the_scene(bullet: Bullet) -> None:
    bullet.reset()
    scene = TreeScene(bullet, _test_tree(), np.random.default_rng(0))
    image = render_snapshot(bullet, 160, 120, background=scene.background)
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8
    bullet.reset()
    assert not np.array_equal(image, render_snapshot(bullet, 160, 120, background=scene.background))


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


@pytest.mark.slow
def test_rebuilding_200_scenes_does_not_leak(bullet: Bullet) -> None:
    tree = _test_tree()
    for seed in range(20):  # warm up allocator pools and caches
        bullet.reset()
        TreeScene(bullet, tree, np.random.default_rng(seed)).render(_scan_pose(0.5))
    before = _rss_mb()
    for seed in range(200):
        bullet.reset()
        TreeScene(bullet, tree, np.random.default_rng(seed)).render(_scan_pose(0.5))
    growth_mb = _rss_mb() - before
    assert growth_mb < 20.0, f"RSS grew {growth_mb:.1f} MB over 200 rebuilds"
    assert not scene_folder().exists()  # no temporary files left behind


@pytest.mark.slow
def test_egl_renderer_matches_the_pinhole_model() -> None:
    try:
        world = Bullet(BulletConfig(use_egl=True))
    except RuntimeError as error:
        pytest.skip(f"EGL unavailable: {error}")
    try:
        test_small_markers_land_on_their_pinhole_projection(world, CameraSpec())
        test_depth_at_the_centre_is_axis_distance_minus_radius(world, 0.005, 0.2, 10.0)
    finally:
        world.close()
