"""Issue 61, part 2: a primary that must not bend into a side branch at the top edge."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from recon.curve2d.fit import fit_mask_curves
from recon.curve2d.types import Curve2DConfig

TRUNK_U = 160
TURN_LIMIT = replace(Curve2DConfig(), max_primary_turn_deg=30.0)


def _trunk_bending_into_a_side_branch(trunk_top_v: int = 40) -> np.ndarray:
    """(240, 320) mask: a 16-px trunk up to ``trunk_top_v`` (its top cut, as by a gap in a
    learned mask) and a 6-px side branch leaving it at v = 110, 30-40 deg off the vertical, up
    through the frame's top edge: the side branch reaches higher than the trunk."""
    mask = np.zeros((240, 320), np.uint8)
    cv2.line(mask, (TRUNK_U, 239), (TRUNK_U, trunk_top_v), 1, 16)
    cv2.line(mask, (TRUNK_U, 110), (200, 40), 1, 6)
    cv2.line(mask, (200, 40), (215, 0), 1, 6)
    return mask.astype(bool)


def test_the_papers_rule_follows_the_side_branch_to_the_top_edge():
    curves = fit_mask_curves(_trunk_bending_into_a_side_branch())
    assert curves.primary is not None
    # The paper's score prefers the path that reaches higher: its top lies on the side branch.
    assert np.abs(curves.primary.samples_px[:, 0] - TRUNK_U).max() > 30.0


def test_a_turn_limit_keeps_the_primary_on_the_trunk_and_finds_the_side_branch():
    curves = fit_mask_curves(_trunk_bending_into_a_side_branch(), TURN_LIMIT)
    assert curves.primary is not None
    samples = curves.primary.samples_px
    assert np.abs(samples[:, 0] - TRUNK_U).max() < 3.0
    assert samples[:, 1].min() < 50.0  # up to the trunk's cut end at v = 40
    # The side branch is a secondary now, from the trunk up to the top edge's band.
    tips = [s.samples_px[-1] for s in curves.secondaries]
    assert any(tip[0] > 200.0 and tip[1] < 20.0 for tip in tips)


def test_a_turn_limit_changes_nothing_on_a_trunk_that_reaches_the_top_itself():
    mask = _trunk_bending_into_a_side_branch(trunk_top_v=0)
    plain = fit_mask_curves(mask).primary
    limited = fit_mask_curves(mask, TURN_LIMIT).primary
    assert plain is not None and limited is not None
    np.testing.assert_allclose(limited.samples_px, plain.samples_px, atol=0.5)


def test_a_gently_leaning_trunk_is_not_cut_by_the_turn_limit():
    mask = np.zeros((240, 320), np.uint8)
    # A trunk leaning 20 deg further after a side branch leaves it: 20 < 30 deg.
    cv2.line(mask, (TRUNK_U, 239), (TRUNK_U, 120), 1, 14)
    top = (TRUNK_U + int(120 * math.tan(math.radians(20.0))), 0)
    cv2.line(mask, (TRUNK_U, 120), top, 1, 12)
    cv2.line(mask, (TRUNK_U, 150), (90, 100), 1, 5)
    curves = fit_mask_curves(mask.astype(bool), TURN_LIMIT)
    assert curves.primary is not None
    assert curves.primary.samples_px[:, 1].min() < 20.0  # up to the top band


def test_a_bad_turn_limit_is_named():
    with pytest.raises(ValueError, match="max_primary_turn_deg"):
        Curve2DConfig(max_primary_turn_deg=0.0)
