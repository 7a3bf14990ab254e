"""Observations of :class:`branch_gym.env.BranchScanEnv`: what the pipeline knows, no ground truth.

:func:`pipeline_state` reads a :class:`PipelineState` off a scan (camera pose, the 3D model, the
latest mask and its 2D curves, the latest modeling outcome, the rotation state);
:func:`draw_state` draws full-resolution canvases of it (mask, projected model, unconfirmed 2D
side-branch candidates) and :func:`make_observation` turns them into the observation: a
(3, H, W) uint8 image and a float32 vector laid out as :class:`branch_gym.env.layout.VectorField`.
:func:`observation_space` gives the matching space, Dict or flattened (vector first, then the
image / 255).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import cv2
import numpy as np
from gymnasium import spaces

from branch_gym.env.config import ObservationConfig
from branch_gym.env.coverage import CoverageConfig
from branch_gym.env.layout import (
    COVERAGE_KEY,
    EXTRA_KEYS,
    IMAGE_KEY,
    N_CHANNELS,
    OUTCOME_FIELDS,
    PRICE_KEY,
    VECTOR_KEY,
    VECTOR_SIZE,
    ImageChannel,
    VectorField,
    flatten_observation,
    vector_bounds,
)
from branch_gym.scan import ScanSession
from recon.camera import CameraIntrinsics
from recon.curve2d.types import Curve2D, MaskCurves
from recon.model import TreeModel
from recon.modeler import IterationReport, Outcome
from recon.overlay import draw_curve, draw_model

_FULL = 255  # drawn / covered pixel value
_OUTCOMES = (Outcome.CONSISTENT, Outcome.INCONSISTENT, Outcome.RESTART)


@dataclass(frozen=True)
class PipelineState:
    """What the robot knows after a step.

    Attributes:
        T_world_camera: (4, 4) current camera pose.
        intrinsics: Camera intrinsics.
        model: The reconstructed tree.
        mask_curves: The latest mask and its fitted 2D curves (None before the first iteration).
        outcome: The latest modeling outcome (None before the first iteration).
        angle_norm: Current rotation / theta_max, in [-1, 1].
        travel_fov: Vertical travel since the last rotation, in vertical FoVs.
        progress: Fraction of the scan height range covered, in [0, 1].
        previous_action: Previous target angle / theta_max, in [-1, 1].
        scan_time_fraction: Scan time so far / the scan-time limit, in [0, 1].
    """

    T_world_camera: np.ndarray
    intrinsics: CameraIntrinsics
    model: TreeModel
    mask_curves: MaskCurves | None
    outcome: Outcome | None
    angle_norm: float
    travel_fov: float
    progress: float
    previous_action: float
    scan_time_fraction: float


@dataclass(frozen=True)
class Drawing:
    """Full-resolution canvases of one state (also what ``render()`` overlays).

    Attributes:
        mask: (H, W) uint8 latest mask (255 on the branch).
        model: (H, W) uint8 projected 3D model (primary and secondaries, as wide as drawn radii).
        unconfirmed: (H, W) uint8 2D side-branch candidates no projected 3D secondary explains.
        candidates: (2D secondary curve, explained) for every candidate of the latest mask.
        n_model_in_view: Model secondaries projecting into the image.
    """

    mask: np.ndarray
    model: np.ndarray
    unconfirmed: np.ndarray
    candidates: list[tuple[Curve2D, bool]]
    n_model_in_view: int

    @property
    def n_unconfirmed(self) -> int:
        return sum(not explained for _, explained in self.candidates)


def pipeline_state(
    session: ScanSession,
    report: IterationReport | None,
    normalise_angle: Callable[[float], float],
    previous_action: float,
) -> PipelineState:
    """What the robot knows from a scan (no ground truth is read).

    Args:
        session: The scan after the latest step.
        report: Its latest modeling iteration (None before the first).
        normalise_angle: Maps an angle (deg) to [-1, 1] (angle / theta_max, clipped).
        previous_action: The previous target angle, normalised.
    """
    return PipelineState(
        T_world_camera=session.world.T_world_camera,
        intrinsics=session.intrinsics,
        model=session.model,
        mask_curves=None if report is None else report.mask_curves,
        outcome=None if report is None else report.outcome,
        angle_norm=normalise_angle(session.angle_deg),
        travel_fov=session.travel_since_rotation_m / session.vertical_fov_m,
        progress=session.progress,
        previous_action=previous_action,
        scan_time_fraction=session.scan_time_s / session.config.max_scan_time_s,
    )


def observation_space(
    config: ObservationConfig,
    flatten: bool,
    coverage: CoverageConfig | None = None,
    price: bool = False,
) -> spaces.Space:
    """The Dict (or flattened Box) observation space.

    Args:
        config: Image size and scales.
        flatten: One flat Box (``layout.flatten_observation`` order) instead of the Dict.
        coverage: Add the ``coverage`` memory (v1).
        price: Add the ``price`` of scan time (v1, ``EnvConfig.branch_value_s``).
    """
    low, high = vector_bounds(config.travel_clip_fov)
    shape = (N_CHANNELS, config.image_height, config.image_width)
    parts = {
        VECTOR_KEY: spaces.Box(low, high, dtype=np.float32),
        IMAGE_KEY: spaces.Box(0, _FULL, shape=shape, dtype=np.uint8),
    }
    if coverage is not None:
        size = coverage.height_bins * coverage.n_channels  # row-major (bins, channels), 1-D
        parts[COVERAGE_KEY] = spaces.Box(0.0, 1.0, shape=(size,), dtype=np.float32)
    if price:
        parts[PRICE_KEY] = spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)
    return flat_space(parts) if flatten else spaces.Dict(parts)


def flat_space(parts: Mapping[str, spaces.Box]) -> spaces.Box:
    """The Box of a Dict observation flattened as ``layout.flatten_observation`` flattens it.

    The vector, the image / 255 (channel-first), then the extras (``EXTRA_KEYS``) it holds.

    Args:
        parts: The Dict's spaces by key (a ``spaces.Dict``'s ``spaces``), in any order.
    """
    bounds = []
    for key in (VECTOR_KEY, IMAGE_KEY, *(k for k in EXTRA_KEYS if k in parts)):
        part = parts[key]
        if key == IMAGE_KEY:
            size = int(np.prod(part.shape))
            bounds.append((np.zeros(size, np.float32), np.ones(size, np.float32)))
        else:
            low = np.broadcast_to(part.low, part.shape).ravel()
            bounds.append((low, np.broadcast_to(part.high, part.shape).ravel()))
    flat_low = np.concatenate([b[0] for b in bounds]).astype(np.float32)
    flat_high = np.concatenate([b[1] for b in bounds]).astype(np.float32)
    return spaces.Box(flat_low, flat_high, dtype=np.float32)


def draw_state(state: PipelineState, config: ObservationConfig) -> Drawing:
    """Draw the mask, the projected model and the unconfirmed candidates at camera resolution."""
    shape = (state.intrinsics.height, state.intrinsics.width)
    T, K = state.T_world_camera, state.intrinsics
    model_canvas = np.zeros(shape, np.uint8)
    if state.model.primary is not None:
        draw_model(model_canvas, [state.model.primary], T, K, _FULL)
    n_in_view = draw_model(model_canvas, state.model.secondaries, T, K, _FULL)
    mask = np.zeros(shape, np.uint8)
    unconfirmed = np.zeros(shape, np.uint8)
    candidates: list[tuple[Curve2D, bool]] = []
    curves = state.mask_curves
    if curves is not None:
        mask[curves.mask] = _FULL
        explains = np.zeros(shape, np.uint8)
        tolerance = config.explained_tolerance_px
        draw_model(explains, state.model.secondaries, T, K, _FULL, tolerance)
        for curve in curves.secondaries:
            explained = _explained(curve, explains, K, config.explained_min_fraction)
            candidates.append((curve, explained))
            if not explained:
                draw_curve(unconfirmed, curve, _FULL)
    return Drawing(mask, model_canvas, unconfirmed, candidates, n_in_view)


def make_observation(
    state: PipelineState,
    drawing: Drawing,
    config: ObservationConfig,
    flatten: bool,
    extras: dict[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray] | np.ndarray:
    """The observation of one state (new arrays every call).

    Args:
        state: What the robot knows.
        drawing: Its canvases (:func:`draw_state`).
        config: Image size and scales.
        flatten: Return the flat vector (``layout.flatten_observation``).
        extras: The v1 entries (``coverage``, ``price``) to add, float32 arrays.
    """
    channels = np.empty((*drawing.mask.shape, N_CHANNELS), np.uint8)
    channels[..., ImageChannel.MASK] = drawing.mask
    channels[..., ImageChannel.MODEL] = drawing.model
    channels[..., ImageChannel.UNCONFIRMED] = drawing.unconfirmed
    size = (config.image_width, config.image_height)
    image = cv2.resize(channels, size, interpolation=cv2.INTER_AREA)
    image = np.ascontiguousarray(image.reshape(*size[::-1], N_CHANNELS).transpose(2, 0, 1))

    vector = np.zeros(VECTOR_SIZE, np.float32)
    vector[VectorField.ANGLE] = np.clip(state.angle_norm, -1.0, 1.0)
    vector[VectorField.TRAVEL_FOV] = np.clip(state.travel_fov, 0.0, config.travel_clip_fov)
    vector[VectorField.PROGRESS] = np.clip(state.progress, 0.0, 1.0)
    if state.outcome is not None:
        vector[OUTCOME_FIELDS[_OUTCOMES.index(state.outcome)]] = 1.0
    n_candidates = 0 if state.mask_curves is None else len(state.mask_curves.secondaries)
    counts = {
        VectorField.MODEL_SECONDARIES: len(state.model.secondaries),
        VectorField.MODEL_SECONDARIES_IN_VIEW: drawing.n_model_in_view,
        VectorField.CANDIDATES_2D: n_candidates,
        VectorField.UNCONFIRMED_CANDIDATES: drawing.n_unconfirmed,
    }
    for index, count in counts.items():
        vector[index] = min(count / config.count_scale, 1.0)
    vector[VectorField.PREVIOUS_ACTION] = np.clip(state.previous_action, -1.0, 1.0)
    vector[VectorField.SCAN_TIME] = np.clip(state.scan_time_fraction, 0.0, 1.0)
    observation = {IMAGE_KEY: image, VECTOR_KEY: vector, **(extras or {})}
    return flatten_observation(observation) if flatten else observation


def _explained(
    curve: Curve2D, explains: np.ndarray, intrinsics: CameraIntrinsics, min_fraction: float
) -> bool:
    """Whether enough of a candidate's samples (off the primary) fall on a drawn 3D secondary."""
    samples = curve.samples_px
    outside = ~np.asarray(curve.inside_primary, bool)
    if outside.any():
        samples = samples[outside]
    inside = intrinsics.in_image(samples)
    hits = np.zeros(len(samples), bool)
    if inside.any():
        cols = np.clip(np.rint(samples[inside, 0]).astype(int), 0, intrinsics.width - 1)
        rows = np.clip(np.rint(samples[inside, 1]).astype(int), 0, intrinsics.height - 1)
        hits[inside] = explains[rows, cols] > 0
    return bool(hits.mean() >= min_fraction) if len(hits) else False
