"""A small U-Net-like fully convolutional branch segmenter.

The network sees a 320x240 RGB frame (optionally with the optical flow from the previous frame,
the paper's input, section III) and returns one logit per pixel: branch (primary or secondary of
the scanned tree) versus everything else. To run in a few milliseconds on one CPU core the
encoder starts with a stride-2 convolution and the decoder stops at half resolution, where a 1x1
convolution predicts 2x2 sub-pixel logits (depth-to-space), so thin (2-5 px) secondaries keep
their edges. Skip connections are added (after a 1x1 projection), not concatenated, and the 3x3
convolutions after the stem are depthwise-separable: the cost is a few hundred MFLOP a frame.
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
    """

    use_flow: bool = False
    flow_picture: bool = False
    widths: tuple[int, ...] = (16, 32, 64, 128)
    decoder_widths: tuple[int, ...] = (64, 32, 16)
    separable: bool = True
    primary_head: bool = False

    def __post_init__(self) -> None:
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
