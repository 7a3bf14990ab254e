"""PPO with a privileged critic: the privileged state, the two halves of the policy, training."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import MultiInputActorCriticPolicy

import branch_gym  # noqa: F401  (registers the env ids)
from branch_gym.scan import ScanConfig
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.privileged_critic import PrivilegedCriticPolicy, actor_model
from branch_gym.training.privileged_state import (
    PRIVILEGED_KEY,
    SLOT_SIZE,
    PrivilegedField,
    PrivilegedStateConfig,
    PrivilegedStateWrapper,
    SlotField,
    privileged_state,
    with_privileged_space,
    without_privileged_space,
)

ENV_ID = "BranchScanDiscrete-v2"  # the shipped orchard student's
# Its spaces, scored as the benchmark (v2 scores in the paper's scope, up to the height reached).
SCORED_ENV_ID = "BranchScanDiscrete-v3"
CHEAP_ENV = {"tracker": "oracle", "render_tracking_frames": False, "segmenter": "gt"}
# A tiny Dict space whose keys sort around the privileged one (price < privileged < vector).
PLAIN_SPACE = spaces.Dict(
    {
        "coverage": spaces.Box(0.0, 1.0, (8,), np.float32),
        "price": spaces.Box(0.0, 1.0, (1,), np.float32),
        "vector": spaces.Box(-1.0, 1.0, (12,), np.float32),
    }
)
ACTIONS = spaces.Discrete(6)


def _lr(_: float) -> float:
    return 3e-4


def _batch(space: spaces.Dict, n: int, seed: int) -> dict[str, torch.Tensor]:
    space.seed(seed)
    samples = [space.sample() for _ in range(n)]
    return {key: torch.as_tensor(np.stack([s[key] for s in samples])) for key in space.spaces}


def _logits_and_values(policy, obs) -> tuple[torch.Tensor, torch.Tensor]:
    with torch.no_grad():
        return policy.get_distribution(obs).distribution.logits, policy.predict_values(obs)


def test_the_actor_ignores_the_privileged_entry_and_the_critic_reads_it() -> None:
    torch.manual_seed(0)
    space = with_privileged_space(PLAIN_SPACE)
    policy = PrivilegedCriticPolicy(space, ACTIONS, _lr)
    obs = _batch(space, 16, seed=0)
    changed = {**obs, PRIVILEGED_KEY: _batch(space, 16, seed=1)[PRIVILEGED_KEY]}
    logits, values = _logits_and_values(policy, obs)
    logits_changed, values_changed = _logits_and_values(policy, changed)
    assert torch.equal(logits, logits_changed)
    assert not torch.allclose(values, values_changed)
    # It acts on the plain observation, without the entry, as on the full one.
    plain = {key: value.numpy() for key, value in obs.items() if key != PRIVILEGED_KEY}
    actions, _ = policy.predict(plain, deterministic=True)
    np.testing.assert_array_equal(actions, logits.argmax(dim=1).numpy())


def test_it_starts_from_a_plain_policy_with_the_same_actions_and_values() -> None:
    torch.manual_seed(0)
    plain = MultiInputActorCriticPolicy(PLAIN_SPACE, ACTIONS, _lr, net_arch={"pi": [9], "vf": [7]})
    torch.manual_seed(1)
    space = with_privileged_space(PLAIN_SPACE)
    policy = PrivilegedCriticPolicy(space, ACTIONS, _lr, net_arch={"pi": [9], "vf": [7]})
    policy.load_plain_weights(plain)
    obs = _batch(space, 16, seed=2)
    plain_obs = {key: value for key, value in obs.items() if key != PRIVILEGED_KEY}
    logits, values = _logits_and_values(policy, obs)
    plain_logits, plain_values = _logits_and_values(plain, plain_obs)
    torch.testing.assert_close(logits, plain_logits)
    torch.testing.assert_close(values, plain_values)  # zero weights on the privileged entry
    with pytest.raises(ValueError, match="shape"):
        PrivilegedCriticPolicy(space, ACTIONS, _lr).load_plain_weights(plain)


def test_actor_model_keeps_the_actor_on_the_plain_space() -> None:
    from stable_baselines3 import PPO

    class _Env(gym.Env):
        observation_space = with_privileged_space(PLAIN_SPACE)
        action_space = ACTIONS

    model = PPO(PrivilegedCriticPolicy, _Env(), n_steps=8, batch_size=8, seed=0, device="cpu")
    obs = _batch(model.observation_space, 8, seed=3)
    logits, _ = _logits_and_values(model.policy, obs)
    actor_model(model)
    assert model.observation_space == PLAIN_SPACE
    assert type(model.policy) is MultiInputActorCriticPolicy
    plain_obs = {key: value for key, value in obs.items() if key != PRIVILEGED_KEY}
    torch.testing.assert_close(_logits_and_values(model.policy, plain_obs)[0], logits)


def test_the_policy_and_the_config_refuse_what_they_cannot_train() -> None:
    with pytest.raises(ValueError, match=PRIVILEGED_KEY):
        PrivilegedCriticPolicy(PLAIN_SPACE, ACTIONS, _lr)
    with pytest.raises(ValueError, match="share_features_extractor"):
        PrivilegedCriticPolicy(
            with_privileged_space(PLAIN_SPACE), ACTIONS, _lr, share_features_extractor=True
        )
    with pytest.raises(ValueError, match="recurrent"):
        TrainConfig(env_id=ENV_ID, privileged_critic=True, recurrent=True)
    with pytest.raises(ValueError, match="Dict observations"):
        TrainConfig(env_id="BranchScanFlat-v0", privileged_critic=True)
    with pytest.raises(ValueError, match="Dict"):
        with_privileged_space(spaces.Box(0.0, 1.0, (3,)))
    assert without_privileged_space(with_privileged_space(PLAIN_SPACE)) == PLAIN_SPACE


def _branch(base_z: float, direction: tuple[float, float]) -> SimpleNamespace:
    base = np.array([0.0, 0.0, base_z])
    return SimpleNamespace(points=np.stack([base, base + np.array([*direction, 0.0]) * 0.1]))


def test_the_privileged_state_sorts_the_scored_branches_by_height_and_heading() -> None:
    # Scored band of the default scan: 0.325 to 0.75 m (+ 2 cm margin); view band +-0.05 m.
    branches = [
        _branch(0.40, (0.0, 1.0)),  # 0: passed, unmatched: missed below
        _branch(0.42, (0.0, 1.0)),  # 1: matched
        _branch(0.51, (0.0, 1.0)),  # 2: in view, heading 0 (+y): 90 deg from the axis at 90
        _branch(0.48, (-1.0, 0.0)),  # 3: in view, heading 90 deg: along the axis, worst first
        _branch(0.60, (1.0, 0.0)),  # 4: ahead, not yet seen
        _branch(0.30, (1.0, 0.0)),  # 5: below the scored band
        _branch(0.80, (1.0, 0.0)),  # 6: above it
    ]
    session = SimpleNamespace(
        tree=SimpleNamespace(secondaries=branches),
        config=ScanConfig(),
        camera_height_m=0.5,
        vertical_fov_m=0.1,
        angle_deg=90.0,
        progress=0.4,
    )
    config = PrivilegedStateConfig(heading_slots=3)
    vector = privileged_state(session, {1}, config)
    assert vector.shape == (config.size,) == (5 + 3 * SLOT_SIZE,)
    assert config.space().contains(vector)
    expected = {"PENDING_IN_VIEW": 2, "MISSED_BELOW": 1, "UNSEEN_AHEAD": 1, "MATCHED": 1}
    for name, count in expected.items():
        assert vector[PrivilegedField[name]] == pytest.approx(count / config.count_scale)
    assert vector[PrivilegedField.PROGRESS] == pytest.approx(0.4)
    slots = vector[len(PrivilegedField) :].reshape(3, SLOT_SIZE)
    # Branch 3 (relative heading 0: along the optical axis), then branch 2 (-90 deg), then none.
    np.testing.assert_allclose(slots[0], [1.0, 1.0, 0.0, -0.2], atol=1e-6)
    np.testing.assert_allclose(slots[1], [1.0, 0.0, -1.0, 0.1], atol=1e-6)
    np.testing.assert_array_equal(slots[2], np.zeros(SLOT_SIZE))
    assert slots[1, SlotField.SIN] == pytest.approx(math.sin(-math.pi / 2))


def test_the_wrapper_adds_the_documented_vector_on_a_real_env() -> None:
    env = PrivilegedStateWrapper(gym.make(SCORED_ENV_ID, **CHEAP_ENV))
    try:
        obs, info = env.reset(seed=0)
        vector = obs[PRIVILEGED_KEY]
        assert vector.shape == (PrivilegedStateConfig().size,) == (21,)
        assert vector.dtype == np.float32 and np.all(np.isfinite(vector))
        assert env.observation_space.contains(obs)
        counts = vector[[PrivilegedField.PENDING_IN_VIEW, PrivilegedField.MISSED_BELOW]]
        counts = [*counts, vector[PrivilegedField.UNSEEN_AHEAD], vector[PrivilegedField.MATCHED]]
        # Every branch the env's score counts is in exactly one group.
        assert round(sum(counts) * PrivilegedStateConfig().count_scale) == info["metrics"]["n_gt"]
        assert info["metrics"]["n_gt"] > 0
        obs, *_ = env.step(0)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


@pytest.mark.slow
def test_a_fine_tuned_model_plays_as_a_ppo_spec_on_the_plain_observation(tmp_path) -> None:
    from stable_baselines3 import PPO

    from agents.factory import make_agent
    from agents.ppo import resolve_model_path
    from branch_gym.training.model_files import load_model, saved_env_id
    from branch_gym.training.train import train

    steps = 8
    config = TrainConfig(
        env_id=ENV_ID,
        timesteps=steps,
        tracker="oracle",
        render_tracking_frames=False,
        end_height_m=0.33,  # ~6 steps per episode (tests/test_train.py)
        eval_every=steps,  # the held-out evaluation plays the actor in the plain env
        eval_trees=1,
        checkpoint_every=steps,
        init_model="ppo_ctg_orchard",
        privileged_critic=True,
        ppo=PPOConfig(n_steps=steps, batch_size=steps, n_epochs=1, cnn_output_dim=64),
    )
    result = train(config, tmp_path / "run", find_model=resolve_model_path)
    assert len(result.evaluations) == 1
    assert saved_env_id(result.final_model) == ENV_ID
    resumed = train(
        replace(config, timesteps=2 * steps), tmp_path / "run", resume=True,
        find_model=resolve_model_path,
    )  # fmt: skip
    assert resumed.num_timesteps == 2 * steps
    saved = PPO.load(result.final_model, device="cpu")  # the privileged model, as trained
    assert isinstance(saved.policy, PrivilegedCriticPolicy)
    student = load_model(resolve_model_path("ppo_ctg_orchard"))
    assert not all(  # the update moved the actor
        torch.equal(value, student.policy.state_dict()[key])
        for key, value in saved.policy.actor_state_dict().items()
    )
    env = gym.make(ENV_ID, **CHEAP_ENV)
    try:
        agent = make_agent(f"ppo:{result.final_model}@100", env)
        obs, _ = env.reset(seed=1, options={"branch_value_s": 100.0})
        assert PRIVILEGED_KEY not in obs
        action, _ = agent.predict(obs)
        tensor, _ = saved.policy.obs_to_tensor(obs)
        with torch.no_grad():
            expected = saved.policy.get_distribution(tensor).distribution.logits.argmax()
        assert int(action) == int(expected)
        env.step(action)
    finally:
        env.close()


def test_the_command_line_switches_it_on() -> None:
    from branch_gym.training.cli import build_parser, config_from_args

    parser = build_parser()
    on = config_from_args(parser.parse_args(["--out", "run", "--privileged-critic"]))
    off = config_from_args(parser.parse_args(["--out", "run"]))
    assert on.privileged_critic and not off.privileged_critic
