"""Camera calibration with lens distortion, and undistortion of images and masks (OpenCV).

The scan format stores the raw (distorted) images with the calibration that produced them, as ROS'
``sensor_msgs/CameraInfo`` does. :class:`CameraModel` holds that calibration;
:class:`Undistorter` remaps images (bilinear) and masks (nearest neighbour) onto the ideal pinhole
camera with the *same* calibration matrix ``K``, so the pipeline's :class:`recon.CameraIntrinsics`
is ``K`` without distortion.

Distortion models (ROS names, with aliases):

* ``none``: no coefficients (or all zero).
* ``plumb_bob`` (aliases ``radtan``, ``opencv``): OpenCV's ``k1, k2, p1, p2[, k3]``.
* ``rational_polynomial``: OpenCV's ``k1, k2, p1, p2, k3, k4, k5, k6``.
* ``equidistant`` (alias ``fisheye``): OpenCV fisheye ``k1, k2, k3, k4``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from recon.camera import CameraIntrinsics

DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    "none": (0,),
    "plumb_bob": (4, 5),
    "rational_polynomial": (8,),
    "equidistant": (4,),
}
_ALIASES = {"radtan": "plumb_bob", "opencv": "plumb_bob", "fisheye": "equidistant", "": "none"}


def canonical_distortion_model(name: str) -> str:
    """The canonical (ROS) name of a distortion model.

    Raises:
        ValueError: an unknown model name.
    """
    key = _ALIASES.get(name.strip().lower(), name.strip().lower())
    if key not in DISTORTION_MODELS:
        known = sorted(set(DISTORTION_MODELS) | set(_ALIASES) - {""})
        raise ValueError(f"unknown distortion model {name!r}: expected one of {known}")
    return key


@dataclass(frozen=True)
class CameraModel:
    """A calibrated camera: pinhole intrinsics plus a lens distortion model.

    Attributes:
        intrinsics: Image size (px) and ``K`` (fx, fy, cx, cy in px).
        distortion_model: Canonical model name (see the module docstring).
        distortion: Distortion coefficients, as many as the model takes (OpenCV order).
    """

    intrinsics: CameraIntrinsics
    distortion_model: str = "none"
    distortion: tuple[float, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        model = canonical_distortion_model(self.distortion_model)
        coeffs = tuple(float(c) for c in self.distortion)
        if not all(math.isfinite(c) for c in coeffs):
            raise ValueError(f"distortion coefficients must be finite, got {coeffs}")
        if model == "none" and any(c != 0.0 for c in coeffs):
            raise ValueError("distortion_model 'none' takes no non-zero coefficients")
        if model == "none":
            coeffs = ()
        elif len(coeffs) not in DISTORTION_MODELS[model]:
            raise ValueError(
                f"distortion model {model!r} takes {DISTORTION_MODELS[model]} coefficients, "
                f"got {len(coeffs)}"
            )
        object.__setattr__(self, "distortion_model", model)
        object.__setattr__(self, "distortion", coeffs)

    @property
    def is_distorted(self) -> bool:
        """Whether any coefficient is non-zero (images then need undistorting)."""
        return any(c != 0.0 for c in self.distortion)

    def to_dict(self) -> dict:
        """The ``camera.json`` content."""
        k = self.intrinsics
        return {
            "width": k.width,
            "height": k.height,
            "fx": k.fx,
            "fy": k.fy,
            "cx": k.cx,
            "cy": k.cy,
            "distortion_model": self.distortion_model,
            "distortion": list(self.distortion),
        }

    @classmethod
    def from_dict(cls, data: dict) -> CameraModel:
        """Parse ``camera.json`` content.

        Raises:
            ValueError: a missing or malformed field (the message names it).
        """
        if not isinstance(data, dict):
            raise ValueError(f"expected a JSON object, got {type(data).__name__}")
        missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy") if k not in data]
        if missing:
            raise ValueError(f"missing field(s) {missing}")
        values: dict[str, float] = {}
        for key in ("width", "height", "fx", "fy", "cx", "cy"):
            value = data[key]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"field {key!r} must be a number, got {value!r}")
            if key in ("width", "height") and value != int(value):
                raise ValueError(f"field {key!r} must be an integer, got {value!r}")
            values[key] = value
        try:
            coeffs = tuple(float(c) for c in data.get("distortion", []) or [])
        except (TypeError, ValueError):
            raise ValueError(
                f"field 'distortion' must be a list of numbers, got {data['distortion']!r}"
            ) from None
        intrinsics = CameraIntrinsics(
            int(values["width"]),
            int(values["height"]),
            float(values["fx"]),
            float(values["fy"]),
            float(values["cx"]),
            float(values["cy"]),
        )
        model = data.get("distortion_model", "none" if not coeffs else "plumb_bob")
        if not isinstance(model, str):
            raise ValueError(f"distortion_model must be a string, got {model!r}")
        return cls(intrinsics, model, coeffs)


class Undistorter:
    """Remaps images and masks of a distorted camera onto its ideal pinhole camera (same ``K``).

    The remap tables are computed once. Pixels that fall outside the raw image become black
    (image) or background (mask).

    Args:
        camera: The calibration of the raw images.
    """

    def __init__(self, camera: CameraModel) -> None:
        self.camera = camera
        k = camera.intrinsics
        size = (k.width, k.height)
        K = k.K
        D = np.asarray(camera.distortion, float)
        if not camera.is_distorted:
            self._maps = None
        elif camera.distortion_model == "equidistant":
            self._maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K, size, cv2.CV_32FC1)
        else:
            self._maps = cv2.initUndistortRectifyMap(K, D, np.eye(3), K, size, cv2.CV_32FC1)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The intrinsics of the undistorted images (``K`` of the calibration, no distortion)."""
        return self.camera.intrinsics

    def image(self, image: np.ndarray) -> np.ndarray:
        """Undistort an (H, W[, C]) image (bilinear); returned unchanged without distortion."""
        if self._maps is None:
            return image
        return cv2.remap(image, *self._maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def mask(self, mask: np.ndarray) -> np.ndarray:
        """Undistort an (H, W) boolean mask (nearest neighbour) -> (H, W) bool."""
        if self._maps is None:
            return mask
        out = cv2.remap(
            mask.astype(np.uint8), *self._maps, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT
        )
        return out.astype(bool)


def distort_image(image: np.ndarray, camera: CameraModel, nearest: bool = False) -> np.ndarray:
    """Simulate the lens: render what the distorted camera sees of an ideal pinhole image.

    The inverse of :meth:`Undistorter.image` up to interpolation; for tests and synthetic data.

    Args:
        image: (H, W[, C]) image of the ideal pinhole camera with ``camera``'s ``K``.
        camera: The distorted camera.
        nearest: Nearest-neighbour sampling (for masks) instead of bilinear.

    Returns:
        The raw image the distorted camera records, same shape and dtype.
    """
    if not camera.is_distorted:
        return image
    k = camera.intrinsics
    u, v = np.meshgrid(np.arange(k.width, dtype=float), np.arange(k.height, dtype=float))
    raw = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    D = np.asarray(camera.distortion, float)
    if camera.distortion_model == "equidistant":
        ideal = cv2.fisheye.undistortPoints(raw, k.K, D, P=k.K)
    else:
        ideal = cv2.undistortPoints(raw, k.K, D, P=k.K)
    ideal = ideal.reshape(k.height, k.width, 2).astype(np.float32)
    interpolation = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.remap(
        image, ideal[..., 0], ideal[..., 1], interpolation, borderMode=cv2.BORDER_CONSTANT
    )
