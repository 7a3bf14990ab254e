"""Reported secondaries must reach out from the primary (``secondary_min_reach_m``).

A learned segmenter's masks add short false side branches along the trunk: spurs, a neighbour's
twig, the mask's ragged edge. From a learned segmenter's masks a secondary is reported only while
its base-to-tip vector reaches ``LEARNED_MASK_MIN_REACH_M`` out from the primary, measured
perpendicular to the primary's base-to-top direction (a twig running beside the trunk reaches
nowhere, however long). From exact masks every secondary is reported, as the paper.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from recon.config import LEARNED_MASK_MIN_REACH_M, ModelerConfig
from recon.model import BranchModel
from recon.model3d.secondary import SecondaryBranches, SecondaryDetection, reach_m

PRIMARY = BranchModel(
    np.column_stack([np.zeros(41), np.zeros(41), np.linspace(0.30, 0.70, 41)]), np.full(41, 0.006)
)


def _detection(start: list[float], end: list[float]) -> SecondaryDetection:
    points = np.linspace(start, end, 12)
    return SecondaryDetection(points, np.full(len(points), 0.003))


# Outward along +x from 1 cm beside the primary's axis. A reported secondary starts at its junction
# on the primary's axis (``secondary_extend_to_junction``): it reaches its tip's x from the axis.
LONG = _detection([0.01, 0.0, 0.40], [0.07, 0.0, 0.43])  # 7 cm out: a side branch
SHORT = _detection([0.01, 0.0, 0.55], [0.025, 0.0, 0.56])  # 2.5 cm out: a spur
BESIDE = _detection([0.012, 0.0, 0.60], [0.015, 0.0, 0.68])  # 8 cm long, 1.5 cm out: a twig


def _reported(config: ModelerConfig, detections: list[SecondaryDetection]) -> int:
    branches = SecondaryBranches(config, np.random.default_rng(0))
    assert branches.add_detections(detections, PRIMARY) == len(detections)  # all connect
    return len(branches.models())


def test_reach_is_the_span_perpendicular_to_the_primary() -> None:
    axis = np.array([0.0, 0.0, 1.0])
    assert reach_m(LONG.points, axis) == pytest.approx(0.06)
    assert reach_m(BESIDE.points, axis) == pytest.approx(0.003)
    assert reach_m(BESIDE.points, None) == pytest.approx(math.hypot(0.003, 0.08))
    tilted = np.array([math.sin(0.5), 0.0, math.cos(0.5)])  # a leaning primary
    along = np.array([[0.0, 0.0, 0.4], [*(np.array([0.0, 0.0, 0.4]) + 0.1 * tilted)[:3]]])
    assert reach_m(along, tilted) == pytest.approx(0.0, abs=1e-12)


def test_short_and_beside_the_trunk_branches_are_not_reported_from_learned_masks() -> None:
    learned = ModelerConfig().for_masks(learned=True)
    assert learned.secondary_min_reach_m == LEARNED_MASK_MIN_REACH_M
    assert 0.025 < LEARNED_MASK_MIN_REACH_M < 0.07  # between the spur and the side branch here
    assert _reported(learned, [LONG, SHORT, BESIDE]) == 1
    assert _reported(learned, [LONG]) == 1


def test_exact_masks_report_every_secondary() -> None:
    exact = ModelerConfig().for_masks(learned=False)
    assert exact.secondary_min_reach_m == 0.0
    assert _reported(exact, [LONG, SHORT, BESIDE]) == 3
    assert _reported(ModelerConfig(), [LONG, SHORT, BESIDE]) == 3  # unresolved: reports all


def test_a_set_reach_is_kept_and_a_bad_one_refused() -> None:
    config = ModelerConfig(secondary_min_reach_m=0.02)
    assert config.for_masks(learned=True).secondary_min_reach_m == 0.02
    assert _reported(config, [LONG, SHORT, BESIDE]) == 2  # the twig beside the trunk goes
    for bad in (-0.01, float("nan"), float("inf"), "3 cm"):
        with pytest.raises(ValueError, match="secondary_min_reach_m"):
            ModelerConfig(secondary_min_reach_m=bad)


def test_the_reach_sweep_rescores_saved_trials(tmp_path) -> None:
    """research/reach_sweep.py: reach 0 gives the trial as saved; 3 cm drops a 2.75 cm spur and
    keeps the 10 cm branch; a reach beyond that branch misses it."""
    from branch_gym.evaluation.trials import TrialRecord, save_trial
    from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
    from recon.metrics import evaluate
    from recon.model import TreeModel
    from research.reach_sweep import sweep

    z = np.linspace(0.3, 0.8, 51)
    axis = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    side = np.linspace([0.0, 0.0, 0.5], [0.1, 0.0, 0.55], 21)
    truth = TreeGT(BranchGT(axis, np.full(51, 0.005)), [BranchGT(side, np.full(21, 0.003))])
    spur = np.linspace([0.0, 0.0, 0.65], [0.027, 0.005, 0.66], 5)  # reaches 2.75 cm
    model = TreeModel(
        BranchModel(axis[5:45], np.full(40, 0.005)),
        [BranchModel(side + 0.001, np.full(21, 0.003)), BranchModel(spur, np.full(5, 0.002))],
    )
    metrics = evaluate(model, truth)
    assert (metrics.n_matched, metrics.n_spurious) == (1, 1)  # over 2.5 cm: scored
    record = TrialRecord(
        0, "none", metrics, model, truth, 20.0, 0, None, "end_height", 40, {}, {}, 1.0,
        config_hash="h", row={},
    )  # fmt: skip
    save_trial(tmp_path / "none" / "0.json", record)
    totals = sweep(tmp_path / "none", [0.0, LEARNED_MASK_MIN_REACH_M, 0.2])
    assert totals[0.0] == {"n_gt": 1, "n_missed": 0, "n_spurious": 1, "n_duplicates": 0}
    assert totals[LEARNED_MASK_MIN_REACH_M]["n_spurious"] == 0
    assert totals[LEARNED_MASK_MIN_REACH_M]["n_missed"] == 0
    assert totals[0.2]["n_missed"] == 1
