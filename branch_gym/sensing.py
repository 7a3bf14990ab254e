"""Sensing: the world's camera images -> a segmented, timestamped :class:`recon.Frame`.

This is the one place where the simulator meets the pipeline's input format. A real robot does
the same with its camera driver and segmenter (``recon/replay.py`` reads recorded frames).

=========================  =====================================================================
segmenter spec             mask from
=========================  =====================================================================
``gt``                     the renderer's instance labels (exact)
``noisy:PRESET``           the labels with segmentation errors (``mild``, ``moderate``,
                           ``severe``; :mod:`branch_gym.sim.segmentation`)
=========================  =====================================================================

=========================  =====================================================================
tracker name               point tracker (:mod:`recon.tracking`)
=========================  =====================================================================
``lk``                     Lucas-Kanade on the rendered images (what a real robot runs)
``oracle``                 exact tracks from the rendered depth (ablations, fast training)
=========================  =====================================================================
"""

from __future__ import annotations

import numpy as np

from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.segmentation import Segmenter, make_segmenter
from branch_gym.sim.world import World
from recon.camera import CameraIntrinsics
from recon.frame import Frame
from recon.tracking import DepthOracleTracker, LucasKanadeTracker, PointTracker

TRACKERS = ("lk", "oracle")
# Which child of the scan seed's SeedSequence drives the segmenter's noise (the world and the
# modeler draw from their own).
_SEGMENTER_STREAM = 2
_SEED_STREAMS = 3


def intrinsics_from_spec(spec: CameraSpec) -> CameraIntrinsics:
    """recon's intrinsics for the simulator's camera."""
    return CameraIntrinsics(spec.width, spec.height, spec.fx, spec.fy, spec.cx, spec.cy)


def make_tracker(name: str) -> PointTracker:
    """The point tracker called ``name`` ("lk" or "oracle").

    Raises:
        ValueError: an unknown name, listing the valid ones.
    """
    if name == "lk":
        return LucasKanadeTracker()
    if name == "oracle":
        return DepthOracleTracker()
    raise ValueError(f"unknown tracker {name!r}: expected one of {TRACKERS}")


class Sensor:
    """The eye-in-hand camera and its segmenter, producing the modeler's frames.

    Args:
        world: The simulated world (its camera renders RGB, depth and labels).
        segmenter: A segmenter spec (see the module docstring).
    """

    def __init__(self, world: World, segmenter: str) -> None:
        self.world = world
        self.segmenter: Segmenter = make_segmenter(segmenter)
        self.intrinsics = intrinsics_from_spec(world.config.camera)
        self._rng = np.random.default_rng(0)

    def reset(self, seed: int) -> None:
        """Seed the segmenter's noise for the scan of ``seed``."""
        streams = np.random.SeedSequence(seed).spawn(_SEED_STREAMS)
        self._rng = np.random.default_rng(streams[_SEGMENTER_STREAM])

    def capture(self, timestamp_s: float) -> Frame:
        """Render the current view and segment it.

        Args:
            timestamp_s: Scan time of the frame (s).

        Returns:
            The frame: RGB, mask, ``T_world_camera``, intrinsics, time and the rendered depth
            (for the depth oracle tracker and diagnostics only).
        """
        images = self.world.render()
        mask = self.segmenter.segment(images.rgb, images.labels, self._rng)
        T = self.world.T_world_camera
        return Frame(images.rgb, mask, T, self.intrinsics, timestamp_s, images.depth_m)

    def pose_only(self, timestamp_s: float) -> Frame:
        """A frame with only the camera pose (no render): for the depth oracle's fast mode."""
        return Frame.pose_only(self.world.T_world_camera, self.intrinsics, timestamp_s)
