"""Recorded scans in and out: the scan folder format, ROS bags, undistortion, tube meshes.

* :mod:`recon.io.folder`: the documented folder format (``docs/replay.md``), reader and writer;
* :mod:`recon.io.rosbag`: ROS 2 bags via the optional ``rosbags`` package (imported lazily);
* :mod:`recon.io.distortion`: calibration with lens distortion, undistortion of images/masks;
* :mod:`recon.io.mesh`: tree models as tube meshes (PLY).
"""

from recon.io.atomic import OutputExistsError, atomic_output_dir
from recon.io.distortion import CameraModel, Undistorter
from recon.io.folder import (
    CAMERA_FILE,
    FRAMES_FILE,
    METADATA_FILE,
    TRUTH_FILE,
    LoadedFrame,
    ScanFolder,
    ScanFormatConfig,
    ScanFormatError,
    ScanWriter,
)
from recon.io.source import ScanSource, open_source

__all__ = [
    "CAMERA_FILE",
    "FRAMES_FILE",
    "METADATA_FILE",
    "TRUTH_FILE",
    "CameraModel",
    "LoadedFrame",
    "OutputExistsError",
    "ScanFolder",
    "ScanFormatConfig",
    "ScanFormatError",
    "ScanSource",
    "ScanWriter",
    "Undistorter",
    "atomic_output_dir",
    "open_source",
]
