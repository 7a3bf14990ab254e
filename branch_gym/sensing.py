"""Sensing: the world's camera images -> a segmented, timestamped :class:`recon.Frame`.

This is the one place where the simulator meets the pipeline's input format. A real robot does
the same with its camera driver and segmenter (``recon.replay`` reads recorded frames).

=========================  =====================================================================
segmenter spec             mask from (:class:`SimSegmenterSpec`)
=========================  =====================================================================
``gt``                     the renderer's instance labels (exact)
``noisy:PRESET``           the labels with segmentation errors (``mild``, ``moderate``,
                           ``severe``; :mod:`branch_gym.sim.segmentation`)
``learned``                the RGB image, by the network trained in simulation and shipped in
                           ``recon/segmentation/weights/`` (:mod:`recon.segmentation`); what a real
                           robot runs. Optical flow, if the weights use it: see below
``learned:PATH``           the same with another weights file
=========================  =====================================================================

Optical flow of a learned segmenter (:class:`RGBSegmenter`):

* a flow-picture network (``uses_flow_picture``, the paper's RGB + flow-picture segmenter) gets
  as ``previous_rgb`` the earlier rendered frame that :class:`recon.segmentation.flow.FramePairer`
  picks by the camera poses (moved >= 7.5 mm and turned < 0.5 deg since, the authors' rule;
  thresholds: ``ScanConfig.frame_pairing``); a frame with no such partner (the first 7.5 mm of
  a scan, after a rotation) is segmented from its colours alone. The history restarts at every
  scan reset;
* an older flow-vector network (``uses_flow`` without ``uses_flow_picture``) gets the previous
  rendered frame;
* an RGB-only network gets no earlier frame.

Every rendered frame enters that history, but only the frames whose mask the modeler reads are
segmented (``Sensor.capture(..., segment=False)``, see :meth:`branch_gym.scan.ScanSession`): the
modeler reads the mask of the frame an iteration runs on, never those of the tracking-only
frames in between (7 of every 8 rendered frames with the default tracker).

The point trackers by name (``lk``, ``oracle``): :func:`recon.tracking.make_tracker`.
"""

from __future__ import annotations

import time
from typing import ClassVar

import numpy as np
import torch

from branch_gym.attribution import BranchVisibility
from branch_gym.sim.scene.camera_spec import CameraSpec
from branch_gym.sim.segmentation import PRESET_NAMES, Segmenter
from branch_gym.sim.segmentation import make_segmenter as make_label_segmenter
from branch_gym.sim.world import World
from recon.camera import CameraIntrinsics
from recon.frame import Frame
from recon.segmentation import LearnedSegmenter, load_segmenter
from recon.segmentation.flow import FramePairer, FramePairingConfig
from recon.segmentation.segmenter import weights_path_of
from recon.segmentation.spec import SegmenterSpec, SpecKind

SCAN_TORCH_THREADS = 1  # a simulated scan is one process per core (see RGBSegmenter)
# Which child of the scan seed's SeedSequence drives the segmenter's noise (the world and the
# modeler draw from their own).
_SEGMENTER_STREAM = 2
_SEED_STREAMS = 3


def intrinsics_from_spec(spec: CameraSpec) -> CameraIntrinsics:
    """recon's intrinsics for the simulator's camera."""
    return CameraIntrinsics(spec.width, spec.height, spec.fx, spec.fy, spec.cx, spec.cy)


class SimSegmenterSpec(SegmenterSpec):
    """A simulated scan's segmenter spec: recon's ``learned[:PATH]`` and the renderer's labels,
    ``gt`` (exact) and ``noisy:PRESET`` (module docstring)."""

    KINDS: ClassVar = {
        "gt": SpecKind(),
        "noisy": SpecKind(PRESET_NAMES),
        **SegmenterSpec.KINDS,
    }


class RGBSegmenter:
    """A learned segmenter behind the simulator's segmenter interface: it reads only the RGB.

    It keeps the earlier frames that the network's optical-flow input is taken against (module
    docstring): call :meth:`reset` at the start of every scan. Building one sets torch to
    ``SCAN_TORCH_THREADS`` threads for the process: scans run one per core (eval.py's workers,
    training's env processes), and a multi-threaded forward pass on a loaded machine was
    measured ~7x slower (54 s against 8 s for one scan on 2 busy cores).

    Args:
        segmenter: The network.
        pairing: How a flow-picture network's frames are paired (default
            ``FramePairingConfig()``, the authors' thresholds); unused by other networks.
    """

    def __init__(
        self, segmenter: LearnedSegmenter, pairing: FramePairingConfig | None = None
    ) -> None:
        torch.set_num_threads(SCAN_TORCH_THREADS)
        self.segmenter = segmenter
        self._previous_rgb: np.ndarray | None = None
        self._pairer = FramePairer(pairing) if segmenter.uses_flow_picture else None

    @property
    def pairer(self) -> FramePairer | None:
        """The frame pairer of a flow-picture network, else None."""
        return self._pairer

    def reset(self) -> None:
        """Forget the earlier frames (a new scan)."""
        self._previous_rgb = None
        if self._pairer is not None:
            self._pairer.reset()

    def segment(
        self,
        rgb: np.ndarray,
        labels: np.ndarray,
        rng: np.random.Generator,
        T_world_camera: np.ndarray | None = None,
    ) -> np.ndarray:
        """Mask of one rendered frame, which then joins the earlier frames.

        Args:
            rgb: (H, W, 3) uint8 rendered frame.
            labels: (H, W) instance labels (not used).
            rng: The scan's segmenter stream (not used: nothing is drawn).
            T_world_camera: (4, 4) camera pose of the frame (OpenCV axes, metres); required by
                a flow-picture network, which pairs frames by it.

        Returns:
            (H, W) bool mask, True on the scanned tree.

        Raises:
            ValueError: A flow-picture network and no ``T_world_camera``.
        """
        return self.segmenter.segment(rgb, self._flow_partner(rgb, T_world_camera))

    def observe(self, rgb: np.ndarray, T_world_camera: np.ndarray | None = None) -> None:
        """Let a rendered frame that is not segmented join the earlier frames (a partner).

        Args:
            rgb: (H, W, 3) uint8 rendered frame (a flow-picture network keeps a copy).
            T_world_camera: (4, 4) camera pose of the frame (OpenCV axes, metres); required by
                a flow-picture network.

        Raises:
            ValueError: A flow-picture network and no ``T_world_camera``.
        """
        self._flow_partner(rgb, T_world_camera)

    def _flow_partner(
        self, rgb: np.ndarray, T_world_camera: np.ndarray | None
    ) -> np.ndarray | None:
        """The earlier frame the flow of ``rgb`` is taken against (or None); remembers ``rgb``."""
        if self._pairer is not None:
            if T_world_camera is None:
                raise ValueError(
                    f"segmenter {self.segmenter.source} reads flow pictures: its frames are "
                    "paired by camera pose, pass T_world_camera"
                )
            return self._pairer.add(rgb, T_world_camera)
        if not self.segmenter.uses_flow:
            return None
        previous, self._previous_rgb = self._previous_rgb, rgb
        return previous


def make_segmenter(
    spec: str | SegmenterSpec, pairing: FramePairingConfig | None = None
) -> Segmenter | RGBSegmenter:
    """The segmenter of a spec (see the module docstring).

    Args:
        spec: A segmenter spec (module docstring), text or parsed.
        pairing: Frame pairing of a flow-picture network (default ``FramePairingConfig()``).

    Raises:
        ValueError: an unknown spec, naming the valid ones.
        recon.segmentation.SegmenterWeightsError: a missing, corrupt or mismatched weights file
            (named).
    """
    spec = SimSegmenterSpec.parse(spec)
    if spec.is_learned:
        return RGBSegmenter(load_segmenter(spec), pairing)
    return make_label_segmenter(str(spec))


def check_segmenter_spec(spec: str | SegmenterSpec) -> None:
    """Validate a segmenter spec cheaply (a ``learned`` weights file must exist, loaded later).

    Raises:
        ValueError: an unknown spec, or a ``learned`` spec whose weights file does not exist.
    """
    spec = SimSegmenterSpec.parse(spec)
    if not spec.is_learned:
        return
    weights = weights_path_of(spec)
    if not weights.is_file():
        raise ValueError(f"segmenter {str(spec)!r}: weights file {weights} does not exist")


class Sensor:
    """The eye-in-hand camera and its segmenter, producing the modeler's frames.

    Args:
        world: The simulated world (its camera renders RGB, depth and labels).
        segmenter: A segmenter spec (see the module docstring).
        pairing: Frame pairing of a flow-picture network (default ``FramePairingConfig()``).
    """

    def __init__(
        self, world: World, segmenter: str, pairing: FramePairingConfig | None = None
    ) -> None:
        self.world = world
        self.segmenter = make_segmenter(segmenter, pairing)
        self.intrinsics = intrinsics_from_spec(world.config.camera)
        # How well the views show each ground-truth secondary (simulation only, for scoring).
        self.visibility = BranchVisibility(self.intrinsics)
        self._rng = np.random.default_rng(0)
        # Wall time (ms) spent in the world's renderer since the sensor was built (a clock the
        # env reads around a step: ``timings_ms["render_ms"]``, the render share of its floor).
        self.render_ms = 0.0

    def reset(self, seed: int) -> None:
        """Start the scan of ``seed``, after the world's reset.

        Seeds the segmenter's noise, forgets the earlier images (flow partners) and starts
        counting the new tree's branch visibility.
        """
        streams = np.random.SeedSequence(seed).spawn(_SEED_STREAMS)
        self._rng = np.random.default_rng(streams[_SEGMENTER_STREAM])
        if isinstance(self.segmenter, RGBSegmenter):
            self.segmenter.reset()
        tree = self.world.tree
        n_secondaries = 0 if tree is None else len(tree.secondaries)
        primary = None if tree is None else tree.primary
        self.visibility.reset(n_secondaries, self.world.T_world_camera, primary)

    def capture(self, timestamp_s: float, segment: bool = True) -> Frame:
        """Render the current view and segment it.

        Args:
            timestamp_s: Scan time of the frame (s).
            segment: False for a frame whose mask nobody reads (a tracking-only frame): a
                learned segmenter then skips the network (the frame still joins its flow
                history) and the frame's mask is empty. The label segmenters (``gt``,
                ``noisy:*``) segment every frame regardless: they are cheap, and the noisy
                one draws from the scan's stream at every frame.

        Returns:
            The frame: RGB, mask ((H, W) bool), ``T_world_camera`` ((4, 4), OpenCV axes,
            metres), intrinsics, time and the rendered depth (for the depth oracle tracker and
            diagnostics only).
        """
        start = time.perf_counter()
        images = self.world.render()
        self.render_ms += (time.perf_counter() - start) * 1e3
        T = self.world.T_world_camera
        if not isinstance(self.segmenter, RGBSegmenter):
            mask = self.segmenter.segment(images.rgb, images.labels, self._rng)
        elif segment:
            mask = self.segmenter.segment(images.rgb, images.labels, self._rng, T)
        else:
            self.segmenter.observe(images.rgb, T)
            mask = np.zeros(images.rgb.shape[:2], bool)
        self.visibility.observe(images.labels, T)
        return Frame(images.rgb, mask, T, self.intrinsics, timestamp_s, images.depth_m)

    def pose_only(self, timestamp_s: float) -> Frame:
        """A frame with only the camera pose (no render): for the depth oracle's fast mode."""
        return Frame.pose_only(self.world.T_world_camera, self.intrinsics, timestamp_s)
