"""Optical flow for segmentation: the flow picture, DIS flow, and the frame to take it against.

The paper's segmenter (You et al. 2022; OSUrobotics/follow-the-leader) reads an RGB frame and
an optical-flow *picture* of it: FlowNet2's flow coded with the Middlebury colour wheel and
normalised by the frame's largest flow (flownet2-pytorch's ``flow2img``). This module makes
that picture from any flow (:func:`flow_to_picture`, through the ``flow-vis`` package), computes
the flow itself with OpenCV's DIS (:func:`compute_flow`), and picks, as the authors' code does,
the earlier frame the flow is taken against (:class:`FramePairer`: the camera moved at least
7.5 mm and turned less than 0.5 deg since).

Conventions:

* Flow is (H, W, 2) float in pixels, (u, v) = (right, down). :func:`compute_flow` returns it
  on the grid of the *current* frame, pointing to where each pixel was in the *previous* one
  (``DenseFlowConfig.direction``), as the authors' code: FlowNet2 gets ``[current, last]``, first
  image first (``networks/flowgan.py``). A camera moving up then gives v < 0 on the scanned
  tree: violet-blue in the picture (RGB (88, 0, 255) at the largest flow).
* The recorded real pictures (``../shared/data/real_dev/N_flow.png``) appear to hold the same
  coding with red and blue exchanged, as ``cv2.imwrite`` of flow2img's RGB array produces. On
  frame 7, where the camera moved up along the trunk (so we were told; the data's README does
  not document the motion), the trunk reads RGB (255, 59, 83), which the wheel codes as
  u = +1.00, v = 0.01: sideways motion, impossible for an upward camera under either flow
  direction. With red and blue exchanged it reads (83, 59, 255): u = -0.33, v = -0.93, up,
  which is our current-to-previous coding of that motion (the orchard world's exact flow for
  7.5 mm up paints the trunk (88-107, 0-29, 255), median, on 9 of seeds 0-9). The exchange
  maps the wheel onto itself, so the pictures alone cannot tell; the other three frames fit
  either reading. Apply :func:`swap_red_blue` to such a picture, read as RGB, before it meets
  ours.

Benchmark (``python tests/test_flow.py --baselines``): 10 orchard-world pairs (seeds 0-9), the
camera moved 7.5 mm up at 0.20 m from the trunk (the tree moves 15.9 px on average, the row
behind it ~0.7 px), 320x240, one core (``cv2.setNumThreads(1)``, load average ~7 on the 2 shared
cores; ms: median over pairs of the best of 5, range over 4 runs), endpoint error against the
renderer's exact flow on the scanned tree (labels 1-99) and on every pixel:

    method          ms/frame  EPE tree px  EPE all px
    DIS ultrafast   1.2-1.7      13.2         1.68
    DIS fast        2.1-3.1      13.7         1.56
    DIS medium       14-18       10.1         1.33
    Farneback        25-30       13.7         1.72

The picture (:func:`flow_to_picture`, flow-vis) costs 13 ms a frame there: more than the flow.

No pybullet or branch_gym import: this runs on real camera frames.
"""

from __future__ import annotations

import functools
import logging
import math
from collections import deque
from dataclasses import dataclass

import cv2
import flow_vis
import numpy as np

from recon.camera import check_pose
from recon.validation import require_int, require_positive

__all__ = [
    "DIS_PRESETS",
    "FLOW_DIRECTIONS",
    "MIN_FLOW_SIDE_PX",
    "DenseFlowConfig",
    "FramePairer",
    "FramePairingConfig",
    "compute_flow",
    "flow_picture",
    "flow_to_picture",
    "flow_to_picture_fast",
    "swap_red_blue",
]

logger = logging.getLogger(__name__)

DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
"""OpenCV DIS presets by name."""

FLOW_DIRECTIONS = ("current_to_previous", "previous_to_current")
"""Flow directions :func:`compute_flow` knows (see the module docstring)."""

MIN_FLOW_SIDE_PX = 32
"""Smallest image side :func:`compute_flow` accepts. OpenCV 5.1's DIS raises below 12 px and
crashes the process (segmentation fault) on some small or thin frames (16 x 200 with the
default scales; finest scale 3 on 32 x 500); every preset with finest scale 0-2 ran on all
sizes tried with both sides >= 32 (up to 2000 x 32)."""


def _check_rgb(image: object, name: str) -> np.ndarray:
    """Raise a ValueError naming ``name`` unless ``image`` is an (H, W, 3) uint8 array."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8, got {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{name} must have shape (H, W, 3), got {image.shape}")
    return image


def _check_flow(flow: object) -> None:
    """Raise ValueError unless ``flow`` is a floating (H, W, 2) numpy array."""
    if not isinstance(flow, np.ndarray):
        raise ValueError(f"flow must be a numpy array, got {type(flow).__name__}")
    if not np.issubdtype(flow.dtype, np.floating):
        raise ValueError(f"flow must be a floating array (pixels), got {flow.dtype}")
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must have shape (H, W, 2), got {flow.shape}")


def flow_to_picture(flow: np.ndarray) -> np.ndarray:
    """The Middlebury colour-wheel picture of a flow field, normalised by its largest flow.

    Exactly ``flow_vis.flow_to_color(flow)``, the coding of FlowNet2's ``flow2img``. That one
    paints unknown flow and an all-zero frame black, and through where it adds its epsilon
    often darkens the frame's fastest pixel (its radius lands just above 1: x 0.75) and moves
    a rare other value by 1 (200 random flows: 98 such maxima, 23 other pixels). Hue is the
    direction, saturation the magnitude over the frame's largest magnitude, so zero motion is
    white and the fastest pixel fully saturated. At the largest magnitude +u (right) is red
    (255, 0, 0), +v (down) yellow (255, 229, 0), -u (left) cyan-blue (0, 209, 255), -v (up)
    violet-blue (88, 0, 255); down-right orange (255, 114, 0), down-left green (32, 255, 0),
    up-left blue (0, 52, 255), up-right magenta (220, 0, 255). Scaling the whole flow leaves
    the picture unchanged (up to 1 in 255 from flow-vis's 1e-5 epsilon). Cost: ~13 ms for
    320x240 on one loaded core here (float64 per channel), eight times DIS ultrafast.

    Args:
        flow: (H, W, 2) float flow in pixels, (u, v) = (right, down). NaN or infinite
            components (unknown flow) count as zero motion: white, and left out of the
            normalisation.

    Returns:
        (H, W, 3) uint8 RGB picture. An all-zero (or all-unknown) flow gives a white picture.

    Raises:
        ValueError: ``flow`` is not a floating (H, W, 2) numpy array.

    >>> flow_to_picture(np.zeros((2, 3, 2), np.float32))[0, 0].tolist()
    [255, 255, 255]
    >>> flow_to_picture(np.array([[[2.0, 0.0], [1.0, 0.0]]]))[0].tolist()
    [[255, 0, 0], [255, 127, 127]]
    """
    _check_flow(flow)
    if flow.dtype == np.float16:
        flow = flow.astype(np.float32)
    known = np.isfinite(flow).all(axis=2)
    if not known.all():
        flow = np.where(known[..., None], flow, flow.dtype.type(0))
    return flow_vis.flow_to_color(flow)


PICTURE_HUE_BINS = 3600
"""Angle bins of :func:`flow_to_picture_fast`'s colour-wheel table (our choice: 0.1 deg, the
picture then stays within 1 level of flow-vis's, tests/test_flow.py)."""


@functools.lru_cache(maxsize=1)
def _wheel_table() -> np.ndarray:
    """(PICTURE_HUE_BINS, 3) float32 flow-vis wheel colours (0-1) at the bins' centre angles.

    Bin k holds the angles [k, k + 1) * 2 pi / PICTURE_HUE_BINS of ``atan2(-v, -u)`` wrapped to
    [0, 2 pi), as OpenCV's ``cartToPolar(-u, -v)`` returns it; the colours are flow-vis's wheel
    interpolated as ``flow_uv_to_colors`` does. A bin edge lies on flow-vis's seam at pi (+u),
    where its wheel jumps from entry 54 to entry 0 (43 levels of blue).
    """
    wheel = flow_vis.make_colorwheel() / 255.0
    n = len(wheel)
    theta = (np.arange(PICTURE_HUE_BINS) + 0.5) * (2.0 * np.pi / PICTURE_HUE_BINS)
    a = np.where(theta >= np.pi, theta - 2.0 * np.pi, theta) / np.pi  # flow-vis's [-1, 1)
    fk = (a + 1.0) / 2.0 * (n - 1)
    k0 = np.floor(fk).astype(np.intp)
    f = (fk - k0)[:, None]
    return ((1.0 - f) * wheel[k0 % n] + f * wheel[(k0 + 1) % n]).astype(np.float32)


@functools.lru_cache(maxsize=1)
def _whiteness_table() -> np.ndarray:
    """(PICTURE_HUE_BINS, 3) float32 ``255 (1 - c)``: what full flow takes from white."""
    table = np.float32(255.0) * (np.float32(1.0) - _wheel_table())
    table.flags.writeable = False
    return table


def flow_to_picture_fast(flow: np.ndarray) -> np.ndarray:
    """:func:`flow_to_picture` in float32 through a table of wheel colours: ~10x faster.

    The same coding (flow-vis's wheel, its interpolation, saturation = magnitude over the
    frame's largest), computed in float32 with the hue read from a table of
    :data:`PICTURE_HUE_BINS` angles; within 1 level of :func:`flow_to_picture` (and without
    its epsilon quirks). The segmenter uses this one (its 10 ms budget, ``make bench``).

    Args:
        flow: (H, W, 2) float flow in pixels, (u, v) = (right, down); NaN or infinite
            components count as zero motion (white), as in :func:`flow_to_picture`.

    Returns:
        (H, W, 3) uint8 RGB picture.

    Raises:
        ValueError: ``flow`` is not a floating (H, W, 2) numpy array.
    """
    _check_flow(flow)
    flow = flow.astype(np.float32, copy=False)
    if not np.isfinite(flow.sum()):  # a scalar test first: the per-pixel one costs 4 ms
        known = np.isfinite(flow).all(axis=2)
        flow = np.where(known[..., None], flow, np.float32(0))
    magnitude, angle = cv2.cartToPolar(-flow[..., 0], -flow[..., 1])
    largest = float(magnitude.max())
    if largest == 0.0:
        return np.full((*flow.shape[:2], 3), 255, np.uint8)
    hue = (angle * np.float32(PICTURE_HUE_BINS / (2.0 * np.pi))).astype(np.int32)  # floor
    np.minimum(hue, PICTURE_HUE_BINS - 1, out=hue)  # an angle rounded up to 2 pi
    # 255 (1 - r (1 - c)) = 255 - r * 255 (1 - c), in place on the looked-up 255 (1 - c)
    picture = np.take(_whiteness_table(), hue, axis=0)  # (H, W, 3)
    picture *= (magnitude * np.float32(1.0 / largest))[..., None]
    np.subtract(np.float32(255.0), picture, out=picture)
    return picture.astype(np.uint8)  # floor, as flow-vis (values are >= 0)


def swap_red_blue(picture: np.ndarray) -> np.ndarray:
    """Exchange the red and blue channels of a picture (RGB <-> BGR).

    The recorded real flow pictures hold the colour-wheel coding with red and blue exchanged
    (module docstring): swap them after reading such a file as RGB, and the picture codes the
    same motion as :func:`flow_to_picture`'s.

    Args:
        picture: (H, W, 3) uint8 picture.

    Returns:
        (H, W, 3) uint8 new array, channels in reverse order.

    Raises:
        ValueError: ``picture`` is not an (H, W, 3) uint8 array.
    """
    return np.ascontiguousarray(_check_rgb(picture, "picture")[..., ::-1])


@dataclass(frozen=True)
class DenseFlowConfig:
    """How :func:`compute_flow` computes the flow.

    Attributes:
        preset: OpenCV DIS preset, one of :data:`DIS_PRESETS`. ``"ultrafast"`` by our
            benchmark (module docstring; 10 orchard-world pairs, 7.5 mm up, 320x240, one core
            under load): 1.2-1.7 ms a frame against 2.1-3.1 (fast) and 14-18 (medium), and on
            the scanned tree no worse than fast (EPE 13.2 against 13.7 px); only medium does
            better there (10.1 px), at more than the whole 10 ms segmentation budget. None of
            them follows the thin tree's 16 px motion against the near-still row behind it (it
            is lost at the coarse pyramid levels): the tree stands out from the rest with a
            flow-magnitude ROC AUC of 0.73 (ultrafast), 0.67 (fast), 0.81 (medium) against 1.0
            for the exact flow. Shorter baselines help: at 2.5 mm ultrafast's tree EPE is 3.0
            px of 5.3 (AUC 0.88), with ``finest_scale=1`` 1.2 px (AUC 0.96) at 5.4 ms.
        finest_scale: Override of the preset's finest pyramid level (0 = full resolution,
            1 = half; the presets use 2, 2 and 1), or None for the preset's. Limited to 0-2:
            DIS crashes on some frame sizes with 3 (:data:`MIN_FLOW_SIDE_PX`).
        direction: ``"current_to_previous"`` (default, the authors' code: each pixel of the
            current frame points to where it was in the previous one) or
            ``"previous_to_current"``.
    """

    preset: str = "ultrafast"  # our benchmark (above)
    finest_scale: int | None = None  # None: the preset's (OpenCV)
    direction: str = "current_to_previous"  # authors' code (networks/flowgan.py)

    def __post_init__(self) -> None:
        if self.preset not in DIS_PRESETS:
            raise ValueError(
                f"DenseFlowConfig.preset must be one of {tuple(DIS_PRESETS)}, got {self.preset!r}"
            )
        if self.finest_scale is not None:
            require_int(self, "finest_scale", minimum=0, maximum=2)
        if self.direction not in FLOW_DIRECTIONS:
            raise ValueError(
                f"DenseFlowConfig.direction must be one of {FLOW_DIRECTIONS}, "
                f"got {self.direction!r}"
            )


def compute_flow(
    previous_rgb: np.ndarray, rgb: np.ndarray, config: DenseFlowConfig | None = None
) -> np.ndarray:
    """Dense optical flow between two frames with OpenCV's DIS, on their grey levels.

    Args:
        previous_rgb: (H, W, 3) uint8 earlier frame.
        rgb: (H, W, 3) uint8 current frame, the same size; both sides >= MIN_FLOW_SIDE_PX.
        config: Preset and direction (default ``DenseFlowConfig()``).

    Returns:
        (H, W, 2) float32 flow in pixels, (u, v) = (right, down). With the default direction it
        lies on the grid of ``rgb`` and points to where each pixel was in ``previous_rgb``
        (``rgb[y, x]`` ~ ``previous_rgb[y + v, x + u]``); with ``"previous_to_current"`` it
        lies on the grid of ``previous_rgb`` and points into ``rgb``.

    Raises:
        ValueError: An image that is not (H, W, 3) uint8, images of different sizes, or a side
            under MIN_FLOW_SIDE_PX.
    """
    config = config or DenseFlowConfig()
    _check_rgb(previous_rgb, "previous_rgb")
    _check_rgb(rgb, "rgb")
    if previous_rgb.shape != rgb.shape:
        raise ValueError(
            f"previous_rgb {previous_rgb.shape} and rgb {rgb.shape} must have the same shape"
        )
    if min(rgb.shape[:2]) < MIN_FLOW_SIDE_PX:
        raise ValueError(
            f"rgb must be at least {MIN_FLOW_SIDE_PX} x {MIN_FLOW_SIDE_PX} pixels for DIS flow, "
            f"got {rgb.shape[:2]}"
        )
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS[config.preset])  # ~0.05 ms
    if config.finest_scale is not None:
        dis.setFinestScale(config.finest_scale)
    previous_grey = cv2.cvtColor(np.ascontiguousarray(previous_rgb), cv2.COLOR_RGB2GRAY)
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    if config.direction == "current_to_previous":
        return dis.calc(grey, previous_grey, None)
    return dis.calc(previous_grey, grey, None)


def flow_picture(
    previous_rgb: np.ndarray, rgb: np.ndarray, config: DenseFlowConfig | None = None
) -> np.ndarray:
    """:func:`flow_to_picture_fast` of :func:`compute_flow`: the (H, W, 3) uint8 flow picture.

    Args:
        previous_rgb: (H, W, 3) uint8 earlier frame.
        rgb: (H, W, 3) uint8 current frame.
        config: Flow settings (default ``DenseFlowConfig()``).

    Returns:
        (H, W, 3) uint8 RGB colour-wheel picture of the flow.

    Raises:
        ValueError: As :func:`compute_flow`.
    """
    return flow_to_picture_fast(compute_flow(previous_rgb, rgb, config))


@dataclass(frozen=True)
class FramePairingConfig:
    """Which earlier frame a frame's flow is taken against (:class:`FramePairer`).

    Attributes:
        min_translation_m: Least camera translation (m) since the earlier frame (authors' code,
            follow-the-leader ``image_processor.py`` ``movement_threshold``: 7.5 mm; with less
            the near tree barely moves against the row behind it).
        max_rotation_deg: The camera must have turned by less than this (deg) since the earlier
            frame (authors' code: 0.5 deg; rotation moves near and far alike and drowns the
            parallax).
        history_travel_m: Frames are kept for this much camera travel (m, summed along the
            path) behind the newest (our choice: 5 cm, ~7 x min_translation_m, so that a
            partner is found past a few frames that turned too far). At least
            ``min_translation_m``.
        max_history_frames: At most this many frames are kept (our choice: a memory bound, 128
            frames of 320x240 RGB are 29 MB; a paused camera fills it with frames at one pose).
    """

    min_translation_m: float = 0.0075  # authors' code (movement_threshold)
    max_rotation_deg: float = 0.5  # authors' code (np.radians(0.5))
    history_travel_m: float = 0.05  # our choice
    max_history_frames: int = 128  # our choice (memory)

    def __post_init__(self) -> None:
        require_positive(self, "min_translation_m", "max_rotation_deg", "history_travel_m")
        if self.max_rotation_deg > 180.0:
            raise ValueError(
                "FramePairingConfig.max_rotation_deg must be at most 180, "
                f"got {self.max_rotation_deg!r}"
            )
        if self.history_travel_m < self.min_translation_m:
            raise ValueError(
                "FramePairingConfig.history_travel_m must be >= min_translation_m "
                f"({self.min_translation_m!r}), got {self.history_travel_m!r}: no kept frame "
                "could ever be far enough"
            )
        require_int(self, "max_history_frames", minimum=1)


@dataclass(frozen=True)
class _Frame:
    """One kept frame: read-only image copy, pose and path length from the scan's first frame."""

    rgb: np.ndarray
    rotation: np.ndarray
    position: tuple[float, float, float]
    travel_m: float


def _rotation_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle (deg) of the rotation between two (3, 3) rotation matrices.

    ``atan2(|sin|, cos)`` of the relative rotation, accurate for small angles (``arccos`` of the
    trace is not).
    """
    R = R_a.T @ R_b
    cos = (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0
    sin = 0.5 * math.hypot(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])
    return math.degrees(math.atan2(sin, cos))


class FramePairer:
    """Keeps a scan's recent frames and picks the one a new frame's flow is taken against.

    The partner of a new frame is the most recent kept frame from which the camera has moved at
    least ``min_translation_m`` and turned by less than ``max_rotation_deg``. (The authors'
    code instead takes the flow against the last frame it segmented and skips a frame after a
    turn of more than 0.5 deg; the rule here is the same test against every kept frame, so a
    frame after a brief turn can still pair with one before it.) Each frame is kept whatever
    its outcome, within ``history_travel_m`` of travel and ``max_history_frames``.

    >>> pairer = FramePairer()
    >>> frame = np.zeros((240, 320, 3), np.uint8)
    >>> pose = np.eye(4)
    >>> pairer.add(frame, pose) is None  # nothing to pair with yet
    True
    >>> pose[1, 3] = -0.0075  # 7.5 mm up (camera y points down)
    >>> pairer.add(frame, pose).shape
    (240, 320, 3)
    """

    def __init__(self, config: FramePairingConfig | None = None) -> None:
        """Start an empty history.

        Args:
            config: Pairing thresholds and history bounds (default ``FramePairingConfig()``).
        """
        self._config = config or FramePairingConfig()
        self._frames: deque[_Frame] = deque()

    @property
    def config(self) -> FramePairingConfig:
        """The pairing thresholds and history bounds."""
        return self._config

    def __len__(self) -> int:
        """Number of frames kept."""
        return len(self._frames)

    def reset(self) -> None:
        """Forget every frame (a new scan)."""
        self._frames.clear()

    def add(self, rgb: np.ndarray, T_world_camera: np.ndarray) -> np.ndarray | None:
        """Pair a new frame with an earlier one, then keep it.

        Args:
            rgb: (H, W, 3) uint8 new frame, the size of the frames kept; a copy is kept.
            T_world_camera: (4, 4) rigid camera pose of the frame (metres).

        Returns:
            (H, W, 3) uint8 read-only image of the partner frame (compute the flow from it to
            ``rgb``), or None when no kept frame qualifies: the frame then has no flow (the
            caller decides what to do with it).

        Raises:
            ValueError: ``rgb`` is not (H, W, 3) uint8 or differs in size from the kept frames
                (``reset()`` starts a new scan), or the pose is not a finite rigid (4, 4)
                transform.
        """
        _check_rgb(rgb, "rgb")
        T = check_pose(T_world_camera, "T_world_camera")
        if self._frames and rgb.shape != self._frames[-1].rgb.shape:
            raise ValueError(
                f"rgb has shape {rgb.shape} but this scan's frames have "
                f"{self._frames[-1].rgb.shape}: call reset() for a new scan"
            )
        config = self._config
        position = (float(T[0, 3]), float(T[1, 3]), float(T[2, 3]))
        rotation = T[:3, :3].copy()
        travel_m = 0.0
        if self._frames:
            last = self._frames[-1]
            travel_m = last.travel_m + math.dist(last.position, position)
        while self._frames and travel_m - self._frames[0].travel_m > config.history_travel_m:
            self._frames.popleft()

        partner = None
        for frame in reversed(self._frames):
            translation_m = math.dist(frame.position, position)
            if translation_m < config.min_translation_m:
                continue
            rotation_deg = _rotation_deg(frame.rotation, rotation)
            if rotation_deg < config.max_rotation_deg:
                partner = frame.rgb
                logger.debug(
                    "frame paired: moved %.4f m, turned %.3f deg", translation_m, rotation_deg
                )
                break
        if partner is None:
            logger.debug("frame unpaired: no kept frame moved enough without turning too far")

        kept = rgb.copy()
        kept.flags.writeable = False
        self._frames.append(_Frame(kept, rotation, position, travel_m))
        while len(self._frames) > config.max_history_frames:
            self._frames.popleft()
        return partner
