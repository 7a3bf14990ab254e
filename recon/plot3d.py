"""3D figures of branches: polylines cut to a box, equal-scale views, a model's figure.

The one way the project draws branches in 3D: the replay's ``plot3d.png``
(:func:`plot_model_3d`) and the per-tree panels of an evaluation
(``branch_gym.evaluation.plots.plot_tree``) both use :func:`plot_branch` and :func:`fit_view`.
Figures are drawn on matplotlib's Agg canvas (no display, no pyplot state), so they work in worker
processes and on headless machines.

>>> import numpy as np
>>> points = np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.5], [0.0, 0.0, 0.9]])
>>> clip_to_box(points, np.array([-1.0, -1.0, 0.2]), np.array([1.0, 1.0, 0.8]))[:, 2]
array([nan, 0.5, nan])
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from recon.model import TreeModel

MIN_HALF_M = 0.02  # the smallest half-extent of a view (m): a short branch still has room
PRIMARY_COLOR = "#8b5a2b"
SECONDARY_COLOR = "#3ca03c"
TRUTH_STYLE = {"color": "k", "linestyle": "--", "linewidth": 0.8}
CAMERA_COLOR = "0.6"


def clip_to_box(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """A float copy of ``points`` (N, 3) with NaN rows outside ``[low, high]`` (gaps in a line)."""
    shown = np.asarray(points, float).copy()
    shown[np.any((shown < low) | (shown > high), axis=1)] = np.nan
    return shown


def plot_branch(
    axes: Any,
    points: np.ndarray,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    **style: Any,
) -> None:
    """A polyline on 3D axes, cut (NaN gaps) outside ``box`` = (low, high) if given."""
    if len(points) == 0:
        return
    shown = np.asarray(points, float) if box is None else clip_to_box(points, *box)
    if np.isfinite(shown).any():
        axes.plot(shown[:, 0], shown[:, 1], shown[:, 2], **style)


def fit_view(
    axes: Any,
    polylines: Sequence[np.ndarray],
    z_range: tuple[float, float] | None = None,
    margin_m: float = 0.0,
    cube: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Equal-scale limits around the points (those within ``z_range`` when given).

    Args:
        axes: 3D axes.
        polylines: (N, 3) point arrays.
        z_range: Fixed height limits; the other axes fit the points inside them.
        margin_m: Added to every half-extent.
        cube: One half-extent for all axes (the largest).

    Returns:
        The view's (low, high) corners, for :func:`plot_branch`'s ``box``.
    """
    points = np.concatenate([p for p in polylines if len(p)] or [np.zeros((1, 3))])
    if z_range is not None:
        points = points[(points[:, 2] >= z_range[0]) & (points[:, 2] <= z_range[1])]
        if len(points) == 0:
            points = np.array([[0.0, 0.0, z_range[0]], [0.0, 0.0, z_range[1]]])
    low, high = points.min(axis=0), points.max(axis=0)
    if z_range is not None:
        low[2], high[2] = z_range
    centre, half = (low + high) / 2.0, (high - low) / 2.0 + margin_m
    if cube:
        half = np.full(3, half.max())
    half = np.maximum(half, MIN_HALF_M)
    if z_range is not None:
        half[2] = (z_range[1] - z_range[0]) / 2.0
    axes.set_xlim(centre[0] - half[0], centre[0] + half[0])
    axes.set_ylim(centre[1] - half[1], centre[1] + half[1])
    axes.set_zlim(centre[2] - half[2], centre[2] + half[2])
    axes.set_box_aspect(tuple(2.0 * half))
    return centre - half, centre + half


def plot_model_3d(
    path: Path,
    model: TreeModel,
    camera_path: np.ndarray,
    truth: TreeModel | None = None,
    title: str = "",
    dpi: int = 120,
) -> None:
    """Save a 3D plot of the model (and the truth, dashed) with the camera path (grey)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6, 7))
    FigureCanvasAgg(figure)
    axes = figure.add_subplot(projection="3d")
    branches = [b for b in (model.primary, *model.secondaries) if b is not None]
    scanned = [b.points for b in branches] + ([camera_path] if len(camera_path) else [])
    if not scanned and truth is not None:
        scanned = [truth.primary.points]
    box = fit_view(axes, scanned, margin_m=MIN_HALF_M, cube=True)
    if truth is not None:  # clipped to the scanned region: the rest of the tree was not seen
        for i, branch in enumerate([truth.primary, *truth.secondaries]):
            label = "ground truth" if i == 0 else None
            plot_branch(axes, branch.points, box, label=label, **TRUTH_STYLE)
    if model.primary is not None:
        plot_branch(axes, model.primary.points, color=PRIMARY_COLOR, lw=2.5, label="primary")
    for i, branch in enumerate(model.secondaries):
        label = "secondaries" if i == 0 else None
        plot_branch(axes, branch.points, color=SECONDARY_COLOR, lw=2, label=label)
    if len(camera_path):
        plot_branch(axes, camera_path, color=CAMERA_COLOR, lw=1, label="camera")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_zlabel("z (m)")
    axes.set_title(title, fontsize=9)
    if axes.get_legend_handles_labels()[0]:
        axes.legend(loc="upper left", fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=dpi)
