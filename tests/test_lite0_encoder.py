"""The EfficientNet-Lite0 encoder of the segmenter: ImageNet start, weights file, ONNX export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from branch_gym.segmenter_training.onnx_export import exporter_available
from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import (
    LITE0_ENCODER,
    LITE0_WIDTHS,
    SegmenterNet,
    SegmenterNetConfig,
    load_lite0_imagenet,
)
from recon.segmentation.segmenter import load_segmenter
from recon.segmentation.weights import load_weights, save_weights

efficientnet_lite = pytest.importorskip("efficientnet_lite_pytorch")

LITE0_NET = SegmenterNetConfig(
    use_flow=True, flow_picture=True, widths=LITE0_WIDTHS, encoder=LITE0_ENCODER
)


def _reference_network() -> torch.nn.Module:
    """A whole EfficientNet-Lite0, random weights and BN statistics: a stand-in for ImageNet."""
    torch.manual_seed(3)
    reference = efficientnet_lite.EfficientNet.from_name("efficientnet-lite0")
    with torch.no_grad():
        for module in reference.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.2, 0.2)
                module.running_var.uniform_(0.5, 2.0)
    return reference.eval()


def test_config_names_a_bad_encoder_or_widths() -> None:
    with pytest.raises(ValueError, match="encoder must be one of"):
        SegmenterNetConfig(encoder="resnet50")
    with pytest.raises(ValueError, match="widths"):
        SegmenterNetConfig(encoder=LITE0_ENCODER)  # the small encoder's widths
    assert SegmenterNetConfig.from_dict(LITE0_NET.to_dict()) == LITE0_NET
    assert SegmenterNetConfig().encoder == "small"  # weights files written before still load


def test_imagenet_start_reproduces_the_reference_features() -> None:
    """RGB in [-0.5, 0.5] through the encoder = the reference on its [-1, 1] input, any flow."""
    reference = _reference_network()
    net = SegmenterNet(LITE0_NET).eval()
    load_lite0_imagenet(net.lite0, reference.state_dict())
    rgb01 = torch.rand(1, 3, 96, 128)
    flow_picture = torch.rand(1, 3, 96, 128) - 0.5
    with torch.no_grad():
        features = net.lite0(torch.cat([rgb01 - 0.5, flow_picture], dim=1))
        expected = reference._swish(reference._bn0(reference._conv_stem((rgb01 - 0.5) / 0.5)))
        outputs = []
        for index, block in enumerate(reference._blocks[:8]):
            expected = block(expected)
            if index in (0, 2, 4, 7):
                outputs.append(expected)
    assert [f.shape[1] for f in features] == list(LITE0_WIDTHS)
    assert [f.shape[2:] for f in features] == [(48, 64), (24, 32), (12, 16), (6, 8)]
    for got, want in zip(features, outputs, strict=True):
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    assert torch.count_nonzero(net.lite0.stem[0].weight[:, 3:]) == 0  # the flow starts unused
    encoder = {id(p) for p in net.encoder_parameters()}  # what --encoder-learning-rate-scale scales
    assert encoder == {id(p) for p in net.lite0.parameters()}
    assert not encoder & {id(p) for p in net.head.parameters()}


def test_imagenet_start_names_a_missing_or_misshapen_weight() -> None:
    net = SegmenterNet(LITE0_NET)
    weights = _reference_network().state_dict()
    missing = {k: v for k, v in weights.items() if not k.startswith("_blocks.6.")}
    with pytest.raises(ValueError, match=r"_blocks\.6\."):
        load_lite0_imagenet(net.lite0, missing)
    misshapen = dict(weights, **{"_bn0.weight": torch.ones(7)})
    with pytest.raises(ValueError, match=r"_bn0\.weight"):
        load_lite0_imagenet(net.lite0, misshapen)


@pytest.mark.skipif(not exporter_available(), reason="needs the export extra (onnx, onnxscript)")
def test_weights_file_and_onnx_export_keep_the_lite0_network(tmp_path: Path) -> None:
    from branch_gym.segmenter_training.onnx_export import export_onnx

    net = SegmenterNet(LITE0_NET).eval()
    load_lite0_imagenet(net.lite0, _reference_network().state_dict())
    weights = save_weights(tmp_path / "lite0.pt", net, FlowConfig(), threshold=0.5)
    loaded, _, _, _ = load_weights(weights)
    assert loaded.config == LITE0_NET
    export_onnx(weights)
    rng = np.random.default_rng(0)
    previous = rng.integers(0, 256, (100, 140, 3), dtype=np.uint8)  # not a multiple of 16
    rgb = np.roll(previous, 2, axis=1)
    onnx_segmenter = load_segmenter(f"learned:{weights}")
    torch_segmenter = load_segmenter(f"learned:{weights}", runtime="torch")
    assert onnx_segmenter.runtime == "onnxruntime"
    np.testing.assert_allclose(
        onnx_segmenter.logits(rgb, previous), torch_segmenter.logits(rgb, previous), atol=1e-3
    )
