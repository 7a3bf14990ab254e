"""The segmenter on ONNX Runtime: the shipped exports are current and give PyTorch's masks."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from branch_gym.segmenter_training.onnx_export import export_onnx, exporter_available
from recon.segmentation.flow import DenseFlowConfig, flow_picture
from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import SegmenterNet, SegmenterNetConfig
from recon.segmentation.onnx_network import load_onnx_network, onnx_path_for
from recon.segmentation.segmenter import (
    RGB_CLEAN_WEIGHTS,
    SHIPPED_WEIGHTS,
    load_segmenter,
)
from recon.segmentation.weights import SegmenterWeightsError, save_weights

TINY_NET = SegmenterNetConfig(
    use_flow=True, flow_picture=True, widths=(8, 16, 16, 16), decoder_widths=(16, 16, 8)
)


def _branch_frames(height: int, width: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two frames of a brown bar on a textured background, the bar moved 4 px between them."""
    rng = np.random.default_rng(seed)
    background = rng.integers(60, 200, (height, width, 3), dtype=np.uint8)
    frames = []
    for shift in (0, 4):
        frame = background.copy()
        x0 = width // 3 + shift
        frame[:, x0 : x0 + 12] = (110, 80, 50)
        frame[height // 2 : height // 2 + 5, x0 : x0 + width // 3] = (120, 90, 60)
        frames.append(frame)
    return frames[0], frames[1]


# The EfficientNet-Lite0 network (docs/orchard_segmenter.md), loadable as learned:PATH.
LITE0_WEIGHTS = SHIPPED_WEIGHTS.with_name("orchard_flow_lite0.pt")
# The side branches' skeleton-recall fine-tune (issue 61), opt-in as learned:PATH.
SIDE_WEIGHTS = SHIPPED_WEIGHTS.with_name("orchard_flow_side.pt")


@pytest.mark.parametrize(
    "weights",
    [SHIPPED_WEIGHTS, RGB_CLEAN_WEIGHTS, LITE0_WEIGHTS, SIDE_WEIGHTS],
    ids=lambda p: p.stem,
)
def test_shipped_weights_have_a_current_onnx_export(weights: Path) -> None:
    if weights == LITE0_WEIGHTS:
        pytest.importorskip("efficientnet_lite_pytorch")  # its PyTorch runtime needs the blocks
    assert load_onnx_network(weights) is not None, f"re-export {weights} (export-onnx)"
    spec = "learned" if weights == SHIPPED_WEIGHTS else f"learned:{weights}"
    assert load_segmenter(spec).runtime == "onnxruntime"
    assert load_segmenter(spec, runtime="torch").runtime == "torch"


@pytest.mark.parametrize("size", [(240, 320), (230, 300)], ids=["320x240", "unpadded"])
def test_shipped_onnx_masks_equal_torch_masks(size: tuple[int, int]) -> None:
    onnx_segmenter = load_segmenter("learned", runtime="onnxruntime")
    torch_segmenter = load_segmenter("learned", runtime="torch")
    previous, rgb = _branch_frames(*size, seed=3)
    picture = flow_picture(previous, rgb, DenseFlowConfig())
    for kwargs in ({"previous_rgb": previous}, {"flow_image": picture}, {}):
        onnx_logits = onnx_segmenter.logits(rgb, **kwargs)
        torch_logits = torch_segmenter.logits(rgb, **kwargs)
        assert onnx_logits.shape == size
        np.testing.assert_allclose(onnx_logits, torch_logits, atol=1e-3)
        onnx_mask = onnx_segmenter.segment(rgb, **kwargs)
        torch_mask = torch_segmenter.segment(rgb, **kwargs)
        assert torch_mask.any(), "the constructed bar should be segmented"
        assert (onnx_mask == torch_mask).mean() >= 0.9999


def test_bad_runtime_and_corrupt_onnx_are_named(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="runtime"):
        load_segmenter("learned", runtime="tensorrt")
    torch.manual_seed(0)
    weights = save_weights(tmp_path / "w.pt", SegmenterNet(TINY_NET), FlowConfig())
    with pytest.raises(ValueError, match="export-onnx"):
        load_segmenter(f"learned:{weights}", runtime="onnxruntime")
    assert load_segmenter(f"learned:{weights}").runtime == "torch"  # no export: PyTorch
    onnx_path_for(weights).write_bytes(b"not an onnx model")
    with pytest.raises(SegmenterWeightsError, match=r"w\.onnx"):
        load_segmenter(f"learned:{weights}")


@pytest.mark.skipif(not exporter_available(), reason="needs the export extra (onnx, onnxscript)")
def test_export_round_trip_and_stale_export(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    torch.manual_seed(0)
    net = SegmenterNet(TINY_NET)
    with torch.no_grad():  # BN statistics away from the identity, so that folding them matters
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    weights = save_weights(tmp_path / "tiny.pt", net, FlowConfig(), threshold=0.5)
    export_onnx(weights)
    previous, rgb = _branch_frames(100, 140, seed=1)  # 140 x 100: not a multiple of 16
    onnx_segmenter = load_segmenter(f"learned:{weights}")
    torch_segmenter = load_segmenter(f"learned:{weights}", runtime="torch")
    assert onnx_segmenter.runtime == "onnxruntime"
    np.testing.assert_allclose(
        onnx_segmenter.logits(rgb, previous), torch_segmenter.logits(rgb, previous), atol=1e-4
    )

    torch.manual_seed(1)  # other weights written over the .pt: the export is now stale
    save_weights(weights, SegmenterNet(TINY_NET), FlowConfig())
    with caplog.at_level(logging.WARNING, logger="recon.segmentation.onnx_network"):
        stale = load_segmenter(f"learned:{weights}")
    assert stale.runtime == "torch"
    assert "other weights" in caplog.text
    with pytest.raises(ValueError, match="export-onnx"):
        load_segmenter(f"learned:{weights}", runtime="onnxruntime")
