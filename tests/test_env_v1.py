"""The v1 and v2 environments: coverage memory (v2: with IN_FRONT) and price of scan time in the
observation, hold action."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import branch_gym
from agents.factory import AGENTS
from branch_gym.env.layout import COVERAGE_KEY, PRICE_KEY, flatten_observation
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig

ROOT = Path(__file__).resolve().parents[1]
SHORT = {"tracker": "oracle", "end_height_m": 0.36}


def test_v1_observations_fit_their_spaces_and_flatten_alike() -> None:
    dict_env = gymnasium.make(branch_gym.ENV_ID_V1, **SHORT)
    flat_env = gymnasium.make(branch_gym.ENV_ID_V1, flatten=True, **SHORT)
    try:
        obs, _ = dict_env.reset(seed=4, options={"branch_value_s": 100.0})
        flat, _ = flat_env.reset(seed=4, options={"branch_value_s": 100.0})
        assert dict_env.observation_space.contains(obs) and flat_env.observation_space.contains(
            flat
        )
        np.testing.assert_allclose(flatten_observation(obs), flat)
        assert obs[PRICE_KEY][0] == pytest.approx(np.log(100 / 25) / np.log(400 / 25))
        for _ in range(4):
            obs, *_ = dict_env.step(np.array([0.0], np.float32))
        seen = obs[COVERAGE_KEY].reshape(16, 8)[:, :5]
        assert seen[:, 2].any() and not np.delete(seen, 2, axis=1).any()  # only from 0 deg
    finally:
        dict_env.close()
        flat_env.close()


def test_the_price_sets_the_time_term_and_is_drawn_per_episode() -> None:
    env = gymnasium.make(branch_gym.ENV_ID_V1, **SHORT)
    try:
        env.reset(seed=1, options={"branch_value_s": 50.0})
        before = env.unwrapped.session.scan_time_s
        _, _, _, _, info = env.step(np.array([0.0], np.float32))
        elapsed = env.unwrapped.session.scan_time_s - before
        assert info["reward_terms"]["time"] == pytest.approx(-elapsed / 50.0)
        prices = {float(env.reset(seed=s)[0][PRICE_KEY][0]) for s in range(5)}
        assert len(prices) == 5 and all(0.0 <= p <= 1.0 for p in prices)
        low, high = env.unwrapped.config.branch_value_s
        for outside in (0.5 * low, 2.0 * high):  # would read as the range's end: refused
            with pytest.raises(ValueError, match=r"branch_value_s.*range"):
                env.reset(seed=1, options={"branch_value_s": outside})
    finally:
        env.close()
    v0 = gymnasium.make(branch_gym.ENV_ID_V0, **SHORT)
    with pytest.raises(ValueError, match="branch_value_s"):
        v0.reset(seed=0, options={"branch_value_s": 50.0})
    v0.close()


def test_the_hold_action_keeps_a_rotation() -> None:
    env = gymnasium.make(branch_gym.DISCRETE_ENV_ID_V1, **SHORT)
    try:
        env.reset(seed=2)
        env.step(4)  # target +22.5 deg
        assert env.unwrapped.session.angle_deg == pytest.approx(22.5, abs=0.6)
        _, _, _, _, info = env.step(0)  # hold
        assert not info["rotated"] and env.unwrapped.session.angle_deg == pytest.approx(
            22.5, abs=0.6
        )
        with pytest.raises(ValueError, match="out of range"):
            env.step(6)
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("env_id", [branch_gym.DISCRETE_ENV_ID_V1, branch_gym.DISCRETE_ENV_ID_V2])
def test_a_short_training_run_writes_a_model_that_plays_at_a_given_price(
    tmp_path: Path, env_id: str
) -> None:
    spec = importlib.util.spec_from_file_location("train_cli", ROOT / "train.py")
    cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cli)
    out = tmp_path / "run"
    argv = [
        "--env", env_id, "--timesteps", "64", "--out", str(out),
        "--tracker", "oracle", "--end-height", "0.33", "--n-envs", "1", "--seed", "3",
        "--n-steps", "32", "--batch-size", "32", "--n-epochs", "1",
        "--checkpoint-every", "64", "--eval-every", "64", "--eval-trees", "1",
    ]  # fmt: skip
    assert cli.main(argv) == 0
    model = out / "final_model.zip"
    result = run_trial(
        0, f"ppo:{model}@80", ScanConfig(tracker="oracle", end_height_m=0.33), AGENTS
    )
    assert result.n_iterations > 0 and result.policy == f"ppo:{model}@80"


@pytest.mark.slow
def test_the_shipped_priced_policy_rotates_more_readily_when_branches_are_dear() -> None:
    """One price-conditioned policy: the same views, a dearer branch, more will to rotate.

    The observations of three hold-only scans are shown to the shipped price-conditioned
    DAgger student with the price at the bottom (25 s) and at the top (400 s) of its range; its
    probability of leaving "hold" must rise with the price (on 60 trees it rotates 2.7 times
    per scan at 25 s and 3.3 at 400 s, its card). The unconditioned student barely moves.
    """
    import torch

    from agents.ppo import resolve_model_path
    from branch_gym.training.model_files import load_model

    env = gymnasium.make(
        branch_gym.DISCRETE_ENV_ID_V1, tracker="oracle", render_tracking_frames=False,
        end_height_m=0.5,
    )  # fmt: skip
    observations = []
    for seed in (0, 1, 2):
        observation, _ = env.reset(seed=seed, options={"branch_value_s": 100.0})
        done = False
        while not done:
            observations.append(observation)
            observation, _, terminated, truncated, _ = env.step(0)
            done = terminated or truncated
    env.close()
    batch = {key: np.stack([o[key] for o in observations]) for key in observations[0]}

    def rotate_probability(model_name: str, price: float) -> float:
        model = load_model(resolve_model_path(model_name))
        batch[PRICE_KEY][:] = price
        tensor, _ = model.policy.obs_to_tensor(batch)
        with torch.no_grad():
            probs = model.policy.get_distribution(tensor).distribution.probs.numpy()
        return float(np.mean(1.0 - probs[:, 0]))

    cheap, dear = (rotate_probability("ppo_dagger_priced.zip", p) for p in (0.0, 1.0))
    assert dear > cheap + 0.01, (cheap, dear)
    plain = [rotate_probability("ppo_dagger.zip", p) for p in (0.0, 1.0)]
    assert abs(plain[1] - plain[0]) < dear - cheap


def _v2_scan(side_branches: str, base_height_m: float, end_height_m: float) -> list[dict]:
    """Observations of a hold-only v2 scan of seed 0's primary with a straight 8 cm branch at
    ``base_height_m`` pointing at the camera ("toward") or none ("none")."""
    from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT

    env = gymnasium.make(
        branch_gym.DISCRETE_ENV_ID_V2, tracker="oracle", render_tracking_frames=False,
        end_height_m=end_height_m,
    )  # fmt: skip
    try:
        env.reset(seed=0)
        primary = env.unwrapped.session.tree.primary
        k = int(np.argmin(np.abs(primary.points[:, 2] - base_height_m)))
        steps = np.linspace(0.0, 0.08, 41)[:, None]
        toward = BranchGT(
            primary.points[k] + steps * np.array([0.0, -1.0, 0.05]) / np.hypot(1.0, 0.05),
            np.full(41, 0.8 * float(primary.radii[k])),
        )
        branches = [toward] if side_branches == "toward" else []
        tree = TreeGT(primary, branches, [], 0)
        observation, _ = env.reset(seed=0, options={"tree": tree, "branch_value_s": 100.0})
        observations, done = [observation], False
        while not done:
            observation, _, terminated, truncated, _ = env.step(0)
            observations.append(observation)
            done = terminated or truncated
    finally:
        env.close()
    return observations


def _in_front_counts(side_branches: str) -> np.ndarray:
    """IN_FRONT counts per height bin at the end of a short scan past a branch at 0.34 m."""
    coverage = _v2_scan(side_branches, 0.34, 0.42)[-1][COVERAGE_KEY].reshape(16, 9)
    return coverage[:, -1] * 10.0


def test_v2_marks_the_height_of_a_branch_pointing_at_the_camera() -> None:
    """The tracked primary samples on the near branch triangulate in front of the model."""
    toward = _in_front_counts("toward")
    assert toward.sum() >= 2 and np.count_nonzero(toward) == 1  # one height bin: the branch's
    assert _in_front_counts("none").sum() == 0


@pytest.mark.slow
def test_the_shipped_v2_student_wants_to_rotate_when_a_branch_points_at_the_camera() -> None:
    """The v2 student's probability of leaving "hold" along a scan past a branch pointing at
    the lens (at 0.40 m) and along the same primary alone."""
    import torch

    from agents.ppo import resolve_model_path
    from branch_gym.training.model_files import load_model

    model = load_model(resolve_model_path("ppo_dagger_v2"))

    def action_probabilities(side_branches: str) -> np.ndarray:
        observations = _v2_scan(side_branches, 0.40, 0.50)[:-1]  # those the student acts on
        batch = {key: np.stack([o[key] for o in observations]) for key in observations[0]}
        tensor, _ = model.policy.obs_to_tensor(batch)
        with torch.no_grad():
            return model.policy.get_distribution(tensor).distribution.probs.numpy()

    toward, alone = action_probabilities("toward"), action_probabilities("none")
    # measured: P(rotate) up to 0.95 once the branch is in view, <= 0.22 on the primary alone
    assert (1.0 - toward[:, 0]).max() > 0.8, toward[:, 0]
    assert (1.0 - alone[:, 0]).max() < 0.3, alone[:, 0]
    # the deterministic policy (what evaluation plays) rotates for the branch, holds without it
    assert (toward.argmax(axis=1) != 0).any() and (alone.argmax(axis=1) == 0).all()
