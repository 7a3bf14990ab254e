"""The price of scan time is an input: one shipped network rotates more when branches are dear."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import branch_gym  # noqa: F401  (registers the env ids)
from agents.ppo import resolve_model_path
from branch_gym.env.layout import PRICE_KEY
from branch_gym.evaluation.episodes import run_episode
from branch_gym.privileged import PrivilegedAgent
from branch_gym.training.imitation.data import RoundData
from branch_gym.training.imitation.fit import action_probabilities
from branch_gym.training.imitation.labels import LabellingAgent
from branch_gym.training.model_files import load_model

# Shipped price-conditioned students: the env id they act in and the world they were trained in.
PRICED_POLICIES = {
    "ppo_dagger_priced": ("BranchScanDiscrete-v1", {}),
    "ppo_ctg_orchard": ("BranchScanDiscrete-v2", {"world": "orchard", "segmenter": "learned"}),
}


@pytest.mark.parametrize("name", sorted(PRICED_POLICIES))
def test_the_price_input_changes_the_rotation_rate(name):
    env_id, world = PRICED_POLICIES[name]
    env = gym.make(
        env_id, tracker="oracle", render_tracking_frames=False, end_height_m=0.6, **world
    )
    try:
        recorder = LabellingAgent(PrivilegedAgent.for_env(env))  # the expert's states
        for seed in (1, 2, 3):
            run_episode(recorder, env, seed)
    finally:
        env.close()
    data = recorder.round_data()
    model = load_model(resolve_model_path(name))
    index = np.arange(len(data.expert_actions))
    rotate_probability, rotate_rate = [], []
    for price in (0.0, 0.5, 1.0):  # the observation's price: 25, 100, 400 s a branch
        observations = {key: value.copy() for key, value in data.observations.items()}
        observations[PRICE_KEY][:] = price
        probabilities = action_probabilities(
            model, RoundData(observations, data.expert_actions), index, len(index)
        )
        rotate_probability.append(float(np.mean(1.0 - probabilities[:, 0])))
        rotate_rate.append(float(np.mean(probabilities.argmax(axis=1) != 0)))
    assert rotate_probability[0] < rotate_probability[1] < rotate_probability[2]
    assert rotate_rate[2] > rotate_rate[0]
