"""The Gymnasium environment (branch_gym/env/) and the baseline agents (agents/baselines.py).

Scans are short (end just above the 0.275 m start) with the depth-oracle tracker and small
rotation angles, so each test takes a second or two; full-length and batch runs live in
tests/test_env_slow.py.
"""

from __future__ import annotations

import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env
from gymnasium.utils.env_checker import env_render_passive_checker
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import branch_gym
from agents.baselines import NoRotationAgent, PeriodicAgent
from branch_gym.env import BranchScanEnv
from branch_gym.env.config import ObservationConfig
from branch_gym.env.layout import VECTOR_SIZE, ImageChannel, VectorField, vector_part
from branch_gym.env.observation import PipelineState, draw_state, make_observation
from branch_gym.env.reward import RewardConfig, RewardTracker
from branch_gym.scan import ScanConfig
from branch_gym.sim.tree.config import TreeConfig
from recon.camera import CameraIntrinsics
from recon.curve2d.fit import fit_mask_curves
from recon.metrics import TreeMetrics
from recon.model import BranchModel, TreeModel
from recon.modeler import Outcome
from recon.overlay import draw_polyline
from tests.synthetic import camera_following, rasterise_mask, side_branch, straight_tube

# Short scans with cheap rotations (an arc of 4 deg is ~14 mm of motion).
SHORT = {
    "tracker": "oracle",
    "end_height_m": 0.32,
    "theta_max_deg": 4.0,
    "discrete_angles_deg": (-4.0, 0.0, 4.0),
    "trigger_angles_deg": (2.0, 4.0),
}
# Two steps per episode: one iteration at ~0.284 m, then the end height.
TINY = {**SHORT, "end_height_m": 0.29}


def _run(env: gymnasium.Env, seed: int, actions: list) -> tuple[list, list[float], dict]:
    """Reset with ``seed`` and step ``actions`` in turn (cycling) until the episode ends."""
    obs, _ = env.reset(seed=seed)
    observations, rewards, i = [obs], [], 0
    while True:
        obs, reward, terminated, truncated, info = env.step(actions[i % len(actions)])
        observations.append(obs)
        rewards.append(reward)
        i += 1
        if terminated or truncated:
            return observations, rewards, info


# ---------------------------------------------------------------------- registration and API
def test_ids_are_registered_with_the_documented_spaces() -> None:
    env = gymnasium.make(branch_gym.ENV_ID_V0)
    assert env.spec.max_episode_steps == branch_gym.MAX_EPISODE_STEPS
    assert env.action_space == gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)
    assert env.observation_space["image"].shape == (3, 60, 80)
    assert env.observation_space["image"].dtype == np.uint8
    assert env.observation_space["vector"].shape == (VECTOR_SIZE,)
    env.close()
    discrete = gymnasium.make(branch_gym.DISCRETE_ENV_ID_V0)
    assert discrete.action_space == gymnasium.spaces.Discrete(5)
    assert discrete.unwrapped.config.discrete_angles_deg == (-45.0, -22.5, 0.0, 22.5, 45.0)
    discrete.close()
    flat = gymnasium.make(branch_gym.FLAT_ENV_ID)
    assert flat.observation_space.shape == (VECTOR_SIZE + 3 * 60 * 80,)
    flat.close()


@pytest.mark.parametrize("env_id", branch_gym.ENV_IDS)
def test_gymnasium_check_env_passes(env_id: str) -> None:
    env = gymnasium.make(env_id, render_mode="rgb_array", **SHORT)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the checker reports problems as warnings too
        # "human" needs a display: rgb_array rendering is checked explicitly instead.
        gymnasium_check_env(env.unwrapped, skip_render_check=True)
        env_render_passive_checker(env.unwrapped)
    env.close()


@pytest.mark.parametrize("env_id", branch_gym.ENV_IDS)
def test_sb3_check_env_passes(env_id: str) -> None:
    env = gymnasium.make(env_id, **SHORT)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env.unwrapped)
    env.close()


def test_same_seed_and_actions_give_identical_episodes() -> None:
    actions = [np.array([0.0], np.float32), np.array([1.0], np.float32), np.array([-0.5])]
    first, second = BranchScanEnv(**SHORT), BranchScanEnv(**SHORT)
    obs_a, rewards_a, info_a = _run(first, 4, actions)
    obs_b, rewards_b, info_b = _run(second, 4, actions)
    obs_c, rewards_c, info_c = _run(first, 4, actions)  # the same env again, after other scans
    for other, other_rewards, other_info in (
        (obs_b, rewards_b, info_b),
        (obs_c, rewards_c, info_c),
    ):
        assert len(other) == len(obs_a)
        for a, b in zip(obs_a, other, strict=True):
            np.testing.assert_array_equal(a["image"], b["image"])
            np.testing.assert_array_equal(a["vector"], b["vector"])
        assert other_rewards == rewards_a
        assert other_info == info_a  # final metrics included (no wall-clock timings by default)
    assert info_a["final_metrics"]["rotations"] >= 1
    # A seedless reset draws its tree seed from the env's generator, seeded by reset(seed=...).
    first.reset(seed=11)
    second.reset(seed=11)
    assert first.reset()[1]["seed"] == second.reset()[1]["seed"]
    first.close()
    second.close()


def test_step_limit_truncates_and_reset_observation_is_empty() -> None:
    env = gymnasium.make(branch_gym.ENV_ID_V0, max_episode_steps=1, **SHORT)
    obs, _ = env.reset(seed=0)
    assert not obs["image"].any()  # nothing seen yet: no iteration before the first step
    assert not obs["vector"][[VectorField.OUTCOME_CONSISTENT, VectorField.OUTCOME_RESTART]].any()
    _, _, terminated, truncated, info = env.step(np.zeros(1, np.float32))
    assert truncated and not terminated
    assert info["metrics"]["n_gt"] == 0 and "final_metrics" not in info
    env.close()


def test_scan_time_limit_terminates_as_a_failure_and_is_observed() -> None:
    # 1 s of scan time at 2.5 cm/s is ~25 mm of travel: the limit comes before the 0.32 m end.
    scan = ScanConfig(tracker="oracle", end_height_m=0.32, max_scan_time_s=1.0)
    env = BranchScanEnv(scan=scan)
    observations, _, info = _run(env, 3, [np.zeros(1, np.float32)])
    assert info["stop_reason"] == "timeout" and info["failure"] == "timeout"
    assert info["reward_terms"]["failure"] == -env.config.reward.failure_penalty
    assert "final_metrics" in info
    times = [float(obs["vector"][VectorField.SCAN_TIME]) for obs in observations]
    assert times[0] == 0.0 and times[-1] == 1.0 and times == sorted(times)
    assert 0.0 < times[1] < 1.0  # the time left is seen before the limit, not only at it
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))
    env.close()


def test_flat_observation_is_the_vector_then_the_image() -> None:
    flat, nested = BranchScanEnv(flatten=True, **TINY), BranchScanEnv(**TINY)
    flat.reset(seed=2)
    nested.reset(seed=2)
    flat_obs = flat.step(np.array([0.5], np.float32))[0]
    obs = nested.step(np.array([0.5], np.float32))[0]
    assert flat_obs.dtype == np.float32 and flat_obs in flat.observation_space
    np.testing.assert_array_equal(flat_obs[:VECTOR_SIZE], obs["vector"])
    np.testing.assert_allclose(flat_obs[VECTOR_SIZE:] * 255, obs["image"].reshape(-1), atol=1e-3)
    np.testing.assert_array_equal(vector_part(flat_obs), vector_part(obs))
    flat.close()
    nested.close()


# ---------------------------------------------------------------------- actions and errors
def test_out_of_range_actions_are_clipped() -> None:
    env = BranchScanEnv(**TINY)
    env.reset(seed=1)
    obs_clipped, _, _, _, info = env.step(np.array([7.5], np.float32))
    assert info["angle_deg"] == pytest.approx(4.0, abs=0.05)
    assert obs_clipped["vector"][VectorField.PREVIOUS_ACTION] == 1.0
    env.reset(seed=1)
    obs_bound = env.step(np.array([1.0], np.float32))[0]
    np.testing.assert_array_equal(obs_clipped["vector"], obs_bound["vector"])
    env.close()


@pytest.mark.parametrize(
    ("action_type", "action", "match"),
    [
        ("continuous", np.array([np.nan], np.float32), "finite"),
        ("continuous", np.array([np.inf]), "finite"),
        ("continuous", np.zeros(2, np.float32), "shape"),
        ("continuous", np.zeros((1, 1), np.float32), "shape"),
        ("continuous", "left", "real number"),
        ("discrete", 3, "out of range"),
        ("discrete", -1, "out of range"),
        ("discrete", 1.0, "integer"),
        ("discrete", np.array([0, 1]), "int index"),
    ],
)
def test_bad_actions_raise_a_clear_value_error(action_type: str, action, match: str) -> None:
    env = BranchScanEnv(action_type=action_type, **TINY)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)
    env.close()


def test_step_outside_an_episode_raises() -> None:
    env = BranchScanEnv(**TINY)
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(np.zeros(1, np.float32))
    _, _, info = _run(env, 0, [np.zeros(1, np.float32)])
    assert info["stop_reason"] == "end_height"
    with pytest.raises(RuntimeError, match="after the episode ended"):
        env.step(np.zeros(1, np.float32))
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))  # a new episode steps again
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"trackr": "lk"}, "'trackr'.*did you mean 'tracker'"),
        ({"tracker": "pips"}, "tracker"),
        ({"tracker": 3}, "tracker"),
        ({"segmenter": "noisy:awful"}, "segmenter"),
        ({"tree": "forest"}, "tree"),
        ({"end_height_m": 0.1}, "end_height_m"),
        ({"end_height_m": "high"}, "end_height_m"),
        ({"reward": {"matchd": 1.0}}, "matchd"),
        ({"reward": {"failure_penalty": -1.0}}, "failure_penalty"),
        ({"observation": {"image_height": 0}}, "image_height"),
        ({"observation": {"pixels": 3}}, "pixels"),
        ({"theta_max_deg": -5.0}, "theta_max_deg"),
        ({"discrete_angles_deg": (0.0, float("nan"))}, "discrete_angles_deg"),
        ({"action_type": "box"}, "action_type"),
        ({"flatten": "yes"}, "flatten"),
        ({"render_mode": "video"}, "render_mode"),
    ],
)
@pytest.mark.filterwarnings("ignore:.*render_mode")  # gymnasium warns before the env raises
def test_bad_kwargs_name_the_offending_key(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        gymnasium.make(branch_gym.ENV_ID_V0, **kwargs)


def test_discrete_angles_must_lie_within_theta_max() -> None:
    with pytest.raises(ValueError, match="discrete_angles_deg"):
        gymnasium.make(branch_gym.DISCRETE_ENV_ID_V0, theta_max_deg=30.0)
    gymnasium.make(branch_gym.ENV_ID_V0, theta_max_deg=30.0).close()  # unused by a continuous env


def test_tree_presets_and_reset_options() -> None:
    env = BranchScanEnv(tree="hard", **TINY)
    assert env.config.scan.world.tree == TreeConfig.hard()
    _, info = env.reset(seed=3)
    assert info["seed"] == 3
    tree = env.session.tree
    env.reset(seed=99, options={"tree": tree})
    assert env.session.tree is tree
    with pytest.raises(ValueError, match="bogus"):
        env.reset(seed=0, options={"bogus": 1})
    with pytest.raises(ValueError, match="TreeGT"):
        env.reset(seed=0, options={"tree": "paper"})
    env.close()
    custom = TreeConfig(secondary_count_range=(1, 1))
    assert BranchScanEnv(tree=custom, **TINY).config.scan.world.tree == custom


# ---------------------------------------------------------------------- info and reward
def test_info_is_flat_and_alike_at_reset_and_step() -> None:
    env = BranchScanEnv(**{**TINY, "info_timings": True})
    _, reset_info = env.reset(seed=0)
    _, _, _, _, step_info = env.step(np.zeros(1, np.float32))
    assert set(reset_info) == set(step_info)
    metrics = step_info["metrics"]
    assert {"n_matched", "n_spurious", "n_duplicates", "n_gt", "missed_pct"} <= set(metrics)
    assert all(not isinstance(v, (dict, list)) for v in metrics.values())
    assert reset_info["metrics"]["pb_residual_mean_m"] is None  # NaN (no model) -> None
    assert step_info["outcome"] == "consistent" and step_info["iterations"] == 1
    timings = step_info["timings_ms"]
    assert {"modeler_total_ms", "scan_step_ms", "render_ms", "metrics_ms", "observation_ms"} <= set(
        timings
    )
    assert 0.0 < timings["render_ms"] < timings["scan_step_ms"]  # the step rendered its frames
    _, _, terminated, _, last = env.step(np.zeros(1, np.float32))
    assert terminated and last["final_metrics"]["stop_reason"] == "end_height"
    assert "wall_time_s" in last["final_metrics"]
    env.close()
    quiet = BranchScanEnv(**TINY)  # the default: no wall-clock measurements anywhere
    _, _, info = _run(quiet, 0, [np.zeros(1, np.float32)])
    assert "timings_ms" not in info and "wall_time_s" not in info["final_metrics"]
    quiet.close()


def _metrics(matched: int, spurious: int, duplicates: int) -> TreeMetrics:
    empty = np.zeros(0)
    return TreeMetrics(
        empty, empty, empty, empty, [], 5, matched, 5 - matched, spurious, duplicates, 0, 0.5
    )


def test_reward_counts_rise_and_fall_and_time_costs() -> None:
    tracker = RewardTracker(RewardConfig())
    reward, terms = tracker.step(_metrics(2, 1, 0), scan_time_s=1.0, failed=False)
    assert terms == {
        "matched": 2.0,
        "spurious": -0.5,
        "duplicates": -0.0,
        "time": -0.01,
        "failure": 0.0,
    }
    assert reward == pytest.approx(1.49)
    reward, terms = tracker.step(_metrics(2, 0, 1), scan_time_s=3.0, failed=True)
    assert terms["spurious"] == 0.5 and terms["duplicates"] == -0.5
    assert terms["time"] == pytest.approx(-0.02) and terms["failure"] == -1.0
    assert reward == pytest.approx(sum(terms.values()))
    tracker.reset()
    assert tracker.step(_metrics(0, 0, 0), 0.0, False)[0] == 0.0


def test_episode_return_telescopes_to_the_final_score() -> None:
    tree = TreeConfig(secondary_count_range=(3, 3), secondary_base_height_range_m=(0.33, 0.36))
    env = BranchScanEnv(tree=tree, tracker="oracle", end_height_m=0.42)
    _, rewards, info = _run(env, 5, [np.zeros(1, np.float32)])
    final = info["final_metrics"]
    assert final["n_matched"] >= 1  # the test means something: branches were found
    weights = env.config.reward
    expected = (
        weights.match_reward * final["n_matched"]
        - weights.spurious_penalty * final["n_spurious"]
        - weights.duplicate_penalty * final["n_duplicates"]
        - weights.time_penalty_per_s * final["scan_time_s"]
    )
    assert sum(rewards) == pytest.approx(expected)
    env.close()


# ---------------------------------------------------------------------- observation and render
def _synthetic_state(model_secondaries: int) -> PipelineState:
    """A branch with two side branches in view; the model holds the first ``n`` of them."""
    intrinsics = CameraIntrinsics.from_fov()
    primary = straight_tube([0.0, 0.0, 0.2], [0.0, 0.0, 0.6], 0.005)
    sides = [
        side_branch(primary, 0.40, 0.0, 0.06, 0.004),
        side_branch(primary, 0.37, 180, 0.06, 0.004),
    ]
    T = camera_following(primary, 0.40)
    curves = fit_mask_curves(rasterise_mask([primary, *sides], T, intrinsics))
    assert curves.primary is not None and len(curves.secondaries) == 2
    model = TreeModel(
        BranchModel(primary.points, primary.radii),
        [BranchModel(s.points, s.radii) for s in sides[:model_secondaries]],
    )
    return PipelineState(T, intrinsics, model, curves, Outcome.RESTART, 0.5, 0.25, 0.4, -1.0, 0.3)


def test_observation_shows_what_the_model_does_not_explain() -> None:
    config = ObservationConfig()
    explained_one = _synthetic_state(model_secondaries=1)
    drawing = draw_state(explained_one, config)
    obs = make_observation(explained_one, drawing, config, flatten=False)
    vector, image = obs["vector"], obs["image"]
    assert vector[VectorField.ANGLE] == 0.5 and vector[VectorField.TRAVEL_FOV] == 0.25
    assert vector[VectorField.PROGRESS] == pytest.approx(0.4)
    assert list(vector[[VectorField.OUTCOME_CONSISTENT, VectorField.OUTCOME_RESTART]]) == [0, 1]
    assert vector[VectorField.MODEL_SECONDARIES] == pytest.approx(0.1)
    assert vector[VectorField.MODEL_SECONDARIES_IN_VIEW] == pytest.approx(0.1)
    assert vector[VectorField.CANDIDATES_2D] == pytest.approx(0.2)
    assert vector[VectorField.UNCONFIRMED_CANDIDATES] == pytest.approx(0.1)
    assert vector[VectorField.PREVIOUS_ACTION] == -1.0
    assert vector[VectorField.SCAN_TIME] == pytest.approx(0.3)
    # The unconfirmed candidate is the one on the left (yaw 180 deg): drawn from the primary's
    # axis (image centre) leftwards, in its channel only.
    columns = np.nonzero(image[ImageChannel.UNCONFIRMED].any(axis=0))[0]
    centre = image.shape[2] / 2
    assert len(columns) and columns.min() < centre - 10 and columns.max() < centre + 4
    assert image[ImageChannel.MASK].max() == 255 and image[ImageChannel.MODEL].max() == 255
    # The model drawn with both secondaries explains both candidates.
    explained_all = _synthetic_state(model_secondaries=2)
    obs_all = make_observation(
        explained_all, draw_state(explained_all, config), config, flatten=False
    )
    assert obs_all["vector"][VectorField.UNCONFIRMED_CANDIDATES] == 0.0
    assert not obs_all["image"][ImageChannel.UNCONFIRMED].any()


def test_a_branch_just_in_front_of_the_lens_is_drawn_covering_the_canvas() -> None:
    # Projected radii explode as depth goes to 0 (seen with noisy masks): the line is clipped to
    # the canvas, not refused by OpenCV (which accepts widths up to 32767 px).
    canvas = np.zeros((60, 80), np.uint8)
    pixels = np.array([[10.0, 10.0], [70.0, 50.0]])
    draw_polyline(canvas, pixels, np.array([1e6, 1e7]), 255)
    assert canvas.all()
    thin = np.zeros((60, 80), np.uint8)
    draw_polyline(thin, pixels, np.array([0.5, 0.5]), 255)
    assert 0 < np.count_nonzero(thin) < 0.1 * thin.size


def test_render_rgb_array_overlays_the_pipeline_state() -> None:
    env = BranchScanEnv(render_mode="rgb_array", **SHORT)
    env.reset(seed=0)
    assert env.render().shape == (240, 320, 3)  # before any iteration: the plain camera view
    env.step(np.zeros(1, np.float32))
    env.step(np.zeros(1, np.float32))
    frame = env.render()
    raw = env.session.world.render().rgb
    assert frame.shape == raw.shape and frame.dtype == np.uint8
    model = env._drawing.model > 0
    assert model.any()
    # The projected model is blended in red.
    assert frame[model][:, 0].astype(int).mean() > raw[model][:, 0].astype(int).mean()
    env.close()


def test_render_without_mode_returns_none_and_human_needs_a_display(monkeypatch) -> None:
    env = BranchScanEnv(**TINY)
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert env.render() is None
    env.close()
    if sys.platform.startswith("linux"):
        monkeypatch.delenv("DISPLAY", raising=False)
        monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
        with pytest.raises(RuntimeError, match=r"render_mode='human'.*display"):
            BranchScanEnv(render_mode="human", **TINY)


# ---------------------------------------------------------------------- baseline agents
def _vector(travel_fov: float = 0.0, outcome: bool = True) -> np.ndarray:
    vector = np.zeros(VECTOR_SIZE, np.float32)
    vector[VectorField.TRAVEL_FOV] = travel_fov
    vector[VectorField.OUTCOME_CONSISTENT] = float(outcome)
    return vector


def test_periodic_agent_cycles_like_the_paper_and_resets_on_episode_start() -> None:
    agent = PeriodicAgent(22.5, 1.5)
    interval = 1.0 / 1.5
    obs = {"image": np.zeros((3, 60, 80), np.uint8), "vector": _vector(0.0, outcome=False)}
    action, _ = agent.predict(obs, episode_start=True)
    assert action.shape == (1,) and action.dtype == np.float32 and action[0] == 0.0
    targets = []
    for _ in range(5):
        targets.append(float(agent.predict({"vector": _vector(interval)})[0][0]))
        assert agent.predict({"vector": _vector(0.01)})[0][0] == targets[-1]
    assert targets == [0.5, 0.0, -0.5, 0.0, 0.5]
    assert agent.predict({"vector": _vector(interval)}, episode_start=True)[0][0] == 0.5
    # A reset observation (no iteration yet) also starts a new episode.
    agent.predict({"vector": _vector(0.0, outcome=False)})
    assert agent.predict({"vector": _vector(interval)})[0][0] == 0.5


def test_agents_handle_batches_state_flat_and_discrete_observations() -> None:
    agent = PeriodicAgent(22.5, 1.5)
    batch = np.stack([_vector(1.0), _vector(0.0), _vector(1.0)])
    actions, state = agent.predict({"vector": batch})
    assert actions.shape == (3, 1) and list(state) == [0, -1, 0]
    actions, state = agent.predict(
        {"vector": batch}, state=state, episode_start=[True, False, False]
    )
    assert list(actions[:, 0]) == [0.5, 0.0, 0.0] and list(state) == [0, -1, 1]
    flat = np.concatenate([batch, np.zeros((3, 14400), np.float32)], axis=1)
    assert PeriodicAgent(22.5, 1.5).predict(flat)[0].shape == (3, 1)
    discrete = PeriodicAgent(22.5, 1.5, action_angles_deg=(-45.0, -22.5, 0.0, 22.5, 45.0))
    index, _ = discrete.predict({"vector": _vector(1.0)})
    assert index.shape == () and int(index) == 3
    still = NoRotationAgent(action_angles_deg=(-4.0, 0.0, 4.0))
    assert list(still.predict({"vector": batch})[0]) == [1, 1, 1]
    assert NoRotationAgent().predict({"vector": _vector()})[0].tolist() == [0.0]
    env = BranchScanEnv(action_type="discrete", **TINY)
    assert PeriodicAgent.for_env(env, 4.0, 2.0).action_angles_deg == (-4.0, 0.0, 4.0)
    env.close()
    with pytest.raises(ValueError, match="angle_deg"):
        PeriodicAgent(60.0, 1.5)
    with pytest.raises(ValueError, match="action_angles_deg"):
        PeriodicAgent(10.0, 1.5, action_angles_deg=(-45.0, 0.0, 45.0))
    with pytest.raises(ValueError, match="observation vector"):
        agent.predict(np.zeros(3, np.float32))
