"""Miss attribution (branch_gym/attribution.py): a hidden branch is "never seen", a visible one
that the model lacks is "seen"."""

from __future__ import annotations

import numpy as np
import pytest

from agents.factory import make_agent
from branch_gym.attribution import (
    MISS_NEVER_SEEN,
    MISS_SEEN,
    AttributionConfig,
    BranchVisibility,
    branch_rows,
)
from branch_gym.env.scan_env import BranchScanEnv
from branch_gym.scan import ScanConfig, ScanSession
from branch_gym.sim.scene.labels import FIRST_SECONDARY_LABEL
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from recon.metrics import evaluate
from recon.model import TreeModel

BASE_Z_M = 0.34  # in the scored band (above 0.325 m), in view soon after the start (0.275 m)
LENGTH_M = 0.08
SCAN_TOP_M = 0.42


def _straight(base: np.ndarray, direction: np.ndarray, radius_m: float) -> BranchGT:
    steps = np.linspace(0.0, LENGTH_M, 41)[:, None]
    return BranchGT(base + steps * direction / np.linalg.norm(direction), np.full(41, radius_m))


def _tree_with_hidden_and_visible_branch(session: ScanSession) -> TreeGT:
    tree = session.world.reset(0)
    primary = tree.primary
    k = int(np.argmin(np.abs(primary.points[:, 2] - BASE_Z_M)))
    base, radius = primary.points[k], 0.8 * float(primary.radii[k])
    hidden = _straight(base, np.array([0.0, 1.0, 0.0]), radius)  # straight away: behind it
    visible = _straight(base, np.array([1.0, 0.0, 0.2]), radius)  # across the view
    return TreeGT(primary, [hidden, visible], [], tree.seed)


@pytest.fixture(scope="module")
def scanned() -> tuple[TreeGT, ScanSession]:
    session = ScanSession(ScanConfig(end_height_m=SCAN_TOP_M, tracker="oracle"))
    tree = session.reset(0, _tree_with_hidden_and_visible_branch(session))
    while not session.done:
        session.step(0.0)
    yield tree, session
    session.close()


def test_hidden_branch_is_never_seen_and_a_dropped_visible_one_is_seen(scanned) -> None:
    tree, session = scanned
    visibility = session.sensor.visibility
    threshold = AttributionConfig().seen_min_pixels
    assert visibility.frames > 10
    assert visibility.peak_pixels[0] < threshold <= visibility.peak_pixels[1]
    nothing = TreeModel(None, [])  # a model that lacks both branches
    rows = branch_rows(tree, evaluate(nothing, tree, scanned_top_z_m=SCAN_TOP_M), visibility)
    assert [row["miss"] for row in rows] == [MISS_NEVER_SEEN, MISS_SEEN]
    assert rows[0]["axis_angle_deg"] == pytest.approx(0.0, abs=1e-6)
    assert rows[1]["axis_angle_deg"] == pytest.approx(90.0, abs=1e-6)
    assert rows[1]["peak_view_angle_deg"] == pytest.approx(0.0, abs=1.0)  # no rotation


def test_a_matched_branch_is_no_miss_and_carries_its_completeness(scanned) -> None:
    tree, session = scanned
    model = TreeModel(None, [tree.secondaries[1]])
    rows = branch_rows(
        tree, evaluate(model, tree, scanned_top_z_m=SCAN_TOP_M), session.sensor.visibility
    )
    assert rows[1]["matched"] and rows[1]["miss"] == ""
    assert rows[1]["completeness"] == pytest.approx(1.0)
    assert rows[0]["miss"] == MISS_NEVER_SEEN


def test_the_privileged_policy_rotates_to_show_a_branch_hidden_behind_the_primary() -> None:
    env = BranchScanEnv(scan=ScanConfig(end_height_m=SCAN_TOP_M, tracker="oracle"))
    try:
        tree = _tree_with_hidden_and_visible_branch(env.session)
        results = {}
        for spec in ("none", "privileged"):
            agent = make_agent(spec, env)
            observation, _ = env.reset(seed=0, options={"tree": tree})
            done, start = False, True
            while not done:
                action, _ = agent.predict(observation, episode_start=start)
                observation, _, terminated, truncated, _ = env.step(action)
                done, start = terminated or truncated, False
            peak = env.session.sensor.visibility.peak_pixels.copy()
            results[spec] = (peak, env.session.rotations)
    finally:
        env.close()
    threshold = AttributionConfig().seen_min_pixels
    (none_peak, none_rotations), (privileged_peak, privileged_rotations) = results.values()
    assert none_rotations == 0 and none_peak[0] < threshold
    assert privileged_rotations >= 1 and privileged_peak[0] >= threshold  # now seen


def test_a_branch_covering_the_primary_counts_only_its_pixels_outside_the_silhouette() -> None:
    """A branch pointing at the camera lies over the primary: its label pixels are many, but in
    the mask (one class for both) almost all of them are the primary's silhouette."""
    every_label = BranchVisibility()  # counts every label pixel: what the silhouette removes

    class CountingBoth(BranchVisibility):
        def observe(self, labels: np.ndarray, T_world_camera: np.ndarray) -> None:
            every_label.observe(labels, T_world_camera)
            super().observe(labels, T_world_camera)

    session = ScanSession(ScanConfig(end_height_m=SCAN_TOP_M, tracker="oracle"))
    try:
        session.sensor.visibility = CountingBoth(session.sensor.intrinsics)
        tree = session.world.reset(0)
        primary = tree.primary
        k = int(np.argmin(np.abs(primary.points[:, 2] - BASE_Z_M)))
        base, radius = primary.points[k], 0.8 * float(primary.radii[k])
        toward_camera = _straight(base, np.array([0.0, -1.0, 0.05]), radius)
        tree = session.reset(0, TreeGT(primary, [toward_camera], [], tree.seed))
        every_label.reset(1, session.world.T_world_camera)
        while not session.done:
            session.step(0.0)
        visibility = session.sensor.visibility
        silhouette = visibility.primary_silhouette(session.world.T_world_camera)
    finally:
        session.close()
    threshold = AttributionConfig().seen_min_pixels
    assert every_label.peak_pixels[0] > 3 * threshold  # the label image shows it, over the primary
    assert visibility.peak_pixels[0] < threshold
    assert silhouette.any() and silhouette.mean() < 0.5  # a tube, not the whole image
    rows = branch_rows(
        tree, evaluate(TreeModel(None, []), tree, scanned_top_z_m=SCAN_TOP_M), visibility
    )
    assert rows[0]["miss"] == MISS_NEVER_SEEN


def test_only_the_secondaries_own_labels_are_counted() -> None:
    """The orchard's row, ground and sky labels (above or below the secondaries' range) add
    nothing to a secondary's count."""
    labels = np.full((6, 8), FIRST_SECONDARY_LABEL + 50, np.int32)  # a row tree's label
    labels[0, :3] = FIRST_SECONDARY_LABEL  # secondary 0: 3 pixels
    labels[1, :2] = FIRST_SECONDARY_LABEL + 1  # secondary 1: 2 pixels
    labels[2, :] = FIRST_SECONDARY_LABEL - 1  # the primary
    labels[3, :] = -1
    visibility = BranchVisibility()
    visibility.reset(2, np.eye(4))
    visibility.observe(labels, np.eye(4))
    np.testing.assert_array_equal(visibility.peak_pixels, [3, 2])
