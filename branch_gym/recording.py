"""Record simulated scans in recon's scan folder format (``docs/replay.md``).

:class:`ScanRecorder` is a :attr:`branch_gym.scan.ScanSession.frame_listeners` entry that writes
every frame the modeler receives; :func:`recording` wraps any loop driving a session with one
(:func:`branch_gym.evaluation.record.record_scan` runs one scan with a policy, ``eval.py
--record DIR`` records every trial). Next to the frames they save the tree's ground
truth (``truth.json``), the model the scan built online (``recorded_model.json``) and the
modeler's seed, config and 2D stage (``metadata.json``), so that::

    python -m agents.commands record --seed 0 --out scans/seed0
    python -m recon.replay scans/seed0 --out replays/seed0 --truth scans/seed0/truth.json

reproduces the online model exactly (PNG images; JPEG recordings are smaller and replay to a
close, not identical, model).
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path

from branch_gym.scan import ScanSession
from branch_gym.scoring import scan_metrics_config, session_surroundings
from branch_gym.surroundings import surroundings_to_json
from recon.frame import Frame
from recon.io.distortion import CameraModel
from recon.io.folder import ScanWriter

logger = logging.getLogger(__name__)

TRUTH_FILE = "truth.json"
RECORDED_MODEL_FILE = "recorded_model.json"
SURROUNDINGS_FILE = "surroundings.json"  # the structures the scoring classes branches against


class ScanRecorder:
    """A frame listener that appends every frame to an open :class:`recon.io.ScanWriter`.

    Pose-only frames (``frame.has_image == False``) are written as lines without an image, so a
    replay feeds the modeler exactly the frames the scan fed it.
    """

    def __init__(self, writer: ScanWriter) -> None:
        self.writer = writer

    def __call__(self, frame: Frame) -> None:
        self.writer.add_frame(frame)

    @property
    def n_frames(self) -> int:
        return self.writer.n_frames


@contextmanager
def recording(
    session: ScanSession,
    out_dir: str | Path,
    seed: int,
    policy: str = "",
    image_format: str = "png",
    jpeg_quality: int = 95,
    overwrite: bool = False,
) -> Iterator[ScanRecorder]:
    """Record whatever ``session`` scans inside the ``with`` block into a scan folder.

    On leaving the block normally the ground truth, the online model and the metadata (modeler
    seed and config, scanned height, outcome counts) are added and the folder is moved into
    place; on an exception nothing is left behind. Use it around any loop that drives the
    session (``run_episode`` of an env, ``eval.py`` trials)::

        with recording(env.session, "scans/seed0", seed=0, policy="none"):
            run_episode(agent, env, 0, "none")

    Args:
        session: The scan session (its ``reset(seed)`` happens inside the block).
        out_dir: The scan folder to create.
        seed: The tree seed scanned (the session resets the modeler with it).
        policy: Policy name for the metadata.
        image_format: "png" (lossless: exact replays) or "jpg" (small).
        jpeg_quality: JPEG quality 0-100.
        overwrite: Replace an existing ``out_dir``.
    """
    writer = ScanWriter(
        out_dir, CameraModel(session.intrinsics), image_format, jpeg_quality, overwrite
    )
    with writer:
        recorder = ScanRecorder(writer)
        session.frame_listeners.append(recorder)
        try:
            yield recorder
        finally:
            session.frame_listeners.remove(recorder)
        if session.tree is None:
            raise RuntimeError("the session scanned nothing inside recording()")
        _finish(writer, session, seed, policy)
        logger.info("recorded seed %d: %d frames -> %s", seed, writer.n_frames, out_dir)


def _finish(writer: ScanWriter, session: ScanSession, seed: int, policy: str) -> None:
    """Ground truth, online model and metadata of a finished scan."""
    config = session.config
    model = session.model
    writer.write_file(TRUTH_FILE, json.dumps(session.tree.to_dict()))
    writer.write_file(RECORDED_MODEL_FILE, json.dumps(model.to_dict()))
    surroundings = surroundings_to_json(session_surroundings(session))
    writer.write_file(SURROUNDINGS_FILE, json.dumps(surroundings))
    writer.metadata.update(
        {
            "created_by": "branch_gym.recording",
            "seed": seed,
            "policy": policy,
            "modeler": {
                "seed": seed,
                "tracker": config.tracker,
                "config": asdict(config.modeler),
                "curve2d": asdict(config.curve2d),  # the 2D stage (recon.replay reads it)
            },
            "scan": {
                "segmenter": config.segmenter,
                "speed_mps": config.speed_mps,
                "end_height_m": config.end_height_m,
            },
            "scanned_top_z_m": session.camera_height_m,
            "truth": TRUTH_FILE,
            # How the scan was scored: the replay scores the same way (recon.replay).
            "scoring": {
                "metrics": asdict(scan_metrics_config(config)),
                "planned_top_z_m": config.end_height_m,
                "surroundings": SURROUNDINGS_FILE,
            },
            "recorded_model": RECORDED_MODEL_FILE,
            "image_format": writer.image_format,
            "lossless": writer.image_format == "png",
            "result": {
                "scan_time_s": session.scan_time_s,
                "rotations": session.rotations,
                "stop_reason": session.stop_reason,
                "n_iterations": len(session.reports),
                "outcomes": dict(Counter(r.outcome.value for r in session.reports)),
                "n_secondaries": len(model.secondaries),
            },
        }
    )
