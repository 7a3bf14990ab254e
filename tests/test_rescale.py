"""recon.io.rescale: a recording replayed at the pipeline's working focal length."""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from replay_fixtures import record_short_scan

from recon.camera import CameraIntrinsics, project_points
from recon.io import open_source
from recon.io.rescale import (
    PIPELINE_FOCAL_PX,
    RescaledSource,
    resize_mask,
    scaled_intrinsics,
    working_size,
)
from recon.replay import main, replay


def test_scaled_intrinsics_project_a_point_where_the_resized_frame_shows_it():
    intrinsics = CameraIntrinsics(640, 480, fx=610.0, fy=608.0, cx=318.2, cy=241.7)
    points = np.array([[0.05, -0.03, 0.30], [-0.1, 0.08, 0.5]])
    pixels, _ = project_points(points, np.eye(4), intrinsics)
    size = working_size(intrinsics, PIPELINE_FOCAL_PX)
    scaled = scaled_intrinsics(intrinsics, size)
    assert abs(0.5 * (scaled.fx + scaled.fy) - PIPELINE_FOCAL_PX) < 2.0  # whole-pixel size
    moved, _ = project_points(points, np.eye(4), scaled)
    # a pixel centre u of the full frame lies at (u + 0.5) * s - 0.5 of the resized one
    s = np.array([size[0] / 640, size[1] / 480])
    np.testing.assert_allclose(moved, (pixels + 0.5) * s - 0.5, atol=1e-9)


def test_a_thin_line_survives_halving_and_a_mask_comes_back_from_doubling():
    mask = np.zeros((48, 64), bool)
    mask[:, 30] = True  # 1 px wide at 64 px
    assert resize_mask(mask, (32, 24))[:, 15].all()
    blob = np.zeros((24, 32), bool)
    blob[5:17, 9:20] = True
    np.testing.assert_array_equal(resize_mask(resize_mask(blob, (64, 48)), (32, 24)), blob)


@pytest.mark.parametrize("focal", [0.0, -3.0, float("nan"), float("inf")])
def test_a_bad_working_focal_length_is_named(focal):
    with pytest.raises(ValueError, match="working focal length"):
        working_size(CameraIntrinsics.from_fov(), focal)
    with pytest.raises(ValueError, match="below one pixel"):
        working_size(CameraIntrinsics.from_fov(), 0.5)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rec") / "scan"
    record_short_scan(out)
    return out


def test_a_recording_at_twice_the_resolution_replays_like_the_original(recording, tmp_path):
    original = replay(recording, tmp_path / "a", progress=False)
    source = open_source(recording)
    doubled = RescaledSource(source, 2.0 * source.intrinsics.fx)  # a 640x480 camera
    assert doubled.intrinsics.width == 640 and doubled.intrinsics.height == 480
    frame = next(f for f in doubled.frames() if f.rgb is not None)
    assert frame.rgb.shape == (480, 640, 3) and frame.mask.shape == (480, 640)
    # brought back to the pipeline's camera, masks exactly and images within a grey level or
    # two: the same tree, within a millimetre
    back = replay(doubled, tmp_path / "b", progress=False, working_focal_px=PIPELINE_FOCAL_PX)
    a, b = original.model.primary.points, back.model.primary.points
    assert len(a) == len(b) and np.abs(a - b).max() < 1e-3
    assert len(back.model.secondaries) == len(original.model.secondaries)
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert (summary["camera"]["width"], summary["camera"]["height"]) == (320, 240)


def test_cli_takes_pipeline_or_pixels_and_names_a_bad_value(recording, tmp_path, capsys):
    args = [str(recording), "--no-progress", "--working-focal-px"]
    assert main([*args, "pipeline", "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "208.4", "--out", str(tmp_path / "b")]) == 0
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert (summary["camera"]["width"], summary["camera"]["height"]) == (160, 120)
    with pytest.raises(SystemExit):
        main([*args, "wide", "--out", str(tmp_path / "c")])
    assert "positive focal length in pixels, 'pipeline'" in capsys.readouterr().err


def test_our_learned_segmenter_reads_the_pipelines_focal_length_unless_asked(
    recording, tmp_path, monkeypatch
):
    sizes = []

    class Sizer:  # records the frame sizes it is given; a vertical bar for a mask
        def segment(self, rgb, previous_rgb=None):
            sizes.append(rgb.shape[:2])
            mask = np.zeros(rgb.shape[:2], bool)
            mask[:, rgb.shape[1] // 2 - 3 : rgb.shape[1] // 2 + 3] = True
            return mask

    fake = types.ModuleType("recon.segmentation")
    fake.load_segmenter = lambda spec: Sizer()
    monkeypatch.setitem(sys.modules, "recon.segmentation", fake)
    source = open_source(recording)
    doubled = RescaledSource(source, 2.0 * source.intrinsics.fx)
    for name, kwargs, seen in (
        ("auto", {"segmenter": "learned"}, (240, 320)),
        ("native", {"segmenter": "learned", "working_focal_px": None}, (480, 640)),
        ("own", {"segmenter": Sizer()}, (480, 640)),  # a segmenter of your own: as recorded
    ):
        sizes.clear()
        replay(doubled, tmp_path / name, progress=False, **kwargs)
        assert set(sizes) == {seen}, name
    with pytest.raises(ValueError, match="working_focal_px"):
        replay(doubled, tmp_path / "bad", progress=False, working_focal_px="wide")
