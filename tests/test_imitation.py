"""DAgger warm start (branch_gym.training.imitation): the fit, a resumable run, a loadable model."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from branch_gym.env.layout import VectorField
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.imitation import (
    ROUNDS_LOG,
    ImitationConfig,
    LabellingAgent,
    RoundData,
    fit_student,
    imitate,
    is_recurrent_model,
    label_weights,
    new_student,
    rotation_auc,
)

FAST = TrainConfig(
    env_id="BranchScanDiscrete-v1",
    tracker="oracle",
    render_tracking_frames=False,
    end_height_m=0.42,
    ppo=PPOConfig(cnn_output_dim=16),
)


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="discrete env"):
        ImitationConfig(train=TrainConfig(env_id="BranchScan-v0"))
    with pytest.raises(ValueError, match="rounds"):
        ImitationConfig(train=FAST, rounds=0)
    with pytest.raises(ValueError, match="rotation_weight"):
        ImitationConfig(train=FAST, rotation_weight=0.0)
    with pytest.raises(ValueError, match="expert"):
        ImitationConfig(train=FAST, expert="periodic:22.5:1.5")


def test_round_data_round_trips_and_a_corrupt_file_is_named(tmp_path):
    data = RoundData({"vector": np.ones((3, 12), np.float32)}, np.array([0, 2, 1]))
    data.save(tmp_path / "round_0.npz")
    loaded = RoundData.load(tmp_path / "round_0.npz")
    np.testing.assert_array_equal(loaded.expert_actions, [0, 2, 1])
    np.testing.assert_array_equal(loaded.observations["vector"], data.observations["vector"])
    (tmp_path / "round_1.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"round_1\.npz"):
        RoundData.load(tmp_path / "round_1.npz")


def test_the_fit_learns_a_rule_the_labels_follow():
    """Labels that depend on one observation field are reproduced by the fitted policy."""
    config = ImitationConfig(train=FAST, epochs=30, batch_size=64, learning_rate=3e-3)
    model = new_student(config)
    rng = np.random.default_rng(0)
    space = model.observation_space
    space.seed(0)  # the other fields are seeded noise, the same on every machine
    n = 400
    observations = {key: np.stack([sub.sample() for _ in range(n)]) for key, sub in space.items()}
    observations["image"][:] = 0
    observations["coverage"][:] = 0
    angle = rng.uniform(-1, 1, n).astype(np.float32)
    observations["vector"][:, VectorField.ANGLE] = angle
    labels = np.where(angle > 0.2, 2, 0).astype(np.int64)  # rotate to -22.5 deg when turned right
    fit = fit_student(model, RoundData(observations, labels), config, rng)
    assert fit["train_accuracy"] >= 0.95
    probe = {key: value[:50] for key, value in observations.items()}
    actions, _ = model.predict(probe, deterministic=True)
    assert np.mean(actions == labels[:50]) >= 0.9
    # It ranks the rotations of labels it was not fitted on (AUC near 1), and a label set that
    # contradicts its rule ranks at the bottom (AUC near 0).
    new_angle = rng.uniform(-1, 1, n).astype(np.float32)
    new_observations = {key: value.copy() for key, value in observations.items()}
    new_observations["vector"][:, VectorField.ANGLE] = new_angle
    held_out = RoundData(new_observations, np.where(new_angle > 0.2, 2, 0).astype(np.int64))
    assert rotation_auc(model, held_out) >= 0.95
    inverted = RoundData(new_observations, np.where(new_angle > 0.2, 0, 2).astype(np.int64))
    assert rotation_auc(model, inverted) <= 0.05
    assert np.isnan(rotation_auc(model, RoundData(new_observations, np.zeros(n, np.int64))))


class _CountingStudent:
    """A student whose state counts its steps, restarting where the episode starts."""

    def __init__(self) -> None:
        self.calls: list[tuple[object, object]] = []

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        self.calls.append((state, episode_start))
        restart = state is None or bool(np.asarray(episode_start).any())
        return np.array([3]), 1 if restart else state + 1


class _HoldingExpert:
    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return np.array(0), None


def test_the_labelling_agent_carries_the_students_state():
    agent = LabellingAgent(_HoldingExpert(), _CountingStudent())
    observation = {"vector": np.zeros(3, np.float32)}
    state = None
    for step in range(3):
        action, state = agent.predict(observation, state=state, episode_start=step == 0)
        assert action == 3 and state == step + 1
    calls = agent.student.calls
    assert [c[0] for c in calls] == [None, 1, 2]
    assert [bool(c[1][0]) for c in calls] == [True, False, False]
    assert agent.labels == [0, 0, 0] and agent.agreed == 0


def test_a_recurrent_fit_holds_out_whole_episodes():
    config = ImitationConfig(
        train=replace(FAST, recurrent=True), epochs=2, batch_size=14, validation_fraction=0.25
    )
    model = new_student(config)
    assert is_recurrent_model(model)
    steps, episodes = 7, 10
    n = steps * episodes
    space = model.observation_space
    observations = {key: np.zeros((n, *sub.shape), sub.dtype) for key, sub in space.items()}
    observations["vector"][:, VectorField.SCAN_TIME] = np.tile(np.arange(steps) / 100.0, episodes)
    labels = np.tile([0, 0, 2, 0, 0, 0, 0], episodes).astype(np.int64)
    fit = fit_student(model, RoundData(observations, labels), config, np.random.default_rng(0))
    assert fit["held_out_labels"] == 2 * steps  # round(0.25 * 10) episodes, not 0.25 of labels
    assert fit["epochs_kept"] in (1, 2) and np.isfinite(fit["held_out_loss"])
    feedforward = ImitationConfig(train=FAST, epochs=1, validation_fraction=0.25)
    fit = fit_student(
        new_student(feedforward), RoundData(observations, labels), feedforward,
        np.random.default_rng(0),
    )  # fmt: skip
    assert fit["held_out_labels"] == round(0.25 * n)


@pytest.mark.slow
def test_a_recurrent_dagger_run_writes_a_policy_that_plays_with_its_state(tmp_path):
    import gymnasium as gym

    from agents.factory import make_agent

    config = ImitationConfig(
        train=replace(FAST, recurrent=True), rounds=2, episodes=2, epochs=1,
        validation_fraction=0.0,
    )  # fmt: skip
    final = imitate(config, tmp_path, workers=1)
    rows = [json.loads(line) for line in (tmp_path / ROUNDS_LOG).read_text().splitlines()]
    assert [row["played_by"] for row in rows] == ["expert", "student"]
    env = gym.make("BranchScanDiscrete-v1", tracker="oracle", render_tracking_frames=False)
    agent = make_agent(f"ppo:{final}@100", env)
    assert is_recurrent_model(agent.model)
    observation, _ = env.reset(seed=3)
    action, state = agent.predict(observation, episode_start=True)
    assert env.action_space.contains(int(action))
    hidden, cell = state  # the LSTM's (hidden, cell), passed back with the next observation
    assert (
        hidden.shape == cell.shape and hidden.shape[-1] == agent.model.policy.lstm_actor.hidden_size
    )
    env.close()


@pytest.mark.slow
def test_a_dagger_run_resumes_and_writes_a_loadable_policy(tmp_path):
    import gymnasium as gym

    from agents.factory import make_agent

    config = ImitationConfig(train=FAST, rounds=1, episodes=2, epochs=1)
    imitate(config, tmp_path, workers=1)
    rows = [json.loads(line) for line in (tmp_path / ROUNDS_LOG).read_text().splitlines()]
    assert [row["played_by"] for row in rows] == ["expert"]
    assert rows[0]["agreement"] == 1.0 and rows[0]["labels"] > 0
    with pytest.raises(FileExistsError):
        imitate(config, tmp_path, workers=1)
    with pytest.raises(ValueError, match="another configuration"):
        imitate(ImitationConfig(train=FAST, rounds=2, episodes=3), tmp_path, resume=True)
    more = ImitationConfig(train=FAST, rounds=2, episodes=2, epochs=1)
    final = imitate(more, tmp_path, resume=True)
    rows = [json.loads(line) for line in (tmp_path / ROUNDS_LOG).read_text().splitlines()]
    assert [row["played_by"] for row in rows] == ["expert", "student"]
    assert np.isnan(rows[0]["student_rotation_auc"])  # the expert played round 0
    assert all("train_rotation_auc" in row for row in rows)  # the fit's own ranking, logged
    assert 0.0 <= rows[1]["student_rotation_auc"] <= 1.0 or np.isnan(
        rows[1]["student_rotation_auc"]
    )
    env = gym.make("BranchScanDiscrete-v1", tracker="oracle", render_tracking_frames=False)
    agent = make_agent(f"ppo:{final}@100", env)
    observation, _ = env.reset(seed=3)
    action, _ = agent.predict(observation)
    assert env.action_space.contains(int(action))
    env.close()


def test_a_new_ppo_run_starts_from_the_init_models_weights(tmp_path):
    import gymnasium as gym
    import torch

    from branch_gym.training.train import new_model

    source = new_student(ImitationConfig(train=FAST))
    source.save(tmp_path / "student.zip")
    env = gym.make(FAST.env_id, **FAST.env_kwargs())
    started = new_model(replace(FAST, seed=1, init_model=str(tmp_path / "student.zip")), env)
    fresh = new_model(replace(FAST, seed=1), env)
    for name, weights in source.policy.state_dict().items():
        assert torch.equal(started.policy.state_dict()[name], weights), name
    assert any(
        not torch.equal(fresh.policy.state_dict()[name], weights)
        for name, weights in source.policy.state_dict().items()
    )
    saved = str(tmp_path / "student.zip")
    wider = replace(FAST, ppo=PPOConfig(cnn_output_dim=32), init_model=saved)
    with pytest.raises(ValueError, match="does not fit"):
        new_model(wider, env)
    with pytest.raises(FileNotFoundError, match=r"missing\.zip"):
        new_model(replace(FAST, init_model=str(tmp_path / "missing.zip")), env)
    env.close()


def test_price_conditioned_weights_follow_the_branch_value():
    """A rotation label weighs rotation_weight * V / reference; holds weigh 1."""
    prices = np.array([[0.0], [0.5], [1.0], [1.0]], np.float32)  # 25, 100, 400, 400 s
    data = RoundData({"price": prices}, np.array([1, 1, 1, 0]))
    config = ImitationConfig(train=FAST, rotation_weight=2.0, reference_value_s=100.0)
    weights = label_weights(data, config, (25.0, 400.0))
    np.testing.assert_allclose(weights, [0.5, 2.0, 8.0, 1.0])
    plain = label_weights(data, ImitationConfig(train=FAST, rotation_weight=2.0))
    np.testing.assert_allclose(plain, [2.0, 2.0, 2.0, 1.0])
    with pytest.raises(ValueError, match="price"):
        label_weights(RoundData({"vector": prices}, data.expert_actions), config, (25.0, 400.0))


def test_without_held_out_labels_every_epoch_runs():
    config = ImitationConfig(train=FAST, epochs=3, batch_size=64, validation_fraction=0.0)
    model = new_student(config)
    space = model.observation_space
    observations = {key: np.stack([sub.sample() for _ in range(64)]) for key, sub in space.items()}
    labels = np.zeros(64, np.int64)
    fit = fit_student(model, RoundData(observations, labels), config, np.random.default_rng(0))
    assert fit["epochs_kept"] == 3 and np.isnan(fit["held_out_loss"])
    assert fit["train_accuracy"] == 1.0  # "hold" everywhere is learnt in three epochs
    with pytest.raises(ValueError, match="validation_fraction"):
        ImitationConfig(train=FAST, validation_fraction=1.0)


FIT_SETTINGS = (
    "epochs", "batch_size", "learning_rate", "weight_decay", "validation_fraction",
    "from_scratch", "rotation_weight", "reference_value_s",
)  # fmt: skip


def test_the_recipe_files_hold_the_shipped_students_fit_settings():
    """configs/dagger_*.json give the settings each shipped student's round log recorded."""
    from pathlib import Path

    from agents.ppo import SHIPPED_MODELS_DIR
    from branch_gym.config_utils import read_config_file

    root = Path(__file__).resolve().parents[1]
    for recipe, log in (("dagger_v2", "ppo_dagger_v2"), ("dagger_v1_priced", "ppo_dagger")):
        config = ImitationConfig.from_dict(read_config_file(root / "configs" / f"{recipe}.json"))
        rows = [json.loads(line) for line in (SHIPPED_MODELS_DIR / f"{log}.rounds.jsonl").open()]
        recorded = {k: rows[-1][k] for k in FIT_SETTINGS if k in rows[-1]}
        assert recorded == {k: getattr(config, k) for k in recorded}, recipe
    v2 = ImitationConfig.from_dict(read_config_file(root / "configs" / "dagger_v2.json"))
    assert v2.train.env_id == "BranchScanDiscrete-v2" and v2.rotation_weight == 4.0
    assert v2.expert == "privileged"  # the shipped students' expert held a turned angle
    orchard = ImitationConfig.from_dict(
        read_config_file(root / "configs" / "aggrevate_orchard.json")
    )
    assert orchard.expert == "privileged:home"


def test_the_cli_layers_defaults_the_recipe_and_the_options(tmp_path):
    from pathlib import Path

    from branch_gym.training.imitation.cli import build_parser, config_from_args

    recipe = Path(__file__).resolve().parents[1] / "configs" / "dagger_v2.json"
    args = build_parser().parse_args(["--config", str(recipe), "--out", "x", "--rounds", "3"])
    config = config_from_args(args)
    assert (config.rounds, config.epochs, config.train.ppo.cnn_output_dim) == (3, 8, 64)
    assert not config.train.render_tracking_frames  # the oracle's fast mode, from the recipe
    lk = config_from_args(build_parser().parse_args(["--out", "x", "--tracker", "lk"]))
    assert lk.train.render_tracking_frames and lk.rounds == ImitationConfig().rounds
    home = build_parser().parse_args(["--out", "x", "--expert", "privileged:home"])
    assert config_from_args(home).expert == "privileged:home" and lk.expert == "privileged"
    (tmp_path / "bad.json").write_text('{"roundz": 3}')
    with pytest.raises(ValueError, match="roundz"):
        config_from_args(
            build_parser().parse_args(["--config", str(tmp_path / "bad.json"), "--out", "x"])
        )


def test_a_kept_run_resumes_after_its_last_student_with_the_earlier_ones_pruned(tmp_path):
    """Every round's labels and the last student are enough to resume; a round whose student
    was not saved is played again; a kept student without the labels before it is refused."""
    from branch_gym.training.imitation.data import model_path, round_path
    from branch_gym.training.imitation.rounds import finished_rounds

    for k in range(3):
        round_path(tmp_path, k).write_bytes(b"labels")
    assert finished_rounds(tmp_path, 8) == 0  # no student saved yet
    model_path(tmp_path, 1).write_bytes(b"student")
    assert finished_rounds(tmp_path, 8) == 2  # round 2 was labelled, its fit interrupted
    model_path(tmp_path, 2).write_bytes(b"student")
    assert finished_rounds(tmp_path, 8) == 3
    assert finished_rounds(tmp_path, 2) == 2  # a run of 2 rounds is done
    round_path(tmp_path, 1).unlink()
    with pytest.raises(ValueError, match=r"round_1\.npz"):
        finished_rounds(tmp_path, 8)
