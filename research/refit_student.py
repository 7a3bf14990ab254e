"""Fit a fresh student on every label an imitation run kept, with other fit settings.

A study of the fit alone: the labels (``round_K.npz``) stay as the run made them, so students fitted
with other settings (rotation weight, label weights, epochs) compare on the same data. The run's
own ``--resume`` fits the next round's student with changed settings, but plays that round first.

    python research/refit_student.py runs/aggrevate_orchard runs/refit/rw8.zip \
        --set rotation_weight=8

``--also RUN ...`` adds the labels of other runs of the same training settings (``train``), e.g.
a run whose students visited states the first run's did not.

Writes the student (an SB3 zip, ``ppo:PATH`` in ``eval.py``) and prints the fit's scores.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np

import branch_gym  # noqa: F401  (registers the env ids)
from branch_gym.training.imitation.config import CONFIG_FILE, RESUMABLE_CHANGES, ImitationConfig
from branch_gym.training.imitation.data import RoundData
from branch_gym.training.imitation.fit import (
    fit_student,
    new_student,
    rotation_auc,
    value_bounds_s,
)
from branch_gym.training.imitation.rounds import finished_rounds

REFIT_STREAM = 99  # the minibatch order's generator: [run seed, REFIT_STREAM]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="an imitation run folder (or a kept record)")
    parser.add_argument("out", type=Path, help="the student's .zip")
    parser.add_argument("--set", nargs="*", default=[], help="fit settings, FIELD=JSON")
    parser.add_argument(
        "--also", nargs="*", type=Path, default=[], help="more runs whose labels join the fit"
    )
    args = parser.parse_args()
    config = ImitationConfig.from_dict(json.loads((args.run / CONFIG_FILE).read_text()))
    changes = {}
    for item in args.set:
        name, _, value = item.partition("=")
        if name not in RESUMABLE_CHANGES or name == "rounds":
            raise SystemExit(
                f"--set {name}: not a fit setting ({', '.join(RESUMABLE_CHANGES[1:])})"
            )
        changes[name] = json.loads(value)
    config = replace(config, **changes)
    rounds = finished_rounds(args.run, config.rounds)
    data = RoundData.load_rounds(args.run, list(range(rounds)))
    for other in args.also:
        theirs = ImitationConfig.from_dict(json.loads((other / CONFIG_FILE).read_text()))
        if theirs.train != config.train:
            raise SystemExit(f"--also {other}: its training settings differ from {args.run}'s")
        more = finished_rounds(other, theirs.rounds)
        data = RoundData.concatenate([data, RoundData.load_rounds(other, list(range(more)))])
        rounds += more
    env = gym.make(config.train.env_id, **config.train.env_kwargs())
    try:
        model = new_student(config, env)
        rng = np.random.default_rng([config.train.seed, REFIT_STREAM])
        scores = fit_student(
            model, data, config, rng, value_bounds_s(env), env.unwrapped.config.reward
        )
    finally:
        env.close()
    scores["train_rotation_auc"] = rotation_auc(model, data)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    model.save(args.out)
    print(json.dumps({"rounds": rounds, "labels": len(data.expert_actions), **changes, **scores}))


if __name__ == "__main__":
    main()
