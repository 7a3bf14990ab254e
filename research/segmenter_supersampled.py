"""Does the shipped segmenter draw branches wider on anti-aliased frames than on the renderer's?

A study for issue 32. The real development frames are 640x480 photographs resized to the
camera's 320x240 with ``cv2.INTER_AREA``: a branch's edge pixels mix bark and sky. Our renders
come from TinyRenderer at 320x240 without anti-aliasing: every pixel is wholly branch or not. On
the real frames a third of the wrongly taken pixels lie within 2 px of the hand masks
(``research/real_frame_errors.py``). If the network read the mixed edge pixels as tree, it would
do the same on renders made the real frames' way: here the orchard world renders the scan
frames of ``branch_gym.segmenter_training.evaluate`` at ``FACTOR`` x the resolution (the camera
model, its noise and JPEG included, at that size, as a real sensor), and resizes frame, partner
frame and tree mask with ``INTER_AREA`` (a mask pixel is tree when half its area is: the rule
the real hand masks get, ``recon.io.rescale.resize_mask``).

    python research/segmenter_supersampled.py --trees 10 --presets paper ufo   # ~1 min

Prints, per preset and rendering, the pooled IoU, precision, recall and the predicted mask's
area over the true one.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import cv2
import numpy as np

from branch_gym.segmenter_training.config import EVAL_SEED_OFFSET
from branch_gym.segmenter_training.evaluate import EvaluateConfig, render_eval_frames
from branch_gym.segmenter_training.generate import branch_mask
from branch_gym.sim.world import WorldConfig
from recon.io.rescale import resize_mask
from recon.segmentation import load_segmenter

FACTOR = 2  # the real frames' 640x480 -> 320x240


def scan_frames(
    preset: str, seed: int, config: EvaluateConfig, factor: int
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(previous_rgb, rgb, tree mask) at the camera's resolution along the evaluation's scan,
    rendered at ``factor`` x and resized (factor 1: the renderer's own frames)."""
    camera = WorldConfig.preset(config.world).camera
    size = (camera.width, camera.height)

    def resized(image: np.ndarray) -> np.ndarray:
        return image if factor == 1 else cv2.resize(image, size, interpolation=cv2.INTER_AREA)

    frames = render_eval_frames(preset, seed, config, camera.scaled(factor))
    for previous, rgb, labels, _, _ in frames:
        yield resized(previous), resized(rgb), resize_mask(branch_mask(labels), size)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=10, help="unseen trees per preset")
    parser.add_argument("--presets", nargs="+", default=["paper", "ufo"])
    args = parser.parse_args()
    segmenter = load_segmenter("learned")
    config = EvaluateConfig(trees=args.trees, world="orchard")
    print("preset | rendering | IoU | precision | recall | predicted / true area")
    for preset in args.presets:
        for factor in (1, FACTOR):
            hit = predicted = true = 0
            for seed in range(EVAL_SEED_OFFSET, EVAL_SEED_OFFSET + args.trees):
                for previous, rgb, tree in scan_frames(preset, seed, config, factor):
                    mask = segmenter.segment(rgb, previous)
                    hit += int(np.count_nonzero(mask & tree))
                    predicted += int(np.count_nonzero(mask))
                    true += int(np.count_nonzero(tree))
            name = "renderer, 320x240" if factor == 1 else f"{FACTOR}x, resized (INTER_AREA)"
            print(
                f"{preset} | {name} | {hit / (predicted + true - hit):.3f} | "
                f"{hit / predicted:.3f} | {hit / true:.3f} | {predicted / true:.3f}"
            )


if __name__ == "__main__":
    main()
