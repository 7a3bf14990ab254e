"""RecordVideo records the env's rgb_array frames (camera image with overlays) to an MP4."""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
from gymnasium.wrappers import RecordVideo

import branch_gym  # noqa: F401  (registers the ids)


def test_record_video_writes_an_episode(tmp_path: Path) -> None:
    env = gymnasium.make(
        "BranchScan-v0", render_mode="rgb_array", tracker="oracle", end_height_m=0.32
    )
    env = RecordVideo(
        env, str(tmp_path / "videos"), episode_trigger=lambda _: True, disable_logger=True
    )
    env.reset(seed=0)
    frame_shape = env.render().shape
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.array([0.0], np.float32))
        done = terminated or truncated
    env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000
    assert frame_shape[2] == 3 and frame_shape[0] >= 240
