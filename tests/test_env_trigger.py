"""The trigger action (``BranchScanTrigger-v0``) and the fast oracle mode (pose-only frames).

Short scans with the depth-oracle tracker and small angles, as in tests/test_env.py.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
import pytest

import branch_gym
from agents.baselines import PeriodicAgent
from branch_gym.env.actions import ActionCodec
from branch_gym.env.layout import DISCRETE_ANGLES_DEG, TRIGGER_ANGLES_DEG
from branch_gym.scan import ScanConfig, ScanSession
from branch_gym.scoring import score_scan
from recon.camera import CameraIntrinsics
from recon.frame import Frame
from recon.tracking.depth_oracle import DepthOracleTracker
from recon.tracking.lucas_kanade import LucasKanadeTracker

SHORT = {
    "tracker": "oracle",
    "end_height_m": 0.33,
    "theta_max_deg": 4.0,
    "trigger_angles_deg": (2.0, 4.0),
}
# Rotate by 4 deg every 0.1 vertical FoV (~11 mm): about every other step of a short scan.
PERIODIC = (4.0, 10.0)


def test_trigger_codec_walks_the_papers_cycle() -> None:
    codec = ActionCodec("trigger", 45.0, DISCRETE_ANGLES_DEG, TRIGGER_ANGLES_DEG)
    assert codec.space == gymnasium.spaces.Discrete(3)
    assert codec.to_angle_deg(0, current_angle_deg=0.0) == 0.0  # hold
    assert codec.to_angle_deg(2, current_angle_deg=0.0) == 45.0  # +theta first
    assert codec.to_angle_deg(0, current_angle_deg=45.0) == 45.0  # hold the rotated view
    assert codec.to_angle_deg(1, current_angle_deg=45.0) == 0.0  # any trigger: back to 0
    assert codec.to_angle_deg(1, current_angle_deg=0.0) == -22.5  # then the other side
    assert codec.to_angle_deg(np.int64(2), current_angle_deg=-22.5) == 0.0
    assert codec.to_angle_deg(np.array([2]), current_angle_deg=0.0) == 45.0
    codec.reset()
    assert codec.to_angle_deg(1, current_angle_deg=0.0) == 22.5  # a new episode starts at +
    for bad, match in ((3, "out of range"), (-1, "out of range"), (1.0, "integer")):
        with pytest.raises(ValueError, match=match):
            codec.to_angle_deg(bad)


def test_trigger_angles_are_validated_for_trigger_envs() -> None:
    with pytest.raises(ValueError, match="trigger_angles_deg"):
        gymnasium.make(branch_gym.TRIGGER_ENV_ID, theta_max_deg=30.0)  # 45 > 30
    with pytest.raises(ValueError, match="trigger_angles_deg"):
        gymnasium.make(branch_gym.TRIGGER_ENV_ID, trigger_angles_deg=(0.0,))
    gymnasium.make(branch_gym.ENV_ID_V0, theta_max_deg=30.0).close()  # not a trigger env: fine


def test_periodic_agent_in_the_trigger_env_makes_the_same_scan() -> None:
    """The paper's controller expressed as triggers rotates exactly as with target angles."""
    results = {}
    for env_id in (branch_gym.ENV_ID_V0, branch_gym.TRIGGER_ENV_ID):
        env = gymnasium.make(env_id, **SHORT)
        agent = PeriodicAgent.for_env(env, *PERIODIC)
        obs, _ = env.reset(seed=4)
        angles, done = [], False
        while not done:
            action, _ = agent.predict(obs)
            obs, _, terminated, truncated, info = env.step(action)
            angles.append(info["angle_deg"])
            done = terminated or truncated
        result = env.unwrapped.result()
        results[env_id] = (np.round(angles, 6), result)
        env.close()
    (angles_a, a), (angles_b, b) = results.values()
    assert a.rotations >= 2, "the short scan must rotate there and back"
    np.testing.assert_array_equal(angles_a, angles_b)
    assert (a.rotations, a.scan_time_s, a.n_iterations) == (
        b.rotations,
        b.scan_time_s,
        b.n_iterations,
    )
    np.testing.assert_allclose(a.model.primary.points, b.model.primary.points)


def test_first_action_logit_starts_ppo_holding(tmp_path: Path) -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv

    from branch_gym.training.config import PPOConfig, TrainConfig
    from branch_gym.training.paths import RunPaths
    from branch_gym.training.train import new_model

    venv = DummyVecEnv([lambda: gymnasium.make(branch_gym.TRIGGER_ENV_ID, tracker="oracle")])
    probabilities = {}
    for bonus in (0.0, 3.0):
        ppo = PPOConfig(n_steps=64, first_action_logit_init=bonus)
        config = TrainConfig(env_id=branch_gym.TRIGGER_ENV_ID, tracker="oracle", ppo=ppo)
        model = new_model(config, venv, str(RunPaths(tmp_path / f"run{bonus}").tensorboard))
        obs = venv.reset()
        tensor, _ = model.policy.obs_to_tensor(obs)
        probabilities[bonus] = model.policy.get_distribution(tensor).distribution.probs[0]
    venv.close()
    np.testing.assert_allclose(probabilities[0.0].detach().numpy(), 1 / 3, atol=0.02)
    hold = float(probabilities[3.0][0].detach())
    assert abs(hold - np.exp(3) / (np.exp(3) + 2)) < 0.02


# ---------------------------------------------------------------------- pose-only frames
def test_pose_only_frames_give_the_same_scan_with_fewer_renders() -> None:
    results, renders = {}, {}
    for render_all in (True, False):
        config = ScanConfig(tracker="oracle", end_height_m=0.34, render_tracking_frames=render_all)
        session = ScanSession(config)
        count = [0]
        render = session.world.render

        def counting_render(render=render, count=count):
            count[0] += 1
            return render()

        session.world.render = counting_render
        session.reset(7)
        while not session.done:
            session.step(0.0)
        results[render_all], renders[render_all] = score_scan(session), count[0]
        session.close()
    full, fast = results[True], results[False]
    assert fast.n_iterations == full.n_iterations > 3
    np.testing.assert_allclose(fast.model.primary.points, full.model.primary.points, atol=1e-9)
    np.testing.assert_equal(fast.metrics.to_dict(), full.metrics.to_dict())  # NaN == NaN
    # One render per iteration (plus the first frame) instead of one per ~1 mm of travel.
    assert renders[False] <= full.n_iterations + 2 < renders[True] / 4


def test_pose_only_frames_are_refused_where_images_or_depth_are_needed() -> None:
    with pytest.raises(ValueError, match="render_tracking_frames=False needs tracker='oracle'"):
        ScanConfig(tracker="lk", render_tracking_frames=False)
    intrinsics = CameraIntrinsics.from_fov(64, 48, 60.0)
    T = np.eye(4)
    pose_only = Frame.pose_only(T, intrinsics)
    assert not pose_only.has_image and pose_only.depth_m is None
    full = Frame(
        np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), bool), T, intrinsics,
        depth_m=np.full((48, 64), 0.2),
    )  # fmt: skip
    query = np.array([[32.0, 24.0]])
    with pytest.raises(ValueError, match="pose-only"):
        LucasKanadeTracker().track([pose_only, full], query)
    with pytest.raises(ValueError, match="frame 1 has no depth_m"):
        DepthOracleTracker().track([full, pose_only], query)
    tracks = DepthOracleTracker().track([pose_only, full], query)  # older pose-only: fine
    np.testing.assert_allclose(tracks.pixels[0], query)
