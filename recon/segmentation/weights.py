"""Saving and loading segmenter weights together with their configuration.

A weights file is a ``torch.save`` dict (loaded with ``weights_only=True``: tensors and plain
values only, no code runs on load)::

    {"format": "branch_gym.segmenter", "version": 1, "net": SegmenterNetConfig.to_dict(),
     "flow": FlowConfig fields, "threshold": float, "state_dict": ..., "meta": {...}}

Every failure to load (missing file, not a torch file, wrong format, a state dict that does not
fit the stored architecture) raises :class:`SegmenterWeightsError` naming the file.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import asdict
from pathlib import Path

import torch

from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import SegmenterNet, SegmenterNetConfig

WEIGHTS_FORMAT = "branch_gym.segmenter"
WEIGHTS_VERSION = 1


class SegmenterWeightsError(ValueError):
    """A segmenter weights file is missing, unreadable or does not match its architecture."""


def save_weights(
    path: str | Path,
    model: SegmenterNet,
    flow: FlowConfig,
    threshold: float = 0.5,
    meta: dict | None = None,
) -> Path:
    """Write ``model`` and its configuration to ``path`` atomically (temp file + rename).

    Args:
        path: Destination (``.pt``).
        model: The network (its ``config`` is stored).
        flow: Flow normalisation used in training.
        threshold: Probability above which a pixel is branch.
        meta: Extra JSON-able information (training seed, steps, ...).

    Returns:
        The path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": WEIGHTS_FORMAT,
        "version": WEIGHTS_VERSION,
        "net": model.config.to_dict(),
        "flow": asdict(flow),
        "threshold": float(threshold),
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        "meta": dict(meta or {}),
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes it owner-only; a shipped file must be readable
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def load_weights(path: str | Path) -> tuple[SegmenterNet, FlowConfig, float, dict]:
    """Read a weights file written by :func:`save_weights`.

    Args:
        path: The ``.pt`` file.

    Returns:
        (model in eval mode, flow config, threshold, meta).

    Raises:
        SegmenterWeightsError: Missing, corrupt or mismatched file (the message names it).
    """
    path = Path(path)
    if not path.is_file():
        raise SegmenterWeightsError(f"segmenter weights file {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types for a damaged file
        raise SegmenterWeightsError(
            f"segmenter weights file {path} is not a readable torch file: {error}"
        ) from error
    if not isinstance(payload, dict) or payload.get("format") != WEIGHTS_FORMAT:
        raise SegmenterWeightsError(
            f"segmenter weights file {path} is not a {WEIGHTS_FORMAT} file "
            "(write it with recon.segmentation.save_weights)"
        )
    if payload.get("version") != WEIGHTS_VERSION:
        raise SegmenterWeightsError(
            f"segmenter weights file {path} has version {payload.get('version')}, "
            f"this code reads version {WEIGHTS_VERSION}"
        )
    try:
        config = SegmenterNetConfig.from_dict(payload["net"])
        flow = FlowConfig(**payload["flow"])
        threshold = float(payload["threshold"])
        model = SegmenterNet(config)
        model.load_state_dict(payload["state_dict"], strict=True)
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        raise SegmenterWeightsError(
            f"segmenter weights file {path} does not match its stored architecture: {error}"
        ) from error
    model.eval()
    return model, flow, threshold, dict(payload.get("meta", {}))
