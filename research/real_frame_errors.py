"""Where a segmenter's mask of real frames departs from the hand masks (issue 32, a study).

For each real frame (``score-real``'s folder) and pooled over them: IoU, precision, recall; the
false positives split by their distance to the hand masks (the mask drawn 1-2 px wider, 3-4 px,
farther) and the far ones in the frame's bottom fifth (the trunk's base and the ground); the
pixels missed split the same way from the predicted mask; and the IoU with the hand masks
shifted by the best whole-pixel offset within ``--max-shift-px`` (a registration check of the
hand masks, never used to score).

A second table takes the hand side-branch masks one by one: their pixels, the share the mask
covers, how far they lie from the trunk masks, and whether the 2D stage finds them on the
predicted mask and on the hand masks themselves (``real_frames.side_branches_found``, the
``score-real`` rule). The 2D stage finds only side branches that leave the primary.

A third table asks where the image's own edges lie against each mask's outline: the mean grey
step between a mask pixel and its 4-neighbours outside, for the mask grown or shrunk by k px, on
the stretches where the two masks run together; the k with the largest step is where the edges
are. With it, the IoU
of the hand masks against themselves grown by 1 px: what a 1-px outline convention costs on
branches a few pixels wide.

    python research/real_frame_errors.py ../shared/data/real_dev [--weights learned] [--no-flow]

Prints three markdown tables. The frames are GPL v3: nothing of them is written.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from branch_gym.segmenter_training.real_frames import (
    RealFrame,
    RealScoreConfig,
    distance_to_mask,
    load_real_frames,
    predict_mask,
    score_prediction,
    side_branches_found,
)
from recon.segmentation import load_segmenter

NEAR_PX = 2.0  # "drawn wider": within this of the hand masks (our choice: a trunk's edge blur)
MIDDLE_PX = 4.0  # "beside it": up to this
BOTTOM_SHARE = 0.2  # the frame's bottom fifth: the trunk's base, the ground and its weeds
OUTLINE_OFFSETS_PX = (-2, -1, 0, 1, 2)  # outlines of the mask shrunk (-) or grown (+) by k px
TOGETHER_PX = 5  # the edge table's stretches: within this (Euclidean) of pixels both masks take
_SQUARE = np.ones((3, 3), np.uint8)  # one pixel of growth per iteration (8-neighbourhood)
_ALL, _HEAD, _TAIL = slice(None), slice(1, None), slice(None, -1)
_NEIGHBOUR_VIEWS = (  # (p, q) index pairs: q the pixel left of, right of, above, below p
    ((_ALL, _HEAD), (_ALL, _TAIL)),
    ((_ALL, _TAIL), (_ALL, _HEAD)),
    ((_HEAD, _ALL), (_TAIL, _ALL)),
    ((_TAIL, _ALL), (_HEAD, _ALL)),
)


@dataclass
class Counts:
    """Pixel counts of one frame (or summed)."""

    hit: int = 0
    wrong_near: int = 0
    wrong_middle: int = 0
    wrong_far: int = 0
    wrong_far_bottom: int = 0
    missed_near: int = 0
    missed_far: int = 0

    def __iadd__(self, other: Counts) -> Counts:
        for name in vars(self):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        return self

    @property
    def wrong(self) -> int:
        return self.wrong_near + self.wrong_middle + self.wrong_far

    @property
    def missed(self) -> int:
        return self.missed_near + self.missed_far

    def iou(self, drop_wrong: int = 0) -> float:
        return self.hit / (self.hit + self.wrong - drop_wrong + self.missed)


def count_errors(predicted: np.ndarray, target: np.ndarray) -> Counts:
    """The pixel counts of one frame (module docstring)."""
    to_target, to_predicted = distance_to_mask(target), distance_to_mask(predicted)
    wrong, missed = predicted & ~target, target & ~predicted
    far = wrong & (to_target > MIDDLE_PX)
    bottom = np.zeros_like(far)
    bottom[round((1.0 - BOTTOM_SHARE) * far.shape[0]) :] = True
    return Counts(
        hit=int(np.count_nonzero(predicted & target)),
        wrong_near=int(np.count_nonzero(wrong & (to_target <= NEAR_PX))),
        wrong_middle=int(np.count_nonzero(wrong & (to_target > NEAR_PX) & ~far)),
        wrong_far=int(np.count_nonzero(far)),
        wrong_far_bottom=int(np.count_nonzero(far & bottom)),
        missed_near=int(np.count_nonzero(missed & (to_predicted <= NEAR_PX))),
        missed_far=int(np.count_nonzero(missed & (to_predicted > NEAR_PX))),
    )


def best_shift(
    predicted: np.ndarray, target: np.ndarray, max_shift_px: int
) -> tuple[tuple[int, int], float]:
    """((du, dv), IoU): the whole-pixel shift of the target that best fits the prediction."""
    best = ((0, 0), -1.0)
    height, width = target.shape
    padded = np.pad(target, max_shift_px)
    for dv in range(-max_shift_px, max_shift_px + 1):
        for du in range(-max_shift_px, max_shift_px + 1):
            top, left = max_shift_px - dv, max_shift_px - du
            moved = padded[top : top + height, left : left + width]
            union = np.count_nonzero(predicted | moved)
            iou = np.count_nonzero(predicted & moved) / union if union else 0.0
            if iou > best[1]:
                best = ((du, dv), iou)
    return best


def _row(name: str, counts: Counts, shift: str) -> str:
    share = 100.0 / max(counts.wrong, 1)
    return (
        f"| {name} | {counts.iou():.3f} | {counts.hit / (counts.hit + counts.wrong):.2f} | "
        f"{counts.hit / (counts.hit + counts.missed):.2f} | {counts.wrong_near * share:.0f} / "
        f"{counts.wrong_middle * share:.0f} / {counts.wrong_far * share:.0f} | "
        f"{100.0 * counts.wrong_far_bottom / max(counts.wrong_far, 1):.0f} | "
        f"{100.0 * counts.missed_near / max(counts.missed, 1):.0f} | "
        f"{counts.iou(counts.wrong_near):.3f} / {counts.iou(counts.wrong_far):.3f} | {shift} |"
    )


def report(frames: list[RealFrame], predicted: list[np.ndarray], max_shift_px: int) -> str:
    """The markdown table of every frame and the pooled row."""
    lines = [
        "| frame | IoU | precision | recall | wrong pixels within 2 px / 2-4 px / farther, % | "
        "farther ones in the bottom fifth, % | missed within 2 px of the mask, % | "
        "IoU without the wrong pixels within 2 px / farther | best hand-mask shift (du, dv): IoU |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    total = Counts()
    for frame, mask in zip(frames, predicted, strict=True):
        counts = count_errors(mask, frame.target)
        total += counts
        shift, shifted_iou = best_shift(mask, frame.target, max_shift_px)
        lines.append(_row(frame.name, counts, f"{shift}: {shifted_iou:.3f}"))
    lines.append(_row("pooled", total, "-"))
    return "\n".join(lines)


def side_branch_report(frames: list[RealFrame], predicted: list[np.ndarray]) -> str:
    """The markdown table of every hand side-branch mask (module docstring)."""
    config = RealScoreConfig()
    lines = [
        "| frame | side branch | pixels | in the mask, % | gap to the trunk masks, px | "
        "found on the mask | found on the hand masks |",
        "|---|---|---|---|---|---|---|",
    ]
    for frame, predicted_mask in zip(frames, predicted, strict=True):
        found, by_hand = (
            side_branches_found(frame, score_prediction(mask, frame, config).curves, config)
            for mask in (predicted_mask, frame.target)
        )
        trunks = np.zeros(frame.shape, bool)
        for mask in frame.trunk_masks:
            trunks |= mask
        to_trunk = distance_to_mask(trunks)
        for k, mask in enumerate(frame.side_branch_masks):
            covered = (
                100.0 * np.count_nonzero(predicted_mask & mask) / max(np.count_nonzero(mask), 1)
            )
            gap = float(to_trunk[mask].min()) if mask.any() else float("nan")
            lines.append(
                f"| {frame.name} | {k} | {np.count_nonzero(mask)} | {covered:.0f} | {gap:.0f} | "
                f"{'yes' if found[k] else 'no'} | {'yes' if by_hand[k] else 'no'} |"
            )
    return "\n".join(lines)


def grown(mask: np.ndarray, k: int) -> np.ndarray:
    """(H, W) bool mask grown by k px (shrunk for k < 0), 8-neighbourhood steps."""
    m8 = mask.astype(np.uint8)
    if k > 0:
        m8 = cv2.dilate(m8, _SQUARE, iterations=k)
    elif k < 0:
        m8 = cv2.erode(m8, _SQUARE, iterations=-k)
    return m8.astype(bool)


def boundary_contrast(
    rgb: np.ndarray, mask: np.ndarray, where: np.ndarray, offsets: tuple[int, ...]
) -> list[np.ndarray]:
    """Grey-level steps across the outline of ``mask`` grown by each offset.

    A step is ``|grey(p) - grey(q)|`` for a pixel p in the mask and its 4-neighbour q outside
    it, counted where p lies in ``where``. An outline on the image's edge crosses the full
    contrast; one a pixel inside or outside the edge sees the flat bark or sky on both sides.

    Args:
        rgb: (H, W, 3) uint8 frame.
        mask: (H, W) bool mask.
        where: (H, W) bool, the pixels counted.
        offsets: Growths in px (negative: shrunk).

    Returns:
        One (N_k,) float32 array of steps (grey levels) per offset.
    """
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    out = []
    for k in offsets:
        moved = grown(mask, k)
        steps = []
        for p, q in _NEIGHBOUR_VIEWS:  # p and q: views whose same index is a neighbour pair
            edge = moved[p] & ~moved[q] & where[p]
            steps.append(np.abs(grey[p] - grey[q])[edge])
        out.append(np.concatenate(steps))
    return out


def edge_report(frames: list[RealFrame], predicted: list[np.ndarray]) -> str:
    """The markdown table of where the image's edges lie against both outlines."""
    ks = " / ".join(f"{k:+d}" for k in OUTLINE_OFFSETS_PX)
    lines = [
        f"| frame | grey step across the hand masks' outline, grown by {ks} px | "
        f"on the predicted mask's | IoU of the hand masks with themselves grown by 1 px |",
        "|---|---|---|---|",
    ]
    pooled: dict[str, list[list[np.ndarray]]] = {"hand": [], "predicted": []}
    hits = unions = 0
    for frame, mask in zip(frames, predicted, strict=True):
        together = distance_to_mask(frame.target & mask) <= TOGETHER_PX
        cells = []
        for name, outline_of in (("hand", frame.target), ("predicted", mask)):
            values = boundary_contrast(frame.rgb, outline_of, together, OUTLINE_OFFSETS_PX)
            pooled[name].append(values)
            cells.append(" / ".join(f"{v.mean():.0f}" if len(v) else "-" for v in values))
        wider = grown(frame.target, 1)
        hits += int(np.count_nonzero(frame.target))
        unions += int(np.count_nonzero(wider))
        cells.append(f"{np.count_nonzero(frame.target) / np.count_nonzero(wider):.3f}")
        lines.append(f"| {frame.name} | " + " | ".join(cells) + " |")
    cells = []
    for name in ("hand", "predicted"):
        per_k = zip(*pooled[name], strict=True)
        cells.append(" / ".join(f"{np.concatenate(v).mean():.0f}" for v in per_k))
    lines.append("| pooled | " + " | ".join(cells) + f" | {hits / max(unions, 1):.3f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="a real frame folder (score-real's --data)")
    parser.add_argument("--weights", default="learned", help="a segmenter spec")
    parser.add_argument("--no-flow", action="store_true", help="colour alone")
    parser.add_argument("--max-shift-px", type=int, default=3)
    args = parser.parse_args()
    frames = load_real_frames(args.data)
    segmenter = load_segmenter(args.weights)
    predicted = [predict_mask(segmenter, frame, not args.no_flow) for frame in frames]
    print(report(frames, predicted, args.max_shift_px))
    print()
    print(side_branch_report(frames, predicted))
    print()
    print(edge_report(frames, predicted))


if __name__ == "__main__":
    main()
