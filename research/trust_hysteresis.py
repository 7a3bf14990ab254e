"""A side branch kept on weaker evidence than it was found on: ``eval.py`` with trust hysteresis.

A study for issue 34 (``docs/results/orchard.md``, "Whose misses"). The modeler's trust check
(``SecondaryBranches.update_trust``, the authors' +1 / -1) asks a model side branch's projection
to land on the frame's mask, the learned segmenter's probability above 0.5. Here it lands on a
looser mask instead, the probability above ``--support-probability`` (hysteresis, as in edge
linking): new detections still come from the 0.5 mask. Everything else is ``eval.py``; its
arguments follow this script's own.

    python research/trust_hysteresis.py --support-probability 0.1 --policies periodic:22.5:1.5 \\
        --trees 60 --seed 10000000 --workers 2 --world orchard --segmenter learned \\
        --out results/weak_val_0.1          # ~20 min on 2 cores

The run patches ``LearnedSegmenter.segment`` (it also keeps the looser mask of each frame) and
the trust check's mask lookup, in this process and the workers it forks.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from agents.commands import evaluate as eval_main
from recon.frame import Frame
from recon.model3d import secondary
from recon.segmentation.segmenter import LearnedSegmenter, subpixels_to_image

_SUPPORT_MASKS_KEPT = 64  # a scan reads the masks of its latest frames only


def install(support_probability: float) -> None:
    """Patch the segmenter and the trust check (module docstring)."""
    if not 0.0 < support_probability < 1.0:
        raise ValueError(f"--support-probability must lie in (0, 1), got {support_probability}")
    support_logit = float(np.log(support_probability / (1.0 - support_probability)))
    support_of: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # id(mask) -> (mask, support)

    def segment(
        self: LearnedSegmenter,
        rgb: np.ndarray,
        previous_rgb: np.ndarray | None = None,
        flow_image: np.ndarray | None = None,
    ) -> np.ndarray:
        subpixels, (h, w) = self._subpixel_logits(rgb, previous_rgb, flow_image)
        mask = subpixels_to_image(subpixels > self._logit_threshold)[:h, :w]
        if len(support_of) >= _SUPPORT_MASKS_KEPT:
            support_of.clear()
        support_of[id(mask)] = (mask, subpixels_to_image(subpixels > support_logit)[:h, :w])
        return mask

    mask_fraction = secondary._mask_fraction
    update_trust = secondary.SecondaryBranches.update_trust
    in_trust_check = False

    def support_fraction(
        points: np.ndarray, frame: Frame, margin_px: float, tolerance_px: float = 0.0
    ) -> tuple[float, int]:
        kept = support_of.get(id(frame.mask)) if in_trust_check else None
        if kept is not None and kept[0] is frame.mask:
            frame = Frame(frame.rgb, kept[1], frame.T_world_camera, frame.intrinsics)
        return mask_fraction(points, frame, margin_px, tolerance_px)

    def trust_check(self: secondary.SecondaryBranches, frame: Frame) -> None:
        nonlocal in_trust_check
        in_trust_check = True
        try:
            update_trust(self, frame)
        finally:
            in_trust_check = False

    LearnedSegmenter.segment = segment
    secondary._mask_fraction = support_fraction
    secondary.SecondaryBranches.update_trust = trust_check


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], epilog="Every other argument goes to eval.py."
    )
    parser.add_argument("--support-probability", type=float, required=True)
    args, eval_args = parser.parse_known_args()
    try:
        install(args.support_probability)
    except ValueError as error:
        parser.error(str(error))
    return eval_main(eval_args)


if __name__ == "__main__":
    sys.exit(main())
