"""Recording simulated scans (branch_gym.recording) and replaying them (recon.replay)."""

from __future__ import annotations

import csv
import json
import math
import shutil
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from replay_fixtures import record_short_scan

from recon.curve2d.types import Curve2DConfig
from recon.io import ScanFolder, ScanFormatError, open_source
from recon.model import TreeModel
from recon.replay import (
    OverlayVideo,
    ReplayConfig,
    ReplayError,
    curve_settings,
    load_segmenter,
    load_truth,
    main,
    replay,
)

OUTPUTS = {
    "model.json",
    "model.ply",
    "iterations.csv",
    "frames.csv",
    "overlay.mp4",
    "plot3d.png",
    "summary.json",
}


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("rec") / "scan"
    return out, record_short_scan(out)


def _same_metrics(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        if isinstance(a[key], float) and math.isnan(a[key]):
            assert math.isnan(b[key]), key
        else:
            assert a[key] == b[key], key


def test_recording_holds_frames_truth_and_seed(recording):
    scan, result = recording
    folder = ScanFolder(scan)
    assert folder.has_masks and len(folder) > 20
    meta = folder.metadata
    assert meta["modeler"]["seed"] == 0 and meta["modeler"]["tracker"] == "lk"
    assert curve_settings(meta, None) == Curve2DConfig()  # the scan's 2D stage
    assert meta["lossless"] and meta["result"]["n_iterations"] == result.n_iterations
    truth = load_truth(folder.truth_path())
    np.testing.assert_array_equal(truth.primary.points, result.truth.primary.points)
    recorded = TreeModel.from_dict(json.loads((scan / "recorded_model.json").read_text()))
    np.testing.assert_array_equal(recorded.primary.points, result.model.primary.points)


def test_replay_reproduces_the_scan_exactly(recording, tmp_path):
    scan, result = recording
    out = tmp_path / "out"
    replayed = replay(scan, out, truth=scan / "truth.json", progress=False)
    assert replayed.model.to_dict() == result.model.to_dict()
    assert [r.outcome for r in replayed.reports] == [
        r.outcome for r in _session_reports(result, replayed)
    ]
    _same_metrics(replayed.metrics.to_dict(), result.metrics.to_dict())
    assert replayed.seed == 0 and replayed.n_skipped == 0
    assert {p.name for p in out.iterdir()} == OUTPUTS
    assert json.loads((out / "model.json").read_text()) == result.model.to_dict()
    with open(out / "iterations.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == result.n_iterations
    assert {"outcome", "reason", "total_ms", "curve2d_ms"} <= rows[0].keys()
    with open(out / "frames.csv") as f:
        frames = list(csv.DictReader(f))
    assert len(frames) == len(ScanFolder(scan))
    assert sum(r["status"] == "iteration" for r in frames) == result.n_iterations
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcomes"] == result.outcomes and summary["metrics"] is not None
    assert (out / "overlay.mp4").stat().st_size > 1000
    assert (out / "plot3d.png").read_bytes()[:4] == b"\x89PNG"


def _session_reports(result, replayed):
    """The scan's outcomes in order, from its counts (ScanResult keeps counts only)."""
    counts = dict(result.outcomes)
    assert {k: v for k, v in counts.items() if v} == dict(
        __import__("collections").Counter(r.outcome.value for r in replayed.reports)
    )
    return replayed.reports


def test_seed_changes_only_when_asked(recording, tmp_path):
    scan, result = recording
    replayed = replay(scan, tmp_path / "a", seed=0, progress=False)
    assert replayed.model.to_dict() == result.model.to_dict()
    assert replay(scan, tmp_path / "b", seed=12345, progress=False).seed == 12345


def test_cli(recording, tmp_path, capsys):
    scan, _ = recording
    out = tmp_path / "out"
    args = [str(scan), "--out", str(out), "--truth", str(scan / "truth.json"), "--no-progress"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "PB residual" in printed and "files: model.json" in printed
    assert main(args) == 2  # refuses to overwrite
    assert "exists already" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    assert main([str(tmp_path / "nope"), "--out", str(tmp_path / "o2")]) == 2
    assert "no such scan folder" in capsys.readouterr().err


def test_jpeg_recording_replays_close(tmp_path):
    result = record_short_scan(tmp_path / "jpg", image_format="jpg", jpeg_quality=90)
    assert all(r.image.endswith(".jpg") for r in ScanFolder(tmp_path / "jpg").records)
    replayed = replay(tmp_path / "jpg", tmp_path / "out", progress=False)
    a, b = replayed.model.primary.points, result.model.primary.points
    n = min(len(a), len(b))
    assert np.abs(a[:n] - b[:n]).max() < 0.003


# ---------------------------------------------------------------------- masks and segmenters
def _strip_masks(scan: Path, dest: Path) -> Path:
    shutil.copytree(scan, dest)
    lines = [json.loads(x) for x in (dest / "frames.jsonl").read_text().splitlines()]
    for line in lines:
        line.pop("mask", None)
    (dest / "frames.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    return dest


def test_no_masks_and_no_segmenter_is_an_error(recording, tmp_path):
    scan, _ = recording
    bare = _strip_masks(scan, tmp_path / "bare")
    with pytest.raises(ReplayError, match=r"have no mask \(first: frame 0\) and no segmenter"):
        replay(bare, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_learned_segmenter_hook(recording, tmp_path, monkeypatch):
    scan, result = recording
    bare = _strip_masks(scan, tmp_path / "bare")
    masks = [f.mask for f in ScanFolder(scan).frames()]
    specs, calls = [], []

    class Replayer:  # a "learned" segmenter that returns the recorded masks
        def segment(self, rgb, previous_rgb=None):
            calls.append(previous_rgb is not None)
            return masks[len(calls) - 1]

    fake = types.ModuleType("recon.segmentation")
    fake.load_segmenter = lambda spec: specs.append(spec) or Replayer()
    monkeypatch.setitem(sys.modules, "recon.segmentation", fake)
    replayed = replay(bare, tmp_path / "out", segmenter="learned:model.pt", progress=False)
    assert specs == ["learned:model.pt"]
    assert calls == [False] + [True] * (len(masks) - 1)
    assert replayed.model.to_dict() == result.model.to_dict()


def test_the_trust_tolerance_follows_the_mask_source(recording, tmp_path, monkeypatch):
    """Exact recorded masks replay at 0 px; a learned segmenter's masks (now, or when the scan
    was recorded) at ModelerConfig.consistency_tolerance_px (recon.config)."""
    scan, _ = recording

    def tolerance(source, name, **kwargs) -> float:
        replay(source, tmp_path / name, progress=False, **kwargs)
        summary = json.loads((tmp_path / name / "summary.json").read_text())
        return summary["modeler_config"]["secondary_trust_tolerance_px"]

    assert tolerance(scan, "exact") == 0.0
    learned = tmp_path / "learned_masks"
    shutil.copytree(scan, learned)
    meta = json.loads((learned / "metadata.json").read_text())
    meta["scan"]["segmenter"] = "learned"
    (learned / "metadata.json").write_text(json.dumps(meta))
    assert tolerance(learned, "recorded_learned") == 4.0
    masks = [f.mask for f in ScanFolder(scan).frames()]

    class Replayer:  # a learned segmenter that returns the recorded masks
        def segment(self, rgb, previous_rgb=None):
            return masks[0]

    assert tolerance(scan, "now_learned", segmenter=Replayer()) == 4.0
    assert main([str(learned), "--out", str(tmp_path / "cli"), "--no-progress",
                 "--modeler", "secondary_trust_tolerance_px=1.5"]) == 0  # fmt: skip
    summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    assert summary["modeler_config"]["secondary_trust_tolerance_px"] == 1.5


def test_learned_segmenter_missing_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "recon.segmentation", None)
    with pytest.raises(ReplayError, match=r"learned RGB segmenter \(recon.segmentation\)"):
        load_segmenter("learned")
    monkeypatch.setitem(sys.modules, "recon.segmentation", types.ModuleType("recon.segmentation"))
    with pytest.raises(ReplayError, match="has no load_segmenter"):
        load_segmenter("learned:x.pt")
    with pytest.raises(ValueError, match="unknown segmenter 'sam'"):
        load_segmenter("sam")
    assert load_segmenter("mask") is None


# ---------------------------------------------------------------------- bad frames
def test_bad_frame_mid_replay_leaves_no_output(recording, tmp_path):
    scan, _ = recording
    broken = tmp_path / "broken"
    shutil.copytree(scan, broken)
    (broken / "images" / "000020.png").write_bytes(b"garbage")
    with pytest.raises(ScanFormatError, match=r"cannot read image .*000020\.png"):
        replay(broken, tmp_path / "out", progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken"]


def test_skipped_frames_are_reported(recording, tmp_path):
    scan, _ = recording
    broken = tmp_path / "broken"
    shutil.copytree(scan, broken)
    (broken / "images" / "000020.png").write_bytes(b"garbage")
    (broken / "masks" / "000021.png").unlink()
    source = open_source(broken, skip_bad_frames=True)
    replayed = replay(source, tmp_path / "out", progress=False)
    assert replayed.n_skipped == 2 and replayed.n_fed == len(source) - 2
    assert set(replayed.skip_reasons) == {"cannot read image", "cannot read mask"}
    rows = list(csv.DictReader(open(tmp_path / "out" / "frames.csv")))
    assert [r["index"] for r in rows if r["status"] == "skipped"] == ["20", "21"]
    assert "000020.png" in rows[20]["reason"]


def test_gif_fallback_without_mp4_codec(tmp_path, monkeypatch):
    class NoCodec:
        def __init__(self, *args):
            pass

        def isOpened(self):
            return False

    import importlib

    writers = importlib.import_module("recon.replay.writers")
    monkeypatch.setattr(writers.cv2, "VideoWriter", NoCodec)
    video = OverlayVideo(tmp_path, (32, 24), ReplayConfig(gif_max_frames=3))
    for i in range(7):
        video.write(np.full((24, 32, 3), 30 * i, np.uint8))
    path = video.close()
    assert path.name == "overlay.gif" and path.read_bytes()[:3] == b"GIF"
    assert not (tmp_path / "overlay.mp4").exists()


def test_shipped_example_replays(tmp_path):
    example = Path(__file__).parents[1] / "examples" / "scan_seed0"
    if not example.exists():
        pytest.skip("examples/scan_seed0 is not in this checkout")
    source = ScanFolder(example)
    assert source.metadata["image_format"] == "jpg" and not source.metadata["lossless"]
    replayed = replay(source, tmp_path / "out", truth=example / "truth.json", progress=False)
    recorded = TreeModel.from_dict(json.loads((example / "recorded_model.json").read_text()))
    assert replayed.n_skipped == 0 and replayed.model.primary is not None
    assert len(replayed.model.secondaries) == len(recorded.secondaries)
    assert replayed.metrics.pb_residual_mean_m < 0.002  # JPEG: close to, not equal to, online


@pytest.mark.slow  # ~10 s: a rotating scan to 0.40 m
def test_periodic_rotation_scan_replays_exactly(tmp_path):
    from agents.factory import AGENTS
    from branch_gym.evaluation.record import record_scan
    from branch_gym.scan import ScanConfig

    result = record_scan(
        2, "periodic:22.5:1.5", ScanConfig(end_height_m=0.40), tmp_path / "rec", factory=AGENTS
    )
    assert result.rotations >= 1
    replayed = replay(tmp_path / "rec", tmp_path / "out", progress=False)
    assert replayed.model.to_dict() == result.model.to_dict()


def test_recording_context_leaves_nothing_on_error(tmp_path):
    from branch_gym.recording import recording
    from branch_gym.scan import ScanConfig, ScanSession

    session = ScanSession(ScanConfig(end_height_m=0.30))
    try:
        with pytest.raises(RuntimeError, match="interrupted"):
            with recording(session, tmp_path / "rec", seed=1):
                session.reset(1)
                session.step(0.0)
                raise RuntimeError("interrupted")
        assert list(tmp_path.iterdir()) == [] and session.frame_listeners == []
        with recording(session, tmp_path / "rec", seed=1, policy="none") as recorder:
            session.reset(1)
            while not session.done:
                session.step(0.0)
        assert recorder.n_frames == len(ScanFolder(tmp_path / "rec")) > 0
        replayed = replay(tmp_path / "rec", tmp_path / "out", progress=False)
        assert replayed.model.to_dict() == session.model.to_dict()
    finally:
        session.close()
