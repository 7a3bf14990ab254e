"""Cost-to-go labels (branch_gym/training/imitation/cost_to_go.py): branches, values, the fit."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import branch_gym  # noqa: F401  (registers the env ids)
from branch_gym.env.layout import VECTOR_KEY, VectorField
from branch_gym.env.reward import RewardConfig
from branch_gym.privileged import PrivilegedAgent
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.imitation import ImitationConfig, RoundData, fit_student, new_student
from branch_gym.training.imitation.cost_to_go import (
    BranchTask,
    HoldAgent,
    branch_outcome,
    distinct_actions,
    play_branch,
)

SCAN_TOP_M = 0.42
FAST = TrainConfig(
    env_id="BranchScanDiscrete-v2",
    tracker="oracle",
    render_tracking_frames=False,
    end_height_m=SCAN_TOP_M,
    ppo=PPOConfig(cnn_output_dim=16),
)
PRICE_S = 100.0  # a found branch is worth 100 s of scan time (the v0 reward's price)


@pytest.fixture(scope="module")
def env():
    env = gym.make(FAST.env_id, **FAST.env_kwargs())
    yield env
    env.close()


def test_actions_are_grouped_by_what_they_do(env):
    # v2: 0 holds, 1..5 target -45, -22.5, 0, 22.5, 45 deg. At 0, "hold" and "to 0" are one.
    assert distinct_actions(env, 0.0) == [[0, 3], [1], [2], [4], [5]]
    # At 22.49 deg (the orbit ends within the tolerance), "hold" and "to 22.5" are one.
    assert distinct_actions(env, 22.49) == [[0, 4], [1], [2], [3], [5]]


def _tree_with_a_branch_behind_the_primary(env) -> TreeGT:
    """Tree 0's primary with one side branch leaving it straight away from the camera."""
    tree = env.unwrapped.session.world.reset(0)
    primary = tree.primary
    k = int(np.argmin(np.abs(primary.points[:, 2] - 0.34)))
    steps = np.linspace(0.0, 0.08, 41)[:, None]
    hidden = BranchGT(primary.points[k] + steps * np.array([0.0, 1.0, 0.0]), np.full(41, 0.004))
    return TreeGT(primary, [hidden], [], tree.seed)


def test_a_blind_rotation_is_priced_above_holding_when_a_branch_hides_behind(env):
    options = {"tree": _tree_with_a_branch_behind_the_primary(env), "branch_value_s": PRICE_S}
    observation, _ = env.reset(seed=0, options=options)
    hold = HoldAgent.for_env(env)
    returns = {}
    for group in distinct_actions(env, 0.0):
        task = BranchTask(0, (), observation[VECTOR_KEY], group[0], None, reset_options=options)
        returns[group[0]] = play_branch(env, task, hold)[0]
    rotations = [returns[a] for a in (1, 2, 4, 5)]
    # Holding never shows the branch; a rotation that shows it is worth about a branch (1.0)
    # less its scan time (a second is 1 / 100 of a branch).
    assert max(rotations) > returns[0] + 0.5
    # Rolled out by the privileged expert, holding loses little: it rotates for the branch next.
    expert = PrivilegedAgent.for_env(env)
    task = BranchTask(0, (), observation[VECTOR_KEY], 0, None, True, reset_options=options)
    assert play_branch(env, task, expert)[0] > returns[0] + 0.5


def test_a_branch_outcome_prices_again_to_its_return(env):
    """The logged end of a branch (counts, scan time, failure) gives back its return."""
    options = {"tree": _tree_with_a_branch_behind_the_primary(env), "branch_value_s": PRICE_S}
    observation, _ = env.reset(seed=0, options=options)
    task = BranchTask(0, (), observation[VECTOR_KEY], 4, None, reset_options=options)
    outcome = branch_outcome(*play_branch(env, task, HoldAgent.for_env(env)))
    assert outcome["n_matched"] == 1 and outcome["scan_time_s"] > 0.0  # the turn shows it
    counts = type("Counts", (), outcome)
    repriced = RewardConfig().episode_return(
        counts, outcome["scan_time_s"], bool(outcome["failure"]), 1.0 / PRICE_S
    )
    assert repriced == pytest.approx(outcome["return"], abs=1e-9)


def test_a_replay_that_diverges_is_an_error(env):
    observation, _ = env.reset(seed=3)
    wrong = observation[VECTOR_KEY].copy()
    wrong[VectorField.PROGRESS] += 0.5
    with pytest.raises(RuntimeError, match="diverged"):
        play_branch(env, BranchTask(3, (), wrong, 0, None), HoldAgent.for_env(env))


def test_round_data_carries_action_values_and_rounds_without_them_concatenate(tmp_path):
    vector = np.zeros((3, 12), np.float32)
    values = np.array([[1.0, 0.5], [np.nan, np.nan], [0.0, 0.2]])
    priced = RoundData({"vector": vector}, np.array([0, 1, 0]), values)
    priced.save(tmp_path / "round_0.npz")
    loaded = RoundData.load(tmp_path / "round_0.npz")
    np.testing.assert_array_equal(loaded.action_values, values)
    assert loaded.priced().tolist() == [0, 2]
    plain = RoundData({"vector": vector[:2]}, np.array([0, 0]))
    both = RoundData.concatenate([plain, loaded])
    assert both.action_values.shape == (5, 2)
    assert both.priced().tolist() == [2, 4]
    assert RoundData.concatenate([plain, plain]).action_values is None


def test_the_fit_follows_the_values_where_the_expert_labels_are_silent():
    """Priced states whose best action is a rotation when one field is high: with the expert
    labels weighed 0, the fitted policy picks the best-valued action."""
    config = ImitationConfig(
        train=FAST, epochs=30, batch_size=64, learning_rate=3e-3, expert_label_weight=0.0
    )
    model = new_student(config)
    rng = np.random.default_rng(0)
    space = model.observation_space
    space.seed(0)
    n = 300
    observations = {key: np.stack([sub.sample() for _ in range(n)]) for key, sub in space.items()}
    observations["image"][:] = 0
    observations["coverage"][:] = 0
    progress = rng.uniform(0, 1, n).astype(np.float32)
    observations["vector"][:, VectorField.PROGRESS] = progress
    n_actions = int(model.action_space.n)
    values = np.zeros((n, n_actions))
    best = np.where(progress > 0.5, 5, 0)  # rotate to 45 deg in the upper half, else hold
    values[np.arange(n), best] = 1.0
    data = RoundData(observations, np.zeros(n, np.int64), values)
    fit = fit_student(model, data, config, rng)
    assert fit["priced_states"] == n - round(config.validation_fraction * n)
    assert fit["priced_regret"] <= 0.05
    actions, _ = model.predict({k: v[:60] for k, v in observations.items()}, deterministic=True)
    assert np.mean(actions == best[:60]) >= 0.95


def _outcome_row(seed, step, action, value, scan_time_s, matched):
    return {
        "tree_seed": seed, "step": step, "action": action, "return": value,
        "scan_time_s": scan_time_s, "n_matched": matched, "n_spurious": 0, "n_duplicates": 0,
        "failure": "",
    }  # fmt: skip


def test_a_branch_log_gives_each_priced_action_its_outcome(tmp_path):
    """The k-th logged state (by tree seed, step) is the k-th priced row; actions of one effect
    share their branch (the same return); a log that does not match is named."""
    import json

    from branch_gym.training.imitation.data import read_outcomes

    vector = np.zeros((5, 12), np.float32)
    values = np.full((5, 3), np.nan)
    values[1] = [0.5, 0.7, 0.5]  # tree 10, step 1: actions 0 and 2 hold (one branch)
    values[4] = [0.1, 0.2, 0.3]  # tree 11, step 1 (its episode: rows 3-4)
    data = RoundData({"vector": vector}, np.zeros(5, np.int64), values)
    rows = [
        _outcome_row(11, 1, 0, 0.1, 30.0, 1),
        _outcome_row(11, 1, 1, 0.2, 31.0, 2),
        _outcome_row(11, 1, 2, 0.3, 32.0, 3),
        _outcome_row(10, 1, 0, 0.5, 20.0, 4),
        _outcome_row(10, 1, 1, 0.7, 21.0, 5),
    ]
    log = tmp_path / "round_0.branches.jsonl"
    log.write_text("".join(json.dumps(row) + "\n" for row in rows))
    outcomes = read_outcomes(data, log)
    assert outcomes.shape == (5, 3, 5)
    assert outcomes[1, :, 0].tolist() == [20.0, 21.0, 20.0]  # action 2 shares action 0's branch
    assert outcomes[4, :, 1].tolist() == [1.0, 2.0, 3.0]
    assert np.isnan(outcomes[[0, 2, 3]]).all()
    rows[0]["return"] = 0.15  # no logged branch returns action 0's value any more
    log.write_text("".join(json.dumps(row) + "\n" for row in rows))
    with pytest.raises(ValueError, match="no branch of tree 11 step 1"):
        read_outcomes(data, log)
    log.write_text(json.dumps(rows[3]) + "\n")
    with pytest.raises(ValueError, match="prices 1 states, its round 2"):
        read_outcomes(data, log)
    old = {k: v for k, v in rows[3].items() if k in ("tree_seed", "step", "action", "return")}
    log.write_text(json.dumps(old) + "\n")
    assert read_outcomes(data, log) is None  # a log from before the outcomes were kept


def test_priced_again_at_other_prices_the_student_follows_its_price_input():
    """States that all drew 100 s: a 45-degree turn finds one more branch for 60 s more. It pays
    above 60 s a branch. Priced again at 25 and 400 s, the student holds at 25 s and turns at
    400 s; fitted on the drawn price alone, it ignores the price and turns at both."""
    from branch_gym.env.layout import PRICE_KEY, price_feature
    from branch_gym.training.imitation.data import OUTCOME_COLUMNS

    bounds = (25.0, 400.0)
    reward = RewardConfig()
    n, turn = 240, 5
    config = ImitationConfig(
        train=FAST, epochs=40, batch_size=64, learning_rate=3e-3, expert_label_weight=0.0,
        validation_fraction=0.0,
    )  # fmt: skip
    rng = np.random.default_rng(0)
    space = new_student(config).observation_space
    space.seed(0)
    observations = {key: np.stack([sub.sample() for _ in range(n)]) for key, sub in space.items()}
    observations["image"][:] = 0
    observations["coverage"][:] = 0
    observations[PRICE_KEY][:] = price_feature(PRICE_S, bounds)
    n_actions = 6
    outcomes = np.zeros((n, n_actions, len(OUTCOME_COLUMNS)))
    outcomes[:, :, 0], outcomes[:, :, 1] = 80.0, 3.0  # other turns: 60 s more, nothing found
    outcomes[:, 0, 0] = 20.0  # hold
    outcomes[:, turn, 1] = 4.0  # the 45-degree turn finds one more
    values = 1.0 * outcomes[:, :, 1] - outcomes[:, :, 0] / PRICE_S
    data = RoundData(observations, np.zeros(n, np.int64), values, outcomes)

    def turn_share(model, value_s):
        shown = dict(observations)
        shown[PRICE_KEY] = np.full_like(observations[PRICE_KEY], price_feature(value_s, bounds))
        actions, _ = model.predict({k: v[:60] for k, v in shown.items()}, deterministic=True)
        return float(np.mean(actions == turn))

    sampled = new_student(config)
    from dataclasses import replace

    fit_student(sampled, data, replace(config, price_samples_s=(25.0, 400.0)), rng, bounds, reward)
    assert turn_share(sampled, 400.0) >= 0.9 and turn_share(sampled, 25.0) <= 0.1
    plain = new_student(config)
    fit_student(plain, data, config, np.random.default_rng(0), bounds, reward)
    assert turn_share(plain, 25.0) >= 0.9  # nothing taught it what 25 s means
    with pytest.raises(ValueError, match="outcomes"):
        fit_student(
            new_student(config), RoundData(observations, data.expert_actions, values),
            replace(config, price_samples_s=(25.0,)), rng, bounds, reward,
        )  # fmt: skip
    wrong = RoundData(observations, data.expert_actions, values + 0.1, outcomes)
    with pytest.raises(ValueError, match="does not match"):
        fit_student(
            new_student(config), wrong, replace(config, price_samples_s=(25.0,)), rng, bounds,
            reward,
        )  # fmt: skip
    with pytest.raises(ValueError, match="price_samples_s"):
        ImitationConfig(train=FAST, price_samples_s=(0.0,))


@pytest.mark.slow
def test_a_cost_to_go_run_prices_sampled_states_and_keeps_its_branches(tmp_path):
    import json

    from branch_gym.training.imitation import ROUNDS_LOG, imitate

    config = ImitationConfig(train=FAST, rounds=1, episodes=1, epochs=1, cost_to_go_states=1)
    imitate(config, tmp_path, workers=1)
    data = RoundData.load(tmp_path / "round_0.npz")
    assert len(data.priced()) == 1  # one state of the episode, every action valued
    branches = (tmp_path / "round_0.branches.jsonl").read_text()
    assert len(branches.splitlines()) == 5  # five distinct actions at the state
    # Each branch's end is logged with its return, so that it can be priced again.
    assert all(json.loads(line)["scan_time_s"] > 0.0 for line in branches.splitlines())
    row = json.loads((tmp_path / ROUNDS_LOG).read_text().splitlines()[0])
    assert row["priced_states"] == 1 and 0.0 <= row["priced_rotation_best_share"] <= 1.0
    # A round interrupted after its branches ran: resumed, it plays the episode again but
    # takes the kept branches instead of running them again.
    for name in ("model_round_0.zip", "round_0.npz", ROUNDS_LOG):
        (tmp_path / name).unlink()
    imitate(config, tmp_path, resume=True, workers=1)
    assert (tmp_path / "round_0.branches.jsonl").read_text() == branches
    again = RoundData.load(tmp_path / "round_0.npz")
    np.testing.assert_array_equal(again.action_values, data.action_values)
    # The log's outcomes give back every priced value (PriceSamples checks it, and raises if not).
    from branch_gym.training.imitation.data import load_round
    from branch_gym.training.imitation.fit import PriceSamples

    with_outcomes = load_round(tmp_path, 0)
    assert np.isfinite(with_outcomes.action_outcomes[with_outcomes.priced()]).all()
    env = gym.make(FAST.env_id, **FAST.env_kwargs())
    bounds = env.unwrapped.config.branch_value_s
    PriceSamples(with_outcomes, (25.0, 400.0), bounds, env.unwrapped.config.reward)
    env.close()


@pytest.mark.slow
def test_ray_labellers_label_as_this_process_does():
    """The labelling calls as Ray tasks (a private local instance) return what they return here."""
    pytest.importorskip("ray", reason="Ray is not installed: pip install '.[ray]'")
    from branch_gym.evaluation.ray_backend import ray_session
    from branch_gym.training.imitation.labels import (
        RayLabellers,
        branch_task,
        episode_task,
        init_worker,
    )

    init_worker(FAST.to_dict())
    here, summary = episode_task((7, None))
    task = BranchTask(7, tuple(summary["actions"][:3]), here.observations[VECTOR_KEY][3], 5, None)
    with ray_session(None, 1) as ray:
        labellers = RayLabellers(ray, FAST.to_dict())
        [(there, _)] = labellers.map(episode_task, [(7, None)])
        [value] = labellers.map(branch_task, [task])
    np.testing.assert_array_equal(there.expert_actions, here.expert_actions)
    for key, array in here.observations.items():
        np.testing.assert_array_equal(there.observations[key], array)
    assert value == branch_task(task)
