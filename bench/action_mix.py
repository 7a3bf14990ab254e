"""A fixed action mix for throughput measurements: the paper's rotation cycle on a schedule.

Training throughput depends on how often the policy rotates (a rotation step costs ~8x a plain
one). :class:`FixedActionMix` replaces whatever action the learner sends by a fixed schedule, so
that a throughput figure (``bench/bench_train.py``: ``train_steps_per_s_fast``) does not depend on
an untrained policy's whims; the single-core env rate it is compared with
(``bench/bench_train.py``: ``env_steps_per_s_train_trees``, the same trees) plays the same
schedule.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

# Our choice (issue "An environment fast enough to learn in"): one rotation every 10 steps, along
# the paper's cycle 0, +theta, 0, -theta with its smaller angle (Table I: 22.5 deg).
MIX_STEPS_PER_ROTATION = 10
MIX_CYCLE_DEG = (0.0, 22.5, 0.0, -22.5)


def mix_angle_deg(step: int) -> float:
    """Target angle (deg) of episode step ``step`` (0-based) in the fixed mix."""
    return MIX_CYCLE_DEG[(step // MIX_STEPS_PER_ROTATION) % len(MIX_CYCLE_DEG)]


class FixedActionMix(gym.Wrapper):
    """Plays :func:`mix_angle_deg` in a continuous-action ``BranchScan`` env, whatever the action.

    Each block of :data:`MIX_STEPS_PER_ROTATION` steps holds the next angle of
    :data:`MIX_CYCLE_DEG` (the first block 0 deg): one rotation every 10 steps.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._theta_max_deg = float(env.unwrapped.config.theta_max_deg)
        self._step = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._step = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        angle = mix_angle_deg(self._step)
        self._step += 1
        return self.env.step(np.array([angle / self._theta_max_deg], np.float32))
