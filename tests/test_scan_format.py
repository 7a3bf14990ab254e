"""The scan folder format (recon.io): round trips, undistortion, tube meshes and every bad input."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from recon.camera import CameraIntrinsics, make_pose
from recon.io.atomic import OutputExistsError, atomic_output_dir
from recon.io.distortion import CameraModel, Undistorter, distort_image
from recon.io.folder import ScanFolder, ScanFormatError, ScanWriter, as_rigid_pose
from recon.io.mesh import read_ply_counts, tree_mesh, tube_mesh, write_ply
from recon.io.source import open_source
from recon.model import BranchModel, TreeModel

INTRINSICS = CameraIntrinsics.from_fov(64, 48, 42.0)
R_FORWARD_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _frames(n: int = 5, seed: int = 0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        mask = np.zeros((48, 64), bool)
        mask[:, 28 + i : 36 + i] = True
        T = make_pose(R_FORWARD_Y, [0.0, -0.2, 0.3 + 0.001 * i])
        out.append((0.1 * i, T, rgb, mask))
    return out


def _write(path: Path, frames=None, camera: CameraModel | None = None, **kwargs) -> Path:
    with ScanWriter(path, camera or CameraModel(INTRINSICS), **kwargs) as writer:
        for t, T, rgb, mask in frames or _frames():
            writer.add(t, T, rgb, mask)
    return path


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in (path / "frames.jsonl").read_text().splitlines()]


def _set_lines(path: Path, lines: list[dict]) -> None:
    (path / "frames.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))


# ---------------------------------------------------------------------- round trips
def test_png_round_trip_is_exact(tmp_path):
    frames = _frames()
    scan = ScanFolder(_write(tmp_path / "scan", frames))
    assert len(scan) == len(frames) and scan.has_masks
    assert scan.intrinsics == INTRINSICS
    for loaded, (t, T, rgb, mask) in zip(scan.frames(), frames, strict=True):
        assert loaded.time_s == t
        np.testing.assert_array_equal(loaded.T_world_camera, T)
        np.testing.assert_array_equal(loaded.rgb, rgb)
        np.testing.assert_array_equal(loaded.mask, mask)
        frame = loaded.to_frame(scan.intrinsics)
        assert frame.has_image and frame.timestamp_s == t


def test_jpeg_round_trip_is_close(tmp_path):
    frames = [(t, T, cv2.GaussianBlur(rgb, (7, 7), 2), m) for t, T, rgb, m in _frames()]
    scan = ScanFolder(_write(tmp_path / "scan", frames, image_format="jpg", jpeg_quality=95))
    assert all(r.image.endswith(".jpg") for r in scan.records)
    for loaded, (_, _, rgb, mask) in zip(scan.frames(), frames, strict=True):
        assert np.abs(loaded.rgb.astype(int) - rgb).mean() < 3
        np.testing.assert_array_equal(loaded.mask, mask)  # masks are always PNG


def test_pose_only_frames_and_frames_without_masks(tmp_path):
    (t0, T0, rgb0, _), (t1, T1, _, _) = _frames(2)
    with ScanWriter(tmp_path / "scan", CameraModel(INTRINSICS)) as writer:
        writer.add(t0, T0, rgb0)  # no mask
        writer.add(t1, T1)  # pose only
    scan = open_source(tmp_path / "scan")
    assert not scan.has_masks and scan.frames_without_mask == [0]
    first, second = scan.frames()
    assert first.mask is None and not first.pose_only
    assert second.pose_only
    assert not second.to_frame(scan.intrinsics).has_image
    with pytest.raises(ValueError, match="no mask"):
        first.to_frame(scan.intrinsics)


def test_six_decimal_poses_are_reorthonormalised():
    angle = 0.3
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    T = np.round(make_pose(R, [0.1, 0.2, 0.3]), 6)
    fixed = as_rigid_pose(T)
    np.testing.assert_allclose(fixed[:3, :3] @ fixed[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(fixed, T, atol=1e-6)


# ---------------------------------------------------------------------- no half-written output
def test_writer_leaves_nothing_on_error(tmp_path):
    out = tmp_path / "scan"
    frames = _frames()
    with pytest.raises(RuntimeError, match="boom"), ScanWriter(out, CameraModel(INTRINSICS)) as w:
        w.add(*frames[0])
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_writer_rejects_bad_frames_and_existing_output(tmp_path):
    frames = _frames()
    _write(tmp_path / "scan", frames)
    with pytest.raises(OutputExistsError, match="exists"):
        ScanWriter(tmp_path / "scan", CameraModel(INTRINSICS))
    with ScanWriter(tmp_path / "b", CameraModel(INTRINSICS)) as w:
        w.add(*frames[1])
        with pytest.raises(ValueError, match="not after"):
            w.add(*frames[0])
        with pytest.raises(ValueError, match="rigid"):
            w.add(5.0, np.diag([2.0, 1.0, 1.0, 1.0]), frames[0][2], frames[0][3])
        with pytest.raises(ValueError, match="rgb must be"):
            w.add(6.0, frames[0][1], np.zeros((10, 10, 3), np.uint8))
    assert len(ScanFolder(tmp_path / "b")) == 1  # the bad frames wrote nothing


def test_overwrite_replaces_only_when_complete(tmp_path):
    out = _write(tmp_path / "scan", _frames(3))
    with pytest.raises(RuntimeError), atomic_output_dir(out, overwrite=True) as tmp:
        (tmp / "x").write_text("partial")
        raise RuntimeError
    assert len(ScanFolder(out)) == 3
    _write(out, _frames(4), overwrite=True)
    assert len(ScanFolder(out)) == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan"]


# ---------------------------------------------------------------------- bad input
@pytest.fixture
def scan(tmp_path) -> Path:
    return _write(tmp_path / "scan")


def test_missing_folder_and_files(tmp_path, scan):
    with pytest.raises(ScanFormatError, match="no such scan folder"):
        open_source(tmp_path / "nothing")
    (scan / "camera.json").unlink()
    with pytest.raises(ScanFormatError, match="neither a scan folder"):
        open_source(scan)
    with pytest.raises(ScanFormatError, match=r"camera\.json: file not found"):
        ScanFolder(scan)


def test_missing_frames_file_and_empty_frames(scan):
    (scan / "frames.jsonl").write_text("\n")
    with pytest.raises(ScanFormatError, match=r"frames\.jsonl: no frames"):
        ScanFolder(scan)
    (scan / "frames.jsonl").unlink()
    with pytest.raises(ScanFormatError, match=r"frames\.jsonl: file not found"):
        ScanFolder(scan)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"width": 0}, "image size must be positive"),
        ({"fx": "a"}, "'fx' must be a number"),
        ({"distortion": ["a"]}, "'distortion' must be a list"),
        ({"distortion_model": "pinhole2"}, "unknown distortion model"),
        ({"distortion_model": "plumb_bob", "distortion": [0.1, 0.2]}, "takes"),
        ({"height": None}, "'height' must be a number"),
        ({"width": 64.5}, "'width' must be an integer"),
    ],
)
def test_bad_camera_json(scan, change, message):
    data = json.loads((scan / "camera.json").read_text())
    data.update(change)
    (scan / "camera.json").write_text(json.dumps(data))
    with pytest.raises(ScanFormatError, match=rf"camera\.json: .*{message}"):
        ScanFolder(scan)


def test_camera_json_not_json(scan):
    (scan / "camera.json").write_text("{width: 3")
    with pytest.raises(ScanFormatError, match="cannot read JSON"):
        ScanFolder(scan)


def test_non_monotonic_times_name_the_line(scan):
    lines = _lines(scan)
    lines[3]["time"] = lines[1]["time"]
    _set_lines(scan, lines)
    with pytest.raises(
        ScanFormatError, match=r"frames\.jsonl:4 \(frame 3\): time .* must increase"
    ):
        ScanFolder(scan)


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        (np.diag([1.0, 1.0, 1.01, 1.0]).tolist(), "not a rigid transform: its rotation block"),
        (np.diag([1.0, -1.0, 1.0, 1.0]).tolist(), "determinant"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "last row"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "must be 4x4"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, "x"]], "not a numeric"),
    ],
)
def test_non_rigid_poses_name_the_line(scan, pose, message):
    lines = _lines(scan)
    lines[2]["T_world_camera"] = pose
    _set_lines(scan, lines)
    with pytest.raises(ScanFormatError, match=rf"frames\.jsonl:3 \(frame 2\): .*{message}"):
        ScanFolder(scan)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("not json", "not valid JSON"),
        ({"T_world_camera": np.eye(4).tolist()}, "missing field 'time'"),
        ({"time": "late", "T_world_camera": np.eye(4).tolist()}, "time must be a number"),
        ({"time": 9.0, "T_world_camera": np.eye(4).tolist(), "image": 3}, "image must be"),
        ({"time": 9.0, "T_world_camera": np.eye(4).tolist(), "mask": "m.png"}, "a mask without"),
    ],
)
def test_malformed_lines(scan, change, message):
    text = (scan / "frames.jsonl").read_text()
    extra = change if isinstance(change, str) else json.dumps(change)
    (scan / "frames.jsonl").write_text(text + extra + "\n")
    with pytest.raises(ScanFormatError, match=rf"frames\.jsonl:6 \(frame 5\): {message}"):
        ScanFolder(scan)


def test_missing_image_and_mask_files_are_named(scan):
    (scan / "images" / "000002.png").unlink()
    (scan / "masks" / "000004.png").unlink()
    with pytest.raises(ScanFormatError, match=r"image .*000002\.png \(frames\.jsonl line 3\)"):
        ScanFolder(scan)
    with pytest.raises(ScanFormatError, match=r"mask .*000004\.png"):
        ScanFolder(scan)
    skipped = [f for f in ScanFolder(scan, skip_bad_frames=True).frames() if f.skip_reason]
    assert [f.index for f in skipped] == [2, 4]
    assert "cannot read image" in skipped[0].skip_reason


def test_unreadable_image_is_named(scan):
    (scan / "images" / "000001.png").write_bytes(b"not a png")
    folder = ScanFolder(scan)
    with pytest.raises(ScanFormatError, match=r"cannot read image .*000001\.png .*frame 1"):
        list(folder.frames())


@pytest.mark.parametrize("kind", ["images", "masks"])
def test_size_disagreeing_with_camera_is_named(scan, kind):
    cv2.imwrite(str(scan / kind / "000003.png"), np.zeros((40, 64, 3), np.uint8))
    with pytest.raises(ScanFormatError, match=r"000003\.png is 64x40 but camera\.json says 64x48"):
        list(ScanFolder(scan).frames())
    frames = list(ScanFolder(scan, skip_bad_frames=True).frames())
    assert [f.index for f in frames if f.skip_reason] == [3]


def test_metadata_must_be_an_object(scan):
    (scan / "metadata.json").write_text("[1, 2]")
    with pytest.raises(ScanFormatError, match=r"metadata\.json: expected a JSON object"):
        ScanFolder(scan)


# ---------------------------------------------------------------------- distortion
def _pattern(w: int = 320, h: int = 240) -> np.ndarray:
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    smooth = 127 + 60 * np.sin(u / 9.0) * np.cos(v / 7.0) + 60 * np.sin((u + v) / 23.0)
    image = np.stack([smooth, np.roll(smooth, 13, axis=1), 255 - smooth], axis=2)
    return np.clip(image, 0, 255).astype(np.uint8)


@pytest.mark.parametrize(
    ("model", "coeffs"),
    [
        ("plumb_bob", (-0.25, 0.08, 0.001, -0.0015, 0.0)),
        ("rational_polynomial", (-0.2, 0.05, 0.001, 0.001, 0.01, 0.02, -0.01, 0.005)),
        ("equidistant", (0.05, -0.02, 0.01, -0.003)),
    ],
)
def test_distortion_round_trip(model, coeffs):
    camera = CameraModel(CameraIntrinsics.from_fov(320, 240, 60.0), model, coeffs)
    ideal = _pattern()
    raw = distort_image(ideal, camera)
    assert np.abs(raw.astype(int) - ideal).mean() > 10  # the lens really bends the image
    undistorted = Undistorter(camera).image(raw)
    inner = (slice(40, 200), slice(50, 270))
    error = np.abs(undistorted[inner].astype(int) - ideal[inner].astype(int))
    assert error.mean() < 2.0 and np.percentile(error, 99) < 12

    mask = np.zeros((240, 320), bool)
    mask[:, 140:180] = True
    mask_raw = distort_image(mask.astype(np.uint8), camera, nearest=True).astype(bool)
    mask_back = Undistorter(camera).mask(mask_raw)
    assert mask_back.dtype == bool
    assert (mask_back[inner] != mask[inner]).mean() < 0.01


def test_reader_undistorts_with_camera_json_coefficients(tmp_path):
    camera = CameraModel(CameraIntrinsics.from_fov(320, 240, 60.0), "radtan", (-0.2, 0.05, 0, 0))
    ideal = _pattern()
    mask = np.zeros((240, 320), bool)
    mask[:, 150:170] = True
    raw_rgb = distort_image(ideal, camera)
    raw_mask = distort_image(mask.astype(np.uint8), camera, nearest=True).astype(bool)
    T = make_pose(R_FORWARD_Y, [0, 0, 0.3])
    _write(tmp_path / "scan", [(0.0, T, raw_rgb, raw_mask)], camera)
    data = json.loads((tmp_path / "scan" / "camera.json").read_text())
    assert data["distortion_model"] == "plumb_bob" and len(data["distortion"]) == 4
    (loaded,) = ScanFolder(tmp_path / "scan").frames()
    inner = (slice(40, 200), slice(50, 270))
    assert np.abs(loaded.rgb[inner].astype(int) - ideal[inner]).mean() < 2.0
    assert (loaded.mask[inner] != mask[inner]).mean() < 0.01


def test_zero_coefficients_mean_no_distortion():
    camera = CameraModel(INTRINSICS, "plumb_bob", (0.0, 0.0, 0.0, 0.0, 0.0))
    assert not camera.is_distorted
    image = _pattern(64, 48)
    assert Undistorter(camera).image(image) is image
    with pytest.raises(ValueError, match="no non-zero"):
        CameraModel(INTRINSICS, "none", (0.1,))


# ---------------------------------------------------------------------- meshes
def test_tube_mesh_is_closed_and_outward(tmp_path):
    z = np.linspace(0.0, 0.1, 11)
    points = np.stack([0.01 * np.sin(20 * z), np.zeros_like(z), z], axis=1)
    vertices, faces = tube_mesh(points, np.full(11, 0.005))
    sides = 12
    assert vertices.shape == (11 * sides + 2, 3) and faces.shape == (2 * 10 * sides + 2 * sides, 3)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    normals = np.cross(b - a, c - a)
    centroids = (a + b + c) / 3
    side = faces[:, 0] < 11 * sides
    nearest = points[np.argmin(np.linalg.norm(centroids[side, None] - points[None], axis=2), 1)]
    assert np.all(np.einsum("ij,ij->i", normals[side], centroids[side] - nearest) > 0)

    model = TreeModel(
        BranchModel(points, np.full(11, 0.005)),
        [BranchModel(points[:4] + np.array([0.02, 0.0, 0.0]), np.full(4, 0.003))],
    )
    v, f, colors = tree_mesh(model)
    write_ply(tmp_path / "m.ply", v, f, colors)
    assert read_ply_counts(tmp_path / "m.ply") == (len(v), len(f))
    assert tree_mesh(TreeModel())[0].shape == (0, 3)
