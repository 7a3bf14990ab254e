"""What a bag recording is read with: topics, frames and tolerances (:class:`BagConfig`), and the
command-line flags that set them (``--image-topic`` ...; ``python -m recon.replay``,
``python -m recon.io.convert``).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class BagConfig:
    """Topics, frames and tolerances of a bag recording.

    Attributes:
        image_topic: Colour images (Image or CompressedImage).
        camera_info_topic: The camera's CameraInfo.
        tf_topic: Dynamic transforms (TFMessage).
        tf_static_topic: Static transforms (TFMessage).
        world_frame: The world (robot base) frame the poses are expressed in.
        camera_frame: The camera's optical frame (x right, y down, z forward).
        pose_topic: A PoseStamped topic of the camera optical frame used instead of TF, or None.
        mask_topic: Branch masks (Image or CompressedImage; non-zero = branch), or None.
        pose_tolerance_s: An image outside the time span of a transform's samples takes the
            nearest sample if it is at most this far (our choice: 50 ms, ~1 mm at 2.5 cm/s).
        max_interpolation_gap_s: Samples further apart than this are not interpolated between.
        mask_tolerance_s: A mask belongs to the image whose stamp is within this (masks are
            stamped with their image's header by the authors' segmenter).
        typestore: rosbags type store for bags without message definitions.
        flow_topic: Optical-flow pictures of the images (Image or CompressedImage, colour
            wheel), or None (default: none recorded). Read only when a segmenter uses them.
        flow_tolerance_s: A flow picture belongs to the image whose stamp is within this (our
            choice: as ``mask_tolerance_s``, pictures stamped with their image's header).
    """

    image_topic: str = "/camera/color/image_raw"
    camera_info_topic: str = "/camera/color/camera_info"
    tf_topic: str = "/tf"
    tf_static_topic: str = "/tf_static"
    world_frame: str = "base_link"
    camera_frame: str = "camera_color_optical_frame"
    pose_topic: str | None = None
    mask_topic: str | None = "/image_mask"
    pose_tolerance_s: float = 0.05
    max_interpolation_gap_s: float = 0.5
    mask_tolerance_s: float = 0.005
    typestore: str = "ros2_humble"
    flow_topic: str | None = None
    flow_tolerance_s: float = 0.005

    def __post_init__(self) -> None:
        names = ("pose_tolerance_s", "max_interpolation_gap_s", "mask_tolerance_s")
        for name in (*names, "flow_tolerance_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"BagConfig.{name} must be >= 0, got {value}")


def add_bag_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--image-topic`` ... ``--mask-topic`` (the :class:`BagConfig` fields) to a parser."""
    group = parser.add_argument_group("ROS bag sources")
    defaults = BagConfig()
    for f in fields(BagConfig):
        flag = "--" + f.name.replace("_", "-")
        default = getattr(defaults, f.name)
        kind = float if isinstance(default, float) else str
        group.add_argument(flag, type=kind, default=default, help=f"(default: {default})")


def bag_config_from_args(args: argparse.Namespace) -> BagConfig:
    """The :class:`BagConfig` of parsed :func:`add_bag_arguments` flags ("none" -> None)."""
    values = {}
    for f in fields(BagConfig):
        value = getattr(args, f.name)
        if isinstance(value, str) and value.lower() == "none" and f.name.endswith("_topic"):
            value = None
        values[f.name] = value
    return BagConfig(**values)
