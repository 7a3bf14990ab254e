"""Where a training run writes its files (everything under its ``--out`` folder).

================================  ==============================================================
``config.json``                   the :class:`~branch_gym.training.config.TrainConfig`, the seed
                                  ranges and library versions
``tb/PPO_1/``                     TensorBoard logs (SB3's ``rollout/``, ``train/``; ours:
                                  ``scan/`` means per log, ``episode/`` per episode, ``eval/``)
``checkpoints/checkpoint.json``   the latest checkpoint: ``num_timesteps``, its files, the
                                  training envs' episode counts, the best evaluation so far
``checkpoints/model_STEPS.zip``   checkpoint models (the latest ``KEEP_CHECKPOINTS`` kept)
``best_model.zip``                the model with the best mean held-out reward so far
``evaluations.jsonl``             one line per held-out evaluation
``final_model.zip``               the model at the end of training
``*_vecnormalize.pkl``            ``VecNormalize`` statistics beside each model, when used
================================  ==============================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

CONFIG_FILE = "config.json"
TENSORBOARD_DIR = "tb"
TB_LOG_NAME = "PPO"
CHECKPOINTS_DIR = "checkpoints"
CHECKPOINT_FILE = "checkpoint.json"
BEST_MODEL = "best_model.zip"
FINAL_MODEL = "final_model.zip"
EVALUATIONS_FILE = "evaluations.jsonl"
KEEP_CHECKPOINTS = 2  # our choice: the latest and the one before, in case the latest is torn


@dataclass(frozen=True)
class RunPaths:
    """The files of the run in ``out``."""

    out: Path

    @property
    def config(self) -> Path:
        return self.out / CONFIG_FILE

    @property
    def tensorboard(self) -> Path:
        return self.out / TENSORBOARD_DIR

    @property
    def checkpoints(self) -> Path:
        return self.out / CHECKPOINTS_DIR

    @property
    def checkpoint(self) -> Path:
        return self.checkpoints / CHECKPOINT_FILE

    def checkpoint_model(self, num_timesteps: int) -> Path:
        return self.checkpoints / f"model_{num_timesteps:09d}.zip"

    @property
    def best_model(self) -> Path:
        return self.out / BEST_MODEL

    @property
    def final_model(self) -> Path:
        return self.out / FINAL_MODEL

    @property
    def evaluations(self) -> Path:
        return self.out / EVALUATIONS_FILE
