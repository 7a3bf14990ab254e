"""Imitation warm start: DAgger from the privileged policy into an SB3 PPO network.

PPO on the scan reward learns slowly: a rotation that pays shows up as ~0.1 found branch per scan
in a return that varies by whole branches from tree to tree (issue 17). The privileged policy
(:mod:`branch_gym.privileged`, reads the ground truth) knows, at every step, whether a rotation pays
and where to. :func:`imitate` distils it into a policy that sees only the observation, with
DAgger (Ross et al., 2011, "A Reduction of Imitation Learning and Structured Prediction to
No-Regret Online Learning"):

- round 0 plays the expert and records (observation, expert action) at every step;
- each later round plays the current student (deterministic, what evaluation plays), still
  labelling every visited observation with the expert's action, so the student learns what to do
  in the states its own mistakes lead to;
- after each round the student's network is fitted to all labels so far (cross-entropy of the
  policy's action distribution, rotations weighted by ``rotation_weight``).

Price conditioning (``reference_value_s``): a label that rotates weighs ``rotation_weight *
V / reference_value_s``, with V the episode's branch value (the price of scan time, seconds a
found branch is worth) that the v1 observation shows. Weighted cross-entropy is cost-sensitive
classification: its best deterministic policy rotates where the expert would with probability
above ``1 / (1 + weight)``, so one network learns to rotate on weaker evidence when branches
are dear (400 s: above 0.2) and only on strong evidence when they are cheap (25 s: above 0.8).

The student is a stable-baselines3 ``PPO`` of the run's architecture (``TrainConfig.ppo``), so
``ppo:OUT/model.zip`` evaluates it and ``train.py --init-model OUT/model.zip`` fine-tunes it with
PPO; with ``--recurrent`` an sb3-contrib ``RecurrentPPO`` (an LSTM after the same features), which
plays with its state carried through the episode and is fitted on whole episodes.

Why not the ``imitation`` library: it pins its own gymnasium / stable-baselines3 ranges and
pulls in sacred, datasets and huggingface-sb3; DAgger with an expert that reads the simulator
needs only the loop here.

==============  ================================================================================
``config.py``   ``ImitationConfig``: the run (its defaults are the one place they are set)
``data.py``     ``RoundData``: a round's labelled observations, its file, its episodes
``labels.py``   labelling episodes in worker processes (``LabellingAgent``)
``fit.py``      fitting a student to labels: feed-forward and recurrent through one interface
``rounds.py``   ``imitate``: the round loop, resumable, ``rounds.jsonl``
``cli.py``      the command line (``python -m branch_gym.training.imitation``,
                ``branch-gym-imitate``; a recipe with ``--config configs/NAME.json``)
==============  ================================================================================

Usage (the shipped students' recipes are ``configs/dagger_*.json``; their cards in
``agents/models/``)::

    python -m branch_gym.training.imitation --config configs/dagger_v2.json --out runs/NAME \\
        [--workers 2] [--resume] [--rounds 12] [--segmenter learned] [--recurrent] ...
"""

from __future__ import annotations

from branch_gym.training.imitation.config import (
    CONFIG_FILE,
    FINAL_MODEL,
    ROUNDS_LOG,
    ImitationConfig,
)
from branch_gym.training.imitation.data import RoundData, episode_slices
from branch_gym.training.imitation.fit import (
    fit_student,
    is_recurrent_model,
    label_weights,
    new_student,
    rotation_auc,
    rotation_auc_of,
    student_probabilities,
    value_bounds_s,
    weighted_nll,
)
from branch_gym.training.imitation.labels import LabellingAgent
from branch_gym.training.imitation.rounds import imitate

__all__ = [
    "CONFIG_FILE",
    "FINAL_MODEL",
    "ROUNDS_LOG",
    "ImitationConfig",
    "LabellingAgent",
    "RoundData",
    "episode_slices",
    "fit_student",
    "imitate",
    "is_recurrent_model",
    "label_weights",
    "new_student",
    "rotation_auc",
    "rotation_auc_of",
    "student_probabilities",
    "value_bounds_s",
    "weighted_nll",
]
