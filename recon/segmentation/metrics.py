"""Mask agreement figures."""

from __future__ import annotations

import numpy as np


def mask_iou(predicted: np.ndarray, target: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty).

    Args:
        predicted: (H, W) bool mask.
        target: (H, W) bool mask.

    Returns:
        |predicted & target| / |predicted | target|.
    """
    if predicted.shape != target.shape:
        raise ValueError(f"mask shapes differ: {predicted.shape} vs {target.shape}")
    union = int(np.count_nonzero(predicted | target))
    if union == 0:
        return 1.0
    return int(np.count_nonzero(predicted & target)) / union


def pooled_iou(intersections: int, unions: int) -> float:
    """IoU pooled over frames: total intersection over total union (1.0 when nothing is there)."""
    return 1.0 if unions == 0 else intersections / unions
