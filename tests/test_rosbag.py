"""ROS 2 bags as scan sources (recon.io.rosbag): bags written with rosbags' writer."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("rosbags")

from replay_fixtures import BAG_START_NS, record_short_scan, write_bag

from recon.camera import CameraIntrinsics, make_pose
from recon.io import ScanFolder, ScanFormatError, open_source
from recon.io.convert import main as convert_main
from recon.io.rosbag import (
    BagConfig,
    BagSource,
    TransformSeries,
    TransformTree,
    camera_from_info,
)
from recon.replay import replay


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("rec") / "scan"
    return out, record_short_scan(out)


def _primary_error(model, reference) -> float:
    a, b = model.primary.points, reference.primary.points
    assert a.shape == b.shape
    return float(np.abs(a - b).max())


@pytest.mark.parametrize(("storage", "compressed"), [("sqlite3", False), ("mcap", True)])
def test_bag_replays_to_the_recorded_model(recording, tmp_path, storage, compressed):
    scan, result = recording
    bag = tmp_path / "bag"
    write_bag(scan, bag, storage=storage, compressed=compressed)
    assert any(bag.glob("*.mcap" if storage == "mcap" else "*.db3"))
    replayed = replay(bag, tmp_path / "out", progress=False)
    assert replayed.n_skipped == 0 and replayed.n_fed == len(ScanFolder(scan))
    assert len(replayed.reports) == result.n_iterations
    assert _primary_error(replayed.model, result.model) < 1e-6
    assert len(replayed.model.secondaries) == len(result.model.secondaries)
    for a, b in zip(replayed.model.secondaries, result.model.secondaries, strict=True):
        np.testing.assert_allclose(a.points, b.points, atol=1e-6)
        np.testing.assert_allclose(a.radii, b.radii, atol=1e-6)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["n_fed"] == replayed.n_fed


def test_pose_topic_instead_of_tf(recording, tmp_path):
    scan, result = recording
    write_bag(scan, tmp_path / "bag", pose_topic=True)
    source = BagSource(tmp_path / "bag", BagConfig(pose_topic="/camera_pose"))
    assert "/camera_pose" in source.metadata["pose_source"]
    replayed = replay(source, tmp_path / "out", progress=False)
    assert _primary_error(replayed.model, result.model) < 1e-6


def test_frames_without_pose_are_skipped_and_counted(recording, tmp_path):
    scan, _ = recording
    n = len(ScanFolder(scan))
    write_bag(scan, tmp_path / "bag", tf_until_frame=n - 9)
    source = BagSource(tmp_path / "bag", BagConfig(pose_tolerance_s=0.005))
    replayed = replay(source, tmp_path / "out", progress=False)
    assert replayed.n_skipped == 8 and replayed.n_fed == n - 8
    assert replayed.skip_reasons == {"no pose": 8}
    rows = (tmp_path / "out" / "frames.csv").read_text().splitlines()
    assert sum(",skipped,no pose: no transform base_link -> tool0 within" in r for r in rows) == 8


def test_import_bag_as_scan_folder(recording, tmp_path, capsys):
    scan, result = recording
    write_bag(scan, tmp_path / "bag")
    assert convert_main([str(tmp_path / "bag"), "--out", str(tmp_path / "imported")]) == 0
    assert f"{len(ScanFolder(scan))} frames, 0 skipped" in capsys.readouterr().out
    imported = ScanFolder(tmp_path / "imported")
    assert len(imported) == len(ScanFolder(scan))
    assert imported.metadata["imported_from"] == str(tmp_path / "bag")
    replayed = replay(imported, tmp_path / "out", progress=False)
    assert _primary_error(replayed.model, result.model) < 1e-6


# ---------------------------------------------------------------------- transforms
def test_slerp_interpolation_between_samples():
    Rz = [Rotation.from_euler("z", a, degrees=True).as_quat() for a in (0.0, 90.0)]
    series = TransformSeries.from_samples(
        "base", "cam", [(2_000, (0.0, 0.0, 1.0), Rz[1]), (0, (0.0, 0.0, 0.0), Rz[0])]
    )
    T, reason = series.at(500, tolerance_ns=10, max_gap_ns=10_000)
    assert reason is None
    np.testing.assert_allclose(T[:3, 3], [0, 0, 0.25])
    angle = Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)[2]
    assert angle == pytest.approx(22.5)
    assert series.at(2_005, 10, 10_000)[0] is not None  # within the tolerance past the end
    T, reason = series.at(2_100, 10, 10_000)
    assert T is None and "within" in reason
    T, reason = series.at(1_000, 10, max_gap_ns=1_000)
    assert T is None and "gap" in reason


def test_chain_to_a_world_frame_that_is_not_the_root():
    tree = TransformTree()
    T_odom_base = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [1, 2, 0])
    T_odom_cam = make_pose(Rotation.from_euler("x", -90, degrees=True).as_matrix(), [1, 2.2, 0.3])
    q = Rotation.from_matrix(T_odom_base[:3, :3]).as_quat()
    tree.add("/odom", "base_link", 0, T_odom_base[:3, 3], q, static=True)
    for t in (0, 100):
        qc = Rotation.from_matrix(T_odom_cam[:3, :3]).as_quat()
        tree.add("odom", "cam", t, T_odom_cam[:3, 3], qc, static=False)
    tree.finalize()
    tree.check_chain("base_link", "cam", "/tf")
    T, _ = tree.lookup("base_link", "cam", 50, 0, 1_000)
    np.testing.assert_allclose(T, np.linalg.inv(T_odom_base) @ T_odom_cam, atol=1e-12)
    with pytest.raises(ScanFormatError, match="'map' appears in no transform"):
        tree.check_chain("map", "cam", "/tf")
    tree.add("world", "island", 0, (0, 0, 0), (0, 0, 0, 1), static=True)
    tree.finalize()
    with pytest.raises(ScanFormatError, match="no transform chain between 'island' and 'cam'"):
        tree.check_chain("island", "cam", "/tf")


def test_camera_info_with_distortion():
    k = CameraIntrinsics.from_fov(320, 240, 60.0)
    msg = SimpleNamespace(
        k=k.K.reshape(-1), d=[-0.2, 0.05, 0.0, 0.0, 0.0], distortion_model="plumb_bob",
        width=320, height=240,
    )  # fmt: skip
    camera = camera_from_info(msg, "info")
    assert camera.is_distorted and camera.distortion_model == "plumb_bob"
    assert camera.intrinsics == k
    msg.d = [0.0] * 5
    assert not camera_from_info(msg, "info").is_distorted
    msg.k = [0.0] * 9
    with pytest.raises(ScanFormatError, match="not calibrated"):
        camera_from_info(msg, "info")


# ---------------------------------------------------------------------- bad input
def test_absent_topic_is_named(recording, tmp_path):
    scan, _ = recording
    write_bag(scan, tmp_path / "bag", n_frames=3)
    with pytest.raises(ScanFormatError, match=r"topic '/camera/image' is absent \(topics in"):
        BagSource(tmp_path / "bag", BagConfig(image_topic="/camera/image"))
    with pytest.raises(ScanFormatError, match="topic '/masks' is absent"):
        BagSource(tmp_path / "bag", BagConfig(mask_topic="/masks"))
    with pytest.raises(
        ScanFormatError, match="topic '/image_mask' has type sensor_msgs/msg/Image, expected"
    ):
        BagSource(tmp_path / "bag", BagConfig(tf_topic="/image_mask"))


def test_empty_topic_is_named(recording, tmp_path):
    scan, _ = recording
    write_bag(scan, tmp_path / "bag", n_frames=0)
    with pytest.raises(ScanFormatError, match="topic '/camera/color/image_raw' has no messages"):
        BagSource(tmp_path / "bag")


def test_missing_camera_frame_is_named(recording, tmp_path):
    scan, _ = recording
    write_bag(scan, tmp_path / "bag", n_frames=3)
    with pytest.raises(ScanFormatError, match="frame 'camera_link' appears in no transform"):
        BagSource(tmp_path / "bag", BagConfig(camera_frame="camera_link"))


def test_non_monotonic_image_stamps_are_named(recording, tmp_path):
    scan, _ = recording
    write_bag(scan, tmp_path / "bag", n_frames=12, stamp_offsets_ns={10: -200_000_000})
    with pytest.raises(ScanFormatError, match=r"message 10: stamp .* times must increase"):
        list(BagSource(tmp_path / "bag", BagConfig(pose_tolerance_s=1.0)).frames())
    assert not (tmp_path / "out").exists()
    with pytest.raises(ScanFormatError, match="must increase"):
        replay(BagSource(tmp_path / "bag", BagConfig(pose_tolerance_s=1.0)), tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # nothing half written


def test_image_size_disagreeing_with_camera_info(recording, tmp_path):
    scan, _ = recording
    write_bag(
        scan, tmp_path / "bag", n_frames=3, info_intrinsics=CameraIntrinsics.from_fov(640, 480)
    )
    with pytest.raises(ScanFormatError, match=r"message 0: image is 320x240 but .* says 640x480"):
        list(BagSource(tmp_path / "bag").frames())


def test_missing_masks_without_segmenter(recording, tmp_path):
    scan, _ = recording
    write_bag(scan, tmp_path / "bag", n_frames=3, mask_topic=None)
    with pytest.raises(ScanFormatError, match="topic '/image_mask' is absent"):
        open_source(tmp_path / "bag")
    source = BagSource(tmp_path / "bag", BagConfig(mask_topic=None))
    from recon.replay import ReplayError

    with pytest.raises(ReplayError, match="no mask"):
        replay(source, tmp_path / "out")


def test_missing_bag_and_stamp_fallback(tmp_path):
    with pytest.raises(ScanFormatError, match="bag not found"):
        BagSource(tmp_path / "nothing.mcap")
    assert BAG_START_NS > 0


def test_rosbags_missing_gives_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "rosbags", None)
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(ImportError, match=r"pip install 'branch_gym\[rosbag\]'"):
        BagSource(tmp_path)


def test_recon_imports_neither_rosbags_nor_the_simulator():
    code = (
        "import sys, recon.replay, recon.io, recon.io.rosbag; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('rosbags', 'pybullet', "
        "'branch_gym', 'agents')]; print(bad); assert not bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).parents[1])
