"""Where the eye-in-hand camera sits on the UR5e's tool flange: the fixed ``T_flange_camera``."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# A camera bracket longer than this is no longer "on the flange" (sanity bound, our choice).
_MAX_MOUNT_OFFSET_M = 0.3


@dataclass(frozen=True)
class CameraMountConfig:
    """Where the camera sits on the tool flange (the fixed ``T_flange_camera``).

    The camera rides on top of the flange on a small bracket: image up is the flange normal
    (flange z) and the optical axis is perpendicular to it. Scanning with the optical axis
    horizontal then holds the flange pointing straight up, the UR's most comfortable wrist posture
    (wrist 2 at +-90 deg, far from the wrist singularity), and turning the camera about a vertical
    axis is mostly wrist 3. A camera looking along the flange normal would instead need wrist 2 to
    follow every yaw, reaching its singularity within the +-45 deg rotations (measured:
    ``branch_gym/sim/robot/home.py``).

    Attributes:
        axial_offset_m: Optical centre above the flange face along flange z. Our choice: a 14 mm
            bracket plate plus half the 42 mm height of an Intel RealSense D405 (the paper's lab
            camera; Intel datasheet).
        forward_offset_m: Optical centre ahead of the joint-6 axis along the optical axis. Our
            choice: keeps the wrist housings (radius <= 45 mm) behind the image plane.
        azimuth_deg: Direction of the optical axis about flange z, from flange x. Our choice:
            along flange -y, which puts wrist 3 near -14 deg at the home pose (measured).
        housing_size_m: Camera box (x, y, z in the camera frame) modelled behind the optical centre
            for contact checks (D405: 42 x 42 x 23 mm, Intel datasheet).
    """

    axial_offset_m: float = 0.035
    forward_offset_m: float = 0.04
    azimuth_deg: float = -90.0
    housing_size_m: tuple[float, float, float] = (0.042, 0.042, 0.023)

    def __post_init__(self) -> None:
        for name in ("axial_offset_m", "forward_offset_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= _MAX_MOUNT_OFFSET_M):
                raise ValueError(f"{name} must be in [0, {_MAX_MOUNT_OFFSET_M}] m, got {value}")
        if not math.isfinite(self.azimuth_deg):
            raise ValueError(f"azimuth_deg must be finite, got {self.azimuth_deg}")
        if len(self.housing_size_m) != 3 or not all(
            math.isfinite(s) and s > 0 for s in self.housing_size_m
        ):
            raise ValueError(f"housing_size_m must be 3 positive sizes, got {self.housing_size_m}")
        if self.axial_offset_m < 0.5 * self.housing_size_m[1]:
            raise ValueError(
                f"axial_offset_m ({self.axial_offset_m}) must clear half the housing height "
                f"({0.5 * self.housing_size_m[1]}): the camera would sit inside the flange"
            )


# The camera frame in the flange frame before the azimuth turn: optical axis (camera z) along
# flange x, image down (camera y) along -flange z, camera x = y cross z = -flange y.
_R_FLANGE_CAMERA_0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _rot_z(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def T_flange_camera(mount: CameraMountConfig | None = None) -> np.ndarray:
    """Fixed camera pose in the flange frame.

    Args:
        mount: The camera mount; defaults to :class:`CameraMountConfig()`.

    Returns:
        (4, 4) transform mapping camera-frame points (OpenCV axes) to flange-frame points.
    """
    mount = mount or CameraMountConfig()
    T = np.eye(4)
    T[:3, :3] = _rot_z(math.radians(mount.azimuth_deg)) @ _R_FLANGE_CAMERA_0
    T[:3, 3] = mount.forward_offset_m * T[:3, 2] + np.array([0.0, 0.0, mount.axial_offset_m])
    return T
