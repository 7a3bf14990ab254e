"""The replay's loop: a recording's frames through the modeler (:func:`replay`), each image
frame segmented when a segmenter makes the masks (:class:`FlowInputs`: its optical-flow input).
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from recon.config import ModelerConfig
from recon.curve2d.types import Curve2DConfig
from recon.io.atomic import atomic_output_dir, check_output_dir
from recon.io.folder import LoadedFrame
from recon.io.source import ScanSource, open_source
from recon.metrics import TreeMetrics, evaluate
from recon.model import TreeModel
from recon.modeler import IterationReport, Modeler
from recon.overlay import model_overlay
from recon.replay.inputs import (
    TRACKERS,
    ReplayError,
    at_working_focal_length,
    curve_settings,
    learned_masks,
    load_scoring,
    load_segmenter,
    load_truth,
    modeler_settings,
)
from recon.replay.writers import (
    OverlayVideo,
    ReplayConfig,
    ReplayLog,
    iteration_row,
    write_outputs,
)
from recon.replay.writers import summary as replay_summary
from recon.segmentation.flow import FramePairer, FramePairingConfig
from recon.segmentation.flow import swap_red_blue as swap_flow_red_blue
from recon.tracking import make_tracker

logger = logging.getLogger(__name__)


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
    curve_config: Curve2DConfig | None = None,
) -> ReplayResult:
    """Run :class:`recon.modeler.Modeler` over a recorded scan and write the outputs.

    Args:
        source: A scan source, or a path for :func:`recon.io.open_source`.
        out_dir: Output folder (written atomically; :mod:`recon.replay` lists its files).
        truth: Ground truth (TreeModel or a TreeGT JSON path) to score the model against.
        segmenter: None / "mask" (recorded masks), "learned[:PATH]", or an object with
            ``segment(rgb, previous_rgb=None) -> (H, W) bool``; one whose
            ``uses_flow_picture`` is true also takes ``flow_image=`` (:mod:`recon.replay`).
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
        curve_config: The 2D stage's settings; default: the recording's (the scan's
            ``ScanConfig.curve2d``), else the defaults.

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
    source = at_working_focal_length(source, working_focal_px, segmenter)
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
    modeler_config = modeler_config.for_masks(learned=seg is not None or learned_masks(source))
    recorded_tracker = source.metadata.get("modeler", {}).get("tracker", tracker)
    if recorded_tracker != tracker:
        logger.warning(
            "the scan was modelled online with tracker %r, the replay uses %r: the models differ",
            recorded_tracker,
            tracker,
        )
    curve_config = curve_settings(source.metadata, curve_config)
    modeler = Modeler(make_tracker(tracker, TRACKERS), modeler_config, curve_config, seed=seed)
    flow = FlowInputs.of(seg, pairing, flow_red_blue_swapped)

    with atomic_output_dir(out_dir, overwrite) as tmp:
        intrinsics = source.intrinsics
        video = OverlayVideo(tmp, (intrinsics.width, intrinsics.height), config)
        log = run_frames(source, seg, flow, modeler, video, config.mask_alpha, progress)
        if log.n_fed == 0:
            raise ReplayError(f"{source.name}: no usable frame ({dict(log.skip_reasons)})")
        model = modeler.model
        metrics = None
        if truth is not None:
            top = source.metadata.get("scanned_top_z_m")
            path = np.array(log.camera_path)
            top = float(top) if top is not None else float(path[:, 2].max())
            scoring = load_scoring(source)
            metrics = evaluate(
                model,
                truth,
                scoring.config,
                scanned_top_z_m=top,
                surroundings=scoring.surroundings,
                planned_top_z_m=top if scoring.planned_top_z_m is None else scoring.planned_top_z_m,
            )
        files = write_outputs(tmp, source, model, log, video, metrics, truth, config)
        wall = time.perf_counter() - wall_start
        summary = replay_summary(
            source, model, log.reports, len(log.frame_rows), log.n_fed, log.skip_reasons,
            metrics, seed, modeler_config, tracker, segmenter, files, wall,
        )  # fmt: skip
        summary["curve_config"] = asdict(curve_config)
        if flow.pairer is not None:
            summary["flow_inputs"] = dict(flow.counts)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
    return ReplayResult(
        model, log.reports, len(log.frame_rows), log.n_fed, dict(log.skip_reasons), metrics,
        seed, Path(out_dir), files, wall, dict(flow.counts),
    )  # fmt: skip


def run_frames(
    source: ScanSource, seg, flow: FlowInputs, modeler: Modeler, video: OverlayVideo,
    mask_alpha: float, progress: bool,
) -> ReplayLog:  # fmt: skip
    """Feed a recording's frames to the modeler, one after the other, drawing the overlay video.

    Args:
        source: The recording.
        seg: Its segmenter (:func:`replay`'s ``segmenter``, loaded), or None: recorded masks.
        flow: Where the segmenter's optical-flow input comes from.
        modeler: The modeler.
        video: The overlay video: each image frame with its mask and the model so far.
        mask_alpha: Opacity of the mask tint in the overlay.
        progress: Show a tqdm progress bar.

    Returns:
        The frames' and iterations' record.
    """
    log = ReplayLog()
    intrinsics = source.intrinsics
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
            log.skip_reasons[loaded.skip_kind or "unusable frame"] += 1
            log.frame_rows.append({**row, "status": "skipped", "reason": reason})
            logger.info("skipping frame %d (%s): %s", loaded.index, loaded.where, reason)
            continue
        report = modeler.update(frame)
        log.n_fed += 1
        log.camera_path.append(frame.T_world_camera[:3, 3].copy())
        status = "fed"
        if report is not None:
            log.reports.append(report)
            status = "iteration"
            last_outcome = report.outcome.value
            log.iteration_rows.append(iteration_row(report, loaded, frame.T_world_camera))
            bar.set_postfix_str(f"{last_outcome}, {len(modeler.model.secondaries)} SB")
        log.frame_rows.append({**row, "status": status, "reason": ""})
        if frame.has_image:
            text = f"frame {loaded.index}  t={loaded.time_s:.2f}s  {last_outcome}"
            overlay = model_overlay(
                frame.rgb,
                frame.mask,
                modeler.model,
                frame.T_world_camera,
                intrinsics,
                [text],
                mask_alpha,
            )
            video.write(cv2.cvtColor(overlay, cv2.COLOR_RGB2BGR))
    bar.close()
    return log


@dataclass
class FlowInputs:
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
    ) -> FlowInputs:
        """The flow inputs of segmenter ``seg`` (None: recorded masks)."""
        if seg is None or not getattr(seg, "uses_flow_picture", False):
            return cls()
        return cls(FramePairer(pairing), swap_red_blue)

    def segment(self, seg, loaded: LoadedFrame) -> np.ndarray:
        """(H, W) mask of an image frame (:mod:`recon.replay`); the frame joins the history.

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


def _make_frame(loaded: LoadedFrame, intrinsics, seg, flow: FlowInputs):
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
