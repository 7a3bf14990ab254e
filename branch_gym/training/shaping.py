"""Potential-based reward shaping for training: a turn that shows a pending branch pays at once.

The env pays a found side branch when the model matches it, steps after the turn that showed it,
while the turn's time is charged at once; fine-tuned with PPO, the orchard student learned to
turn less even at prices where its turns pay (``research/records/ppo_ft_orchard_v2g``).
:class:`ViewShapingWrapper` adds ``F = gamma * phi(s') - phi(s)`` to every reward, with the
potential ``phi(s) = weight x`` (scored side branches in the view band, unmatched, that the
current view shows well: their line at least ``good_view_deg`` from the optical axis, the
privileged bound's test, :class:`branch_gym.privileged.PrivilegedConfig`), read from the
simulator's ground truth as the privileged state is
(:func:`~branch_gym.training.privileged_state.scored_branch_groups`). A turn that brings such a
branch into a good view earns ``weight`` at that step; matching it, or leaving it behind unmatched,
takes the ``weight`` back. ``phi`` is 0 after the last step of a terminated scan, so the shaping
sums to ``-phi(s_0)`` over an episode, discounted: by Ng, Harada and Russell (1999, "Policy
invariance under reward transformations") the optimal policies are the env's own; what changes is
how soon the learner hears about a turn's worth.

Training only (the ground truth): the evaluation and every benchmark score the env's own reward.
The shaping sits outside the ``Monitor`` (:func:`branch_gym.training.envs.make_env`), so the
training curve's returns are the env's; ``info["reward_terms"]["view_shaping"]`` holds ``F``.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym

from branch_gym.privileged import PrivilegedConfig
from branch_gym.sim.validation import require_positive
from branch_gym.training.privileged_state import matched_branches, scored_branch_groups

SHAPING_TERM = "view_shaping"


def view_potential(
    session: Any,
    matched: set[int],
    weight: float,
    good_view_deg: float = PrivilegedConfig().good_view_deg,
    view_band_fov: float = PrivilegedConfig().view_band_fov,
) -> float:
    """``weight`` x the unmatched scored side branches in view that the current view shows well.

    Args:
        session: A reset :class:`branch_gym.scan.ScanSession`.
        matched: Indices into ``session.tree.secondaries`` of the matched branches.
        weight: Reward units a well-shown pending branch is worth.
        good_view_deg: A branch line at least this far from the optical axis is well in view (deg).
        view_band_fov: Half-height of the view band in vertical FoVs.
    """
    _, pending = scored_branch_groups(session, matched, view_band_fov)
    good_rad = math.radians(good_view_deg)
    return weight * sum(1 for folded, _, _ in pending if folded >= good_rad)


class ViewShapingWrapper(gym.Wrapper):
    """Adds ``gamma * phi(s') - phi(s)`` to a single ``BranchScan`` env's reward (module docstring).

    Args:
        env: A single (possibly wrapped) ``BranchScan`` env.
        weight: Reward units a well-shown pending branch is worth (> 0).
        gamma: The learner's discount (PPO's ``gamma``): the shaping preserves the optimal
            policies of that discount only.

    Raises:
        ValueError: a weight that is not positive, a discount outside (0, 1], or an env without a
            scan session.
    """

    def __init__(self, env: gym.Env, weight: float, gamma: float) -> None:
        super().__init__(env)
        self.weight = weight
        self.gamma = gamma
        require_positive(self, "weight")
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"ViewShapingWrapper.gamma must be in (0, 1], got {gamma}")
        if getattr(env.unwrapped, "session", None) is None:
            raise ValueError(f"ViewShapingWrapper needs a BranchScan env, got {env!r}")
        self._potential = 0.0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._potential = self._potential_of(info)
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        # A terminated scan's last state is worth nothing more; a truncated one goes on.
        potential = 0.0 if terminated else self._potential_of(info)
        shaping = self.gamma * potential - self._potential
        self._potential = potential
        info = {**info, "reward_terms": {**info.get("reward_terms", {}), SHAPING_TERM: shaping}}
        return obs, float(reward) + shaping, terminated, truncated, info

    def _potential_of(self, info: dict[str, Any]) -> float:
        return view_potential(self.env.unwrapped.session, matched_branches(info), self.weight)
