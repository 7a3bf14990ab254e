"""The bag's messages decoded: stamps, images (raw and compressed), calibration.

:func:`decode_image` turns an Image or CompressedImage message into an array;
:func:`camera_from_info` a CameraInfo into a :class:`CameraModel`; :class:`FrameDecoder` makes the
undistorted image, mask and flow picture of a frame, checked against the calibration.
"""

from __future__ import annotations

import cv2
import numpy as np

from recon.camera import CameraIntrinsics
from recon.io.distortion import CameraModel, Undistorter, canonical_distortion_model
from recon.io.folder import ScanFormatError, flow_picture_from_array, mask_from_array


def stamp_ns(header, fallback_ns: int) -> int:
    """Header stamp in ns (the bag's receive time when the stamp is zero)."""
    t = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    return t if t > 0 else int(fallback_ns)


def decode_image(msg, msgtype: str) -> np.ndarray:
    """(H, W, 3) RGB uint8, or (H, W) for mono images, from an Image or CompressedImage.

    Raises:
        ValueError: an unsupported encoding or undecodable data.
    """
    if msgtype.endswith("CompressedImage"):
        data = np.frombuffer(bytes(msg.data), np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"cannot decode compressed image (format {msg.format!r})")
        if image.ndim == 3:
            code = cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB
            image = cv2.cvtColor(image, code)
        return image
    encoding = msg.encoding.lower()
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3}
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.frombuffer(bytes(msg.data), np.uint8)
    if encoding in ("mono16", "16uc1"):
        dtype = np.dtype(">u2" if msg.is_bigendian else "<u2")
        rows = raw[: h * step].reshape(h, step)[:, : 2 * w].copy()
        return rows.view(dtype).reshape(h, w).astype(np.uint16)
    if encoding not in channels:
        raise ValueError(f"unsupported image encoding {msg.encoding!r}")
    c = channels[encoding]
    if len(raw) < h * step or step < w * c:
        raise ValueError(f"image data too short for {w}x{h} {msg.encoding} (step {step})")
    image = raw[: h * step].reshape(h, step)[:, : w * c].reshape(h, w, c)
    if c == 1:
        return image[..., 0].copy()
    if encoding in ("bgr8", "8uc3"):
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if encoding == "bgra8":
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    if encoding == "rgba8":
        return image[..., :3].copy()
    return image.copy()


def camera_from_info(msg, where: str) -> CameraModel:
    """A :class:`CameraModel` from a CameraInfo message (K, D, distortion model, size)."""
    K = np.asarray(msg.k, float).reshape(3, 3)
    if not np.any(K):
        raise ScanFormatError(f"{where}: K is all zeros (camera not calibrated)")
    coeffs = tuple(float(c) for c in np.asarray(msg.d, float))
    name = msg.distortion_model or ("plumb_bob" if coeffs else "none")
    try:
        model = canonical_distortion_model(name)
        if not any(coeffs):
            model, coeffs = "none", ()
        elif model == "plumb_bob" and len(coeffs) > 5:  # some drivers pad D with zeros
            if any(coeffs[5:]):
                model = "rational_polynomial"
                coeffs = (*coeffs, 0.0, 0.0, 0.0)[:8]
            else:
                coeffs = coeffs[:5]
        intrinsics = CameraIntrinsics.from_matrix(K, int(msg.width), int(msg.height))
        return CameraModel(intrinsics, model, coeffs)
    except ValueError as error:
        raise ScanFormatError(f"{where}: {error}") from None


class FrameDecoder:
    """Image, mask and flow-picture messages -> a frame's undistorted arrays.

    Args:
        where: The bag (the start of every error message).
        camera: The calibration: every image and mask must have its size.
        camera_info_topic: Where the calibration came from (for messages).
        mask_threshold: Mask pixels above this are branch (``ScanFormatConfig.mask_threshold``).
    """

    def __init__(
        self, where: str, camera: CameraModel, camera_info_topic: str, mask_threshold: float
    ) -> None:
        self.where = where
        self.camera = camera
        self.undistorter = Undistorter(camera)
        self.camera_info_topic = camera_info_topic
        self.mask_threshold = mask_threshold

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The intrinsics of the undistorted arrays."""
        return self.undistorter.intrinsics

    def image(self, msg, msgtype: str, where: str) -> np.ndarray:
        """(H, W, 3) uint8 RGB image of an image message, undistorted (mono -> grey RGB)."""
        image = self._decoded(msg, msgtype, where)
        if image.ndim == 2:
            image = cv2.cvtColor(image.astype(np.uint8), cv2.COLOR_GRAY2RGB)
        return self.undistorter.image(image)

    def mask(self, msg, msgtype: str, where: str) -> np.ndarray:
        """(H, W) bool mask of a mask message (non-zero = branch), undistorted."""
        image = self._decoded(msg, msgtype, where)
        if image.dtype == np.uint16:
            image = (image > 0).astype(np.uint8)
        return self.undistorter.mask(mask_from_array(image, self.mask_threshold))

    def flow_picture(self, msg, msgtype: str, where: str) -> np.ndarray:
        """(H, W, 3) uint8 RGB flow picture of a message, resized to the image and undistorted."""
        try:
            image = decode_image(msg, msgtype)
        except ValueError as error:
            raise ScanFormatError(f"{self.where}: {where}: {error}") from None
        if image.ndim != 3 or image.dtype != np.uint8:
            raise ScanFormatError(
                f"{self.where}: {where}: a flow picture must be an 8-bit colour image, got "
                f"{image.dtype} {image.shape}"
            )
        k = self.camera.intrinsics
        return flow_picture_from_array(image, k.width, k.height, self.undistorter)

    def _decoded(self, msg, msgtype: str, where: str) -> np.ndarray:
        """The message's array, of the calibration's size."""
        k = self.camera.intrinsics
        try:
            image = decode_image(msg, msgtype)
        except ValueError as error:
            raise ScanFormatError(f"{self.where}: {where}: {error}") from None
        if image.shape[:2] != (k.height, k.width):
            raise ScanFormatError(
                f"{self.where}: {where}: image is {image.shape[1]}x{image.shape[0]} but "
                f"{self.camera_info_topic!r} says {k.width}x{k.height}"
            )
        return image
