"""Scan sources: a scan folder or a ROS bag, behind one small interface."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

from recon.camera import CameraIntrinsics
from recon.io import rosbag
from recon.io.folder import CAMERA_FILE, LoadedFrame, ScanFolder, ScanFormatConfig, ScanFormatError


class ScanSource(Protocol):
    """What the replay reads: frames in time order with the calibration and metadata.

    Attributes:
        name: Where it comes from (a path).
        intrinsics: Intrinsics of the (undistorted) frames.
        metadata: Provenance, modeler seed and config when recorded (may be empty).
        has_masks: Every image frame has a mask.
    """

    name: str
    metadata: dict

    @property
    def intrinsics(self) -> CameraIntrinsics: ...

    @property
    def has_masks(self) -> bool: ...

    @property
    def frames_without_mask(self) -> list[int]: ...

    def __len__(self) -> int: ...

    def truth_path(self) -> Path | None: ...

    def frames(self, load_masks: bool = True, load_flow: bool = False) -> Iterator[LoadedFrame]:
        """Frames in time order; ``load_flow`` also reads recorded optical-flow pictures."""
        ...


def open_source(
    path: str | Path,
    bag_config: object | None = None,
    format_config: ScanFormatConfig | None = None,
    skip_bad_frames: bool = False,
) -> ScanSource:
    """Open a scan folder (``camera.json``) or a ROS bag (``metadata.yaml``, .db3, .mcap, .bag).

    Args:
        path: The folder or bag.
        bag_config: :class:`recon.io.rosbag.BagConfig` for bags (authors' topics by default).
        format_config: Reader tolerances.
        skip_bad_frames: Folders only: report unreadable/missing/mis-sized files as skipped
            frames instead of raising.

    Raises:
        ScanFormatError: neither a scan folder nor a bag, or an invalid one.
        ImportError: a bag, but ``rosbags`` is not installed.
    """
    path = Path(path)
    if not path.exists():
        raise ScanFormatError(f"{path}: no such scan folder or bag")
    if path.is_dir() and (path / CAMERA_FILE).exists():
        return ScanFolder(path, format_config, skip_bad_frames)
    if rosbag.is_bag(path):
        return rosbag.BagSource(path, bag_config, format_config)
    raise ScanFormatError(
        f"{path}: neither a scan folder (no {CAMERA_FILE}) nor a ROS bag "
        "(no metadata.yaml, not a .db3/.mcap/.bag file)"
    )
