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
* ``summary.json``: counts, seed, config (the modeler's and the 2D stage's), outcomes, median
  timings and the metrics (``--truth``).

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

The package, by role: ``cli.py`` (the command line), ``loop.py`` (:func:`replay`: the frames
through the modeler), ``writers.py`` (the output files), ``inputs.py`` (segmenter, tracker,
modeler settings, ground truth and working focal length).
"""

from recon.replay.cli import main
from recon.replay.inputs import (
    TRACKERS,
    ReplayError,
    ReplaySegmenterSpec,
    curve_settings,
    load_segmenter,
    load_truth,
    modeler_settings,
)
from recon.replay.loop import ReplayResult, replay
from recon.replay.writers import OverlayVideo, ReplayConfig

__all__ = [
    "TRACKERS",
    "OverlayVideo",
    "ReplayConfig",
    "ReplayError",
    "ReplayResult",
    "ReplaySegmenterSpec",
    "curve_settings",
    "load_segmenter",
    "load_truth",
    "main",
    "modeler_settings",
    "replay",
]
