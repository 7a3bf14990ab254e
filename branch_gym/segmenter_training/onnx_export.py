"""Export a segmenter weights file to ONNX, for ONNX Runtime (recon.segmentation.onnx_network).

``python -m branch_gym.segmenter_training export-onnx WEIGHTS.pt`` writes ``WEIGHTS.onnx``
beside it; :func:`branch_gym.segmenter_training.train.export` does the same for every weights
file it writes. The exporter is PyTorch's (``torch.onnx.export(dynamo=True)``), which needs the
``onnx`` and ``onnxscript`` packages (the ``export`` and ``dev`` extras); running the ONNX file
needs only ``onnxruntime``.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import tempfile
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon.segmentation.onnx_network import (
    INPUT_NAME,
    OUTPUT_NAME,
    WEIGHTS_DIGEST_KEY,
    OnnxNetwork,
    onnx_path_for,
    weights_digest,
)
from recon.segmentation.segmenter import fuse_batch_norm
from recon.segmentation.weights import load_weights

logger = logging.getLogger(__name__)

EXPORT_PACKAGES = ("onnx", "onnxscript")
"""What ``torch.onnx.export(dynamo=True)`` imports."""
MAX_SIDE_PX = 4096
"""Largest frame side the exported graph accepts (a bound the exporter asks for)."""
CHECK_TOLERANCE = 1e-3
"""Largest |ONNX - PyTorch| sub-pixel logit accepted when checking an export (float32 rounding
of a BN-folded network is ~1e-5)."""


class _SubpixelLogits(nn.Module):
    """The graph to export: :meth:`SegmenterNet.subpixel_logits` as ``forward``."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model.subpixel_logits(x)


def exporter_available() -> bool:
    """Whether the packages of PyTorch's ONNX exporter are installed."""
    return all(importlib.util.find_spec(name) is not None for name in EXPORT_PACKAGES)


def export_onnx(weights_path: str | Path, seed: int = 0) -> Path:
    """Write the ONNX export of a weights file beside it and check it against PyTorch.

    Args:
        weights_path: A ``.pt`` written by :func:`recon.segmentation.save_weights`.
        seed: Seed of the random check input.

    Returns:
        The ``.onnx`` path (:func:`recon.segmentation.onnx_network.onnx_path_for`).

    Raises:
        RuntimeError: The exporter's packages are missing, or the export's logits differ from
            PyTorch's by more than :data:`CHECK_TOLERANCE`.
        SegmenterWeightsError: A missing or corrupt weights file.
    """
    if not exporter_available():
        raise RuntimeError(
            f"exporting to ONNX needs the packages {EXPORT_PACKAGES}: "
            "pip install 'branch-gym[export]'"
        )
    import onnx  # only the exporter needs it

    weights_path = Path(weights_path)
    model, _, _, _ = load_weights(weights_path)
    graph = _SubpixelLogits(fuse_batch_norm(model)).eval()
    m = model.config.size_multiple
    height = torch.export.Dim("height", min=1, max=MAX_SIDE_PX // m)
    width = torch.export.Dim("width", min=1, max=MAX_SIDE_PX // m)
    example = torch.zeros(1, model.config.in_channels, 15 * m, 20 * m)  # 240 x 320 for m = 16
    program = torch.onnx.export(
        graph,
        (example,),
        dynamo=True,
        input_names=[INPUT_NAME],
        output_names=[OUTPUT_NAME],
        dynamic_shapes={"x": {2: m * height, 3: m * width}},
        verbose=False,
    )
    proto = program.model_proto
    onnx.helper.set_model_props(proto, {WEIGHTS_DIGEST_KEY: weights_digest(weights_path)})
    path = onnx_path_for(weights_path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        onnx.save(proto, tmp)
        os.chmod(tmp, 0o644)
        _check_export(tmp, model, seed)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    logger.info("wrote %s", path)
    return path


def _check_export(onnx_file: str | Path, model: nn.Module, seed: int) -> None:
    """Raise unless the ONNX graph matches ``model`` on a random input of a second size."""
    m = model.config.size_multiple
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.5, 0.5, (1, model.config.in_channels, 7 * m, 9 * m)).astype(np.float32)
    with torch.inference_mode():
        expected = model.eval().subpixel_logits(torch.from_numpy(x)).numpy()
    got = OnnxNetwork(onnx_file)(x)
    error = float(np.abs(got - expected).max()) if got.shape == expected.shape else np.inf
    if error > CHECK_TOLERANCE:
        raise RuntimeError(
            f"the ONNX export of the segmenter differs from PyTorch by {error:.3g} "
            f"(shapes {got.shape} and {expected.shape}; tolerance {CHECK_TOLERANCE})"
        )
