"""Score a segmenter on real orchard frames with hand-drawn masks (issue 15).

The real frames (``../shared/data/real_dev/``: per frame ``N``, the RGB frame ``N.png``, its
optical-flow picture ``N_flow.png`` and one hand-drawn mask per trunk, ``N_trunk_K.png``, and per
side branch, ``N_sidebranch_K.png``) are GPL: they are read from their folder at run time and
never copied into this repository.

A predicted (H, W) bool mask is scored three ways (the issue's figures):

* **IoU** against the target mask, the union of all hand masks of the frame (pooled over frames
  as total intersection over total union, and as the mean of the per-frame IoUs).
* **Primary on the trunk**: the 2D stage of the pipeline (:func:`recon.curve2d.fit.fit_mask_curves`,
  paper IV-B: mask -> skeleton graph -> primary and side-branch Bezier curves) is run on the
  predicted mask; its primary curve is *on the trunk* when it exists and at least
  ``min_on_trunk_fraction`` of its points (sampled every ``curve_spacing_px`` of arc length) lie
  inside one trunk hand mask dilated by ``tolerance_px``. Reported as the fraction of frames.
* **Side branches found**: a hand side-branch mask is *found* when some side-branch curve of the
  2D stage (a) has at least ``min_on_branch_fraction`` of its points inside that mask dilated by
  ``tolerance_px``, and (b) covers at least ``min_branch_coverage`` of that mask's skeleton: a
  skeleton pixel is covered when the curve passes within its radius (distance to the mask's edge)
  plus ``tolerance_px`` of it. Skeleton pixels in the 2D stage's border band
  (``SkeletonConfig.border_px``) are left out: the stage never sees them. Reported as the fraction
  of hand side-branch masks, pooled over frames.

These rules and their thresholds are ours (:class:`RealScoreConfig`); the issue defines the
figures, not how a curve is matched to a hand mask.

The same scores computed with the hand masks' union as the prediction are the upper bound the
issue quotes ("on the hand-drawn masks themselves the 2D stage finds the trunk in 13 of 14 frames
and 20 of 28 side branches"): :func:`score_hand_masks`.

The 2D stage needs no camera intrinsics, only pixels; its thresholds (``Curve2DConfig``: 40 px
shortest primary, 20 px shortest side branch, 10 px border band, 6 px gap bridging) are set for
the pipeline's default 320x240 camera (``recon.camera.DEFAULT_WIDTH_PX`` x
``DEFAULT_HEIGHT_PX``, the authors' simulated camera), so frames are resized to 320x240 by
default before anything is segmented or fitted.

Flow pictures: the recorded pictures hold the Middlebury colour-wheel coding with red and blue
exchanged (``recon/segmentation/flow.py``, module docstring). :func:`load_real_frames` reads them
as RGB (OpenCV's BGR converted) and then, by default, applies
:func:`recon.segmentation.flow.swap_red_blue`, so that ``RealFrame.flow_picture`` codes motion as
:func:`recon.segmentation.flow.flow_to_picture` does, the coding the segmenter is trained on.

Pixel coordinates are ``(u, v)`` = (column, row), as in ``recon.camera``.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import cv2
import numpy as np
from scipy.spatial import cKDTree
from skimage.morphology import skeletonize

from branch_gym.sim.scene.labels import FIRST_SECONDARY_LABEL, PRIMARY_LABEL, own_uprights_label
from recon.camera import DEFAULT_HEIGHT_PX, DEFAULT_WIDTH_PX
from recon.curve2d.fit import fit_mask_curves, points_in_mask
from recon.curve2d.types import Curve2D, Curve2DConfig, MaskCurves
from recon.frame import as_binary_mask
from recon.io.rescale import resize_image, resize_mask
from recon.segmentation.flow import flow_to_picture_fast, swap_red_blue
from recon.segmentation.metrics import pooled_iou
from recon.validation import require_non_negative, require_positive

__all__ = [
    "DEFAULT_SIZE",
    "MaskSegmenter",
    "RealFrame",
    "RealFrameScore",
    "RealScoreConfig",
    "asked_side_branches",
    "distance_to_mask",
    "draw_score_figure",
    "format_scores",
    "frames_from_renders",
    "load_real_frames",
    "predict_mask",
    "resize_mask",
    "score_hand_masks",
    "score_prediction",
    "score_report",
    "score_segmenter",
    "side_branches_found",
    "summarise",
]

logger = logging.getLogger(__name__)

DEFAULT_SIZE = (DEFAULT_WIDTH_PX, DEFAULT_HEIGHT_PX)
"""(width, height) frames are resized to: the pipeline's default camera, 320x240 px."""

# Hand masks on disk are 0/255 pictures; a pixel above mid-grey is drawn (tolerates antialiasing).
MASK_LEVEL = 127

_FRAME_NAME = re.compile(r"^(\d+)\.png$")


@dataclass(frozen=True)
class RealScoreConfig:
    """How a predicted mask's 2D curves are matched to the hand masks (all values ours).

    Attributes:
        tolerance_px: Hand masks are dilated by this many pixels (at the scored resolution)
            before curve points are tested against them (ours: 3 px at 320x240 absorbs the hand
            masks' ragged borders and the 2D stage's sub-pixel fit; about a trunk radius / 3).
        min_on_trunk_fraction: Least fraction of the primary curve's points inside one dilated
            trunk mask for the primary to be on the trunk (ours: 0.8 tolerates a primary whose
            end runs a little into a side branch at a junction, not one that follows it).
        min_on_branch_fraction: Least fraction of a side-branch curve's points inside a dilated
            side-branch mask for the curve to be on that branch (ours: 0.5; a side-branch
            curve starts on the primary's axis, so its first radius or so lies on the trunk).
        min_branch_coverage: Least fraction of a side-branch mask's skeleton that one curve on
            it must cover for the branch to be found (ours: 0.3; the 2D stage keeps curves of
            20 px and more and stops at a skeleton junction, so a branch is rarely covered whole).
        curve_spacing_px: Arc-length spacing of the points a curve is tested with (ours: dense
            enough that the fractions do not depend on the 2D stage's 10-30 px sample spacing).
        curve2d: The 2D stage's parameters (the pipeline's defaults, paper IV-B).
        rule: ``"coverage"``: the rules above (issue 15). ``"attached"``: the rule the kept-aside
            frames are scored by (``../shared/data/real_dev/README.md``, :meth:`attached`): the
            2D stage's own samples are tested (not points every ``curve_spacing_px``), the
            primary against the union of the trunk masks, a side branch by its samples but the
            first, no coverage; only the attached side-branch masks are asked for.
        min_side_branch_px: ``"attached"``: a side-branch mask is asked for when it covers at
            least this many pixels ...
        attached_within_px: ... and lies within this distance of a trunk mask.
    """

    tolerance_px: float = 3.0
    min_on_trunk_fraction: float = 0.8
    min_on_branch_fraction: float = 0.5
    min_branch_coverage: float = 0.3
    curve_spacing_px: float = 2.0
    curve2d: Curve2DConfig = field(default_factory=Curve2DConfig)
    rule: Literal["coverage", "attached"] = "coverage"
    min_side_branch_px: int = 100
    attached_within_px: float = 5.0

    @classmethod
    def attached(cls, curve2d: Curve2DConfig | None = None) -> RealScoreConfig:
        """The kept-aside frames' rule (``../shared/data/real_dev/README.md``; issue 61).

        Primary on the trunk: >= 80 % of its samples in the trunk masks' union grown by 2 px.
        A side-branch mask is asked for when it covers >= 100 px within 5 px of a trunk mask,
        and found when some side-branch curve has >= 60 % of its samples but the first inside
        that mask grown by 2 px.
        """
        return cls(
            tolerance_px=2.0, min_on_trunk_fraction=0.8, min_on_branch_fraction=0.6,
            min_branch_coverage=0.0, rule="attached", min_side_branch_px=100,
            attached_within_px=5.0, curve2d=curve2d or Curve2DConfig(),
        )  # fmt: skip

    def __post_init__(self) -> None:
        require_non_negative(self, "tolerance_px")
        require_positive(self, "curve_spacing_px")
        for name in ("min_on_trunk_fraction", "min_on_branch_fraction", "min_branch_coverage"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"RealScoreConfig.{name} must be in [0, 1], got {value!r}")
        if self.rule not in ("coverage", "attached"):
            raise ValueError(
                f"RealScoreConfig.rule must be 'coverage' or 'attached', got {self.rule!r}"
            )
        require_non_negative(self, "attached_within_px")

    def to_dict(self) -> dict[str, Any]:
        """The thresholds as a JSON-ready dict (the 2D stage's parameters left out)."""
        return {k: v for k, v in asdict(self).items() if k != "curve2d"}


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class RealFrame:
    """One real frame with its hand masks, all at one resolution.

    Attributes:
        name: The frame's number as a string (``"7"`` for ``7.png``).
        rgb: (H, W, 3) uint8 RGB frame.
        flow_picture: (H, W, 3) uint8 RGB optical-flow picture (Middlebury colour wheel), or
            None when the frame has none.
        trunk_masks: (H, W) bool masks, one per trunk or upright of the scanned tree.
        side_branch_masks: (H, W) bool masks, one per side branch.
    """

    name: str
    rgb: np.ndarray
    flow_picture: np.ndarray | None
    trunk_masks: list[np.ndarray]
    side_branch_masks: list[np.ndarray]

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the frame in pixels."""
        return self.rgb.shape[0], self.rgb.shape[1]

    @property
    def target(self) -> np.ndarray:
        """(H, W) bool union of all hand masks: the scanned tree."""
        union = np.zeros(self.shape, dtype=bool)
        for mask in [*self.trunk_masks, *self.side_branch_masks]:
            union |= mask
        return union


@dataclass(frozen=True, eq=False)  # holds arrays: compared by identity
class RealFrameScore:
    """The scores of one predicted mask against one real frame.

    Attributes:
        name: The frame's name.
        iou: Intersection over union of the prediction and the target mask.
        intersection: Pixels in both (for the pooled IoU).
        union: Pixels in either.
        primary_on_trunk: The 2D stage's primary exists and lies on a trunk mask.
        primary_trunk_fraction: Largest fraction of the primary's points inside one dilated
            trunk mask (NaN without a primary).
        side_branches_found: Hand side-branch masks found by a 2D side-branch curve.
        side_branches: Hand side-branch masks of the frame.
        side_curves: Side-branch curves the 2D stage returned (found or not).
        predicted: (H, W) bool scored mask (for figures; not serialised).
        curves: The 2D stage's output on ``predicted`` (for figures; not serialised).
    """

    name: str
    iou: float
    intersection: int
    union: int
    primary_on_trunk: bool
    primary_trunk_fraction: float
    side_branches_found: int
    side_branches: int
    side_curves: int
    predicted: np.ndarray | None = field(default=None, repr=False)
    curves: MaskCurves | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """The figures as a JSON-ready dict (NaN as None; masks and curves left out)."""
        fraction = self.primary_trunk_fraction
        return {
            "name": self.name,
            "iou": self.iou,
            "intersection": self.intersection,
            "union": self.union,
            "primary_on_trunk": self.primary_on_trunk,
            "primary_trunk_fraction": None if math.isnan(fraction) else fraction,
            "side_branches_found": self.side_branches_found,
            "side_branches": self.side_branches,
            "side_curves": self.side_curves,
        }


class MaskSegmenter(Protocol):
    """What :func:`score_segmenter` needs: ``recon.segmentation.LearnedSegmenter``'s ``segment``."""

    def segment(
        self,
        rgb: np.ndarray,
        previous_rgb: np.ndarray | None = None,
        flow_image: np.ndarray | None = None,
    ) -> np.ndarray:
        """(H, W) bool branch mask of an (H, W, 3) uint8 RGB frame."""
        ...


# ---------------------------------------------------------------------------------- loading
def load_real_frames(
    folder: str | Path,
    size: tuple[int, int] | None = DEFAULT_SIZE,
    swap_flow_red_blue: bool = True,
) -> list[RealFrame]:
    """Load the real frames of a folder with their flow pictures and hand masks.

    Frames are the files named ``N.png`` (N a number), in numeric order; ``N_flow.png`` is
    optional; ``N_trunk_K.png`` (at least one) and ``N_sidebranch_K.png`` are its hand masks, in
    order of K. Images are read with OpenCV and converted to RGB.

    Args:
        folder: The folder (e.g. ``../shared/data/real_dev``).
        size: (width, height) in pixels everything is resized to (default 320x240, the
            pipeline's camera), or None to keep the frames' own size. Images are resized with
            ``INTER_AREA`` (``recon.io.rescale.resize_image``); masks by area and thresholded at
            half (``recon.io.rescale.resize_mask``).
        swap_flow_red_blue: Exchange red and blue of the flow pictures after reading them as
            RGB, so that they code motion as ``recon.segmentation.flow.flow_to_picture`` does
            (the recorded pictures hold the coding with red and blue exchanged, see the module
            docstring); False keeps the picture as stored.

    Returns:
        The frames, in numeric order.

    Raises:
        FileNotFoundError: ``folder`` does not exist or holds no ``N.png`` frame.
        ValueError: An image cannot be read (the message names the file), a flow picture or mask
            differs in size from its frame, a frame has no trunk mask, or ``size`` is invalid.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"real frame folder {folder} does not exist")
    if size is not None and not (
        len(size) == 2 and all(isinstance(s, int) and not isinstance(s, bool) for s in size)
    ):
        raise ValueError(f"size must be (width, height) in whole pixels, got {size!r}")
    if size is not None and min(size) < 1:
        raise ValueError(f"size must be positive, got {size!r}")
    numbered = []
    for path in folder.iterdir():
        match = _FRAME_NAME.match(path.name)
        if match and path.is_file():
            numbered.append((int(match.group(1)), path))
    if not numbered:
        raise FileNotFoundError(f"no frames (N.png) in {folder}")
    frames = [_load_frame(path, size, swap_flow_red_blue) for _, path in sorted(numbered)]
    logger.info(
        "loaded %d real frames from %s (%s)",
        len(frames),
        folder,
        "x".join(map(str, (frames[0].shape[1], frames[0].shape[0]))),
    )
    return frames


def frames_from_renders(data: dict[str, np.ndarray]) -> list[RealFrame]:
    """Orchard renders as real frames: the same figures on our world (issue 61, part 3).

    Each pair's current frame becomes a :class:`RealFrame` whose "hand masks" are the
    renderer's labels drawn as the real frames' are: one trunk mask for the primary and one for
    the scanned tree's other uprights (a UFO tree's), one side-branch mask per secondary; its
    spurs, stubs and buds are in none (as the hand masks leave them out). The flow picture is
    the renderer's exact flow coded as the real frames' (a flow network's best case).

    Args:
        data: Arrays of :func:`~branch_gym.segmenter_training.orchard_pairs.load_orchard_shards`
            (with ``n_secondaries``).

    Returns:
        One frame per pair, named ``<tree seed>_<pair index>``.

    Raises:
        ValueError: ``data`` lacks ``n_secondaries`` (shards written before it was stored).
    """
    if "n_secondaries" not in data:
        raise ValueError(
            "render frames need shards that store n_secondaries: generate them again with "
            "`python -m branch_gym.segmenter_training generate-orchard --evaluation`"
        )
    frames = []
    for index, (pair, flow, labels, n_secondaries, seed) in enumerate(
        zip(data["rgb"], data["flow"], data["labels"], data["n_secondaries"], data["seeds"],
            strict=True)
    ):  # fmt: skip
        trunks = [labels == PRIMARY_LABEL, labels == own_uprights_label(int(n_secondaries))]
        sides = [labels == FIRST_SECONDARY_LABEL + i for i in range(int(n_secondaries))]
        frames.append(
            RealFrame(
                name=f"{int(seed)}_{index}",
                rgb=pair[1],
                flow_picture=flow_to_picture_fast(flow.astype(np.float32)),
                trunk_masks=[m for m in trunks if m.any()],
                side_branch_masks=[m for m in sides if m.any()],
            )
        )
    return frames


def _load_frame(path: Path, size: tuple[int, int] | None, swap_flow: bool) -> RealFrame:
    """One frame ``N.png`` with its flow picture and hand masks (see :func:`load_real_frames`)."""
    name = path.stem
    rgb = _read_rgb(path)
    native = rgb.shape[:2]
    flow_path = path.with_name(f"{name}_flow.png")
    flow = None
    if flow_path.exists():
        flow = _read_rgb(flow_path)
        _check_size(flow.shape[:2], native, flow_path, path)
        if swap_flow:
            flow = swap_red_blue(flow)
    trunks = [_read_mask(p, native, path) for p in _mask_paths(path, "trunk")]
    if not trunks:
        raise ValueError(f"frame {path} has no trunk mask ({name}_trunk_K.png)")
    sides = [_read_mask(p, native, path) for p in _mask_paths(path, "sidebranch")]
    if size is not None and (size[1], size[0]) != native:
        rgb = resize_image(rgb, size)
        flow = None if flow is None else resize_image(flow, size)
        trunks = [resize_mask(m, size) for m in trunks]
        sides = [resize_mask(m, size) for m in sides]
    for kind, masks in (("trunk", trunks), ("sidebranch", sides)):
        for index, mask in enumerate(masks):
            if not mask.any():
                logger.warning("frame %s: mask %s %d is empty at %s", name, kind, index, size)
    return RealFrame(name, rgb, flow, trunks, sides)


def _mask_paths(frame_path: Path, kind: str) -> list[Path]:
    """The frame's ``N_<kind>_K.png`` masks in order of K."""
    pattern = re.compile(rf"^{re.escape(frame_path.stem)}_{kind}_(\d+)\.png$")
    found = []
    for path in frame_path.parent.iterdir():
        match = pattern.match(path.name)
        if match:
            found.append((int(match.group(1)), path))
    return [p for _, p in sorted(found)]


def _read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of a file; ValueError naming the file when unreadable."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None or bgr.size == 0:
        raise ValueError(f"cannot read image {path} (missing, corrupt or not an image)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _read_mask(path: Path, shape: tuple[int, int], frame_path: Path) -> np.ndarray:
    """(H, W) bool hand mask of a file, checked against its frame's (H, W)."""
    grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if grey is None or grey.size == 0:
        raise ValueError(f"cannot read mask {path} (missing, corrupt or not an image)")
    _check_size(grey.shape[:2], shape, path, frame_path)
    return grey > MASK_LEVEL


def _check_size(got: tuple[int, ...], want: tuple[int, ...], path: Path, frame: Path) -> None:
    """ValueError naming ``path`` when its (H, W) differs from its frame's."""
    if tuple(got) != tuple(want):
        raise ValueError(
            f"{path} is {got[1]}x{got[0]} px but its frame {frame.name} is {want[1]}x{want[0]} px"
        )


# ---------------------------------------------------------------------------------- scoring
def score_prediction(
    predicted: np.ndarray, frame: RealFrame, config: RealScoreConfig | None = None
) -> RealFrameScore:
    """Score one predicted mask against a frame's hand masks (rules: module docstring).

    Args:
        predicted: (H, W) bool (or {0, 1}) predicted mask at the frame's resolution.
        frame: The frame with its hand masks.
        config: Matching thresholds (default :class:`RealScoreConfig`).

    Returns:
        The frame's scores, with the mask and the 2D stage's curves attached.

    Raises:
        ValueError: ``predicted`` is not a binary mask of the frame's (H, W).
    """
    config = config or RealScoreConfig()
    predicted = as_binary_mask(predicted, frame.shape)
    target = frame.target
    intersection = int(np.count_nonzero(predicted & target))
    union = int(np.count_nonzero(predicted | target))
    curves = fit_mask_curves(predicted, config.curve2d)
    trunk_fraction = math.nan
    if curves.primary is not None:
        points = _curve_points(curves.primary, config)
        trunks = frame.trunk_masks
        if config.rule == "attached":
            trunks = [np.logical_or.reduce(trunks)] if trunks else []
        trunk_fraction = max(
            (_fraction_inside(points, _dilate(m, config.tolerance_px)) for m in trunks),
            default=0.0,
        )
    on_trunk = bool(trunk_fraction >= config.min_on_trunk_fraction)  # False for NaN
    found = sum(side_branches_found(frame, curves, config))
    return RealFrameScore(
        name=frame.name,
        iou=pooled_iou(intersection, union),
        intersection=intersection,
        union=union,
        primary_on_trunk=on_trunk,
        primary_trunk_fraction=float(trunk_fraction),
        side_branches_found=int(found),
        side_branches=len(asked_side_branches(frame, config)),
        side_curves=len(curves.secondaries),
        predicted=predicted,
        curves=curves,
    )


def side_branches_found(
    frame: RealFrame, curves: MaskCurves, config: RealScoreConfig | None = None
) -> list[bool]:
    """Which of the frame's hand side-branch masks the 2D stage's side-branch curves find.

    Args:
        frame: The frame with its hand masks.
        curves: The 2D stage's output on a mask of the frame (``fit_mask_curves``).
        config: Matching thresholds (module docstring).

    Returns:
        One flag per mask of :func:`asked_side_branches`, in order.
    """
    config = config or RealScoreConfig()
    asked = asked_side_branches(frame, config)
    if config.rule == "attached":
        dilated = [_dilate(m, config.tolerance_px) for m in asked]
        side_points = [c.samples_px[1:] for c in curves.secondaries]
        return [
            any(
                len(points) and _fraction_inside(points, mask) >= config.min_on_branch_fraction
                for points in side_points
            )
            for mask in dilated
        ]
    side_points = [_curve_points(c, config) for c in curves.secondaries]
    return [_side_branch_found(m, side_points, config) for m in asked]


def asked_side_branches(frame: RealFrame, config: RealScoreConfig) -> list[np.ndarray]:
    """The frame's side-branch masks a rule asks for: all, or the attached ones.

    Args:
        frame: The frame with its hand masks.
        config: ``rule == "attached"``: the masks of at least ``min_side_branch_px`` pixels
            within ``attached_within_px`` of a trunk mask; else every mask.

    Returns:
        The masks asked for, in the frame's order.
    """
    if config.rule != "attached":
        return list(frame.side_branch_masks)
    if not frame.trunk_masks:
        return []
    near_trunk = _dilate(np.logical_or.reduce(frame.trunk_masks), config.attached_within_px)
    return [
        m
        for m in frame.side_branch_masks
        if np.count_nonzero(m) >= config.min_side_branch_px and (m & near_trunk).any()
    ]


def score_hand_masks(
    frames: Sequence[RealFrame], config: RealScoreConfig | None = None
) -> list[RealFrameScore]:
    """Score the hand masks' union as the prediction: the 2D stage's upper bound.

    Args:
        frames: The frames.
        config: Matching thresholds.

    Returns:
        One score per frame (IoU 1 by construction).
    """
    return [score_prediction(frame.target, frame, config) for frame in frames]


def predict_mask(
    segmenter: MaskSegmenter, frame: RealFrame, use_flow_picture: bool = True
) -> np.ndarray:
    """The segmenter's (H, W) bool mask of a frame.

    Args:
        segmenter: Anything with ``segment(rgb, previous_rgb=None, flow_image=None)``.
        frame: The frame.
        use_flow_picture: Pass the frame's flow picture as ``flow_image`` when it has one;
            otherwise the segmenter gets the RGB frame alone.

    Returns:
        (H, W) bool mask.

    Raises:
        ValueError: The segmenter returned something other than a binary mask of the frame's
            (H, W).
    """
    if use_flow_picture and frame.flow_picture is not None:
        mask = segmenter.segment(frame.rgb, flow_image=frame.flow_picture)
    else:
        mask = segmenter.segment(frame.rgb)
    return as_binary_mask(np.asarray(mask), frame.shape)


def score_segmenter(
    segmenter: MaskSegmenter,
    frames: Sequence[RealFrame],
    use_flow_picture: bool = True,
    config: RealScoreConfig | None = None,
) -> list[RealFrameScore]:
    """Segment every frame and score the masks against the hand masks.

    Args:
        segmenter: Anything with ``segment(rgb, previous_rgb=None, flow_image=None)`` returning
            an (H, W) bool mask (``recon.segmentation.LearnedSegmenter``).
        frames: The frames (:func:`load_real_frames`).
        use_flow_picture: Give the segmenter each frame's flow picture (``flow_image=``) when
            there is one; False: RGB only.
        config: Matching thresholds.

    Returns:
        One score per frame, in order.
    """
    scores = []
    for frame in frames:
        score = score_prediction(predict_mask(segmenter, frame, use_flow_picture), frame, config)
        logger.debug("frame %s: %s", frame.name, score)
        scores.append(score)
    return scores


def summarise(scores: Sequence[RealFrameScore]) -> dict[str, Any]:
    """Pool the per-frame scores.

    Args:
        scores: Per-frame scores (at least one).

    Returns:
        ``frames``; ``pooled_iou`` (total intersection / total union); ``mean_iou``;
        ``primary_on_trunk`` (frames) and ``primary_on_trunk_fraction`` (of frames);
        ``side_branches_found`` and ``side_branches`` (hand masks, all frames) and
        ``side_branch_found_fraction`` (None when there are no side branches).

    Raises:
        ValueError: ``scores`` is empty.
    """
    if not scores:
        raise ValueError("no scores to summarise")
    on_trunk = sum(s.primary_on_trunk for s in scores)
    found = sum(s.side_branches_found for s in scores)
    sides = sum(s.side_branches for s in scores)
    return {
        "frames": len(scores),
        "pooled_iou": pooled_iou(sum(s.intersection for s in scores), sum(s.union for s in scores)),
        "mean_iou": float(np.mean([s.iou for s in scores])),
        "primary_on_trunk": int(on_trunk),
        "primary_on_trunk_fraction": on_trunk / len(scores),
        "side_branches_found": int(found),
        "side_branches": int(sides),
        "side_branch_found_fraction": found / sides if sides else None,
    }


def score_report(scores: Sequence[RealFrameScore]) -> dict[str, Any]:
    """``{"frames": [per-frame dicts], "summary": summarise(scores)}``, JSON-ready."""
    return {"frames": [s.to_dict() for s in scores], "summary": summarise(scores)}


def format_scores(title: str, scores: Sequence[RealFrameScore]) -> str:
    """A plain-text table of per-frame scores and their summary.

    Args:
        title: First line.
        scores: Per-frame scores (at least one).

    Returns:
        The table, lines joined by newlines (no trailing newline).
    """
    lines = [title, f"{'frame':>6} {'IoU':>6} {'primary on trunk':>17} {'side branches':>14}"]
    for s in scores:
        fraction = (
            "-" if math.isnan(s.primary_trunk_fraction) else f"{s.primary_trunk_fraction:.2f}"
        )
        trunk = f"{'yes' if s.primary_on_trunk else 'no'} ({fraction})"
        lines.append(
            f"{s.name:>6} {s.iou:6.3f} {trunk:>17} "
            f"{f'{s.side_branches_found}/{s.side_branches}':>14}"
        )
    summary = summarise(scores)
    side_fraction = summary["side_branch_found_fraction"]
    lines.append(
        f"pooled IoU {summary['pooled_iou']:.3f}, mean IoU {summary['mean_iou']:.3f}; "
        f"primary on trunk {summary['primary_on_trunk']}/{summary['frames']} frames; "
        f"side branches found {summary['side_branches_found']}/{summary['side_branches']}"
        + ("" if side_fraction is None else f" ({side_fraction:.2f})")
    )
    return "\n".join(lines)


def _curve_points(curve: Curve2D, config: RealScoreConfig) -> np.ndarray:
    """(K, 2) points (u, v) along a 2D curve, ``config.curve_spacing_px`` apart at most
    (rule ``"attached"``: the 2D stage's own samples)."""
    if config.rule == "attached":
        return np.asarray(curve.samples_px, float)
    return curve.curve.resample_by_arclength(config.curve_spacing_px)[0]


def _dilate(mask: np.ndarray, radius_px: float) -> np.ndarray:
    """(H, W) bool: pixels within ``radius_px`` (Euclidean, centre to centre) of ``mask``."""
    if radius_px <= 0.0 or not mask.any():
        return mask
    return distance_to_mask(mask) <= radius_px


def distance_to_mask(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32 distance of every pixel to the nearest ``mask`` pixel (0 on it)."""
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _fraction_inside(points_uv: np.ndarray, mask: np.ndarray) -> float:
    """Fraction of the (K, 2) points (u, v), rounded to pixels, on ``mask`` (0 for no points)."""
    return float(points_in_mask(mask, points_uv).mean()) if len(points_uv) else 0.0


def _side_branch_found(
    mask: np.ndarray, curves_points: list[np.ndarray], config: RealScoreConfig
) -> bool:
    """Whether one of the side-branch curves (as point arrays) finds this hand mask."""
    if not curves_points or not mask.any():
        return False
    skeleton = skeletonize(mask)
    border = config.curve2d.skeleton.border_px
    if border > 0:  # the 2D stage drops this band: it can never cover it
        skeleton[:border] = skeleton[-border:] = False
        skeleton[:, :border] = skeleton[:, -border:] = False
    rows, cols = np.nonzero(skeleton)
    if len(rows) == 0:
        return False
    skeleton_uv = np.column_stack([cols, rows]).astype(float)
    # Radius of the branch at each skeleton pixel: distance to the mask's edge.
    radii = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    reach = radii[rows, cols] + config.tolerance_px
    dilated = _dilate(mask, config.tolerance_px)
    for points in curves_points:
        if _fraction_inside(points, dilated) < config.min_on_branch_fraction:
            continue
        distance = cKDTree(points).query(skeleton_uv)[0]
        if np.mean(distance <= reach) >= config.min_branch_coverage:
            return True
    return False


# ---------------------------------------------------------------------------------- figure
_PREDICTED_RGB = (70, 140, 255)
_OUTLINE_RGB = (0, 255, 0)
_PRIMARY_RGB = (255, 40, 40)
_SIDE_RGB = (255, 220, 0)
_PANEL_GAP_PX = 4


def draw_score_figure(
    frames: Sequence[RealFrame],
    scores: Sequence[RealFrameScore],
    path: str | Path,
    hand_scores: Sequence[RealFrameScore] | None = None,
) -> None:
    """Write a grid picture: one row per frame.

    Columns: RGB | flow picture (grey when none) | predicted mask (blue) on the darkened frame,
    hand masks' outline (green), the 2D stage's primary (red) and side-branch curves (yellow) |
    (with ``hand_scores``) the same for the hand masks as the prediction.

    Args:
        frames: The frames.
        scores: Their scores, with ``predicted`` and ``curves`` (from :func:`score_prediction`).
        path: Output picture (PNG, ...); its folder is created.
        hand_scores: Scores of the hand masks (:func:`score_hand_masks`), or None.

    Raises:
        ValueError: Frames and scores differ in number or a score lacks its mask.
        OSError: The picture cannot be written.
    """
    if len(frames) != len(scores) or (hand_scores is not None and len(hand_scores) != len(frames)):
        raise ValueError("one score per frame is needed")
    rows = []
    for index, frame in enumerate(frames):
        h, w = frame.shape
        flow = frame.flow_picture
        panels = [
            _label(frame.rgb, f"frame {frame.name}"),
            _label(np.full((h, w, 3), 128, np.uint8) if flow is None else flow, "flow picture"),
            _overlay(frame, scores[index], "predicted"),
        ]
        if hand_scores is not None:
            panels.append(_overlay(frame, hand_scores[index], "hand masks"))
        gap = np.full((h, _PANEL_GAP_PX, 3), 255, np.uint8)
        rows.append(np.hstack([p for panel in panels for p in (panel, gap)][:-1]))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, _PANEL_GAP_PX), (0, width - r.shape[1]), (0, 0)), constant_values=255)
            for r in rows]  # fmt: skip
    grid = np.vstack(rows)[:-_PANEL_GAP_PX]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR)):
        raise OSError(f"cannot write figure {path}")
    logger.info("wrote %s", path)


def _overlay(frame: RealFrame, score: RealFrameScore, title: str) -> np.ndarray:
    """(H, W, 3) uint8 panel: prediction, hand outline and 2D curves on the darkened frame."""
    if score.predicted is None:
        raise ValueError(f"score of frame {score.name} has no predicted mask to draw")
    panel = (frame.rgb.astype(np.float32) * 0.35).astype(np.uint8)
    panel[score.predicted] = (
        0.5 * panel[score.predicted] + 0.5 * np.array(_PREDICTED_RGB, np.float32)
    ).astype(np.uint8)
    contours, _ = cv2.findContours(
        frame.target.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE
    )
    cv2.drawContours(panel, contours, -1, _OUTLINE_RGB, 1)
    if score.curves is not None:
        curves = [(c, _SIDE_RGB) for c in score.curves.secondaries]
        if score.curves.primary is not None:
            curves.append((score.curves.primary, _PRIMARY_RGB))
        for curve, colour in curves:
            points = curve.curve.resample_by_arclength(2.0)[0]
            cv2.polylines(
                panel, [np.rint(points * 4).astype(np.int32)], False, colour, 2, cv2.LINE_AA, 2
            )
    text = (
        f"{title} IoU {score.iou:.2f} trunk {'yes' if score.primary_on_trunk else 'no'} "
        f"side {score.side_branches_found}/{score.side_branches}"
    )
    return _label(panel, text)


def _label(image: np.ndarray, text: str) -> np.ndarray:
    """A copy of an (H, W, 3) uint8 image with ``text`` in its top-left corner."""
    image = np.ascontiguousarray(image).copy()
    scale = max(0.3, image.shape[1] / 900.0)
    org = (4, int(14 * scale / 0.35))
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return image
