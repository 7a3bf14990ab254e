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

    python research/real_frame_errors.py ../shared/data/real_dev [--weights learned] [--no-flow]

Prints two markdown tables. The frames are GPL v3: nothing of them is written.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

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


if __name__ == "__main__":
    main()
