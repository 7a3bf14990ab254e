"""The fast paths of issue 14 against their reference paths (and the fixed action mix)."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import branch_gym
from bench.action_mix import MIX_STEPS_PER_ROTATION, FixedActionMix, mix_angle_deg
from branch_gym.env.score_cache import ScoreCache
from branch_gym.scan import ScanSession, reference_scan_config, training_scan_config
from branch_gym.sim.robot.config import RobotConfig
from branch_gym.sim.robot.motion import CameraMotion, manipulability
from branch_gym.sim.world import World
from recon.metrics import evaluate

SHORT_END_M = 0.36  # a few iterations past the first rotation of the mix (our choice)
MIX_PLAN_DEG = (0.0, 0.0, 22.5, 22.5, 0.0, -22.5)


@pytest.fixture(scope="module")
def world():
    world = World()
    world.reset(0)
    yield world
    world.close()


def test_direct_solve_matches_svd(world):
    robot = world.robot
    rng = np.random.default_rng(0)
    fast = CameraMotion(RobotConfig(), 1.0, lambda: None, robot._world_jacobian, lambda *a: None)
    slow = CameraMotion(
        RobotConfig(dls_direct_solve=False), 1.0, lambda: None, robot._world_jacobian, None
    )
    R = world.T_world_camera[:3, :3]
    for _ in range(20):
        q = robot.q + rng.normal(0.0, 0.05, 6)
        J = robot._world_jacobian(q)
        twist = rng.normal(0.0, 0.03, 6)
        q_fast, m_fast = fast._joint_rates(J, R, twist)
        q_slow, m_slow = slow._joint_rates(J, R, twist)
        np.testing.assert_allclose(q_fast, q_slow, rtol=0, atol=1e-12)
        assert m_fast is None  # the direct solve leaves |det J| to the step (cached there)
        assert manipulability(J) == pytest.approx(m_slow, rel=1e-10)


def test_motion_bounds_are_conservative(world):
    robot = world.robot
    p = world.bullet.p
    rng = np.random.default_rng(1)
    links = robot._all_links[1:]
    q0 = robot.q

    def corners():
        boxes = [np.array(p.getAABB(robot.body_id, link)) for link in links]
        return np.array([box.ravel() for box in boxes])

    c0 = corners()
    try:
        for _ in range(20):
            dq = rng.normal(0.0, 0.02, 6)
            robot.set_joint_positions(q0 + dq)
            moved = np.abs(corners() - c0).reshape(len(links), 2, 3).max(axis=(1, 2))
            bound = robot._motion_bounds[: len(links)] @ np.abs(dq)
            assert np.all(moved <= bound + 1e-9)
    finally:
        robot.set_joint_positions(q0)


def test_contact_skipping_keeps_the_trajectory():
    config = training_scan_config().replace(end_height_m=SHORT_END_M)
    poses = {}
    for name, cfg in (("fast", config), ("reference", reference_scan_config(config))):
        session = ScanSession(cfg)
        session.reset(3)
        path = []
        k = 0
        while not session.done:
            session.step(MIX_PLAN_DEG[min(k, len(MIX_PLAN_DEG) - 1)])
            path.append(session.world.T_world_camera.copy())
            k += 1
        poses[name] = np.array(path)
        session.close()
    assert poses["fast"].shape == poses["reference"].shape
    np.testing.assert_allclose(poses["fast"], poses["reference"], rtol=0, atol=1e-9)


def test_score_cache_equals_fresh_scores():
    env = gymnasium.make(
        branch_gym.ENV_ID_V0, tracker="oracle", render_tracking_frames=False, end_height_m=0.4
    )
    env = FixedActionMix(env)
    cache = ScoreCache()
    env.reset(seed=5)
    session = env.unwrapped.session
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(None)
        done = terminated or truncated
        cached = cache.score(session.model, session.tree, session.camera_height_m)
        fresh = evaluate(session.model, session.tree, scanned_top_z_m=session.camera_height_m)
        assert cached.to_dict() == fresh.to_dict() or (
            str(cached.to_dict()) == str(fresh.to_dict())  # NaN != NaN
        )
    assert cache.evaluations <= len(session.reports) + 1
    env.close()


def test_action_mix_rotates_every_block():
    angles = [mix_angle_deg(k) for k in range(4 * MIX_STEPS_PER_ROTATION)]
    changes = [k for k in range(1, len(angles)) if angles[k] != angles[k - 1]]
    assert angles[0] == 0.0
    assert changes == [MIX_STEPS_PER_ROTATION * i for i in (1, 2, 3)]


def test_bench_ratios_come_from_figures_of_the_same_run():
    from bench.run import derived_figures

    measured = {
        "train_steps_per_s_fast": 45.0,
        "train_steps_per_s_fast_lockstep": 30.0,
        "env_steps_per_s_train_trees": 25.0,
        "env_steps_per_s_side_by_side": 40.0,
        "env_steps_per_s_mix": 30.0,
    }
    assert derived_figures(measured) == pytest.approx(
        {
            "train_over_env_fast": 0.9,
            "train_over_env_fast_lockstep": 0.6,
            "env_parallel_efficiency": 0.8,
            "train_over_side_by_side": 1.125,
            "train_over_env_fast_mix_seeds": 0.75,
        }
    )
    assert derived_figures({"train_steps_per_s_fast": 45.0}) == {}  # no env figure this run
