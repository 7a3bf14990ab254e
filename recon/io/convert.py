"""Import any scan source (e.g. a ROS bag) as a scan folder."""

from __future__ import annotations

import logging
from collections import Counter
from pathlib import Path

from recon.io.distortion import CameraModel
from recon.io.folder import ScanWriter
from recon.io.source import ScanSource

logger = logging.getLogger(__name__)


def convert(
    source: ScanSource,
    out_dir: str | Path,
    image_format: str = "png",
    jpeg_quality: int = 95,
    overwrite: bool = False,
) -> dict:
    """Write the usable frames of ``source`` as a scan folder (undistorted, no distortion left).

    Skipped frames (no pose, no mask, ...) are not written; they are counted in the returned
    report and listed in the folder's ``metadata.json`` under ``"skipped"``.

    Args:
        source: A :class:`recon.io.ScanFolder` or :class:`recon.io.rosbag.BagSource`.
        out_dir: The scan folder to create (written atomically).
        image_format: "png" or "jpg".
        jpeg_quality: JPEG quality 0-100.
        overwrite: Replace an existing ``out_dir``.

    Returns:
        {"written": int, "skipped": int, "skip_reasons": {reason: count}}.
    """
    camera = CameraModel(source.intrinsics)  # images are written undistorted
    skipped: list[dict] = []
    with ScanWriter(out_dir, camera, image_format, jpeg_quality, overwrite) as writer:
        for loaded in source.frames():
            if loaded.skip_reason is not None:
                skipped.append(
                    {
                        "index": loaded.index,
                        "time": loaded.time_s,
                        "kind": loaded.skip_kind,
                        "reason": loaded.skip_reason,
                    }
                )
                continue
            writer.add(loaded.time_s, loaded.T_world_camera, loaded.rgb, loaded.mask)
        writer.metadata.update(
            {"imported_from": source.name, "source": source.metadata, "skipped": skipped}
        )
        written = writer.n_frames
    reasons = Counter(s["kind"] for s in skipped)
    logger.info("imported %s: %d frames, %d skipped", source.name, written, len(skipped))
    return {"written": written, "skipped": len(skipped), "skip_reasons": dict(reasons)}
