"""The privileged policy's choice of angle, and its actions in every action space."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import branch_gym  # noqa: F401  (registers the env ids)
from branch_gym.env.layout import DISCRETE_ANGLES_DEG
from branch_gym.privileged import PrivilegedAgent, choose_angle_deg

GOOD_DEG = 45.0


def headings(*degrees: float) -> np.ndarray:
    return np.radians(np.array(degrees, float))


def test_it_holds_with_nothing_pending_or_everything_well_in_view():
    assert choose_angle_deg(headings(), 22.5, DISCRETE_ANGLES_DEG, GOOD_DEG) == 22.5
    assert choose_angle_deg(headings(80.0, -60.0), 0.0, DISCRETE_ANGLES_DEG, GOOD_DEG) == 0.0


def test_it_takes_the_nearest_angle_that_shows_the_branch_well():
    # A branch 49 deg off the home axis, seen from 22.5 deg at 26.5 deg: 0 deg already shows it
    # at 49 deg, nearer than -45 deg (94 deg, the best view).
    assert choose_angle_deg(headings(49.0), 22.5, DISCRETE_ANGLES_DEG, GOOD_DEG) == 0.0
    # A branch pointing at the lens (heading ~0): +-45 deg both show it at 45 deg; the nearer.
    assert choose_angle_deg(headings(-9.0), 0.0, DISCRETE_ANGLES_DEG, GOOD_DEG) == 45.0
    assert choose_angle_deg(headings(-9.0), -22.5, DISCRETE_ANGLES_DEG, GOOD_DEG) == 45.0


def test_where_no_angle_shows_all_it_maximises_the_worst_view():
    # Branches at 0 and +-30 deg: every candidate leaves one within 45 deg of the axis; +-45
    # show the worst one at 15 deg, the best there is, and 45 is the nearer from 40.
    spread = headings(0.0, 30.0, -30.0)
    assert choose_angle_deg(spread, 40.0, DISCRETE_ANGLES_DEG, GOOD_DEG) == 45.0
    assert choose_angle_deg(spread, -30.0, DISCRETE_ANGLES_DEG, GOOD_DEG) == -45.0
    # Already at the best of them: hold.
    assert choose_angle_deg(spread, 45.0, DISCRETE_ANGLES_DEG, GOOD_DEG) == 45.0


def test_in_the_v1_env_action_zero_holds_and_every_rotation_reaches_its_angle():
    """The v1 discrete env's action k >= 1 targets angle k - 1: no off-by-one."""
    env = gym.make(
        "BranchScanDiscrete-v1", tracker="oracle", render_tracking_frames=False, end_height_m=0.5
    )
    agent = PrivilegedAgent.for_env(env)
    assert agent.hold_action
    session = env.unwrapped.session
    rotations = 0
    for seed in range(3):
        observation, _ = env.reset(seed=100_000_000 + seed)
        done = False
        while not done:
            wanted = agent.target_angle_deg()
            action, _ = agent.predict(observation)
            before = session.angle_deg
            observation, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
            if int(action) == 0:
                assert session.angle_deg == pytest.approx(before)
            else:
                rotations += 1
                assert DISCRETE_ANGLES_DEG[int(action) - 1] == pytest.approx(wanted)
                assert session.angle_deg == pytest.approx(wanted, abs=1.0)
    env.close()
    assert rotations >= 1


def test_the_home_expert_turns_back_once_nothing_is_pending_and_the_bound_holds():
    """``privileged:home`` returns to 0 when no branch waits; ``privileged`` stays turned."""
    from agents.factory import check_spec, make_agent

    env = gym.make(
        "BranchScanDiscrete-v2", tracker="oracle", render_tracking_frames=False, end_height_m=0.5
    )
    env.reset(seed=100_000_000)
    session = env.unwrapped.session
    env.step(DISCRETE_ANGLES_DEG.index(22.5) + 1)  # turn to 22.5 deg
    assert session.angle_deg == pytest.approx(22.5, abs=1.0)
    check_spec("privileged:home")
    home, bound = make_agent("privileged:home", env), make_agent("privileged", env)
    assert home.config.return_home and not bound.config.return_home
    for agent in (home, bound):
        agent._pending_directions_rad = lambda: np.zeros(0)  # nothing waits in view
    assert home.target_angle_deg() == 0.0
    assert bound.target_angle_deg() == pytest.approx(session.angle_deg)
    # A branch pointing at the lens still pulls the home expert away from 0.
    home._pending_directions_rad = lambda: headings(-9.0)
    assert home.target_angle_deg() == 45.0
    env.close()
    with pytest.raises(ValueError, match="privileged"):
        check_spec("privileged:away")
