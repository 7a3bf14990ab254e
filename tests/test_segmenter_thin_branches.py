"""Issue 61, part 1: the thin-structure loss and the near-twig flow normalisation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from branch_gym.segmenter_training.config import FlowAugmentConfig, TrainConfig
from branch_gym.segmenter_training.generate import CLASS_PRIMARY, CLASS_SECONDARY
from branch_gym.segmenter_training.orchard_augment import add_near_twig
from branch_gym.segmenter_training.train import (
    cl_dice_loss,
    segmentation_loss,
    skeleton_term,
    soft_skeleton,
)
from recon.segmentation.flow import flow_to_picture_fast

ITERATIONS = TrainConfig.skeleton_iterations


def _trunk_with_one_pixel_branch() -> tuple[torch.Tensor, tuple[slice, ...]]:
    """(1, 1, 64, 64) target: an 8-px trunk and a 1-px-wide, 24-px-long side branch."""
    target = torch.zeros(1, 1, 64, 64)
    target[..., 8:60, 26:34] = 1.0
    branch = (slice(None), slice(None), 30, slice(34, 58))
    target[branch] = 1.0
    return target, branch


def test_soft_skeleton_keeps_a_one_pixel_line_and_thins_a_trunk_to_its_centre():
    target, branch = _trunk_with_one_pixel_branch()
    skeleton = soft_skeleton(target, ITERATIONS)
    # All of the line but the pixel where it meets the trunk (which the trunk's opening keeps).
    assert torch.allclose(skeleton[branch][..., 1:], torch.ones(23), atol=1e-6)
    trunk_rows = skeleton[0, 0, 20:50, 26:34]
    # Each trunk row's skeleton is a pixel or two in the middle, never its edges.
    assert float(trunk_rows[:, 0].max()) == 0.0 and float(trunk_rows[:, -1].max()) == 0.0
    assert float(trunk_rows.sum(dim=1).max()) <= 2.0


def test_the_skeleton_term_rewards_keeping_a_one_pixel_branch_and_punishes_losing_it():
    target, branch = _trunk_with_one_pixel_branch()
    kept = target.clone()
    lost = target.clone()
    lost[branch] = 0.0
    assert float(cl_dice_loss(kept, target, ITERATIONS)) < 1e-6
    assert float(cl_dice_loss(lost, target, ITERATIONS)) > 0.08
    # Beside BCE + Dice, the branch's 24 pixels weigh more with the term than without it.
    logits_kept, logits_lost = (
        torch.logit(kept.clamp(0.02, 0.98)),
        torch.logit(lost.clamp(0.02, 0.98)),
    )
    gap_without = float(segmentation_loss(logits_lost, target, 1.0)) - float(
        segmentation_loss(logits_kept, target, 1.0)
    )
    gap_with = float(segmentation_loss(logits_lost, target, 1.0, skeleton_weight=1.0)) - float(
        segmentation_loss(logits_kept, target, 1.0, skeleton_weight=1.0)
    )
    assert gap_with > 2.0 * gap_without > 0.0
    # Its gradient pushes the lost branch's logits up (all but the pixel at the trunk).
    logits = logits_lost.clone().requires_grad_(True)
    cl_dice_loss(torch.sigmoid(logits), target, ITERATIONS).backward()
    assert float(logits.grad[branch][..., 1:].max()) < 0.0


def test_the_skeleton_term_punishes_a_spurious_thin_line_outside_the_target():
    target, branch = _trunk_with_one_pixel_branch()
    target_without = target.clone()
    target_without[branch] = 0.0
    assert float(cl_dice_loss(target, target_without, ITERATIONS)) > 0.08


def _classes(trunk_width: int) -> tuple[torch.Tensor, tuple[slice, ...]]:
    """(1, 1, 64, 64) branch_target: a trunk ``trunk_width`` px wide (its right edge at column
    34) and a 1-px-wide, 24-px-long side branch leaving it."""
    target = torch.zeros(1, 1, 64, 64)
    target[..., 8:60, 34 - trunk_width : 34] = CLASS_PRIMARY
    branch = (slice(None), slice(None), 30, slice(34, 58))
    target[branch] = CLASS_SECONDARY
    return target, branch


def test_the_side_branch_skeleton_recall_costs_a_lost_branch_and_ignores_the_trunk():
    terms = {}
    for width in (4, 8, 16):
        target, branch = _classes(width)
        kept = (target > 0).float()
        lost = kept.clone()
        lost[branch] = 0.0
        thin_trunk = kept.clone()  # the trunk predicted 2 px wide, the branch kept
        thin_trunk[..., 8:60, 34 - width : 32] = 0.0
        terms[width] = [
            float(skeleton_term(prob, target, ITERATIONS, "side"))
            for prob in (kept, lost, thin_trunk)
        ]
    for kept, lost, thin_trunk in terms.values():
        assert kept < 1e-6 and thin_trunk < 1e-6
        assert lost > 0.9  # the whole skeleton (24 px, smoothed by 1) missed
    # The trunk's width, in the target or in the prediction, does not change the term.
    assert terms[4] == pytest.approx(terms[8], abs=1e-6)
    assert terms[16] == pytest.approx(terms[8], abs=1e-6)
    # clDice ("all") does see the trunk: the same lost branch weighs less beside a wider one.
    target, branch = _classes(16)
    lost = (target > 0).float()
    lost[branch] = 0.0
    wide = float(skeleton_term(lost, target, ITERATIONS, "all"))
    target, branch = _classes(4)
    lost = (target > 0).float()
    lost[branch] = 0.0
    assert float(skeleton_term(lost, target, ITERATIONS, "all")) != pytest.approx(wide, abs=1e-3)


def test_the_side_branch_term_in_the_loss_pushes_the_lost_branch_up_and_leaves_the_trunk():
    target, branch = _classes(8)
    lost = (target > 0).float()
    lost[branch] = 0.0
    logits = torch.logit(lost.clamp(0.02, 0.98))
    without = float(segmentation_loss(logits, target, 1.0))
    side = float(
        segmentation_loss(logits, target, 1.0, skeleton_weight=1.0, skeleton_target="side")
    )
    assert side > without + 0.9
    # The default ("all") is clDice, as before the option.
    every = float(segmentation_loss(logits, target, 1.0, skeleton_weight=1.0))
    cl_dice = float(cl_dice_loss(torch.sigmoid(logits), (target > 0).float(), ITERATIONS))
    assert every == pytest.approx(without + cl_dice, rel=1e-5)
    # Its gradient reaches the lost branch's logits, upwards, and no other pixel.
    logits.requires_grad_(True)
    skeleton_term(torch.sigmoid(logits), target, ITERATIONS, "side").backward()
    assert float(logits.grad[branch].max()) < 0.0
    elsewhere = logits.grad.clone()
    elsewhere[branch] = 0.0
    assert float(elsewhere.abs().max()) == 0.0


def test_train_config_names_a_bad_skeleton_setting():
    with pytest.raises(ValueError, match="skeleton_weight"):
        TrainConfig(skeleton_weight=-1.0)
    with pytest.raises(ValueError, match="skeleton_iterations"):
        TrainConfig(skeleton_iterations=0)
    with pytest.raises(ValueError, match="skeleton_target"):
        TrainConfig(skeleton_target="primary")
    assert TrainConfig().skeleton_target == "all"
    with pytest.raises(ValueError, match="near_twig_flow_gain_range"):
        FlowAugmentConfig(near_twig_flow_gain_range=(0.5, 2.0))


def test_a_near_twig_sets_the_flow_pictures_scale_and_hides_the_tree_behind_it():
    rng = np.random.default_rng(3)
    h, w = 120, 160
    frame = np.full((h, w, 3), 200, np.uint8)
    classes = np.zeros((h, w), np.uint8)
    classes[:, 70:90] = 1
    frame[classes > 0] = (90, 70, 50)
    flow = np.zeros((h, w, 2), np.float32)
    flow[..., 1] = 1.0  # the background
    flow[classes > 0] = (0.0, 4.0)  # the tree, the largest flow before the twig
    config = FlowAugmentConfig(near_twig_flow_gain_range=(2.0, 2.0))
    twig_frame, twig_flow, twig_classes = add_near_twig(frame, flow, classes, rng, config)
    twig = np.hypot(twig_flow[..., 0], twig_flow[..., 1]) > 5.0
    assert 20 <= twig.sum() < 0.2 * h * w
    np.testing.assert_allclose(twig_flow[twig], [[0.0, 8.0]] * int(twig.sum()), atol=1e-4)
    assert not (twig_classes[twig] > 0).any()
    assert (twig_classes[~twig] == classes[~twig]).all()
    # Bark-coloured (its edges blurred a little into the sky: 200 grey).
    assert float(np.median(np.abs(twig_frame[twig].astype(int) - (90, 70, 50)))) < 30
    # The tree reads paler: its saturation halves against the picture without the twig.
    tree = (classes > 0) & ~twig
    whiteness = [flow_to_picture_fast(f)[tree].min(axis=1).mean() for f in (flow, twig_flow)]
    assert whiteness[1] > whiteness[0] + 40
    # A frame without the tree is left alone.
    empty = np.zeros_like(classes)
    out = add_near_twig(frame, flow, empty, rng, config)
    assert out[0] is frame and out[1] is flow and out[2] is empty
