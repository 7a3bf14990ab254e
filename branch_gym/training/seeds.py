"""Tree seeds of training and evaluation: three disjoint ranges, so no tree is seen twice.

Every episode scans one procedural tree, fully determined by its seed. The ranges:

==============================  =====================================  =========================
range                           tree seeds                             used by
==============================  =====================================  =========================
benchmark trees                 ``[0, EVAL_SEED_BASE)``                ``eval.py`` (``--seed 0``
                                                                       ``--trees 60``: 0 .. 59)
held-out evaluation trees       ``EVAL_SEED_BASE + i``,                the evaluation during
                                ``0 <= i < MAX_EVAL_TREES``            training (fixed: the same
                                                                       trees every evaluation)
training trees                  ``TRAIN_SEED_BASE + seed *             the training envs of a run
                                SEEDS_PER_RUN + episode * n_envs +     with ``--seed seed``
                                rank``
==============================  =====================================  =========================

Training trees never overlap the evaluation trees (``MAX_EVAL_TREES`` < ``TRAIN_SEED_BASE -
EVAL_SEED_BASE``), nor the benchmark trees that ``eval.py`` compares policies on, nor the trees
of another training seed (each run seed owns ``SEEDS_PER_RUN`` seeds; env ``rank`` of ``n_envs``
takes every ``n_envs``-th). All of them stay below 2**31 - 1, the env's own seed bound.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

# Our choice: far above any eval.py benchmark (--seed 0 --trees 60 uses 0 .. 59).
EVAL_SEED_BASE = 10_000_000
MAX_EVAL_TREES = 1_000  # our choice: evaluations of more trees belong in eval.py
# Our choice: a run of 1M episodes (>= 6M steps, months at ~10 steps/s) never exhausts its range.
SEEDS_PER_RUN = 1_000_000
TRAIN_SEED_BASE = 100_000_000
MAX_RUN_SEEDS = 1_000  # run seeds 0 .. 999: the last training tree is 1_099_999_999 < 2**31 - 1


def eval_tree_seeds(n_trees: int) -> list[int]:
    """The held-out evaluation trees: the same ``n_trees`` seeds at every evaluation.

    Raises:
        ValueError: ``n_trees`` outside ``[1, MAX_EVAL_TREES]``.
    """
    if not 1 <= n_trees <= MAX_EVAL_TREES:
        raise ValueError(f"n_trees must be in [1, {MAX_EVAL_TREES}], got {n_trees}")
    return [EVAL_SEED_BASE + i for i in range(n_trees)]


def train_tree_seed(seed: int, rank: int, n_envs: int, episode: int) -> int:
    """The tree of training episode ``episode`` of env ``rank`` (of ``n_envs``) in run ``seed``.

    Raises:
        ValueError: an argument out of range (named), or the run's seed range is exhausted.
    """
    if not 0 <= seed < MAX_RUN_SEEDS:
        raise ValueError(f"seed must be in [0, {MAX_RUN_SEEDS}), got {seed}")
    if not 0 <= rank < n_envs:
        raise ValueError(f"rank must be in [0, n_envs={n_envs}), got {rank}")
    if episode < 0:
        raise ValueError(f"episode must be >= 0, got {episode}")
    index = episode * n_envs + rank
    if index >= SEEDS_PER_RUN:
        raise ValueError(
            f"episode {episode} of env {rank}/{n_envs} exhausts the run's {SEEDS_PER_RUN} "
            "tree seeds"
        )
    return TRAIN_SEED_BASE + seed * SEEDS_PER_RUN + index


def train_seed_range(seed: int) -> range:
    """All training tree seeds of run ``seed`` (whatever ``n_envs``)."""
    start = train_tree_seed(seed, 0, 1, 0)
    return range(start, start + SEEDS_PER_RUN)


class TreeSeedWrapper(gym.Wrapper):
    """Scans training tree ``train_tree_seed(seed, rank, n_envs, episode)`` at every reset.

    The seed a vector env passes to ``reset`` is ignored: the tree sequence depends only on the
    run seed, the env's rank and the episode count, which a resumed run restores
    (:meth:`set_episodes`) so that it goes on with new trees.

    Args:
        env: A ``BranchScan`` environment.
        seed: The run seed.
        rank: This env's index among ``n_envs``.
        n_envs: Parallel training envs.
    """

    def __init__(self, env: gym.Env, seed: int, rank: int, n_envs: int) -> None:
        super().__init__(env)
        train_tree_seed(seed, rank, n_envs, 0)  # validates the arguments
        self.run_seed, self.rank, self.n_envs = seed, rank, n_envs
        self.episodes = 0  # episodes started so far

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        tree_seed = train_tree_seed(self.run_seed, self.rank, self.n_envs, self.episodes)
        self.episodes += 1
        return self.env.reset(seed=tree_seed, options=options)

    def set_episodes(self, episodes: int) -> None:
        """Continue the tree sequence after ``episodes`` started episodes (resume)."""
        if episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {episodes}")
        self.episodes = int(episodes)
