"""Tube meshes (winding, closure, resampling, texture coordinates, OBJ) and procedural textures."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from branch_gym.sim.scene.texture import (
    BARK,
    FOLIAGE,
    TextureConfig,
    band_limited_noise,
    make_texture,
    write_png,
)
from branch_gym.sim.scene.tree_mesh import TubeMesh, TubeMeshConfig, tube_mesh, write_obj


def _curved_branch(n: int = 301) -> tuple[np.ndarray, np.ndarray]:
    """A 0.3 m branch bending in two planes, 1 mm spacing, radius tapering 6 -> 4 mm."""
    s = np.linspace(0.0, 1.0, n)
    points = np.stack([0.05 * np.sin(2.0 * s), 0.03 * s**2, 0.3 * s], axis=1)
    return points, 0.006 - 0.002 * s


def _welded_faces(mesh: TubeMesh) -> np.ndarray:
    """Faces re-indexed so that vertices at the same position (texture seam) share one index."""
    _, index = np.unique(np.round(mesh.vertices, 9), axis=0, return_inverse=True)
    return index.ravel()[mesh.faces]


def _face_normals(mesh: TubeMesh) -> np.ndarray:
    a, b, c = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


def test_mesh_is_closed_and_consistently_oriented() -> None:
    mesh = tube_mesh(*_curved_branch())
    faces = _welded_faces(mesh)
    directed = Counter()
    for face in faces:
        for k in range(3):
            directed[(int(face[k]), int(face[(k + 1) % 3]))] += 1
    assert all(count == 1 for count in directed.values()), "an edge is used twice the same way"
    assert all((b, a) in directed for a, b in directed), "an edge has no opposite: mesh not closed"


def test_all_faces_point_outwards() -> None:
    points, radii = _curved_branch()
    mesh = tube_mesh(points, radii)
    v0, v1, v2 = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    signed_volume = np.einsum("ij,ij->i", v0, np.cross(v1, v2)).sum() / 6.0
    length = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
    expected = math.pi * np.mean(radii**2) * length
    assert signed_volume == pytest.approx(expected, rel=0.03)  # positive: wound outwards
    # Each wall face points away from the nearest centerline point; each cap away from the tube.
    normals = _face_normals(mesh)
    centroids = (v0 + v1 + v2) / 3.0
    nearest = np.argmin(np.linalg.norm(centroids[:, None] - points[None], axis=2), axis=1)
    outward = centroids - points[nearest]
    base, tip = nearest == 0, nearest == len(points) - 1
    outward[base] = points[0] - points[1]
    outward[tip] = points[-1] - points[-2]
    assert np.all(np.einsum("ij,ij->i", normals, outward) > 0)
    # The shading normals agree with the winding.
    vertex_normals = mesh.normals[mesh.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", normals, vertex_normals) > 0)


def test_wall_follows_the_dense_centerline_within_the_chord_error() -> None:
    points, radii = _curved_branch()
    config = TubeMeshConfig()
    mesh = tube_mesh(points, radii, config)
    distances = np.linalg.norm(mesh.vertices[:, None] - points[None], axis=2)
    nearest = np.argmin(distances, axis=1)
    distance = distances[np.arange(len(mesh.vertices)), nearest]
    surface = distance > 0.5 * radii[nearest]  # all but the two cap centres
    assert surface.sum() == len(mesh.vertices) - 2
    error = np.abs(distance - radii[nearest])[surface]
    assert error.max() < config.max_chord_error_m + 2e-5


def test_rings_are_few_on_straight_stretches_and_more_where_it_bends() -> None:
    z = np.linspace(0.0, 1.0, 1001)
    straight = tube_mesh(np.stack([0 * z, 0 * z, z], 1), np.full_like(z, 0.005))
    bent = tube_mesh(np.stack([0.1 * np.sin(6 * z), 0 * z, z], 1), np.full_like(z, 0.005))
    config = TubeMeshConfig()
    straight_rings = 1.0 / config.max_ring_spacing_m + 1
    sides = config.sides
    assert straight.n_triangles == 2 * sides * (straight_rings - 1) + 2 * sides
    assert bent.n_triangles > 2 * straight.n_triangles


def test_texture_coordinates_wrap_whole_turns_and_run_continuously_along() -> None:
    points, radii = _curved_branch()
    config = TubeMeshConfig()
    mesh = tube_mesh(points, radii, config)
    wall = np.abs(mesh.normals @ np.array([0.0, 0.0, 1.0])) < 0.9
    u, v = mesh.uvs[wall, 0], mesh.uvs[wall, 1]
    wraps = max(1, round(2 * math.pi * np.mean(radii) / config.tile_width_m))
    assert u.min() == 0.0 and u.max() == pytest.approx(wraps)
    length = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
    circumference = 2 * math.pi * np.mean(radii)  # mean over arc length = mean over 1 mm samples
    assert v.max() == pytest.approx(length * wraps / circumference, rel=0.01)
    rings = v.reshape(-1, config.sides + 1)[:, 0]
    assert np.all(np.diff(rings) > 0)


def test_thick_branches_wrap_the_texture_several_times() -> None:
    z = np.linspace(0.0, 0.2, 201)
    mesh = tube_mesh(np.stack([0 * z, 0 * z, z], 1), np.full_like(z, 0.02))
    tile_m = TubeMeshConfig().tile_width_m
    assert mesh.uvs[:, 0].max() == pytest.approx(round(2 * math.pi * 0.02 / tile_m))


def test_duplicate_points_and_sparse_input_are_handled() -> None:
    points = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0.5], [0, 0.1, 1.0]], dtype=float)
    mesh = tube_mesh(points, np.full(4, 0.004))
    assert np.all(np.isfinite(mesh.vertices)) and mesh.n_triangles > 0


@pytest.mark.parametrize(
    ("points", "radii", "problem"),
    [
        (np.zeros((5, 2)), np.ones(5), "points"),
        (np.zeros((1, 3)), np.ones(1), "points"),
        (np.random.default_rng(0).random((5, 3)), np.ones(4), "radii"),
        (np.random.default_rng(0).random((5, 3)), -np.ones(5), "positive"),
        (np.full((5, 3), np.nan), np.ones(5), "finite"),
        (np.zeros((5, 3)), np.ones(5), "zero length"),
    ],
)
def test_bad_polylines_raise(points: np.ndarray, radii: np.ndarray, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        tube_mesh(points, radii)


def test_bad_config_raises() -> None:
    with pytest.raises(ValueError, match="sides"):
        TubeMeshConfig(sides=2)
    with pytest.raises(ValueError, match="max_chord_error_m"):
        TubeMeshConfig(max_chord_error_m=0.0)


def test_obj_round_trip(tmp_path) -> None:
    mesh = tube_mesh(*_curved_branch())
    png = write_png(np.zeros((8, 8, 3), np.uint8), tmp_path / "bark.png")
    path = write_obj(mesh, tmp_path / "tree.obj", png)
    lines = path.read_text().splitlines()
    tags = Counter(line.split()[0] for line in lines)
    assert tags["v"] == tags["vt"] == tags["vn"] == len(mesh.vertices)
    assert tags["f"] == mesh.n_triangles
    assert "map_Kd bark.png" in (tmp_path / "tree.mtl").read_text()
    vertices = np.array([line.split()[1:] for line in lines if line.startswith("v ")], float)
    np.testing.assert_allclose(vertices, mesh.vertices, atol=1e-6)
    faces = [line.split()[1:] for line in lines if line.startswith("f ")]
    parsed = np.array([[int(corner.split("/")[0]) - 1 for corner in face] for face in faces])
    np.testing.assert_array_equal(parsed, mesh.faces)


# --- textures ---------------------------------------------------------------------------------


def test_bark_texture_is_seeded_contrasty_and_stretched_along_rows() -> None:
    image = make_texture(np.random.default_rng(7), BARK)
    assert image.shape == (BARK.size_px, BARK.size_px, 3) and image.dtype == np.uint8
    np.testing.assert_array_equal(image, make_texture(np.random.default_rng(7), BARK))
    assert not np.array_equal(image, make_texture(np.random.default_rng(8), BARK))
    grey = image.astype(float).mean(axis=2)
    assert grey.std() > 25  # features a point tracker can lock onto
    along = np.mean(np.diff(grey, axis=0) ** 2)  # rows run along the branch
    across = np.mean(np.diff(grey, axis=1) ** 2)
    assert across > 4 * along


def test_noise_features_fall_in_the_configured_band() -> None:
    noise = band_limited_noise(np.random.default_rng(1), FOLIAGE)
    power = np.abs(np.fft.fft2(noise)) ** 2
    frequency = np.hypot(*np.meshgrid(*2 * [np.fft.fftfreq(FOLIAGE.size_px)], indexing="ij"))
    wavelength_m = FOLIAGE.texel_m / np.maximum(frequency, 1e-12)
    # Pass band 2 * feature size, plus the half-octave soft edges.
    band = (wavelength_m >= 2 * FOLIAGE.feature_min_m / 2**0.5) & (
        wavelength_m <= 2 * FOLIAGE.feature_max_m * 2**0.5
    )
    assert power[band].sum() / power.sum() > 0.999
    assert noise.mean() == pytest.approx(0.0, abs=1e-9) and noise.std() == pytest.approx(1.0)


def test_textures_tile_seamlessly() -> None:
    grey = make_texture(np.random.default_rng(3), BARK).astype(float).mean(axis=2)
    inner = np.abs(np.diff(grey, axis=1)).mean()
    seam = np.abs(grey[:, 0] - grey[:, -1]).mean()
    assert seam < 1.5 * inner


def test_bad_texture_config_raises() -> None:
    with pytest.raises(ValueError, match="feature_max_m"):
        TextureConfig(64, 0.001, 0.01, 0.005, 1.0, BARK.palette)
    with pytest.raises(ValueError, match="two texels"):
        TextureConfig(64, 0.001, 0.0015, 0.005, 1.0, BARK.palette)
    with pytest.raises(ValueError, match="palette"):
        TextureConfig(64, 0.001, 0.005, 0.01, 1.0, ((0.2, (0, 0, 0)), (1.0, (9, 9, 9))))
    with pytest.raises(ValueError, match="uint8"):
        write_png(np.zeros((4, 4, 3)), "unused.png")
