"""Replay a recorded scan (a scan folder or a ROS bag) through the modeler and write the results.

``python -m recon.replay SOURCE --out OUT [--truth GT.json] [--segmenter learned[:PATH]]``

OUT holds (``docs/replay.md``):

* ``model.json``: the tree model (:meth:`recon.TreeModel.to_dict`: primary and secondaries,
  points and radii in metres, world frame);
* ``model.ply``: the model as tube meshes (primary brown, secondaries green);
* ``iterations.csv``: one row per modeling iteration (outcome, reason, counts, stage timings);
* ``frames.csv``: one row per input frame (fed / iteration / skipped, with the reason);
* ``overlay.mp4`` (``overlay.gif`` without an MP4 codec): each image with its mask and the
  projected model;
* ``plot3d.png``: the model, the camera path and the ground truth if given;
* ``summary.json``: counts, seed, config, outcomes, median timings and the metrics (``--truth``).

The output folder is written next to OUT and renamed when complete: a failed replay leaves nothing.

Optical flow of a learned segmenter (``--segmenter learned[:PATH]``): a network that reads the
paper's flow picture (``uses_flow_picture``) gets, per image frame, the recording's flow picture
when it has one (a scan folder's ``"flow"`` / ``<image>_flow.png``, a bag's ``--flow-topic``;
``recon.io.folder``) as ``flow_image``, else the earlier frame that
:class:`recon.segmentation.flow.FramePairer` picks by the recorded camera poses (moved >= 7.5 mm
and turned < 0.5 deg since) as ``previous_rgb``, else nothing (colours alone). Every image
frame enters the pairing history. Recorded pictures are taken as RGB; pass
``--flow-red-blue-swapped`` for pictures saved with ``cv2.imwrite`` of an RGB array (red and blue
exchanged, as the authors' real pictures appear to be: ``recon/segmentation/flow.py``). Any
other segmenter gets the previous image frame as ``previous_rgb``.

A camera of another resolution (``--working-focal-px``): the pipeline's pixel thresholds and
our segmenters were made for the authors' 320x240 camera (416.8 px focal length);
:class:`recon.io.rescale.RescaledSource` resizes a recording's frames, masks, flow pictures and
intrinsics to a chosen focal length before anything reads them. With ``--segmenter learned``
that is the default (``auto``); recorded masks are read as recorded unless asked.
"""

from __future__ import annotations

import argparse
import csv
import importlib
import json
import logging
import math
import sys
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from tqdm import tqdm

from recon.config import (
    REMOVED_MODELER_FIELDS,
    ModelerConfig,
    add_modeler_argument,
    modeler_overrides,
    removed_field_message,
)
from recon.io.atomic import atomic_output_dir, check_output_dir
from recon.io.folder import LoadedFrame, ScanFormatError
from recon.io.mesh import TubeMeshConfig, tree_mesh, write_ply
from recon.io.rescale import PIPELINE_FOCAL_PX, RescaledSource
from recon.io.rosbag import add_bag_arguments, bag_config_from_args
from recon.io.source import ScanSource, open_source
from recon.metrics import TreeMetrics, evaluate
from recon.model import TreeModel
from recon.modeler import IterationReport, Modeler
from recon.overlay import model_overlay
from recon.plot3d import plot_model_3d
from recon.segmentation.flow import FramePairer
from recon.segmentation.flow import swap_red_blue as swap_flow_red_blue
from recon.segmentation.spec import is_learned_segmenter
from recon.tracking import LucasKanadeTracker, PointTracker

if TYPE_CHECKING:  # recon.segmentation (torch) is imported only for a learned segmenter
    from recon.segmentation.flow import FramePairer, FramePairingConfig

logger = logging.getLogger(__name__)

TRACKERS = ("lk",)
MASK_SOURCES = ("mask",)  # masks from the recording; "learned[:PATH]" -> recon.segmentation


class ReplayError(RuntimeError):
    """The replay cannot run (no masks and no segmenter, segmenter missing, ...)."""


@dataclass(frozen=True)
class ReplayConfig:
    """Output settings of a replay.

    Attributes:
        video_fps: Frame rate of the overlay video.
        gif_max_frames: Frames kept for the GIF fallback (every k-th frame beyond this).
        mask_alpha: Opacity of the mask tint in the overlay.
        plot_dpi: Resolution of ``plot3d.png``.
        mesh: Tube mesh tessellation.
    """

    video_fps: float = 15.0
    gif_max_frames: int = 150
    mask_alpha: float = 0.35
    plot_dpi: int = 120
    mesh: TubeMeshConfig = field(default_factory=TubeMeshConfig)


@dataclass
class ReplayResult:
    """What a replay produced.

    Attributes:
        model: The final tree model.
        reports: Every iteration's report, in order.
        n_frames: Frames in the source.
        n_fed: Frames handed to the modeler.
        skip_reasons: Reason category (:attr:`LoadedFrame.skip_kind`) -> frames skipped for it;
            ``frames.csv`` has each frame's full reason.
        metrics: Scores against the ground truth (``truth`` given), else None.
        seed: The modeler seed used.
        out_dir: The output folder.
        files: Output file names.
        wall_time_s: Wall-clock time of the replay.
        flow_inputs: A flow-picture segmenter's inputs, frames by kind (``"recorded"``: the
            recording's flow picture, ``"paired"``: flow against a paired earlier frame,
            ``"none"``: colours alone); empty for other segmenters.
    """

    model: TreeModel
    reports: list[IterationReport]
    n_frames: int
    n_fed: int
    skip_reasons: dict[str, int]
    metrics: TreeMetrics | None
    seed: int
    out_dir: Path
    files: list[str]
    wall_time_s: float
    flow_inputs: dict[str, int] = field(default_factory=dict)

    @property
    def n_skipped(self) -> int:
        return sum(self.skip_reasons.values())


# ---------------------------------------------------------------------- hooks
def make_tracker(name: str) -> PointTracker:
    """The point tracker of a replay ("lk": Lucas-Kanade, the simulator's default)."""
    if name == "lk":
        return LucasKanadeTracker()
    raise ValueError(f"unknown tracker {name!r}: expected one of {TRACKERS}")


def load_segmenter(spec: str | None):
    """None for masks from the recording; ``learned`` / ``learned:PATH`` -> recon.segmentation.

    Returns:
        None, or an object with ``segment(rgb, previous_rgb=None) -> (H, W) bool`` (a
        :class:`recon.segmentation.LearnedSegmenter`).

    Raises:
        ValueError: an unknown spec.
        ReplayError: ``recon.segmentation`` (the learned RGB segmenter) is not available.
    """
    if spec is None or spec in MASK_SOURCES:
        return None
    if not is_learned_segmenter(spec):
        raise ValueError(
            f"unknown segmenter {spec!r}: expected 'mask' (the recorded masks), 'learned' or "
            "'learned:PATH'"
        )
    try:
        module = importlib.import_module("recon.segmentation")
    except ImportError as error:
        raise ReplayError(
            f"--segmenter {spec} needs the learned RGB segmenter (recon.segmentation), which "
            f"cannot be imported here ({error})"
        ) from error
    loader = getattr(module, "load_segmenter", None)
    if loader is None:
        raise ReplayError(
            f"--segmenter {spec}: recon.segmentation has no load_segmenter(spec) in this "
            "checkout (the learned segmenter is not available yet)"
        )
    return loader(spec)


def modeler_settings(
    metadata: dict, seed: int | None, config: ModelerConfig | None
) -> tuple[int, ModelerConfig]:
    """The seed and config: explicit values, else the recording's metadata, else defaults.

    A recorded field that has been removed since (:data:`recon.config.REMOVED_MODELER_FIELDS`)
    is dropped, with a warning naming it where the recording ran another value than today's
    code runs.
    """
    recorded = metadata.get("modeler", {}) if isinstance(metadata, dict) else {}
    if seed is None:
        seed = int(recorded.get("seed", 0))
    if config is None:
        values = recorded.get("config") or {}
        for name in sorted(set(values) & set(REMOVED_MODELER_FIELDS)):
            if values[name] != REMOVED_MODELER_FIELDS[name].value:
                logger.warning("the recording ran %s=%r: %s", name, values[name],
                               removed_field_message(name))  # fmt: skip
        known = {f.name for f in fields(ModelerConfig)}
        unknown = sorted(set(values) - known - set(REMOVED_MODELER_FIELDS))
        if unknown:
            logger.warning("ignoring unknown recorded ModelerConfig fields %s", unknown)
        config = ModelerConfig(**{k: v for k, v in values.items() if k in known})
    return seed, config


def _learned_masks(source: ScanSource) -> bool:
    """The recorded masks come from a learned segmenter (a branch_gym recording says so)."""
    scan = source.metadata.get("scan", {}) if isinstance(source.metadata, dict) else {}
    return isinstance(scan, dict) and is_learned_segmenter(scan.get("segmenter"))


def load_truth(path: str | Path) -> TreeModel:
    """Ground truth JSON (branch_gym's TreeGT: ``primary`` and ``secondaries`` with points/radii).

    Raises:
        ScanFormatError: unreadable, or no primary branch.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        truth = TreeModel.from_dict(data)
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ScanFormatError(f"{path}: cannot read ground truth ({error})") from None
    if truth.primary is None:
        raise ScanFormatError(f"{path}: ground truth has no primary branch")
    return truth


# ---------------------------------------------------------------------- overlay
class OverlayVideo:
    """MP4 through OpenCV; an animated GIF (Pillow) where no MP4 codec is available."""

    def __init__(self, folder: Path, size: tuple[int, int], config: ReplayConfig) -> None:
        self.config = config
        self.size = size
        self.path = folder / "overlay.mp4"
        self._writer = cv2.VideoWriter(
            str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), config.video_fps, size
        )
        self._gif: list[np.ndarray] = []
        self._n = 0
        if not self._writer.isOpened():
            logger.warning("no MP4 codec in this OpenCV: writing overlay.gif instead")
            self._writer = None
            self.path.unlink(missing_ok=True)
            self.path = folder / "overlay.gif"

    def write(self, bgr: np.ndarray) -> None:
        self._n += 1
        if self._writer is not None:
            self._writer.write(bgr)
        else:
            self._gif.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))

    def close(self) -> Path | None:
        """Finish the file; None when no frame was written."""
        if self._writer is not None:
            self._writer.release()
            if self._n == 0:
                self.path.unlink(missing_ok=True)
                return None
            return self.path
        if not self._gif:
            return None
        from PIL import Image

        step = max(1, math.ceil(len(self._gif) / self.config.gif_max_frames))
        images = [Image.fromarray(f) for f in self._gif[::step]]
        duration_ms = int(1000 * step / self.config.video_fps)
        images[0].save(
            self.path, save_all=True, append_images=images[1:], duration=duration_ms, loop=0
        )
        return self.path


# ---------------------------------------------------------------------- tables
def _write_csv(path: Path, rows: list[dict]) -> None:
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def _json_float(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


# ---------------------------------------------------------------------- the replay
def replay(
    source: ScanSource | str | Path,
    out_dir: str | Path,
    truth: TreeModel | str | Path | None = None,
    segmenter: str | object | None = None,
    tracker: str = "lk",
    seed: int | None = None,
    modeler_config: ModelerConfig | None = None,
    config: ReplayConfig | None = None,
    overwrite: bool = False,
    progress: bool = True,
    flow_red_blue_swapped: bool = False,
    pairing: FramePairingConfig | None = None,
    working_focal_px: float | str | None = "auto",
) -> ReplayResult:
    """Run :class:`recon.modeler.Modeler` over a recorded scan and write the outputs.

    Args:
        source: A scan source, or a path for :func:`recon.io.open_source`.
        out_dir: Output folder (written atomically; see the module docstring for its files).
        truth: Ground truth (TreeModel or a TreeGT JSON path) to score the model against.
        segmenter: None / "mask" (recorded masks), "learned[:PATH]", or an object with
            ``segment(rgb, previous_rgb=None) -> (H, W) bool``; one whose
            ``uses_flow_picture`` is true also takes ``flow_image=`` (module docstring).
        tracker: Point tracker name (``TRACKERS``).
        seed: Modeler seed; default: the recording's (``metadata.json``), else 0.
        modeler_config: Modeler thresholds; default: the recording's, else the defaults. Those
            left to the mask source (``ModelerConfig.for_masks``) are resolved as for a learned
            segmenter's masks when ``segmenter`` is one or the recording's masks came from one
            (its ``metadata.json`` says ``learned``), else as for exact masks.
        config: Output settings.
        overwrite: Replace an existing ``out_dir``.
        progress: Show a tqdm progress bar.
        flow_red_blue_swapped: The recorded flow pictures hold the colour wheel with red and
            blue exchanged (written with ``cv2.imwrite`` of an RGB array): exchange them back
            (:func:`recon.segmentation.flow.swap_red_blue`) before the segmenter sees them.
        pairing: How a flow-picture segmenter's frames are paired by pose (default
            ``FramePairingConfig()``, the authors' thresholds).
        working_focal_px: Resize the frames (images, masks, flow pictures, intrinsics) so that
            their focal length becomes this many pixels before anything reads them
            (:class:`recon.io.rescale.RescaledSource`); None keeps them as recorded.
            ``"auto"`` (default): ``PIPELINE_FOCAL_PX``, the camera the pipeline's thresholds
            and every network of ``branch_gym``'s segmenter training were made for, with a
            ``learned[:PATH]`` segmenter; as recorded with recorded masks or a segmenter object
            of your own.

    Returns:
        The :class:`ReplayResult`.

    Raises:
        ScanFormatError: a bad recording (the message names the file, topic or frame).
        ReplayError: frames without masks and no segmenter, or a segmenter that is missing.
        OutputExistsError: ``out_dir`` exists and ``overwrite`` is False.
    """
    wall_start = time.perf_counter()
    config = config or ReplayConfig()
    check_output_dir(out_dir, overwrite)
    if isinstance(source, str | Path):
        source = open_source(source)
    source = _at_working_focal_length(source, working_focal_px, segmenter)
    seg = load_segmenter(segmenter) if isinstance(segmenter, str | None) else segmenter
    if seg is None and not source.has_masks:
        missing = source.frames_without_mask
        raise ReplayError(
            f"{source.name}: {len(missing)} frame(s) have no mask (first: frame {missing[0]}) and "
            "no segmenter was given: record masks or pass --segmenter learned[:PATH]"
        )
    if truth is not None and not isinstance(truth, TreeModel):
        truth = load_truth(truth)
    seed, modeler_config = modeler_settings(source.metadata, seed, modeler_config)
    modeler_config = modeler_config.for_masks(learned=seg is not None or _learned_masks(source))
    recorded_tracker = source.metadata.get("modeler", {}).get("tracker", tracker)
    if recorded_tracker != tracker:
        logger.warning(
            "the scan was modelled online with tracker %r, the replay uses %r: the models differ",
            recorded_tracker,
            tracker,
        )
    modeler = Modeler(make_tracker(tracker), modeler_config, seed=seed)
    intrinsics = source.intrinsics
    flow = _FlowInputs.of(seg, pairing, flow_red_blue_swapped)

    reports: list[IterationReport] = []
    iteration_rows: list[dict] = []
    frame_rows: list[dict] = []
    skip_reasons: Counter[str] = Counter()
    camera_path: list[np.ndarray] = []
    n_fed = 0
    with atomic_output_dir(out_dir, overwrite) as tmp:
        video = OverlayVideo(tmp, (intrinsics.width, intrinsics.height), config)
        if flow.pairer is None:
            frames = source.frames(load_masks=seg is None)
        else:
            frames = source.frames(load_masks=False, load_flow=True)
        bar = tqdm(frames, total=len(source), desc="replay", unit="frame", disable=not progress)
        last_outcome = "-"
        for loaded in bar:
            row = {"index": loaded.index, "time_s": loaded.time_s, "source": loaded.where}
            frame, reason = _make_frame(loaded, intrinsics, seg, flow)
            if frame is None:
                skip_reasons[loaded.skip_kind or "unusable frame"] += 1
                frame_rows.append({**row, "status": "skipped", "reason": reason})
                logger.info("skipping frame %d (%s): %s", loaded.index, loaded.where, reason)
                continue
            report = modeler.update(frame)
            n_fed += 1
            camera_path.append(frame.T_world_camera[:3, 3].copy())
            status = "fed"
            if report is not None:
                reports.append(report)
                status = "iteration"
                last_outcome = report.outcome.value
                iteration_rows.append(_iteration_row(report, loaded, frame.T_world_camera))
                bar.set_postfix_str(f"{last_outcome}, {len(modeler.model.secondaries)} SB")
            frame_rows.append({**row, "status": status, "reason": ""})
            if frame.has_image:
                text = f"frame {loaded.index}  t={loaded.time_s:.2f}s  {last_outcome}"
                overlay = model_overlay(
                    frame.rgb,
                    frame.mask,
                    modeler.model,
                    frame.T_world_camera,
                    intrinsics,
                    [text],
                    config.mask_alpha,
                )
                video.write(cv2.cvtColor(overlay, cv2.COLOR_RGB2BGR))
        bar.close()
        if n_fed == 0:
            raise ReplayError(f"{source.name}: no usable frame ({dict(skip_reasons)})")
        model = modeler.model
        path = np.array(camera_path)
        metrics = None
        if truth is not None:
            top = source.metadata.get("scanned_top_z_m")
            top = float(top) if top is not None else float(path[:, 2].max())
            metrics = evaluate(model, truth, scanned_top_z_m=top)

        (tmp / "model.json").write_text(json.dumps(model.to_dict()))
        write_ply(tmp / "model.ply", *tree_mesh(model, config.mesh))
        _write_csv(tmp / "iterations.csv", iteration_rows or [{"index": ""}])
        _write_csv(tmp / "frames.csv", frame_rows)
        video_path = video.close()
        title = f"{Path(source.name).name}: {len(model.secondaries)} secondaries"
        if metrics is not None:
            title += f", PB residual {metrics.pb_residual_mean_m * 1e3:.1f} mm"
        plot_model_3d(tmp / "plot3d.png", model, path, truth, title, config.plot_dpi)
        files = ["model.json", "model.ply", "iterations.csv", "frames.csv", "plot3d.png"]
        if video_path is not None:
            files.insert(4, video_path.name)
        files.append("summary.json")
        wall = time.perf_counter() - wall_start
        summary = _summary(
            source, model, reports, len(frame_rows), n_fed, skip_reasons, metrics, seed,
            modeler_config, tracker, segmenter, files, wall,
        )  # fmt: skip
        if flow.pairer is not None:
            summary["flow_inputs"] = dict(flow.counts)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
    return ReplayResult(
        model, reports, len(frame_rows), n_fed, dict(skip_reasons), metrics, seed,
        Path(out_dir), files, wall, dict(flow.counts),
    )  # fmt: skip


@dataclass
class _FlowInputs:
    """What a segmenter's optical-flow input is taken from, frame after frame.

    Attributes:
        pairer: The frame pairer of a flow-picture segmenter, else None (then the previous
            image frame is the flow partner).
        swap_red_blue: Exchange red and blue of the recorded flow pictures.
        previous_rgb: (H, W, 3) uint8 previous image frame (segmenters without flow pictures).
        counts: Frames by input kind (``ReplayResult.flow_inputs``).
    """

    pairer: FramePairer | None = None
    swap_red_blue: bool = False
    previous_rgb: np.ndarray | None = None
    counts: Counter[str] = field(default_factory=Counter)

    @classmethod
    def of(
        cls, seg: object | None, pairing: FramePairingConfig | None, swap_red_blue: bool
    ) -> _FlowInputs:
        """The flow inputs of segmenter ``seg`` (None: recorded masks)."""
        if seg is None or not getattr(seg, "uses_flow_picture", False):
            return cls()
        return cls(FramePairer(pairing), swap_red_blue)

    def segment(self, seg, loaded: LoadedFrame) -> np.ndarray:
        """(H, W) mask of an image frame (module docstring); the frame joins the history.

        Args:
            seg: The segmenter.
            loaded: A usable image frame (``rgb``, ``T_world_camera``, maybe ``flow_image``).

        Returns:
            (H, W) bool (or 0/1) mask from the segmenter.
        """
        if self.pairer is None:
            previous, self.previous_rgb = self.previous_rgb, loaded.rgb
            return np.asarray(seg.segment(loaded.rgb, previous_rgb=previous))
        partner = self.pairer.add(loaded.rgb, loaded.T_world_camera)
        if loaded.flow_image is not None:
            picture = (
                swap_flow_red_blue(loaded.flow_image) if self.swap_red_blue else loaded.flow_image
            )
            self.counts["recorded"] += 1
            return np.asarray(seg.segment(loaded.rgb, flow_image=picture))
        self.counts["none" if partner is None else "paired"] += 1
        return np.asarray(seg.segment(loaded.rgb, previous_rgb=partner))


def _make_frame(loaded: LoadedFrame, intrinsics, seg, flow: _FlowInputs):
    """(Frame, None) or (None, reason)."""
    if loaded.skip_reason is not None:
        return None, loaded.skip_reason
    mask = None
    if seg is not None and not loaded.pose_only:
        mask = flow.segment(seg, loaded)
    try:
        return loaded.to_frame(intrinsics, mask), None
    except ValueError as error:
        return None, f"unusable frame: {error}"


def _iteration_row(report: IterationReport, loaded: LoadedFrame, T: np.ndarray) -> dict:
    row = {
        "iteration": report.index,
        "frame_index": loaded.index,
        "time_s": loaded.time_s,
        "camera_z_m": float(T[2, 3]),
        "outcome": report.outcome.value,
        "reason": report.reason,
        "consistency_fraction": report.consistency_fraction,
        "n_lifted": report.n_lifted,
        "n_secondary_detections": report.n_secondary_detections,
        "n_new_secondaries": report.n_new_secondaries,
        "n_secondaries": report.n_secondaries,
        "search_truncated": report.search_truncated,
    }
    row.update({k: round(v, 3) for k, v in report.timings_ms.items()})
    return row


def _summary(
    source, model, reports, n_frames, n_fed, skip_reasons, metrics, seed, modeler_config,
    tracker, segmenter, files, wall,
) -> dict:  # fmt: skip
    outcomes = Counter(r.outcome.value for r in reports)
    stages = sorted({k for r in reports for k in r.timings_ms})
    stage_ms = {
        k: float(np.median([r.timings_ms[k] for r in reports if k in r.timings_ms])) for k in stages
    }
    return {
        "source": source.name,
        "n_frames": n_frames,
        "n_fed": n_fed,
        "n_skipped": sum(skip_reasons.values()),
        "skip_reasons": dict(skip_reasons),
        "n_iterations": len(reports),
        "outcomes": dict(outcomes),
        "median_stage_ms": stage_ms,
        "seed": seed,
        "tracker": tracker,
        "segmenter": segmenter if isinstance(segmenter, str | None) else type(segmenter).__name__,
        "camera": asdict(source.intrinsics),  # as the pipeline saw the frames (maybe resized)
        "modeler_config": asdict(modeler_config),
        "model": {
            "has_primary": model.primary is not None,
            "primary_points": 0 if model.primary is None else len(model.primary.points),
            "primary_length_m": 0.0 if model.primary is None else model.primary.length_m,
            "n_secondaries": len(model.secondaries),
        },
        "metrics": None if metrics is None else metrics.to_json_dict(),
        "files": files,
        "wall_time_s": wall,
    }


# ---------------------------------------------------------------------- CLI
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


def _at_working_focal_length(
    source: ScanSource, focal_px: float | str | None, segmenter: str | object | None
) -> ScanSource:
    """``source`` resized to the working focal length of :func:`replay` (its docstring)."""
    if focal_px == "auto":
        learned = isinstance(segmenter, str) and is_learned_segmenter(segmenter)
        focal_px = PIPELINE_FOCAL_PX if learned else None
    if focal_px is None:
        return source
    if isinstance(focal_px, str):
        raise ValueError(f"working_focal_px must be a number, 'auto' or None, got {focal_px!r}")
    rescaled = RescaledSource(source, focal_px)
    intrinsics = source.intrinsics
    return source if rescaled.size == (intrinsics.width, intrinsics.height) else rescaled


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


if __name__ == "__main__":
    raise SystemExit(main())
