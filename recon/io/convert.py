"""Import any scan source (e.g. a ROS bag) as a scan folder: ``python -m recon.io.convert``."""

from __future__ import annotations

import argparse
import logging
from collections import Counter
from pathlib import Path

from recon.io.distortion import CameraModel
from recon.io.folder import ScanWriter
from recon.io.rosbag import BagSource, add_bag_arguments, bag_config_from_args
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
    report and listed in the folder's ``metadata.json`` under ``"skipped"``. Recorded
    optical-flow pictures (a bag's ``flow_topic``) are written as ``flow/NNNNNN.png``, colours
    as decoded.

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
        for loaded in source.frames(load_flow=True):
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
            writer.add(
                loaded.time_s, loaded.T_world_camera, loaded.rgb, loaded.mask, loaded.flow_image
            )
        writer.metadata.update(
            {"imported_from": source.name, "source": source.metadata, "skipped": skipped}
        )
        written = writer.n_frames
    reasons = Counter(s["kind"] for s in skipped)
    logger.info("imported %s: %d frames, %d skipped", source.name, written, len(skipped))
    return {"written": written, "skipped": len(skipped), "skip_reasons": dict(reasons)}


def main(argv: list[str] | None = None) -> int:
    """``python -m recon.io.convert BAG --out DIR``: import a bag as a scan folder."""
    parser = argparse.ArgumentParser(
        prog="python -m recon.io.convert",
        description="Import a ROS 2 bag as a scan folder (undistorted images, masks, poses).",
    )
    parser.add_argument("bag", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--image-format", choices=("png", "jpg"), default="png")
    parser.add_argument("--overwrite", action="store_true")
    add_bag_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    source = BagSource(args.bag, bag_config_from_args(args))
    report = convert(source, args.out, image_format=args.image_format, overwrite=args.overwrite)
    print(f"wrote {args.out}: {report['written']} frames, {report['skipped']} skipped")
    for reason, count in report["skip_reasons"].items():
        print(f"  skipped {count}: {reason}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
