"""Checkpoints: the model, its ``VecNormalize`` statistics and a small JSON, written atomically.

Every file is written to a temporary name and renamed into place, and ``checkpoint.json`` last:
a run killed while saving still has the previous checkpoint, so it loses at most one checkpoint
interval. ``checkpoint.json`` names the model file and holds what a resumed run needs besides
the model: ``num_timesteps``, the training envs' episode counts (their next trees) and the best
held-out reward so far.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from branch_gym.files import write_json_atomic
from branch_gym.training.envs import episode_counts
from branch_gym.training.model_files import normalizer_path
from branch_gym.training.paths import KEEP_CHECKPOINTS, RunPaths

logger = logging.getLogger(__name__)

_TMP = ".tmp"


class CheckpointError(ValueError):
    """``checkpoint.json`` is unreadable or incomplete."""


@dataclass(frozen=True)
class Checkpoint:
    """The contents of ``checkpoint.json``.

    Attributes:
        num_timesteps: Environment steps trained when saved.
        model: The model file, relative to the checkpoints folder.
        vecnormalize: Its ``VecNormalize`` statistics file (same folder), or None.
        episodes: Episodes started by each training env.
        best_mean_reward: Best mean held-out reward so far (None before any evaluation).
    """

    num_timesteps: int
    model: str
    vecnormalize: str | None
    episodes: list[int]
    best_mean_reward: float | None = None


def save_model(model: Any, venv: Any, path: Path) -> Path | None:
    """Save ``model`` (and the ``VecNormalize`` statistics of ``venv``, if any) atomically.

    Returns:
        The statistics file, or None when ``venv`` is not normalised.
    """
    from stable_baselines3.common.vec_env import VecNormalize

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + _TMP + path.suffix)  # SB3 appends .zip to other names
    model.save(tmp)
    os.replace(tmp, path)
    if not isinstance(venv, VecNormalize):
        return None
    stats = normalizer_path(path)
    stats_tmp = stats.with_name(stats.name + _TMP)
    venv.save(stats_tmp)
    os.replace(stats_tmp, stats)
    return stats


def write_checkpoint(
    model: Any, venv: Any, paths: RunPaths, best_mean_reward: float | None
) -> Checkpoint:
    """Save a checkpoint of the run at ``model.num_timesteps``; keep the latest few models."""
    model_path = paths.checkpoint_model(model.num_timesteps)
    stats = save_model(model, venv, model_path)
    checkpoint = Checkpoint(
        num_timesteps=int(model.num_timesteps),
        model=model_path.name,
        vecnormalize=None if stats is None else stats.name,
        episodes=episode_counts(venv),
        best_mean_reward=best_mean_reward,
    )
    write_json_atomic(paths.checkpoint, asdict(checkpoint), indent=2, sort_keys=True)
    _prune(paths, keep=KEEP_CHECKPOINTS)
    logger.info("checkpoint at %d steps: %s", checkpoint.num_timesteps, model_path)
    return checkpoint


def read_checkpoint(paths: RunPaths) -> Checkpoint:
    """The latest checkpoint of the run.

    Raises:
        FileNotFoundError: no ``checkpoint.json``, or the model file it names is missing.
        CheckpointError: ``checkpoint.json`` is not valid (named).
    """
    path = paths.checkpoint
    if not path.is_file():
        raise FileNotFoundError(
            f"no checkpoint to resume from: {path} does not exist (run without --resume)"
        )
    try:
        data = json.loads(path.read_text())
        checkpoint = Checkpoint(**data)
        valid = (
            isinstance(checkpoint.num_timesteps, int)
            and checkpoint.num_timesteps >= 0
            and isinstance(checkpoint.model, str)
            and isinstance(checkpoint.episodes, list)
        )
    except (ValueError, TypeError) as exc:
        raise CheckpointError(f"checkpoint file {path} is unreadable: {exc}") from exc
    if not valid:
        raise CheckpointError(f"checkpoint file {path} holds invalid fields: {data}")
    model_path = paths.checkpoints / checkpoint.model
    if not model_path.is_file():
        raise FileNotFoundError(f"model file {model_path} named by {path} does not exist")
    return checkpoint


def _prune(paths: RunPaths, keep: int) -> None:
    """Delete all but the newest ``keep`` checkpoint models (and their statistics)."""
    models = sorted(paths.checkpoints.glob("model_*[0-9].zip"))
    for old in models[:-keep]:
        old.unlink(missing_ok=True)
        normalizer_path(old).unlink(missing_ok=True)


class CheckpointCallback(BaseCallback):
    """Write a checkpoint every ``every`` environment steps (counted across all envs).

    Args:
        paths: The run's files.
        every: Steps between checkpoints.
        best_mean_reward: Reads the evaluation's best mean reward at save time.
    """

    def __init__(
        self, paths: RunPaths, every: int, best_mean_reward: Callable[[], float | None]
    ) -> None:
        super().__init__()
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.paths, self.every, self.best_mean_reward = paths, every, best_mean_reward
        self._last = 0

    def _on_training_start(self) -> None:
        self._last = self.num_timesteps

    def _on_step(self) -> bool:
        if self.num_timesteps // self.every > self._last // self.every:
            write_checkpoint(self.model, self.training_env, self.paths, self.best_mean_reward())
            self._last = self.num_timesteps
        return True
