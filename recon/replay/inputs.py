"""What a replay reads besides the frames: its segmenter, tracker, modeler settings, ground truth
and working focal length.
"""

from __future__ import annotations

import importlib
import json
import logging
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from recon.config import REMOVED_MODELER_FIELDS, ModelerConfig, removed_field_message
from recon.curve2d.types import Curve2DConfig
from recon.io.folder import ScanFormatError
from recon.io.rescale import PIPELINE_FOCAL_PX, RescaledSource
from recon.io.source import ScanSource
from recon.metrics import MetricsConfig
from recon.model import BranchModel, TreeModel
from recon.segmentation.spec import SegmenterSpec, SpecKind, is_learned_segmenter

logger = logging.getLogger(__name__)

TRACKERS = ("lk",)
"""The trackers a recording can run (:func:`recon.tracking.make_tracker`; it has no depth for the
oracle)."""


class ReplayError(RuntimeError):
    """The replay cannot run (no masks and no segmenter, segmenter missing, ...)."""


class ReplaySegmenterSpec(SegmenterSpec):
    """A replay's segmenter spec: ``mask`` (the recording's masks) or recon's ``learned[:PATH]``."""

    KINDS: ClassVar = {"mask": SpecKind(), **SegmenterSpec.KINDS}


def load_segmenter(spec: str | None):
    """None for masks from the recording; ``learned`` / ``learned:PATH`` -> recon.segmentation.

    Returns:
        None, or an object with ``segment(rgb, previous_rgb=None) -> (H, W) bool`` (a
        :class:`recon.segmentation.LearnedSegmenter`).

    Raises:
        ValueError: an unknown spec.
        ReplayError: ``recon.segmentation`` (the learned RGB segmenter) is not available.
    """
    if spec is None:
        return None
    parsed = ReplaySegmenterSpec.parse(spec)
    if not parsed.is_learned:
        return None
    try:
        module = importlib.import_module("recon.segmentation")
    except ImportError as error:
        raise ReplayError(
            f"--segmenter {spec} needs the learned RGB segmenter (recon.segmentation), which "
            f"cannot be imported here ({error})"
        ) from error
    loader = getattr(module, "load_segmenter", None)
    if loader is None:
        raise ReplayError(
            f"--segmenter {spec}: recon.segmentation has no load_segmenter(spec) in this "
            "checkout (the learned segmenter is not available yet)"
        )
    return loader(str(parsed))


def modeler_settings(
    metadata: dict, seed: int | None, config: ModelerConfig | None
) -> tuple[int, ModelerConfig]:
    """The seed and config: explicit values, else the recording's metadata, else defaults.

    A recorded field that has been removed since (:data:`recon.config.REMOVED_MODELER_FIELDS`)
    is dropped, with a warning naming it where the recording ran another value than today's
    code runs.
    """
    recorded = metadata.get("modeler", {}) if isinstance(metadata, dict) else {}
    if seed is None:
        seed = int(recorded.get("seed", 0))
    if config is None:
        values = recorded.get("config") or {}
        for name in sorted(set(values) & set(REMOVED_MODELER_FIELDS)):
            if values[name] != REMOVED_MODELER_FIELDS[name].value:
                logger.warning("the recording ran %s=%r: %s", name, values[name],
                               removed_field_message(name))  # fmt: skip
        known = {f.name for f in fields(ModelerConfig)}
        unknown = sorted(set(values) - known - set(REMOVED_MODELER_FIELDS))
        if unknown:
            logger.warning("ignoring unknown recorded ModelerConfig fields %s", unknown)
        config = ModelerConfig(**{k: v for k, v in values.items() if k in known})
    return seed, config


def curve_settings(metadata: dict, config: Curve2DConfig | None) -> Curve2DConfig:
    """The 2D stage's settings: ``config``, else the recording's, else the defaults.

    A branch_gym recording holds them as ``modeler.curve2d`` of its ``metadata.json`` (the
    scan's ``ScanConfig.curve2d``); one made before, or elsewhere, ran the defaults. Recorded
    fields unknown today are dropped with a warning.
    """
    if config is not None:
        return config
    recorded = metadata.get("modeler", {}) if isinstance(metadata, dict) else {}
    values = recorded.get("curve2d") if isinstance(recorded, dict) else None
    return _config_from(Curve2DConfig, values) if isinstance(values, dict) else Curve2DConfig()


def _config_from(cls: type, values: dict) -> Any:
    """A config dataclass from its ``asdict`` form (nested configs and tuples rebuilt)."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        logger.warning("ignoring unknown recorded %s fields %s", cls.__name__, unknown)
    defaults = cls()
    changes = {}
    for name in known & set(values):
        value, default = values[name], getattr(defaults, name)
        if is_dataclass(default) and isinstance(value, dict):
            value = _config_from(type(default), value)
        elif isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        elif isinstance(default, float) and isinstance(value, str):  # "inf", strict JSON's form
            value = float(value)
        changes[name] = value
    return cls(**changes)


def learned_masks(source: ScanSource) -> bool:
    """The recorded masks come from a learned segmenter (a branch_gym recording says so)."""
    scan = source.metadata.get("scan", {}) if isinstance(source.metadata, dict) else {}
    return isinstance(scan, dict) and is_learned_segmenter(scan.get("segmenter"))


def load_truth(path: str | Path) -> TreeModel:
    """Ground truth JSON (branch_gym's TreeGT: ``primary`` and ``secondaries`` with points/radii).

    Raises:
        ScanFormatError: unreadable, or no primary branch.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        truth = TreeModel.from_dict(data)
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ScanFormatError(f"{path}: cannot read ground truth ({error})") from None
    if truth.primary is None:
        raise ScanFormatError(f"{path}: ground truth has no primary branch")
    return truth


def at_working_focal_length(
    source: ScanSource, focal_px: float | str | None, segmenter: str | object | None
) -> ScanSource:
    """``source`` resized to the working focal length of :func:`replay` (its docstring)."""
    if focal_px == "auto":
        learned = isinstance(segmenter, str) and is_learned_segmenter(segmenter)
        focal_px = PIPELINE_FOCAL_PX if learned else None
    if focal_px is None:
        return source
    if isinstance(focal_px, str):
        raise ValueError(f"working_focal_px must be a number, 'auto' or None, got {focal_px!r}")
    rescaled = RescaledSource(source, focal_px)
    intrinsics = source.intrinsics
    return source if rescaled.size == (intrinsics.width, intrinsics.height) else rescaled


@dataclass(frozen=True)
class Scoring:
    """How a recording with ground truth is scored: as the scan that recorded it was.

    Attributes:
        config: The scoring rules (the recording's ``scoring.metrics``, else the authors').
        planned_top_z_m: The height the scan was to reach (m), None when not recorded: then
            the scope ends where the scan did.
        surroundings: The structures around the tree by kind (``scoring.surroundings``, a JSON
            file of ``{kind: [{"points", "radii"}]}``), empty when not recorded.
    """

    config: MetricsConfig = field(default_factory=MetricsConfig)
    planned_top_z_m: float | None = None
    surroundings: dict[str, list[BranchModel]] = field(default_factory=dict)


def load_scoring(source: ScanSource) -> Scoring:
    """The scoring a simulated recording carries in its metadata (``scoring``), or the authors'.

    Raises:
        ScanFormatError: a malformed ``scoring`` entry or an unreadable surroundings file.
    """
    recorded = source.metadata.get("scoring")
    if recorded is None:
        return Scoring()
    try:
        config = MetricsConfig(**recorded["metrics"])
        planned = float(recorded["planned_top_z_m"])
        surroundings = {}
        folder = getattr(source, "path", None)
        name = recorded.get("surroundings")
        if name is not None and folder is not None:
            data = json.loads((Path(folder) / str(name)).read_text())
            surroundings = {
                str(kind): [
                    BranchModel(np.asarray(b["points"]), np.asarray(b["radii"])) for b in items
                ]
                for kind, items in data.items()
            }
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ScanFormatError(
            f"{source.name}: cannot read the recorded scoring ({error})"
        ) from None
    return Scoring(config, planned, surroundings)
