"""The learned segmenter: network, weights file, training loop, shipped weights."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest
import torch

from branch_gym.segmenter_training.config import (
    EVAL_SEED_OFFSET,
    AugmentConfig,
    GenerateConfig,
    TrainConfig,
)
from branch_gym.segmenter_training.evaluate import (
    EvaluateConfig,
    evaluate_segmenter,
    render_eval_frames,
)
from branch_gym.segmenter_training.generate import generate_shard, shard_path, write_shard
from branch_gym.segmenter_training.train import PairBatches, segmentation_loss, train
from branch_gym.sim.scene.labels import PART_NAMES, label_parts
from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import SegmenterNet, SegmenterNetConfig, count_parameters
from recon.segmentation.segmenter import LearnedSegmenter, default_weights_path, load_segmenter
from recon.segmentation.weights import SegmenterWeightsError, load_weights, save_weights

# Flow on: the tiny runs exercise the flow input path too (the shipped model is RGB only).
TINY_NET = SegmenterNetConfig(use_flow=True, widths=(8, 16, 16, 16), decoder_widths=(16, 16, 8))


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two trees, two frame pairs each, rendered once for the module."""
    out = tmp_path_factory.mktemp("segdata")
    config = GenerateConfig(trees=2, pairs_per_tree=2, trees_per_shard=2)
    write_shard(shard_path(out, 0), generate_shard(config, seed=0, index=0))
    return out


def _tiny_config(steps: int, augment: bool = True) -> TrainConfig:
    config = TrainConfig(net=TINY_NET, steps=steps, batch_size=2, checkpoint_every=1,
                         validate_every=10_000, learning_rate=1e-2)  # fmt: skip
    if augment:
        return config
    off = {f.name: 0.0 for f in fields(AugmentConfig) if f.name.endswith("_probability")}
    return replace(config, augment=AugmentConfig(**off))


@pytest.mark.parametrize("use_flow", [True, False])
def test_forward_pass_shapes(use_flow: bool) -> None:
    net = SegmenterNet(SegmenterNetConfig(use_flow=use_flow)).eval()
    assert count_parameters(net) <= 2_000_000
    x = torch.randn(3, net.config.in_channels, 240, 320)
    with torch.inference_mode():
        out = net(x)
    assert out.shape == (3, 1, 240, 320)
    assert torch.isfinite(out).all()


def test_segment_any_size_with_and_without_previous() -> None:
    segmenter = LearnedSegmenter(SegmenterNet(TINY_NET).eval())
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (250, 330, 3), dtype=np.uint8)
    for previous in (None, np.roll(rgb, 2, axis=0)):
        mask = segmenter.segment(rgb, previous)
        assert mask.shape == (250, 330) and mask.dtype == bool


def test_the_inference_network_and_the_mask_match_the_network() -> None:
    torch.manual_seed(0)
    net = SegmenterNet(TINY_NET)
    net.train()
    net(torch.randn(4, net.config.in_channels, 64, 64))  # non-trivial running statistics
    net.eval()
    x = torch.randn(1, net.config.in_channels, 64, 64)
    segmenter = LearnedSegmenter(net)
    fast = segmenter._net  # BN folded, 1x1 convs as matrix products
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fast.modules())
    assert not any(isinstance(m, torch.nn.Conv2d) and m.kernel_size == (1, 1)
                   for m in fast.modules())  # fmt: skip
    with torch.inference_mode():
        reference = net(x)
        assert torch.allclose(reference, fast(x), atol=1e-4)
    # The mask thresholded before depth-to-space is the logits' mask.
    rgb = np.random.default_rng(1).integers(0, 256, (62, 70, 3), dtype=np.uint8)
    logits = segmenter.logits(rgb)
    assert logits.shape == (62, 70)
    np.testing.assert_array_equal(segmenter.segment(rgb), logits > 0.0)


def test_training_lowers_the_loss(tiny_data: Path, tmp_path: Path) -> None:
    config = _tiny_config(steps=40, augment=False)
    fixed = PairBatches(*_arrays(tiny_data), config, seed=123, augment=False)[0]
    torch.manual_seed(0)
    with torch.inference_mode():
        before = float(segmentation_loss(SegmenterNet(TINY_NET).eval()(fixed[0]), fixed[1], 1.0))
    result = train(config, tiny_data, tmp_path / "run", seed=0, workers=0, progress=False)
    with torch.inference_mode():
        after = float(segmentation_loss(result.model(fixed[0]), fixed[1], 1.0))
    assert after < 0.85 * before


def test_same_seed_same_weights_and_resume(tiny_data: Path, tmp_path: Path) -> None:
    config = _tiny_config(steps=3)
    a = train(config, tiny_data, tmp_path / "a", seed=7, workers=0, progress=False).model
    b = train(config, tiny_data, tmp_path / "b", seed=7, workers=0, progress=False).model
    # Interrupted after one step (max_minutes=0), then resumed from the checkpoint.
    first = train(config, tiny_data, tmp_path / "c", seed=7, workers=0, progress=False,
                  max_minutes=0.0)  # fmt: skip
    assert not first.finished
    c = train(config, tiny_data, tmp_path / "c", seed=7, workers=0, progress=False).model
    for (name, pa), pb, pc in zip(a.state_dict().items(), b.state_dict().values(),
                                  c.state_dict().values(), strict=True):  # fmt: skip
        assert torch.equal(pa, pb), name
        assert torch.equal(pa, pc), name
    d = train(config, tiny_data, tmp_path / "d", seed=8, workers=0, progress=False).model
    assert not all(torch.equal(x, y) for x, y in zip(a.parameters(), d.parameters(), strict=True))


def test_encoder_learning_rate_scale_holds_the_encoder(tiny_data: Path, tmp_path: Path) -> None:
    """At scale 0 training moves the decoder only; bad scales are refused by name."""
    config = replace(_tiny_config(steps=3), encoder_learning_rate_scale=0.0)
    torch.manual_seed(0)  # train() seeds the same init from its seed
    trained = train(config, tiny_data, tmp_path / "run", seed=5, workers=0, progress=False).model
    torch.manual_seed(5)
    start = SegmenterNet(TINY_NET)
    encoder = ("stem.", "down.")
    for (name, before), after in zip(
        start.state_dict().items(), trained.state_dict().values(), strict=True
    ):
        if name.startswith(encoder) and "running_" not in name and "num_batches" not in name:
            assert torch.equal(before, after), name
    moved = [
        name
        for (name, before), after in zip(
            start.state_dict().items(), trained.state_dict().values(), strict=True
        )
        if not name.startswith(encoder) and not torch.equal(before, after)
    ]
    assert moved
    with pytest.raises(ValueError, match="encoder_learning_rate_scale"):
        TrainConfig(encoder_learning_rate_scale=1.5)


def _arrays(data_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    with np.load(shard_path(data_dir, 0)) as shard:
        return shard["rgb"], shard["classes"]


def test_weights_round_trip(tmp_path: Path) -> None:
    net = SegmenterNet(TINY_NET).eval()
    path = save_weights(tmp_path / "w.pt", net, FlowConfig(clip=2.0), threshold=0.4)
    loaded, flow, threshold, _ = load_weights(path)
    assert loaded.config == TINY_NET and flow.clip == 2.0 and threshold == 0.4
    for pa, pb in zip(net.state_dict().values(), loaded.state_dict().values(), strict=True):
        assert torch.equal(pa, pb)
    assert load_segmenter(f"learned:{path}").config == TINY_NET


def test_bad_weights_files_name_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "missing.pt"
    with pytest.raises(SegmenterWeightsError, match=r"missing\.pt"):
        load_segmenter(f"learned:{missing}")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x00not a torch file" * 10)
    with pytest.raises(SegmenterWeightsError, match=r"corrupt\.pt"):
        load_segmenter(f"learned:{corrupt}")
    alien = tmp_path / "alien.pt"
    torch.save({"state_dict": {}}, alien)
    with pytest.raises(SegmenterWeightsError, match=r"alien\.pt"):
        load_weights(alien)
    # Mismatch: the stored architecture differs from the stored state dict.
    mismatched = tmp_path / "mismatched.pt"
    save_weights(mismatched, SegmenterNet(TINY_NET), FlowConfig())
    payload = torch.load(mismatched, weights_only=True)
    payload["net"] = replace(TINY_NET, widths=(8, 16, 32, 16)).to_dict()
    torch.save(payload, mismatched)
    with pytest.raises(SegmenterWeightsError, match=r"mismatched\.pt.*does not match"):
        load_segmenter(f"learned:{mismatched}")
    with pytest.raises(ValueError, match="learned"):
        load_segmenter("gt")


def test_recon_segmentation_imports_no_simulator() -> None:
    code = (
        "import sys, recon.segmentation; "
        "bad = [m for m in sys.modules if m.startswith(('pybullet', 'branch_gym'))]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.skipif(not default_weights_path().is_file(), reason="no shipped weights")
def test_shipped_weights_segment_unseen_trees() -> None:
    segmenter = load_segmenter("learned")
    config = EvaluateConfig(trees=2, frames_per_tree=2)
    result = evaluate_segmenter(segmenter, "paper", config, progress=False)
    assert result["frames"] == 4
    assert result["iou"] >= 0.8


@pytest.mark.skipif(not default_weights_path().is_file(), reason="no shipped weights")
def test_evaluation_views_after_an_orbit_are_scored_too() -> None:
    """``orbit_deg`` scores the views after a rotation stage: the camera has moved about the
    primary (other pixels), and the side-branch recall is reported with the IoU."""
    straight, orbited = (
        next(render_eval_frames("paper", EVAL_SEED_OFFSET, EvaluateConfig(orbit_deg=angle)))
        for angle in (0.0, 22.5)
    )
    assert np.mean(straight[1] != orbited[1]) > 0.2
    config = EvaluateConfig(trees=1, frames_per_tree=2, orbit_deg=22.5)
    result = evaluate_segmenter(load_segmenter("learned"), "paper", config, progress=False)
    assert result["frames"] == 2 and result["iou"] >= 0.8
    assert 0.0 <= result["side_branch_recall"] <= 1.0


def test_label_parts_names_what_each_pixel_shows() -> None:
    n = 3  # secondaries 2-4, details 5, uprights 6
    labels = np.array([[0, 1, 2, 4, 5, 6], [7, 100, 200, 201, 202, 203], [300, 301, 305, 99, 1, 1]])
    names = np.array(PART_NAMES)[label_parts(labels, n)]
    assert names.tolist() == [
        ["background", "primary", "side_branches", "side_branches", "details", "own_uprights"],
        ["other", "clutter", "sky", "ground", "posts", "wires"],
        ["row_neighbours", "back_rows", "back_rows", "other", "primary", "primary"],
    ]
    with pytest.raises(ValueError, match="labels must be >= 0"):
        label_parts(np.array([[-1]]), n)


class _TakesEverything:
    def segment(self, rgb: np.ndarray, previous_rgb: np.ndarray | None = None) -> np.ndarray:
        return np.ones(rgb.shape[:2], bool)


def test_evaluation_attributes_wrong_pixels_to_what_they_show() -> None:
    """A segmenter that takes every pixel: its false positives are the frame's parts outside
    the tree, in their shares, and it misses nothing."""
    config = EvaluateConfig(trees=1, frames_per_tree=1, world="orchard")
    result = evaluate_segmenter(_TakesEverything(), "paper", config, progress=False)
    _, _, labels, details, _ = next(render_eval_frames("paper", EVAL_SEED_OFFSET, config))
    parts = np.array(PART_NAMES)[label_parts(labels, details - 2)[(labels < 1) | (labels >= 100)]]
    names, counts = np.unique(parts, return_counts=True)
    expected = dict(zip(names.tolist(), (counts / counts.sum()).tolist(), strict=True))
    assert result["false_positive_parts"] == pytest.approx(expected)
    assert {"sky", "ground"} <= set(expected) and result["missed_parts"] == {}
    assert list(result["false_positive_parts"].values()) == sorted(expected.values(), reverse=True)
    assert 0.0 <= result["false_positive_in_front"] < 0.5  # the sky and ground lie behind
