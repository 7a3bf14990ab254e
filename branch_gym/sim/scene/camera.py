"""The eye-in-hand camera: RGB, metric depth and instance labels rendered by pybullet.

The camera's geometry (:class:`CameraSpec`, :func:`check_pose`, :func:`look_at`,
:func:`pixel_grid` and the default intrinsics) lives in ``sim/scene/camera_spec.py``, with
its conventions: OpenCV camera axes, pixel ``(u, v)`` = (column, row),
``p_world = T_world_camera @ p_camera``.

pybullet wants OpenGL matrices: a view matrix into a camera looking along -z with y up, and a
projection matrix to normalised device coordinates (NDC). The renderers then map NDC to pixels
with different half-pixel conventions (measured by rendering small markers at known points):
with a centred projection, TinyRenderer puts the principal point at (160, 119) for 320x240 and
the EGL/OpenGL renderer at (159.5, 119.5). :func:`projection_matrix` compensates per renderer,
so rendered images follow the pinhole model ``u = fx x / z + cx`` to a small fraction of a pixel.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
import pybullet

from branch_gym.sim.bullet import Bullet
from branch_gym.sim.scene.camera_spec import (
    CameraSpec,
    check_pose,
    look_at,
)

__all__ = [
    "BACKGROUND_LABEL",
    "BackgroundPainter",
    "CameraImages",
    "Lighting",
    "projection_matrix",
    "render_camera",
    "render_snapshot",
    "view_matrix",
]

# Where each renderer samples pixel (u, v), as the NDC offset (a, b) in
# ndc_x = 2 (u + a) / W - 1 and ndc_y = 1 - 2 (v + b) / H (measured, see module docstring).
_PIXEL_SAMPLE_OFFSET = {
    pybullet.ER_TINY_RENDERER: (0.0, 1.0),
    pybullet.ER_BULLET_HARDWARE_OPENGL: (0.5, 0.5),
}
_OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # flips camera y and z
_LINK_SHIFT = 24  # pybullet segmentation value = body + ((link + 1) << 24)
_BODY_MASK = (1 << _LINK_SHIFT) - 1
BACKGROUND_LABEL = 0


@dataclass(frozen=True)
class Lighting:
    """Light for pybullet's renderers; always passed explicitly because it is sticky.

    Attributes:
        direction: Direction towards the light, world frame (our choice: above, on the camera side).
        colour: RGB in [0, 1].
        ambient: Ambient coefficient (our choice: bright, flat light; no specular glints that move
            with the camera and confuse the point tracker).
        diffuse: Diffuse coefficient.
        specular: Specular coefficient.
    """

    direction: tuple[float, float, float] = (0.3, -0.8, 1.0)
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ambient: float = 0.6
    diffuse: float = 0.45
    specular: float = 0.0


@dataclass(frozen=True)
class CameraImages:
    """One rendered frame.

    Attributes:
        rgb: (H, W, 3) uint8 colour image.
        depth_m: (H, W) float32 z-depth along the optical axis in metres; inf where nothing was hit.
        labels: (H, W) int32 instance labels: 0 background, 1 primary, 2 + i secondary i,
            100 + k clutter object k (whatever ``label_of`` says; bodies it omits read 0).
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    labels: np.ndarray


class BackgroundPainter(Protocol):
    """Fills the pixels no pybullet body covers (e.g. ground and a backdrop, drawn cheaply)."""

    def paint(
        self,
        rgb: np.ndarray,
        depth_m: np.ndarray,
        empty: np.ndarray,
        T_world_camera: np.ndarray,
        spec: CameraSpec,
    ) -> None:
        """Write colour and depth in place where ``empty`` (H, W) bool is True."""


def view_matrix(T_world_camera: np.ndarray) -> list[float]:
    """pybullet view matrix (16 floats, column-major) for an OpenCV camera pose."""
    view = _OPENCV_TO_OPENGL @ np.linalg.inv(check_pose(T_world_camera))
    return view.T.ravel().tolist()


def projection_matrix(spec: CameraSpec, renderer: int = pybullet.ER_TINY_RENDERER) -> list[float]:
    """pybullet projection matrix (16 floats, column-major) reproducing ``spec``'s pinhole model.

    Args:
        spec: Intrinsics and clip planes.
        renderer: ``pybullet.ER_TINY_RENDERER`` or ``pybullet.ER_BULLET_HARDWARE_OPENGL``: they
            sample pixels at different offsets (module docstring).
    """
    if renderer not in _PIXEL_SAMPLE_OFFSET:
        raise ValueError(f"unknown renderer {renderer}")
    offset_u, offset_v = _PIXEL_SAMPLE_OFFSET[renderer]
    near, far = spec.near_m, spec.far_m
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * spec.fx / spec.width
    P[1, 1] = 2.0 * spec.fy / spec.height
    P[0, 2] = 1.0 - 2.0 * (spec.cx + offset_u) / spec.width
    P[1, 2] = 2.0 * (spec.cy + offset_v) / spec.height - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P.T.ravel().tolist()


def render_camera(
    bullet: Bullet,
    T_world_camera: np.ndarray,
    spec: CameraSpec | None = None,
    label_of: Mapping[tuple[int, int], int] | None = None,
    background: BackgroundPainter | None = None,
    lighting: Lighting | None = None,
) -> CameraImages:
    """Render RGB, metric depth and instance labels from an OpenCV camera pose.

    Args:
        bullet: The world; its ``renderer`` (TinyRenderer, or EGL when loaded) draws the image.
        T_world_camera: (4, 4) camera pose.
        spec: Intrinsics and clip planes (default: the authors' 320x240 camera).
        label_of: Instance label per (body unique id, link index), link -1 being the base.
            Pixels of bodies it omits are labelled 0; without it every label is 0.
        background: Paints pixels no body covers (see :class:`BackgroundPainter`).
        lighting: Light (default :class:`Lighting`); passed explicitly every time: it is sticky.

    Returns:
        The frame. Without a background, uncovered pixels keep the renderer's clear colour and
        have depth inf.
    """
    spec = spec or CameraSpec()
    lighting = lighting or Lighting()
    _, _, rgba, depth_buffer, segmentation = bullet.p.getCameraImage(
        spec.width,
        spec.height,
        viewMatrix=view_matrix(T_world_camera),
        projectionMatrix=projection_matrix(spec, bullet.renderer),
        lightDirection=list(lighting.direction),
        lightColor=list(lighting.colour),
        lightAmbientCoeff=lighting.ambient,
        lightDiffuseCoeff=lighting.diffuse,
        lightSpecularCoeff=lighting.specular,
        shadow=0,
        renderer=bullet.renderer,
        flags=pybullet.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX,
    )
    shape = (spec.height, spec.width)
    rgb = cv2.cvtColor(
        np.reshape(rgba, (*shape, 4)).astype(np.uint8, copy=False), cv2.COLOR_RGBA2RGB
    )
    segmentation = np.reshape(segmentation, shape)
    empty = segmentation < 0
    depth_m = _linear_depth(np.reshape(depth_buffer, shape), spec)
    np.copyto(depth_m, np.float32(np.inf), where=empty)
    if background is not None:
        background.paint(rgb, depth_m, empty, T_world_camera, spec)
    return CameraImages(rgb=rgb, depth_m=depth_m, labels=_labels(segmentation, label_of))


def render_snapshot(
    bullet: Bullet,
    width: int = 640,
    height: int = 480,
    eye: tuple[float, float, float] = (1.0, -1.4, 1.0),
    target: tuple[float, float, float] = (0.0, 0.0, 0.5),
    hfov_deg: float = 50.0,
    background: BackgroundPainter | None = None,
) -> np.ndarray:
    """Third-person colour view of the whole scene (for ``render_mode="rgb_array"``).

    Args:
        bullet: The world.
        width: Image width in pixels.
        height: Image height in pixels.
        eye: Viewpoint in metres, world frame (default: in front, to the right, above).
        target: Point looked at, metres, world frame.
        hfov_deg: Horizontal field of view in degrees.
        background: Optional painter for the pixels no body covers.

    Returns:
        (height, width, 3) uint8 RGB image.
    """
    spec = CameraSpec.from_hfov(width, height, hfov_deg)
    return render_camera(bullet, look_at(eye, target), spec, background=background).rgb


def _linear_depth(depth_buffer: np.ndarray, spec: CameraSpec) -> np.ndarray:
    """Metric z-depth (H, W) float32 from OpenGL's non-linear [0, 1] depth buffer."""
    near, far = spec.near_m, spec.far_m
    buffer = np.asarray(depth_buffer, dtype=np.float64)
    return (far * near / (far - (far - near) * buffer)).astype(np.float32)


def _labels(segmentation: np.ndarray, label_of: Mapping[tuple[int, int], int] | None) -> np.ndarray:
    """Instance labels (H, W) int32 from pybullet's object-and-link segmentation buffer."""
    labels = np.full(segmentation.shape, BACKGROUND_LABEL, dtype=np.int32)
    if not label_of:
        return labels
    n_bodies = max(body for body, _ in label_of) + 1
    n_links = max(link for _, link in label_of) + 2  # column 0 is the base (link -1)
    table = np.full((n_bodies + 1, n_links + 1), BACKGROUND_LABEL, dtype=np.int32)  # +1: unknown
    for (body, link), label in label_of.items():
        table[body, link + 1] = label
    covered = segmentation >= 0
    value = segmentation[covered].astype(np.int64)
    body = np.minimum(value & _BODY_MASK, n_bodies)
    link_column = np.minimum(value >> _LINK_SHIFT, n_links)
    labels[covered] = table[body, link_column]
    return labels
