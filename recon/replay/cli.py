"""The ``python -m recon.replay`` (``recon-replay``) command line."""

from __future__ import annotations

import argparse
import logging
import math
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

from recon.config import add_modeler_argument, modeler_overrides
from recon.io.folder import ScanFormatError
from recon.io.rescale import PIPELINE_FOCAL_PX
from recon.io.rosbag import add_bag_arguments, bag_config_from_args
from recon.io.source import open_source
from recon.replay.inputs import TRACKERS, ReplayError, modeler_settings
from recon.replay.loop import ReplayResult, replay


def main(argv: list[str] | None = None) -> int:
    """The ``python -m recon.replay`` command line."""
    parser = argparse.ArgumentParser(
        prog="python -m recon.replay",
        description="Reconstruct a tree from a recorded scan (scan folder or ROS bag).",
    )
    parser.add_argument("source", type=Path, help="scan folder (camera.json) or ROS bag")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--truth", type=Path, help="ground truth JSON (branch_gym TreeGT)")
    parser.add_argument(
        "--segmenter", default="mask", help="'mask' (recorded masks), 'learned' or 'learned:PATH'"
    )
    parser.add_argument(
        "--flow-red-blue-swapped",
        action="store_true",
        help="the recorded flow pictures have red and blue exchanged (cv2.imwrite of an RGB "
        "array, as the authors' real pictures): exchange them back (flow-picture segmenters)",
    )
    parser.add_argument(
        "--working-focal-px",
        type=_focal_px,
        default="auto",
        metavar="F|pipeline|native|auto",
        help="resize the frames so that their focal length becomes F px; 'pipeline': "
        f"{PIPELINE_FOCAL_PX:.1f} px, the camera the paper's pixel thresholds and our "
        "segmenters were made for; 'native': as recorded; 'auto' (default): 'pipeline' with "
        "--segmenter learned[:PATH], else 'native'",
    )
    parser.add_argument("--tracker", choices=TRACKERS, default="lk")
    parser.add_argument("--seed", type=int, help="modeler seed (default: the recording's, or 0)")
    add_modeler_argument(
        parser,
        "over the recording's, e.g. secondary_trust_tolerance_px=4 for masks of your own learned "
        "segmenter",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument(
        "--skip-bad-frames",
        action="store_true",
        help="scan folders: skip (and report) frames with missing/unreadable/mis-sized files",
    )
    parser.add_argument("--no-progress", action="store_true")
    add_bag_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        source = open_source(
            args.source, bag_config_from_args(args), skip_bad_frames=args.skip_bad_frames
        )
        modeler_config = None
        if args.modeler:
            _, recorded = modeler_settings(source.metadata, args.seed, None)
            modeler_config = replace(recorded, **modeler_overrides(args.modeler))
        result = replay(
            source,
            args.out,
            truth=args.truth,
            segmenter=args.segmenter,
            tracker=args.tracker,
            seed=args.seed,
            modeler_config=modeler_config,
            overwrite=args.overwrite,
            progress=not args.no_progress,
            flow_red_blue_swapped=args.flow_red_blue_swapped,
            working_focal_px=args.working_focal_px,
        )
    except (
        ScanFormatError,
        ReplayError,
        ImportError,
        FileExistsError,
        ValueError,
        TypeError,
    ) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    _print_summary(result)
    return 0


def _focal_px(text: str) -> float | str | None:
    """``--working-focal-px``: a positive number of pixels, ``pipeline``, ``native`` or ``auto``."""
    if text in ("auto", "native", "pipeline"):
        return {"auto": "auto", "native": None, "pipeline": PIPELINE_FOCAL_PX}[text]
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(
            f"expected a positive focal length in pixels, 'pipeline', 'native' or 'auto', got "
            f"{text!r}"
        )
    return value


def _print_summary(result: ReplayResult) -> None:
    model = result.model
    outcomes = Counter(r.outcome.value for r in result.reports)
    primary = (
        "no primary"
        if model.primary is None
        else f"primary {model.primary.length_m * 100:.1f} cm ({len(model.primary.points)} points)"
    )
    print(f"{result.out_dir}: {primary}, {len(model.secondaries)} secondaries")
    print(
        f"frames: {result.n_frames} read, {result.n_fed} fed, {result.n_skipped} skipped; "
        f"iterations: {dict(outcomes)}; seed {result.seed}; {result.wall_time_s:.1f} s"
    )
    for reason, count in result.skip_reasons.items():
        print(f"  skipped {count}: {reason}")
    if result.metrics is not None:
        m = result.metrics
        print(
            f"PB residual {m.pb_residual_mean_m * 1e3:.2f} mm, PB radius RMSE "
            f"{m.pb_radius_rmse_m * 1e3:.2f} mm, missed {m.missed_pct:.1f} %, spurious "
            f"{m.spurious_pct:.1f} %"
        )
    print("files: " + ", ".join(result.files))
