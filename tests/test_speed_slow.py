"""Slow checks of issue 14: fast vs reference paths on 10 trees; memory over 300 episodes."""

from __future__ import annotations

import gc
import os

import gymnasium
import pytest

import branch_gym
from bench.action_mix import FixedActionMix
from branch_gym.scan import reference_scan_config, training_scan_config

pytestmark = pytest.mark.slow

EQUIVALENCE_SEEDS = tuple(range(10))
PB_TOLERANCE_M = 1e-4  # issue 14: PB residual within 0.1 mm
MEMORY_EPISODES = 300
MEMORY_LIMIT_MB = 50.0  # issue 14
MEMORY_WARMUP_EPISODES = 5
MEMORY_END_HEIGHT_M = 0.30  # short random-action episodes: ~4 steps each (our choice: CI time)


def _final(scan, score_cache: bool, seed: int) -> dict:
    env = FixedActionMix(gymnasium.make(branch_gym.ENV_ID_V0, scan=scan, score_cache=score_cache))
    env.reset(seed=seed)
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(None)
        done = terminated or truncated
    env.close()
    return info["final_metrics"] if "final_metrics" in info else info["metrics"]


@pytest.mark.parametrize("seed", EQUIVALENCE_SEEDS)
def test_fast_paths_keep_the_final_metrics(seed):
    fast_scan = training_scan_config()
    fast = _final(fast_scan, True, seed)
    reference = _final(reference_scan_config(fast_scan), False, seed)
    assert fast["matches"] == reference["matches"]
    assert fast["n_spurious"] == reference["n_spurious"]
    assert fast["n_duplicates"] == reference["n_duplicates"]
    pb_fast, pb_ref = fast["pb_residual_mean_m"], reference["pb_residual_mean_m"]
    assert (pb_fast is None) == (pb_ref is None)
    if pb_ref is not None:
        assert abs(pb_fast - pb_ref) <= PB_TOLERANCE_M


def _rss_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="needs /proc")
def test_random_episodes_do_not_grow_memory():
    env = gymnasium.make(
        branch_gym.ENV_ID_V0,
        tracker="oracle",
        render_tracking_frames=False,
        end_height_m=MEMORY_END_HEIGHT_M,
    )
    env.action_space.seed(0)

    def episodes(n: int, first_seed: int) -> None:
        for seed in range(first_seed, first_seed + n):
            env.reset(seed=seed)
            done = False
            while not done:
                _, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated

    episodes(MEMORY_WARMUP_EPISODES, 10_000)
    gc.collect()
    before = _rss_mb()
    episodes(MEMORY_EPISODES, 0)
    gc.collect()
    grown = _rss_mb() - before
    env.close()
    assert grown < MEMORY_LIMIT_MB, f"RSS grew {grown:.1f} MB over {MEMORY_EPISODES} episodes"
