"""Does memory help the student? A feed-forward and a recurrent fit of the same DAgger labels.

Issue 17 asks for a recurrent variant (sb3-contrib's ``RecurrentPPO``) if memory helps. The v1
and v2 observations already carry an explicit memory (the view-coverage memory of
:mod:`branch_gym.env.coverage`); whether a learned one adds to it is a question about the labels,
answered here without a training run. A DAgger run's labels (``round_K.npz``, whole episodes in
play order) are split by round; on the first rounds two policies are fitted with the run's own
fit settings (epochs, learning rate, weight decay, label weights):

- the run's feed-forward student (:func:`branch_gym.training.imitation.new_student`, fitted by
  :func:`branch_gym.training.imitation.fit_student`, exactly as the run fits its students);
- a ``RecurrentPPO`` policy of the same features followed by an LSTM (``MultiInputLstmPolicy``,
  sb3-contrib's default 256 units, what ``train.py --recurrent`` trains), fitted on whole
  episodes, the LSTM state carried from each episode's first step.

Both are scored on the later rounds' labels (trees neither saw, played by later students): the
rotation AUC (:func:`branch_gym.training.imitation.rotation_auc_of`), the weighted cross-entropy
and the accuracy of the most likely action. A recurrent policy that ranks the expert's rotations
no better than the feed-forward one does not earn a RecurrentPPO run at scale.

Usage (``docs/results/history.md`` has the measured table)::

    python -m research.memory_probe runs/dagger_v2r --test-rounds 10 11 \\
        --out results/memory_probe.json
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from branch_gym.training.imitation import (
    CONFIG_FILE,
    ImitationConfig,
    RoundData,
    fit_student,
    label_weights,
    new_student,
    rotation_auc_of,
    student_probabilities,
    value_bounds_s,
    weighted_nll,
)

logger = logging.getLogger(__name__)


def scores(
    probabilities: np.ndarray,
    data: RoundData,
    config: ImitationConfig,
    value_bounds: tuple[float, float] | None,
) -> dict[str, float]:
    """Rotation AUC, weighted cross-entropy and accuracy of action probabilities on labels."""
    actions = data.expert_actions
    return {
        "rotation_auc": rotation_auc_of(probabilities, actions != 0),
        "weighted_nll": weighted_nll(
            probabilities, actions, label_weights(data, config, value_bounds)
        ),
        "accuracy": float(np.mean(probabilities.argmax(axis=1) == actions)),
    }


def probe(
    run: str | Path,
    test_rounds: list[int],
    train_rounds: list[int] | None = None,
    epochs: int | None = None,
) -> dict[str, Any]:
    """Fit both policies on a DAgger run's first rounds; score them on ``test_rounds``.

    Args:
        run: The DAgger run folder (``imitation_config.json``, ``round_K.npz``).
        test_rounds: Rounds whose labels score the fits.
        train_rounds: Rounds whose labels are fitted; by default every round before the first
            test round.
        epochs: Passes over the labels for both fits; by default the run's own.

    Returns:
        ``{"feedforward": {...}, "recurrent": {...}}`` with the scores on the test and on the
        fitted labels, and the label counts.

    Raises:
        FileNotFoundError: no run, or a round file missing (named).
        ValueError: train and test rounds overlap.
    """
    run = Path(run)
    config_path = run / CONFIG_FILE
    if not config_path.exists():
        raise FileNotFoundError(f"{run} holds no imitation run ({CONFIG_FILE} missing)")
    config = ImitationConfig.from_dict(json.loads(config_path.read_text()))
    if epochs is not None:
        config = replace(config, epochs=epochs)
    if train_rounds is None:
        train_rounds = list(range(min(test_rounds)))
    if set(train_rounds) & set(test_rounds) or not train_rounds:
        raise ValueError(
            f"train rounds {train_rounds} must be non-empty and disjoint from {test_rounds}"
        )
    train, test = RoundData.load_rounds(run, train_rounds), RoundData.load_rounds(run, test_rounds)
    env = gym.make(config.train.env_id, **config.train.env_kwargs())
    try:
        bounds = value_bounds_s(env)
        seed = config.train.seed
        logger.info("fitting the feed-forward student on %d labels", len(train.expert_actions))
        feedforward = new_student(config, env)
        fit_student(feedforward, train, config, np.random.default_rng([seed, max(train_rounds)]))
        logger.info("fitting the recurrent policy on %d labels", len(train.expert_actions))
        recurrent = new_student(replace(config, train=replace(config.train, recurrent=True)), env)
        fit_student(recurrent, train, config, np.random.default_rng(seed), bounds)
    finally:
        env.close()
    result: dict[str, Any] = {
        "run": str(run),
        "train_rounds": train_rounds,
        "test_rounds": test_rounds,
        "train_labels": len(train.expert_actions),
        "test_labels": len(test.expert_actions),
        "epochs": config.epochs,
    }
    for name, model in (("feedforward", feedforward), ("recurrent", recurrent)):
        result[name] = {
            "test": scores(student_probabilities(model, test), test, config, bounds),
            "train": scores(student_probabilities(model, train), train, config, bounds),
        }
    return result


def format_table(result: dict[str, Any]) -> str:
    """A Markdown table of the probe's scores."""
    lines = [
        "| policy | rotation AUC, test | weighted NLL, test | accuracy, test | rotation AUC, fit |",
        "|---|---|---|---|---|",
    ]
    for name in ("feedforward", "recurrent"):
        test, train = result[name]["test"], result[name]["train"]
        lines.append(
            f"| {name} | {test['rotation_auc']:.3f} | {test['weighted_nll']:.3f} | "
            f"{test['accuracy']:.3f} | {train['rotation_auc']:.3f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("run", type=Path, help="a DAgger run folder (imitation --out)")
    parser.add_argument("--test-rounds", type=int, nargs="+", required=True)
    parser.add_argument("--train-rounds", type=int, nargs="*", default=None)
    parser.add_argument(
        "--epochs", type=int, default=None, help="passes over the labels (default: the run's)"
    )
    parser.add_argument("--out", type=Path, default=None, help="write the scores as JSON here")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        result = probe(args.run, args.test_rounds, args.train_rounds, args.epochs)
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_table(result))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
