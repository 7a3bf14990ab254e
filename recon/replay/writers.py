"""What a replay writes into its output folder (``recon/replay/__init__.py`` lists the files):
the model, its mesh, the frame and iteration tables, the overlay video, the 3D plot and the
summary.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from recon.io.folder import LoadedFrame
from recon.io.mesh import TubeMeshConfig, tree_mesh, write_ply
from recon.io.source import ScanSource
from recon.metrics import TreeMetrics
from recon.model import TreeModel
from recon.modeler import IterationReport
from recon.plot3d import plot_model_3d

logger = logging.getLogger(__name__)


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
class ReplayLog:
    """What the loop over a recording's frames records for the output files.

    Attributes:
        reports: Every iteration's report, in order.
        iteration_rows: The rows of ``iterations.csv`` (:func:`iteration_row`).
        frame_rows: The rows of ``frames.csv``: one per input frame.
        skip_reasons: Reason category (:attr:`LoadedFrame.skip_kind`) -> frames skipped for it.
        camera_path: (3,) camera positions of the frames fed to the modeler (m, world frame).
        n_fed: Frames handed to the modeler.
    """

    reports: list[IterationReport] = field(default_factory=list)
    iteration_rows: list[dict] = field(default_factory=list)
    frame_rows: list[dict] = field(default_factory=list)
    skip_reasons: Counter[str] = field(default_factory=Counter)
    camera_path: list[np.ndarray] = field(default_factory=list)
    n_fed: int = 0


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


def write_outputs(
    folder: Path, source: ScanSource, model: TreeModel, log: ReplayLog, video: OverlayVideo,
    metrics: TreeMetrics | None, truth: TreeModel | None, config: ReplayConfig,
) -> list[str]:  # fmt: skip
    """Write the model, its mesh, the tables and the 3D plot into ``folder``; close the video.

    Args:
        folder: The output folder (being written).
        source: The recording.
        model: The final tree model.
        log: The loop's record.
        video: The overlay video (closed here).
        metrics: Scores against ``truth``, or None.
        truth: The ground truth, or None.
        config: Output settings.

    Returns:
        The output file names, ``summary.json`` (:func:`summary`, written last) included.
    """
    (folder / "model.json").write_text(json.dumps(model.to_dict()))
    write_ply(folder / "model.ply", *tree_mesh(model, config.mesh))
    write_csv(folder / "iterations.csv", log.iteration_rows or [{"index": ""}])
    write_csv(folder / "frames.csv", log.frame_rows)
    video_path = video.close()
    title = f"{Path(source.name).name}: {len(model.secondaries)} secondaries"
    if metrics is not None:
        title += f", PB residual {metrics.pb_residual_mean_m * 1e3:.1f} mm"
    path = np.array(log.camera_path)
    plot_model_3d(folder / "plot3d.png", model, path, truth, title, config.plot_dpi)
    files = ["model.json", "model.ply", "iterations.csv", "frames.csv", "plot3d.png"]
    if video_path is not None:
        files.insert(4, video_path.name)
    files.append("summary.json")
    return files


def write_csv(path: Path, rows: list[dict]) -> None:
    """A CSV of ``rows`` whose columns are every key, in the order they first appear."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys]
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)


def iteration_row(report: IterationReport, loaded: LoadedFrame, T: np.ndarray) -> dict:
    """The ``iterations.csv`` row of an iteration run on frame ``loaded`` (pose ``T``)."""
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


def summary(
    source, model, reports, n_frames, n_fed, skip_reasons, metrics, seed, modeler_config,
    tracker, segmenter, files, wall,
) -> dict:  # fmt: skip
    """The ``summary.json`` of a replay: counts, seed, settings, outcomes, median stage timings,
    the model's size and the metrics (:mod:`recon.replay`)."""
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
