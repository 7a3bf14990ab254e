"""Memory probe (research.memory_probe): a recurrent fit beats a feed-forward one
exactly where the labels depend on an earlier observation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from branch_gym.env.layout import VectorField
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.imitation import (
    CONFIG_FILE,
    ImitationConfig,
    RoundData,
    episode_slices,
    new_student,
)
from research.memory_probe import format_table, probe

FAST = TrainConfig(
    env_id="BranchScanDiscrete-v2",
    tracker="oracle",
    render_tracking_frames=False,
    end_height_m=0.42,
    ppo=PPOConfig(cnn_output_dim=8),
)
EPISODE_STEPS = 6


def _cue_round(space, rng: np.random.Generator, episodes: int) -> RoundData:
    """Episodes whose first observation shows a cue (or not) and look alike afterwards.

    The expert rotates at every later step of a cued episode and holds otherwise, so only a
    policy that remembers the first step can tell its labels apart.
    """
    n = episodes * EPISODE_STEPS
    observations = {key: np.zeros((n, *sub.shape), sub.dtype) for key, sub in space.items()}
    step = np.tile(np.arange(EPISODE_STEPS), episodes)
    cued = np.repeat(rng.permutation(np.arange(episodes) % 2 == 0), EPISODE_STEPS)
    vector = observations["vector"]
    vector[:, VectorField.SCAN_TIME] = step / 100.0
    vector[:, VectorField.CANDIDATES_2D] = np.where((step == 0) & cued, 1.0, 0.0)
    labels = np.where(cued & (step > 0), 2, 0).astype(np.int64)
    return RoundData(observations, labels)


def test_episodes_split_where_the_scan_time_falls():
    vector = np.zeros((7, 12), np.float32)
    vector[:, VectorField.SCAN_TIME] = [0.0, 0.1, 0.2, 0.0, 0.1, 0.0, 0.3]
    slices = episode_slices(RoundData({"vector": vector}, np.zeros(7, np.int64)))
    assert [(s.start, s.stop) for s in slices] == [(0, 3), (3, 5), (5, 7)]
    with pytest.raises(ValueError, match="no labels"):
        episode_slices(RoundData({"vector": vector[:0]}, np.zeros(0, np.int64)))


def test_bad_runs_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="imitation run"):
        probe(tmp_path, [1])
    config = ImitationConfig(train=FAST)
    (tmp_path / CONFIG_FILE).write_text(json.dumps(config.to_dict()))
    with pytest.raises(FileNotFoundError, match=r"round_0\.npz"):
        probe(tmp_path, [1])
    with pytest.raises(ValueError, match="disjoint"):
        probe(tmp_path, [1], train_rounds=[0, 1])
    with pytest.raises(ValueError, match="epochs"):
        probe(tmp_path, [1], epochs=0)


@pytest.mark.slow
def test_the_recurrent_fit_remembers_a_cue_the_feedforward_one_cannot(tmp_path):
    config = ImitationConfig(
        train=FAST,
        epochs=40,
        batch_size=48,
        learning_rate=3e-3,
        weight_decay=0.0,
        validation_fraction=0.0,
    )
    (tmp_path / CONFIG_FILE).write_text(json.dumps(config.to_dict()))
    space = new_student(config).observation_space
    rng = np.random.default_rng(0)
    for k, episodes in enumerate((60, 40)):
        _cue_round(space, rng, episodes).save(tmp_path / f"round_{k}.npz")
    result = probe(tmp_path, [1])
    assert result["train_labels"] == 60 * EPISODE_STEPS
    assert result["test_labels"] == 40 * EPISODE_STEPS
    # After the first step the feed-forward policy sees the same observation in both kinds of
    # episode: it ties every rotation with 5 of the 7 holds of a cued / uncued pair (AUC 9/14).
    assert result["feedforward"]["test"]["rotation_auc"] < 0.75
    assert result["recurrent"]["test"]["rotation_auc"] > 0.95
    assert result["recurrent"]["test"]["accuracy"] > 0.95
    nll = {name: result[name]["test"]["weighted_nll"] for name in ("feedforward", "recurrent")}
    assert nll["recurrent"] < 0.5 * nll["feedforward"]
    assert "| recurrent |" in format_table(result)
