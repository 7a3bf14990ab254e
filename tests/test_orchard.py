"""The orchard world: determinism, labels against geometry, ground-truth flow, config checks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from branch_gym.scan import ScanConfig
from branch_gym.sim.scene.camera_spec import CameraSpec, look_at
from branch_gym.sim.scene.flow import ground_truth_flow
from branch_gym.sim.scene.labels import (
    GROUND_LABEL,
    PRIMARY_LABEL,
    SKY_LABEL,
    WIRE_LABEL,
    is_scanned_tree,
)
from branch_gym.sim.scene.orchard_background import srgb_to_linear
from branch_gym.sim.scene.orchard_row import OrchardRowConfig
from branch_gym.sim.scene.orchard_scene import OrchardConfig
from branch_gym.sim.segmentation import NoisySegmenter, NoisySegmenterConfig
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.world import World, WorldConfig


@pytest.fixture(scope="module")
def orchard_world() -> World:
    world = World(WorldConfig.preset("orchard"))
    world.reset(3)
    yield world
    world.close()


def test_same_seed_gives_the_same_frames() -> None:
    frames = []
    for _ in range(2):
        world = World(WorldConfig.preset("orchard", TreeConfig.tall_spindle()))
        world.reset(7)
        world.apply_camera_twist(np.array([0.0, -0.025, 0.0, 0.0, 0.0, 0.0]), 1 / 60)
        frames.append([world.render() for _ in range(2)])
        world.close()
    for a, b in zip(frames[0], frames[1], strict=True):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.labels, b.labels)
        np.testing.assert_array_equal(a.depth_m, b.depth_m)
    other = World(WorldConfig.preset("orchard"))
    other.reset(8)
    assert not np.array_equal(other.render().rgb, frames[0][0].rgb)


def test_frame_shows_tree_sky_ground_and_row(orchard_world: World) -> None:
    images = orchard_world.render()
    labels = set(np.unique(images.labels).tolist())
    assert {PRIMARY_LABEL, SKY_LABEL, GROUND_LABEL} <= labels
    assert any(label >= 300 for label in labels)  # trees of the row
    assert np.all(np.isinf(images.depth_m[images.labels == SKY_LABEL]))
    assert np.all(np.isfinite(images.depth_m[images.labels != SKY_LABEL]))
    # The scanned primary is the nearest thing in the middle of the frame, at ~z_target.
    primary_depth = images.depth_m[images.labels == PRIMARY_LABEL]
    assert 0.15 < float(np.median(primary_depth)) < 0.25


@pytest.mark.parametrize(
    ("left_out", "gone"), [(("wires",), {WIRE_LABEL}), (("crossing", "neighbours"), {300})]
)
def test_a_part_left_out_leaves_the_rest_of_the_scene_as_it_was(left_out, gone) -> None:
    """An ablation's scene is the full orchard's, one part apart: every pixel the full scene
    shows as something else keeps its label and depth (the sky, posts, rows behind and camera
    draws come after the row's)."""
    images = []
    for parts in ((), left_out):
        config = WorldConfig.preset("orchard")
        row = dataclasses.replace(config.orchard.row, left_out=parts)
        orchard = dataclasses.replace(config.orchard, row=row)
        world = World(dataclasses.replace(config, orchard=orchard))
        world.reset(1)
        primary = world.primary_point_at_height(0.55, world.tree)  # a wire and neighbours in view
        T = look_at(primary + np.array([0.0, -0.3, 0.0]), primary)
        images.append(world.scene.render(T, world.config.camera))
        world.close()
    full, ablated = images
    shown = np.isin(full.labels, list(gone))
    assert shown.any() and not np.isin(ablated.labels, list(gone)).any()
    np.testing.assert_array_equal(full.labels[~shown], ablated.labels[~shown])
    np.testing.assert_array_equal(full.depth_m[~shown], ablated.depth_m[~shown])
    with pytest.raises(ValueError, match="left_out"):
        OrchardRowConfig(left_out=("posts",))


def test_wire_pixels_lie_on_the_wire_projection(orchard_world: World) -> None:
    wire = orchard_world.scene.row.wires[0]
    centre = wire.points[np.argmin(np.abs(wire.points[:, 0]))]
    eye = centre + np.array([0.3, -0.5, 0.0])
    spec = CameraSpec()
    T = look_at(eye, centre)
    images = orchard_world.scene.render(T, spec)
    v_px, u_px = np.nonzero(images.labels == WIRE_LABEL)
    assert len(u_px) > 50, "the wire must be in view"
    # Dense projection of every wire and clip; each wire pixel within the drawn half-width.
    row = orchard_world.scene.row
    uv, half_width = [], []
    for branch in [*row.wires, *row.clips]:
        dense = np.concatenate(
            [np.linspace(a, b, 200) for a, b in zip(branch.points[:-1], branch.points[1:],
                                                     strict=True)]
        )  # fmt: skip
        camera = (np.linalg.inv(T) @ np.c_[dense, np.ones(len(dense))].T).T[:, :3]
        ahead = camera[:, 2] > 0.05
        uv.append(camera[ahead, :2] / camera[ahead, 2:] * [spec.fx, spec.fy] + [spec.cx, spec.cy])
        half_width.append(spec.fx * branch.radii[0] / camera[ahead, 2])
    uv, half_width = np.concatenate(uv), np.concatenate(half_width)
    distance = np.hypot(u_px[:, None] - uv[:, 0], v_px[:, None] - uv[:, 1]) - half_width
    assert np.all(distance.min(axis=1) <= 1.0)  # within a pixel of the wire's silhouette


def _ray_cylinder_depth(ray: np.ndarray, eye: np.ndarray, a: np.ndarray, b: np.ndarray,
                        radius: float) -> float:  # fmt: skip
    """Distance along a unit world ray to the cylinder of axis a-b and ``radius`` (front hit)."""
    axis = (b - a) / np.linalg.norm(b - a)
    d = ray - (ray @ axis) * axis
    m = (eye - a) - ((eye - a) @ axis) * axis
    qa, qb, qc = d @ d, 2 * d @ m, m @ m - radius**2
    return (-qb - math.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)


def test_ground_truth_flow_moves_known_points_to_their_projections(orchard_world: World) -> None:
    spec = CameraSpec()
    tree = orchard_world.tree
    T1 = orchard_world.T_world_camera
    T2 = T1.copy()
    T2[:3, 3] += [0.002, 0.0, 0.0075]  # 7.5 mm up (the paper's pairing), 2 mm sideways
    angle = math.radians(0.4)
    rotation = np.array(
        [[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]]
    )
    T2[:3, :3] = rotation @ T1[:3, :3]
    images = orchard_world.scene.render(T1, spec)
    flow = ground_truth_flow(images.depth_m, T1, T2, spec)
    checked = 0
    for v in range(100, 141, 10):
        row = np.flatnonzero(images.labels[v] == PRIMARY_LABEL)
        for u in row[len(row) // 4 : 3 * len(row) // 4 : 3]:
            # The point of the primary's analytic surface (not the rendered depth) this pixel sees.
            ray = T1[:3, :3] @ np.array([(u - spec.cx) / spec.fx, (v - spec.cy) / spec.fy, 1.0])
            ray /= np.linalg.norm(ray)
            eye = T1[:3, 3]
            nearest = np.argmin(np.linalg.norm(np.cross(tree.primary.points - eye, ray), axis=1))
            a, b = tree.primary.points[max(nearest - 3, 0)], tree.primary.points[nearest + 3]
            point = eye + _ray_cylinder_depth(ray, eye, a, b, tree.primary.radii[nearest]) * ray
            p2 = np.linalg.inv(T2) @ np.append(point, 1.0)
            u2 = spec.fx * p2[0] / p2[2] + spec.cx
            v2 = spec.fy * p2[1] / p2[2] + spec.cy
            assert abs(u + flow[v, u, 0] - u2) < 0.5 and abs(v + flow[v, u, 1] - v2) < 0.5
            checked += 1
    assert checked > 20
    # The sky moves by the rotation alone: the same flow for any depth there.
    sky = images.labels == SKY_LABEL
    assert np.all(np.isfinite(flow[sky]))


def test_ground_truth_flow_rejects_a_depth_of_another_size() -> None:
    with pytest.raises(ValueError, match="depth_m must have shape"):
        ground_truth_flow(np.ones((10, 10)), np.eye(4), np.eye(4), CameraSpec())


def test_noisy_segmenter_never_leaks_sky_or_ground(orchard_world: World) -> None:
    images = orchard_world.render()
    config = NoisySegmenterConfig(
        boundary_jitter_px=0, thin_drop_prob=0, blob_rate=0, chunk_rate=0, clutter_leak_prob=1.0
    )
    mask = NoisySegmenter(config).segment(images.rgb, images.labels, np.random.default_rng(0))
    assert not mask[images.labels == SKY_LABEL].any()
    assert not mask[images.labels == GROUND_LABEL].any()
    assert mask[is_scanned_tree(images.labels)].all()


def test_world_names_reach_the_scan_and_env_configs() -> None:
    assert ScanConfig(world="orchard").world.name == "orchard"
    assert ScanConfig().world.name == "clean" and ScanConfig().world.orchard is None
    with pytest.raises(ValueError, match="unknown world 'forest'"):
        ScanConfig(world="forest")
    from branch_gym.env.config import env_config_from_kwargs

    config = env_config_from_kwargs({"world": "orchard", "tree": "ufo"})
    assert config.scan.world.orchard is not None
    assert config.scan.world.tree.architecture == "ufo"
    with pytest.raises(ValueError, match="world must be one of"):
        env_config_from_kwargs({"world": 3})


def test_fast_orchard_is_the_same_scene_with_a_coarser_background_and_no_jpeg() -> None:
    config = WorldConfig.preset("orchard_fast").orchard
    assert config.background_scale == 4 and not config.camera.jpeg
    assert OrchardConfig().background_scale == 2 and OrchardConfig().camera.jpeg  # the default
    frames = {}
    for name in ("orchard", "orchard_fast"):
        world = World(WorldConfig.preset(name))
        world.reset(5)
        frames[name] = world.render()
        world.close()
    default, fast = frames["orchard"], frames["orchard_fast"]
    # The same draws: the scanned tree's pixels, labels and depth are the default world's.
    tree = is_scanned_tree(default.labels)
    assert tree.sum() > 1000
    np.testing.assert_array_equal(is_scanned_tree(fast.labels), tree)
    np.testing.assert_array_equal(fast.depth_m[tree], default.depth_m[tree])
    # Its colours differ by the background's share of the exposure and by JPEG only.
    difference = np.abs(fast.rgb.astype(float) - default.rgb.astype(float))
    assert 0.0 < difference[tree].mean() < 12.0
    assert (fast.labels == default.labels).mean() > 0.8  # the background's outlines are coarser


def test_trellis_reach_cuts_the_wires_mesh_and_keeps_their_geometry() -> None:
    spans = {}
    for reach in (None, 1.5):
        world = World(WorldConfig(orchard=OrchardConfig(trellis_reach_m=reach)))
        world.reset(2)
        wires = world.scene.row.wires
        meshed = [world.scene._within_reach(wire) for wire in wires]  # what _add_trellis meshes
        spans[reach] = (
            [float(np.ptp(part.points[:, 0])) for part in meshed],
            [float(np.ptp(wire.points[:, 0])) for wire in wires],
        )
        world.close()
    (whole, row_whole), (cut, row_cut) = spans[None], spans[1.5]
    assert min(whole) > 20.0  # the wires run the row's length
    assert max(cut) <= 2 * (1.5 + 0.5) + 1e-9  # within the reach, plus a 0.5 m step each side
    assert row_cut == row_whole  # the row's geometry (its ground truth) keeps every wire whole


def _bad_value(value: object) -> object:
    if isinstance(value, tuple) and len(value) != 2:
        return ("trees",)
    if isinstance(value, tuple):
        return (value[1] + 1.0, value[0]) if value[1] + 1.0 > value[0] else (-1.0, -2.0)
    return -1


@pytest.mark.parametrize("name", [f.name for f in dataclasses.fields(OrchardRowConfig)])
def test_every_row_config_field_rejects_a_bad_value(name: str) -> None:
    bad = _bad_value(getattr(OrchardRowConfig(), name))
    with pytest.raises(ValueError, match=f"OrchardRowConfig.{name}"):
        OrchardRowConfig(**{name: bad})


@pytest.mark.parametrize("name", [f.name for f in dataclasses.fields(OrchardConfig)])
def test_every_orchard_config_field_rejects_a_bad_value(name: str) -> None:
    with pytest.raises(ValueError, match=f"OrchardConfig.{name}"):
        OrchardConfig(**{name: "nonsense"})


def test_world_config_rejects_a_bad_orchard() -> None:
    with pytest.raises(ValueError, match=r"WorldConfig\.orchard"):
        WorldConfig(orchard="yes")


def test_srgb_to_linear_follows_the_srgb_curve_and_refuses_other_dtypes() -> None:
    """sRGB 8-bit -> linear: black 0, white 1, the curve's mid point, and the same values for
    a colour image (table lookup by OpenCV) as for any other shape."""
    image = np.arange(256, dtype=np.uint8).reshape(16, 16)
    colour = np.stack([image, image[::-1], image.T], axis=2)
    linear = srgb_to_linear(colour)
    assert linear.dtype == np.float32 and linear.shape == colour.shape
    assert linear[0, 0, 0] == 0.0 and linear[-1, -1, 0] == 1.0
    assert linear[7, 15, 0] == pytest.approx(((127 / 255 + 0.055) / 1.055) ** 2.4, rel=1e-6)
    np.testing.assert_array_equal(linear[..., 1], srgb_to_linear(image[::-1]))
    with pytest.raises(ValueError, match="uint8"):
        srgb_to_linear(colour.astype(np.float32))
