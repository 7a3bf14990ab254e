"""The learned segmenter: RGB (+ the previous frame) -> branch mask, and how to load it.

``load_segmenter("learned")`` loads the shipped weights, package data of this package
(:data:`SHIPPED_WEIGHTS`, its card beside it), in a checkout and in any installed copy alike.
``load_segmenter("learned:PATH")`` loads any other weights file, such as the RGB-only network of
the clean world that was the default before (:data:`RGB_CLEAN_WEIGHTS`).
"""

from __future__ import annotations

import copy
import itertools
import logging

import numpy as np
import torch
from torch import nn

from recon.segmentation.flow import DenseFlowConfig, flow_picture
from recon.segmentation.inputs import FlowConfig, check_flow_image, make_input, make_picture_input
from recon.segmentation.network import SUBPIXELS, SegmenterNet, subpixels_to_image
from recon.segmentation.onnx_network import OnnxNetwork, load_onnx_network
from recon.segmentation.spec import (  # noqa: F401  (torch-free; re-exported here)
    LEARNED_KIND,
    SHIPPED_WEIGHTS,
    WEIGHTS_DIR,
    SegmenterSpec,
    default_weights_path,
    weights_path_of,
)
from recon.segmentation.weights import load_weights

logger = logging.getLogger(__name__)

# The RGB-only network trained on the clean world (issue 15), loadable as learned:PATH.
RGB_CLEAN_WEIGHTS = WEIGHTS_DIR / "rgb_clean.pt"
RUNTIMES = ("auto", "onnxruntime", "torch")
"""What may run the network (:func:`load_segmenter`)."""


def fuse_batch_norm(model: nn.Module) -> nn.Module:
    """A copy of ``model`` with every Conv2d -> BatchNorm2d pair folded into the conv (eval only).

    Args:
        model: A network in eval mode.

    Returns:
        An equivalent network without BatchNorm layers after convolutions (faster on CPU).
    """
    fused = copy.deepcopy(model).eval()
    for module in fused.modules():
        if not isinstance(module, nn.Sequential):
            continue
        children = list(module.named_children())
        for (_, conv), (bn_name, bn) in itertools.pairwise(children):
            if not (isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d)):
                continue
            scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
            bias = conv.bias if conv.bias is not None else torch.zeros_like(bn.running_mean)
            conv.weight = nn.Parameter((conv.weight * scale[:, None, None, None]).detach())
            conv.bias = nn.Parameter(((bias - bn.running_mean) * scale + bn.bias).detach())
            setattr(module, bn_name, nn.Identity())
    return fused


def _is_pointwise(module: nn.Module) -> bool:
    """Whether ``module`` is a 1x1, stride-1, ungrouped convolution (a per-pixel matrix)."""
    return (
        isinstance(module, nn.Conv2d)
        and module.kernel_size == (1, 1)
        and module.stride == (1, 1)
        and module.groups == 1
    )


class PointwiseMatmul(nn.Module):
    """A 1x1 convolution (stride 1, no groups) as one matrix product over channels-last pixels.

    On one thread PyTorch runs 1x1 convolutions through its slow reference kernel (with a copy
    of the input); a matrix product over the (B H W, C) pixels of a channels-last tensor skips
    both. Inference only.

    Args:
        conv: The convolution to replace.
    """

    def __init__(self, conv: nn.Conv2d) -> None:
        super().__init__()
        if not _is_pointwise(conv):
            raise ValueError(f"PointwiseMatmul needs a 1x1, stride-1, ungrouped conv, got {conv}")
        self.weight_t = nn.Parameter(conv.weight.detach()[:, :, 0, 0].t().contiguous(), False)
        bias = conv.bias.detach() if conv.bias is not None else torch.zeros(conv.out_channels)
        self.bias = nn.Parameter(bias.contiguous(), requires_grad=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, H, W) -> (B, C_out, H, W), channels-last."""
        b, c, h, w = x.shape
        pixels = x.permute(0, 2, 3, 1).reshape(b * h * w, c)  # free for channels-last input
        out = torch.addmm(self.bias, pixels, self.weight_t)
        return out.reshape(b, h, w, -1).permute(0, 3, 1, 2)


def inference_network(model: nn.Module) -> nn.Module:
    """The fastest equivalent of a network on one CPU thread: BN folded, 1x1 convs as matmuls.

    Args:
        model: A :class:`SegmenterNet` (any mode).

    Returns:
        An eval-mode, channels-last copy (outputs equal to ``model.eval()``'s within float
        rounding).
    """
    fused = fuse_batch_norm(model).to(memory_format=torch.channels_last)
    for module in list(fused.modules()):
        for name, child in list(module.named_children()):
            if _is_pointwise(child):
                setattr(module, name, PointwiseMatmul(child))
    return fused


class LearnedSegmenter:
    """A trained :class:`SegmenterNet` wrapped for single frames.

    Args:
        model: The network (any mode; a BN-folded eval copy is used).
        flow: Flow normalisation the network was trained with (flow-vector networks).
        threshold: Branch probability threshold.
        source: Where the weights came from (for messages).
        dense_flow: How a flow-picture network computes the flow from ``previous_rgb``.
        onnx_network: The same network exported to ONNX
            (:mod:`recon.segmentation.onnx_network`), run by ONNX Runtime instead of PyTorch
            (about twice as fast on one core); None runs ``model`` on PyTorch.
    """

    def __init__(
        self,
        model: SegmenterNet,
        flow: FlowConfig | None = None,
        threshold: float = 0.5,
        source: str = "<memory>",
        dense_flow: DenseFlowConfig | None = None,
        onnx_network: OnnxNetwork | None = None,
    ) -> None:
        self.config = model.config
        self.flow = flow or FlowConfig()
        self.dense_flow = dense_flow or DenseFlowConfig()
        self.threshold = float(threshold)
        self.source = source
        self._net = inference_network(model)
        self._onnx = onnx_network
        self._logit_threshold = float(np.log(threshold / (1.0 - threshold)))

    @property
    def runtime(self) -> str:
        """What runs the network: ``"onnxruntime"`` or ``"torch"``."""
        return "torch" if self._onnx is None else "onnxruntime"

    @property
    def uses_flow(self) -> bool:
        """Whether ``previous_rgb`` (or ``flow_image``) is used (optical flow input)."""
        return self.config.use_flow

    @property
    def uses_flow_picture(self) -> bool:
        """Whether the network reads the flow as the colour-wheel picture (the paper's input)."""
        return self.config.flow_picture

    def input(
        self,
        rgb: np.ndarray,
        previous_rgb: np.ndarray | None = None,
        flow_image: np.ndarray | None = None,
    ) -> np.ndarray:
        """The network input of one frame (see :meth:`segment` for the arguments).

        Returns:
            (C, H, W) float32 input.
        """
        if previous_rgb is not None and flow_image is not None:
            raise ValueError("give previous_rgb or flow_image, not both")
        if flow_image is not None:
            check_flow_image(flow_image, rgb)
            if self.config.use_flow and not self.config.flow_picture:
                raise ValueError(
                    f"segmenter {self.source} reads flow vectors, not a flow picture: pass "
                    "previous_rgb instead of flow_image"
                )
        if not self.config.flow_picture:
            previous_rgb = previous_rgb if self.config.use_flow else None
            return make_input(rgb, previous_rgb, self.config.use_flow, self.flow)
        if previous_rgb is not None:
            if previous_rgb.shape != rgb.shape or previous_rgb.dtype != np.uint8:
                raise ValueError(
                    f"previous_rgb must be a uint8 image of the frame's shape {rgb.shape}, got "
                    f"{previous_rgb.dtype} {previous_rgb.shape}"
                )
            flow_image = flow_picture(previous_rgb, rgb, self.dense_flow)
        return make_picture_input(rgb, flow_image)

    def logits(
        self,
        rgb: np.ndarray,
        previous_rgb: np.ndarray | None = None,
        flow_image: np.ndarray | None = None,
    ) -> np.ndarray:
        """Branch logits of one frame (see :meth:`segment` for the arguments).

        Returns:
            (H, W) float32 logits (> logit(threshold): branch).
        """
        subpixels, (h, w) = self._subpixel_logits(rgb, previous_rgb, flow_image)
        return subpixels_to_image(subpixels)[:h, :w]

    def _subpixel_logits(
        self, rgb: np.ndarray, previous_rgb: np.ndarray | None, flow_image: np.ndarray | None
    ) -> tuple[np.ndarray, tuple[int, int]]:
        """(4, H' / 2, W' / 2) branch sub-pixel logits of the padded frame, and its (H, W)."""
        x = self.input(rgb, previous_rgb, flow_image)
        h, w = x.shape[1:]
        m = self.config.size_multiple
        pad_h, pad_w = (-h) % m, (-w) % m
        if pad_h or pad_w:
            x = np.pad(x, ((0, 0), (0, pad_h), (0, pad_w)), mode="edge")
        if self._onnx is not None:
            return self._onnx(x[None])[0, :SUBPIXELS], (h, w)
        with torch.inference_mode():
            # NCHW input measured faster than a channels_last copy
            out = self._net.subpixel_logits(torch.from_numpy(x)[None])
        return out[0, :SUBPIXELS].numpy(), (h, w)

    def segment(
        self,
        rgb: np.ndarray,
        previous_rgb: np.ndarray | None = None,
        flow_image: np.ndarray | None = None,
    ) -> np.ndarray:
        """Mask of the scanned tree in one frame.

        Args:
            rgb: (H, W, 3) uint8 RGB frame.
            previous_rgb: (H, W, 3) uint8 earlier frame to take the flow against (the camera
                moved >= 7.5 mm and turned < 0.5 deg since: :class:`recon.segmentation.flow.
                FramePairer`), or None. The segmenter computes the flow (DIS,
                ``dense_flow``) and codes it as the paper's picture.
            flow_image: (H, W, 3) uint8 RGB colour-wheel flow picture of the frame from any
                flow method (:func:`recon.segmentation.flow.flow_to_picture`), instead of
                ``previous_rgb``. With neither, the frame is segmented from its colours alone
                (a flow network then sees zero flow). A network without flow input ignores both.

        Returns:
            (H, W) bool mask, True on the scanned tree's branches.

        Raises:
            ValueError: A malformed ``rgb``, ``previous_rgb`` or ``flow_image`` (dtype, shape,
                another size than ``rgb``), both given, or a flow picture for a network that
                reads flow vectors.
        """
        subpixels, (h, w) = self._subpixel_logits(rgb, previous_rgb, flow_image)
        # Thresholded before depth-to-space (a permutation): the same mask, less to move.
        return subpixels_to_image(subpixels > self._logit_threshold)[:h, :w]


def load_segmenter(
    spec: str | SegmenterSpec = LEARNED_KIND, runtime: str = "auto"
) -> LearnedSegmenter:
    """Load a learned segmenter from a spec.

    Args:
        spec: ``"learned"`` (the shipped weights, :func:`default_weights_path`) or
            ``"learned:PATH"`` (a weights file written by :func:`recon.segmentation.save_weights`),
            as text or a parsed :class:`recon.segmentation.spec.SegmenterSpec`.
        runtime: What runs the network (one of :data:`RUNTIMES`): ``"auto"``, ONNX Runtime where
            an ONNX export of these weights lies beside them
            (:func:`recon.segmentation.onnx_network.load_onnx_network`; the shipped weights have
            one), else PyTorch; ``"onnxruntime"`` requires that export; ``"torch"`` always uses
            PyTorch. ONNX Runtime gets as many threads as PyTorch (``torch.get_num_threads()``).

    Returns:
        The segmenter.

    Raises:
        ValueError: Unknown spec or runtime, or ``runtime="onnxruntime"`` without a current
            export.
        SegmenterWeightsError: Missing, corrupt or mismatched weights file (or ONNX export).
    """
    if runtime not in RUNTIMES:
        raise ValueError(f"segmenter runtime must be one of {RUNTIMES}, got {runtime!r}")
    path = weights_path_of(spec)
    model, flow, threshold, _meta = load_weights(path)
    onnx_network = None
    if runtime != "torch":
        onnx_network = load_onnx_network(path, threads=torch.get_num_threads())
        if onnx_network is None and runtime == "onnxruntime":
            raise ValueError(
                f"segmenter runtime 'onnxruntime' needs an ONNX export of {path} beside it: "
                f"python -m branch_gym.segmenter_training export-onnx {path}"
            )
    segmenter = LearnedSegmenter(
        model, flow, threshold, source=str(path), onnx_network=onnx_network
    )
    logger.info(
        "loaded segmenter %s (flow input: %s, runtime: %s)",
        path, model.config.use_flow, segmenter.runtime,
    )  # fmt: skip
    return segmenter
