"""Test-time variants of the shipped segmenter on the real development frames (and renders).

A study of inference alone (issue 32): does the real frames' IoU move with a mirrored second
pass (the logits of the mirrored frame and flow picture, mirrored back and averaged: the
network was trained on mirrored frames and direction-free flow pictures), with the frame
resized before the network (the real trees' scale in pixels against the renders'), or with
another threshold? The weights stay the shipped ones.

    python research/segmenter_test_time.py --real ../shared/data/real_dev --trees 10

Prints one line per variant: pooled and mean IoU, primary on the trunk, side branches found;
with ``--trees N`` also the pooled IoU on orchard renders of N unseen trees per preset.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import cv2
import numpy as np

from branch_gym.segmenter_training.evaluate import EvaluateConfig, evaluate_segmenters
from branch_gym.segmenter_training.real_frames import load_real_frames, score_segmenter, summarise
from recon.segmentation import LearnedSegmenter, load_segmenter

SCALES = (0.75, 0.9, 1.25)  # the shipped variant is 1.0
LOGIT_SHIFTS = (-1.0, -0.5, 0.5, 1.0)  # added to the threshold's logit (0: probability 0.5)
PRESETS = ("paper", "ufo")


class TestTimeSegmenter:
    """The segmenter run on a resized and (optionally) also on a mirrored copy of the frame.

    Args:
        segmenter: The shipped segmenter.
        scale: Resize factor of the frame (and flow picture) before the network.
        mirrored: Average the logits of the mirrored frame, mirrored back.
        logit_shift: Added to the threshold's logit.
    """

    def __init__(
        self,
        segmenter: LearnedSegmenter,
        scale: float = 1.0,
        mirrored: bool = False,
        logit_shift: float = 0.0,
    ) -> None:
        self.segmenter, self.scale, self.mirrored = segmenter, scale, mirrored
        probability = segmenter.threshold
        self.threshold = float(np.log(probability / (1.0 - probability))) + logit_shift

    def _logits(self, rgb, previous_rgb, flow_image) -> np.ndarray:
        height, width = rgb.shape[:2]
        size = (round(width * self.scale), round(height * self.scale))
        interpolation = cv2.INTER_AREA if self.scale < 1 else cv2.INTER_LINEAR

        def resized(image):
            if image is None or self.scale == 1.0:
                return image
            return cv2.resize(image, size, interpolation=interpolation)

        logits = self.segmenter.logits(resized(rgb), resized(previous_rgb), resized(flow_image))
        return cv2.resize(logits, (width, height), interpolation=cv2.INTER_LINEAR)

    def segment(self, rgb, previous_rgb=None, flow_image=None) -> np.ndarray:
        """(H, W) bool mask (the arguments of ``LearnedSegmenter.segment``)."""
        logits = self._logits(rgb, previous_rgb, flow_image)
        if self.mirrored:

            def mirror(image):
                return None if image is None else np.ascontiguousarray(image[:, ::-1])

            back = self._logits(mirror(rgb), mirror(previous_rgb), mirror(flow_image))
            logits = 0.5 * (logits + back[:, ::-1])
        return logits > self.threshold


def variants(segmenter: LearnedSegmenter) -> dict[str, TestTimeSegmenter]:
    """The variants compared, by name."""
    found = {
        "shipped": TestTimeSegmenter(segmenter),
        "mirrored": TestTimeSegmenter(segmenter, mirrored=True),
    }
    for scale in SCALES:
        found[f"scale {scale}"] = TestTimeSegmenter(segmenter, scale=scale)
    for shift in LOGIT_SHIFTS:
        found[f"threshold logit {shift:+}"] = TestTimeSegmenter(segmenter, logit_shift=shift)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", type=Path, required=True, help="real frames folder")
    parser.add_argument("--trees", type=int, default=0, help="orchard render trees per preset")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    segmenter = load_segmenter("learned")
    frames = load_real_frames(args.real)
    named = variants(segmenter)
    print("variant | real pooled IoU | mean IoU | primary on trunk | side branches found")
    for name, variant in named.items():
        s = summarise(score_segmenter(variant, frames, use_flow_picture=True))
        print(
            f"{name} | {s['pooled_iou']:.3f} | {s['mean_iou']:.3f} | "
            f"{s['primary_on_trunk']} / {s['frames']} | {s['side_branches_found']} / "
            f"{s['side_branches']}"
        )
    if args.trees:
        config = EvaluateConfig(trees=args.trees, world="orchard")
        chosen = {name: (named[name], True) for name in ("shipped", "mirrored", "scale 0.9")}
        for preset in PRESETS:
            scores = evaluate_segmenters(chosen, preset, config, progress=False)
            for name, score in scores.items():
                print(
                    f"orchard {preset}, {name}: IoU {score['iou']:.3f}, side-branch recall "
                    f"{score['side_branch_recall']:.3f}, {score['segment_ms_mean']:.1f} ms"
                )


if __name__ == "__main__":
    main()
