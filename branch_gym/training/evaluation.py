"""Evaluation on held-out trees during training, keeping the best model.

Every ``eval_every`` steps the current policy scans the same ``eval_trees`` held-out trees
(:func:`branch_gym.training.seeds.eval_tree_seeds`, never used for training) deterministically,
in an env of this process with the training settings. Logged under ``eval/``: the mean return,
missed %, spurious %, scan time, rotations and failures; one JSON line per evaluation in
``evaluations.jsonl``; ``best_model.zip`` whenever the mean return is the best so far.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from branch_gym.env.info import final_metrics
from branch_gym.evaluation.episodes import evaluate_policy
from branch_gym.policy import Policy
from branch_gym.training.callbacks import scan_metrics
from branch_gym.training.checkpoints import save_model
from branch_gym.training.model_files import PolicyAgent
from branch_gym.training.paths import RunPaths

logger = logging.getLogger(__name__)

EVAL_PREFIX = "eval/"


@dataclass(frozen=True)
class EvalResult:
    """One evaluation: means over the held-out trees (NaN when no tree defines a metric).

    Attributes:
        num_timesteps: Training steps when evaluated.
        mean_reward: Mean episode return.
        missed_pct: Mean missed secondaries (%).
        spurious_pct: Mean spurious secondaries (%).
        scan_time_s: Mean scan time (s).
        rotations: Mean rotations per scan.
        failed: Fraction of failed scans.
        episodes: Trees evaluated.
    """

    num_timesteps: int
    mean_reward: float
    missed_pct: float
    spurious_pct: float
    scan_time_s: float
    rotations: float
    failed: float
    episodes: int


def evaluate_policy_on_trees(
    agent: Policy, env: Any, tree_seeds: list[int], num_timesteps: int = 0
) -> EvalResult:
    """Play one deterministic episode per tree seed and average the scan metrics.

    Args:
        agent: Anything with SB3's ``predict`` (e.g. a
            :class:`~branch_gym.training.model_files.PolicyAgent`).
        env: A single ``BranchScan`` env (not vectorised).
        tree_seeds: The trees to scan.
        num_timesteps: Recorded in the result.
    """
    episodes = evaluate_policy(agent, env, tree_seeds)
    rows = [
        scan_metrics(final_metrics(episode.result, with_timings=False))
        if episode.terminated
        else {}
        for episode in episodes
    ]

    def mean(name: str) -> float:
        values = [row[name] for row in rows if name in row]
        return float(np.mean(values)) if values else math.nan

    return EvalResult(
        num_timesteps=int(num_timesteps),
        mean_reward=float(np.mean([episode.episode_return for episode in episodes])),
        missed_pct=mean("missed_pct"),
        spurious_pct=mean("spurious_pct"),
        scan_time_s=mean("scan_time_s"),
        rotations=mean("rotations"),
        failed=mean("failed"),
        episodes=len(tree_seeds),
    )


class HeldOutEvalCallback(BaseCallback):
    """Evaluate on the held-out trees every ``every`` steps; save the best model.

    Args:
        env: The evaluation env (:func:`branch_gym.training.envs.make_eval_env`).
        tree_seeds: The held-out trees.
        every: Steps between evaluations.
        paths: The run's files (``best_model.zip``, ``evaluations.jsonl``).
        best_mean_reward: The best mean return of earlier evaluations (resumed runs).
    """

    def __init__(
        self,
        env: Any,
        tree_seeds: list[int],
        every: int,
        paths: RunPaths,
        best_mean_reward: float | None = None,
    ) -> None:
        super().__init__()
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.env, self.tree_seeds, self.every, self.paths = env, tree_seeds, every, paths
        self.best_mean_reward = best_mean_reward
        self.results: list[EvalResult] = []
        self._last = 0

    def _on_training_start(self) -> None:
        self._last = self.num_timesteps

    def _on_step(self) -> bool:
        if self.num_timesteps // self.every > self._last // self.every:
            self._last = self.num_timesteps
            self.evaluate()
        return True

    def evaluate(self) -> EvalResult:
        """Run one evaluation now, log it, keep the model if it is the best so far."""
        from stable_baselines3.common.vec_env import VecNormalize

        venv = self.training_env
        normalizer = venv if isinstance(venv, VecNormalize) else None
        agent = PolicyAgent(self.model, normalizer)
        result = evaluate_policy_on_trees(agent, self.env, self.tree_seeds, self.num_timesteps)
        self.results.append(result)
        for name, value in asdict(result).items():
            if name != "num_timesteps" and math.isfinite(value):
                self.logger.record(EVAL_PREFIX + name, value)
        with self.paths.evaluations.open("a") as handle:
            handle.write(json.dumps(_json_safe(asdict(result))) + "\n")
        if self.best_mean_reward is None or result.mean_reward > self.best_mean_reward:
            self.best_mean_reward = result.mean_reward
            save_model(self.model, venv, self.paths.best_model)
            logger.info("new best held-out mean reward %.3f", result.mean_reward)
        self.logger.dump(self.num_timesteps)
        return result


def _json_safe(row: dict[str, Any]) -> dict[str, Any]:
    """NaN -> None (strict JSON)."""
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()}
