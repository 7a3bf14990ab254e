"""Drawing what the pipeline knows into images: projected 3D branches, fitted 2D curves, masks.

The one overlay of the project: the Gymnasium env's observation channels (single-channel
canvases) and ``render()``'s ``rgb_array`` frames (:func:`compose_frame`), and the overlay video
of a replayed recording (:func:`model_overlay`, ``python -m recon.replay``). Branches are drawn as
polylines as wide as the branch (2 x radius in pixels), so a drawn model covers the mask where it
explains it.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from recon.camera import CameraIntrinsics, project_points
from recon.curve2d.types import Curve2D
from recon.model import BranchModel, TreeModel

# Sub-pixel precision of cv2 drawing: coordinates carry 2 fractional bits.
_SHIFT = 2
_SCALE = 1 << _SHIFT
# Projections far outside the image are clamped (cv2 needs int32 coordinates; lines are clipped).
_COORD_LIMIT_PX = 1e5
# Overlay colours (RGB) and blending, our choice for legibility.
MASK_RGB = (0, 200, 0)
MASK_ALPHA = 0.35
MODEL_RGB = (255, 60, 60)
MODEL_ALPHA = 0.5
PRIMARY_CURVE_RGB = (255, 230, 0)
EXPLAINED_CANDIDATE_RGB = (0, 220, 255)
UNCONFIRMED_CANDIDATE_RGB = (255, 0, 255)
TEXT_RGB = (255, 255, 255)
TEXT_OUTLINE_RGB = (0, 0, 0)
_TEXT_SCALE = 0.4
_TEXT_LINE_PX = 14


def project_branch(
    branch: BranchModel, T_world_camera: np.ndarray, intrinsics: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project a 3D branch into the image.

    Returns:
        pixels: (N, 2) pixel coordinates (u, v); NaN behind the camera.
        radii_px: (N,) branch radius in pixels (f * r / depth).
        valid: (N,) in front of the camera.
    """
    pixels, depth = project_points(branch.points, T_world_camera, intrinsics)
    valid = depth > 0
    radii_px = np.zeros(len(depth))
    radii_px[valid] = intrinsics.fx * branch.radii[valid] / depth[valid]
    return pixels, radii_px, valid


def in_view(pixels: np.ndarray, valid: np.ndarray, intrinsics: CameraIntrinsics) -> bool:
    """Whether any valid projected point lies inside the image."""
    return bool(np.any(valid & intrinsics.in_image(pixels)))


def draw_polyline(
    canvas: np.ndarray,
    pixels: np.ndarray,
    radii_px: np.ndarray,
    colour: int | tuple[int, ...],
    valid: np.ndarray | None = None,
    extra_halfwidth_px: float = 0.0,
) -> None:
    """Draw a polyline whose width follows the radius (in place).

    Args:
        canvas: (H, W) or (H, W, 3) uint8 image.
        pixels: (N, 2) vertices (u, v).
        radii_px: (N,) half-widths in pixels; a segment uses the mean of its ends.
        colour: Grey value or RGB triple.
        valid: (N,) vertices that may be used (default: the finite ones).
        extra_halfwidth_px: Added to every half-width (e.g. a tolerance band).
    """
    finite = np.all(np.isfinite(pixels), axis=1)
    ok = finite if valid is None else finite & valid
    if len(pixels) == 1 and ok[0]:
        pixels, radii_px, ok = (
            np.repeat(pixels, 2, axis=0),
            np.repeat(radii_px, 2),
            np.repeat(ok, 2),
        )
    fixed = np.rint(np.clip(np.nan_to_num(pixels), -_COORD_LIMIT_PX, _COORD_LIMIT_PX) * _SCALE)
    fixed = fixed.astype(np.int64)
    # A branch point just in front of the lens projects with a huge radius: no line needs to be
    # wider than twice the canvas diagonal to cover it (OpenCV refuses widths above 32767).
    max_thickness = int(2 * np.hypot(*canvas.shape[:2])) + 1
    if len(pixels) < 2:
        return
    half = 0.5 * (radii_px[:-1] + radii_px[1:]) + extra_halfwidth_px
    thickness = np.clip(np.rint(2.0 * half), 1, max_thickness).astype(int)
    # Segments whose box, grown by their width, misses the canvas draw nothing: skip them.
    start_px, end_px = fixed[:-1] / _SCALE, fixed[1:] / _SCALE
    reach = thickness + 1.0
    height, width = canvas.shape[:2]
    touches = (
        (np.maximum(start_px[:, 0], end_px[:, 0]) >= -reach)
        & (np.minimum(start_px[:, 0], end_px[:, 0]) <= width - 1 + reach)
        & (np.maximum(start_px[:, 1], end_px[:, 1]) >= -reach)
        & (np.minimum(start_px[:, 1], end_px[:, 1]) <= height - 1 + reach)
    )
    vertices, widths = fixed.tolist(), thickness.tolist()  # Python ints for the cv2 calls
    for i in np.flatnonzero(ok[:-1] & ok[1:] & touches).tolist():
        start, end = vertices[i], vertices[i + 1]
        cv2.line(
            canvas, (start[0], start[1]), (end[0], end[1]), colour, widths[i], cv2.LINE_8, _SHIFT
        )


def draw_model(
    canvas: np.ndarray,
    branches: Sequence[BranchModel],
    T_world_camera: np.ndarray,
    intrinsics: CameraIntrinsics,
    colour: int | tuple[int, ...],
    extra_halfwidth_px: float = 0.0,
) -> int:
    """Draw 3D branches as seen from ``T_world_camera`` (in place).

    Returns:
        How many of them project into the image.
    """
    n_in_view = 0
    for branch in branches:
        pixels, radii_px, valid = project_branch(branch, T_world_camera, intrinsics)
        draw_polyline(canvas, pixels, radii_px, colour, valid, extra_halfwidth_px)
        n_in_view += in_view(pixels, valid, intrinsics)
    return n_in_view


def draw_curve(canvas: np.ndarray, curve: Curve2D, colour: int | tuple[int, ...]) -> None:
    """Draw a fitted 2D curve through its samples, as wide as the branch (in place)."""
    draw_polyline(canvas, curve.samples_px, curve.radii_px, colour)


def compose_frame(
    rgb: np.ndarray,
    mask: np.ndarray | None,
    primary_curve: Curve2D | None,
    candidates: Sequence[tuple[Curve2D, bool]],
    model_canvas: np.ndarray,
    text: Sequence[str] = (),
    mask_alpha: float = MASK_ALPHA,
) -> np.ndarray:
    """The camera image with the pipeline's state overlaid (``render()``'s rgb_array frame).

    Args:
        rgb: (H, W, 3) uint8 camera image.
        mask: (H, W) bool latest mask, or None.
        primary_curve: The fitted 2D primary, drawn as a centre line.
        candidates: (2D secondary curve, explained by the 3D model) pairs, drawn as centre lines
            (cyan explained, magenta unconfirmed).
        model_canvas: (H, W) uint8 projected 3D model (non-zero where drawn), blended in red.
        text: Lines written in the top-left corner.
        mask_alpha: Opacity of the mask's tint.

    Returns:
        (H, W, 3) uint8 frame (a new array).
    """
    frame = rgb.astype(np.float32)
    if mask is not None:
        frame[mask] = (1 - mask_alpha) * frame[mask] + mask_alpha * np.float32(MASK_RGB)
    drawn = model_canvas > 0
    frame[drawn] = (1 - MODEL_ALPHA) * frame[drawn] + MODEL_ALPHA * np.float32(MODEL_RGB)
    out = np.ascontiguousarray(np.clip(frame, 0, 255).astype(np.uint8))
    if primary_curve is not None:
        zeros = np.zeros(len(primary_curve.samples_px))
        draw_polyline(out, primary_curve.samples_px, zeros, PRIMARY_CURVE_RGB)
    for curve, explained in candidates:
        colour = EXPLAINED_CANDIDATE_RGB if explained else UNCONFIRMED_CANDIDATE_RGB
        draw_polyline(out, curve.samples_px, np.zeros(len(curve.samples_px)), colour)
    for row, line in enumerate(text):
        origin = (4, (row + 1) * _TEXT_LINE_PX)
        for colour, thickness in ((TEXT_OUTLINE_RGB, 3), (TEXT_RGB, 1)):
            cv2.putText(out, line, origin, cv2.FONT_HERSHEY_SIMPLEX, _TEXT_SCALE, colour, thickness)
    return out


def model_overlay(
    rgb: np.ndarray,
    mask: np.ndarray | None,
    model: TreeModel,
    T_world_camera: np.ndarray,
    intrinsics: CameraIntrinsics,
    text: Sequence[str] = (),
    mask_alpha: float = MASK_ALPHA,
) -> np.ndarray:
    """A camera image with its mask and a tree model projected into it (a replay's video frame).

    Returns:
        (H, W, 3) uint8 RGB frame, as :func:`compose_frame` draws it.
    """
    canvas = np.zeros(rgb.shape[:2], np.uint8)
    branches = [b for b in (model.primary, *model.secondaries) if b is not None]
    draw_model(canvas, branches, T_world_camera, intrinsics, 255)
    return compose_frame(rgb, mask, None, [], canvas, text, mask_alpha)
