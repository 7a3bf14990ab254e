"""Network inputs: RGB normalisation and the optical flow from the previous frame.

The flow is OpenCV's DIS flow (``ULTRAFAST`` preset, ~1 ms for 320x240 on one core) from the
previous frame to the current one, the paper's extra input (section III). Its scale depends on the
camera speed and on the frame spacing, which the segmenter does not know, so it is divided by a
robust scale of the frame's own flow (a high percentile of its magnitude): what is left is the
relative motion (near branches move more than the background behind them under translation).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recon.segmentation.network import FLOW_CHANNELS, RGB_CHANNELS

_RGB_SCALE = 1.0 / 255.0
_RGB_CENTER = 0.5


@dataclass(frozen=True)
class FlowConfig:
    """How the flow input is computed.

    Attributes:
        scale_percentile: Percentile of the flow magnitude that the flow is divided by.
        min_scale_px: Floor of that scale, so a still camera gives near-zero flow, not noise.
        clip: Normalised flow components are clipped to [-clip, clip].
    """

    scale_percentile: float = 90.0
    min_scale_px: float = 1.0
    clip: float = 3.0


def dis_flow(previous_rgb: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Dense optical flow from ``previous_rgb`` to ``rgb``.

    Args:
        previous_rgb: (H, W, 3) uint8 earlier frame.
        rgb: (H, W, 3) uint8 current frame.

    Returns:
        (H, W, 2) float32 flow in pixels (dx, dy): where each pixel of the previous frame went.
    """
    if previous_rgb.shape != rgb.shape:
        raise ValueError(f"previous_rgb {previous_rgb.shape} and rgb {rgb.shape} differ in shape")
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    prev_gray = cv2.cvtColor(previous_rgb, cv2.COLOR_RGB2GRAY)
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return dis.calc(prev_gray, gray, None)


def normalise_flow(flow: np.ndarray, config: FlowConfig | None = None) -> np.ndarray:
    """Divide a flow field by its robust scale.

    Args:
        flow: (H, W, 2) float flow in pixels.
        config: Scale and clipping.

    Returns:
        (H, W, 2) float32 flow in units of the frame's flow scale, clipped.
    """
    config = config or FlowConfig()
    # The percentile of every 2nd pixel in each direction: the same scale at a quarter the cost.
    sample = flow[::2, ::2].reshape(-1, 2)
    squared = sample[:, 0] * sample[:, 0] + sample[:, 1] * sample[:, 1]
    k = min(len(squared) - 1, int(config.scale_percentile / 100.0 * (len(squared) - 1) + 0.5))
    scale = max(float(np.sqrt(np.partition(squared, k)[k])), config.min_scale_px)
    return np.clip(flow * np.float32(1.0 / scale), -config.clip, config.clip).astype(np.float32)


def make_input(
    rgb: np.ndarray,
    previous_rgb: np.ndarray | None = None,
    use_flow: bool = True,
    flow_config: FlowConfig | None = None,
) -> np.ndarray:
    """The network input of one frame.

    Args:
        rgb: (H, W, 3) uint8 frame.
        previous_rgb: (H, W, 3) uint8 previous frame, or None (first frame: flow planes are 0).
        use_flow: Append the flow planes (the network's ``config.use_flow``).
        flow_config: Flow normalisation.

    Returns:
        (C, H, W) float32: RGB in [-0.5, 0.5], then (with flow) normalised dx, dy and a validity
        plane (1 with a previous frame, else 0).
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be a (H, W, 3) uint8 image, got {rgb.dtype} {rgb.shape}")
    h, w = rgb.shape[:2]
    out = np.zeros((RGB_CHANNELS + (FLOW_CHANNELS if use_flow else 0), h, w), np.float32)
    np.multiply(rgb.transpose(2, 0, 1), np.float32(_RGB_SCALE), out=out[:RGB_CHANNELS])
    out[:RGB_CHANNELS] -= np.float32(_RGB_CENTER)
    if use_flow and previous_rgb is not None:
        flow = normalise_flow(dis_flow(previous_rgb, rgb), flow_config)
        out[RGB_CHANNELS : RGB_CHANNELS + 2] = flow.transpose(2, 0, 1)
        out[RGB_CHANNELS + 2] = 1.0
    return out


def check_flow_image(flow_image: object, rgb: np.ndarray) -> np.ndarray:
    """Validate a flow picture against its frame.

    Args:
        flow_image: Candidate (H, W, 3) uint8 RGB colour-wheel flow picture.
        rgb: (H, W, 3) uint8 frame it belongs to.

    Returns:
        ``flow_image`` as an array.

    Raises:
        ValueError: Not an (H, W, 3) uint8 array, or another size than ``rgb``.
    """
    if not isinstance(flow_image, np.ndarray):
        raise ValueError(f"flow_image must be a numpy array, got {type(flow_image).__name__}")
    if flow_image.dtype != np.uint8 or flow_image.ndim != 3 or flow_image.shape[2] != 3:
        raise ValueError(
            f"flow_image must be an (H, W, 3) uint8 RGB flow picture, got {flow_image.dtype} "
            f"{flow_image.shape}"
        )
    if flow_image.shape != rgb.shape:
        raise ValueError(
            f"flow_image has shape {flow_image.shape} but rgb has {rgb.shape}: resize the flow "
            "picture to the frame"
        )
    return flow_image


def make_picture_input(rgb: np.ndarray, flow_image: np.ndarray | None) -> np.ndarray:
    """The input of a network that reads the flow picture (``SegmenterNetConfig.flow_picture``).

    Args:
        rgb: (H, W, 3) uint8 frame.
        flow_image: (H, W, 3) uint8 RGB colour-wheel flow picture of the frame, or None (no
            flow: a white picture, zero motion everywhere).

    Returns:
        (6, H, W) float32: RGB, then the flow picture's RGB, each in [-0.5, 0.5].

    Raises:
        ValueError: ``rgb`` or ``flow_image`` malformed or of different sizes.
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be a (H, W, 3) uint8 image, got {rgb.dtype} {rgb.shape}")
    h, w = rgb.shape[:2]
    out = np.empty((RGB_CHANNELS + FLOW_CHANNELS, h, w), np.float32)
    np.multiply(rgb.transpose(2, 0, 1), np.float32(_RGB_SCALE), out=out[:RGB_CHANNELS])
    if flow_image is None:
        out[RGB_CHANNELS:] = 1.0
    else:
        check_flow_image(flow_image, rgb)
        np.multiply(flow_image.transpose(2, 0, 1), np.float32(_RGB_SCALE), out=out[RGB_CHANNELS:])
    out -= np.float32(_RGB_CENTER)
    return out
