"""Training at a sub-range of prices: each episode's branch value drawn from a narrower range.

A priced env (``BranchScan*-v1`` and later) draws its episode's branch value (seconds of scan
time a found side branch is worth) log-uniformly over its whole ``branch_value_s`` range, and its
observation reads the price against that range. :class:`PriceRangeWrapper` draws it instead from
a sub-range and passes it as ``reset(options={"branch_value_s": v})``: the observation's price
keeps its meaning, while the training episodes see only (say) the dear prices, where turning the
camera pays (issue 63: fine-tuned over the whole range, PPO learned never to turn).

The draw depends only on the reset's seed (the tree, :class:`~branch_gym.training.seeds.
TreeSeedWrapper` outside this wrapper), so a resumed run draws the same prices for the same trees.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from branch_gym.env.config import draw_branch_value_s, price_range

# Keeps the price stream apart from every other stream seeded by a tree seed.
PRICE_STREAM = 0x9A1CE


def tree_branch_value_s(tree_seed: int, bounds_s: tuple[float, float]) -> float:
    """The price of the episode on tree ``tree_seed``: log-uniform on ``bounds_s`` seconds."""
    return draw_branch_value_s(np.random.default_rng([int(tree_seed), PRICE_STREAM]), bounds_s)


class PriceRangeWrapper(gym.Wrapper):
    """Resets a priced env with a branch value drawn from ``branch_value_s`` (low, high) seconds.

    The range must lie within the env's own ``branch_value_s`` range (the env raises otherwise,
    at the first reset). A reset whose options already fix ``branch_value_s`` keeps it.

    Args:
        env: A priced ``BranchScan`` env.
        branch_value_s: (low, high) seconds a found side branch is worth.

    Raises:
        ValueError: a bad range, or (at reset) no seed to draw the price from.
    """

    def __init__(self, env: gym.Env, branch_value_s: tuple[float, float]) -> None:
        super().__init__(env)
        self.branch_value_s = price_range(branch_value_s)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        options = dict(options or {})
        if "branch_value_s" not in options:
            if seed is None:
                raise ValueError(
                    "PriceRangeWrapper draws the price from the reset's tree seed: reset(seed=...)"
                )
            options["branch_value_s"] = tree_branch_value_s(seed, self.branch_value_s)
        return self.env.reset(seed=seed, options=options)
