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

Usage (the README's "Learned rotation policies" has the measured table)::

    python -m branch_gym.training.memory_probe runs/dagger_v2r --test-rounds 10 11 \\
        --out results/memory_probe.json
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import replace
from itertools import pairwise
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from branch_gym.env.layout import VECTOR_KEY, VectorField
from branch_gym.training.imitation import (
    CONFIG_FILE,
    ImitationConfig,
    RoundData,
    action_probabilities,
    fit_student,
    label_weights,
    new_student,
    rotation_auc_of,
    value_bounds_s,
    weighted_nll_step,
)
from branch_gym.training.train import new_model

logger = logging.getLogger(__name__)

_EVAL_BATCH = 1024  # observations per forward pass when scoring (memory, not results)


def episode_slices(data: RoundData) -> list[slice]:
    """The episodes of a round's labels, in play order.

    An episode starts where the observation's scan time (``VectorField.SCAN_TIME``) falls: it is
    0 at every reset and grows within a scan.

    Raises:
        ValueError: no labels.
    """
    scan_time = data.observations[VECTOR_KEY][:, VectorField.SCAN_TIME]
    if len(scan_time) == 0:
        raise ValueError("the round holds no labels")
    starts = np.flatnonzero(np.diff(scan_time) < 0) + 1
    bounds = [0, *starts.tolist(), len(scan_time)]
    return [slice(a, b) for a, b in pairwise(bounds)]


def load_rounds(run: Path, rounds: list[int]) -> RoundData:
    """The labels of some rounds of a DAgger run, concatenated in round order.

    Raises:
        FileNotFoundError: a round file is missing (named).
    """
    missing = [run / f"round_{k}.npz" for k in rounds if not (run / f"round_{k}.npz").exists()]
    if missing:
        raise FileNotFoundError(f"no labels {', '.join(str(p) for p in missing)}")
    return RoundData.concatenate([RoundData.load(run / f"round_{k}.npz") for k in rounds])


def _sequence_batch(
    data: RoundData, episodes: list[slice]
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Episodes padded to one length, episode-major (sb3-contrib's sequence layout).

    Returns:
        ``(observations, actions, mask)``: each (B * L, ...) for B episodes of at most L steps;
        padding repeats an episode's last step with mask 0.
    """
    length = max(s.stop - s.start for s in episodes)
    index = np.concatenate(
        [np.minimum(np.arange(s.start, s.start + length), s.stop - 1) for s in episodes]
    )
    mask = np.concatenate([np.arange(length) < s.stop - s.start for s in episodes])
    observations = {key: value[index] for key, value in data.observations.items()}
    return observations, data.expert_actions[index], mask


def _zero_state(policy: Any, n_sequences: int) -> tuple[Any, Any]:
    """The actor LSTM's (hidden, cell) state at an episode's start, for ``n_sequences``."""
    import torch

    lstm = policy.lstm_actor
    zeros = torch.zeros(lstm.num_layers, n_sequences, lstm.hidden_size)
    return zeros, zeros


def recurrent_probabilities(model: Any, data: RoundData, episodes: list[slice]) -> np.ndarray:
    """(N, n_actions) action probabilities of a recurrent policy, each episode from its start.

    Args:
        model: An sb3-contrib RecurrentPPO (discrete actions).
        data: Labelled observations.
        episodes: The episodes to score (rows of the result follow them in order).
    """
    import torch

    policy = model.policy
    rows = []
    with torch.no_grad():
        for episode in episodes:
            observation, _ = policy.obs_to_tensor(
                {key: value[episode] for key, value in data.observations.items()}
            )
            starts = torch.zeros(episode.stop - episode.start)
            distribution, _ = policy.get_distribution(observation, _zero_state(policy, 1), starts)
            rows.append(distribution.distribution.probs.numpy())
    return np.concatenate(rows)


def fit_recurrent(
    model: Any,
    data: RoundData,
    config: ImitationConfig,
    rng: np.random.Generator,
    value_bounds: tuple[float, float] | None = None,
) -> None:
    """Fit a RecurrentPPO policy's actions to the expert's labels, whole episodes at a time.

    The objective is :func:`branch_gym.training.imitation.fit_student`'s (weighted
    cross-entropy, AdamW, gradient clipping, every label every epoch); a minibatch holds as many
    whole episodes as make about ``config.batch_size`` labels.
    """
    import torch

    policy = model.policy
    episodes = episode_slices(data)
    weights = label_weights(data, config, value_bounds).astype(np.float32)
    mean_length = len(data.expert_actions) / len(episodes)
    per_batch = max(1, round(config.batch_size / mean_length))
    optimizer = torch.optim.AdamW(
        policy.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    policy.set_training_mode(True)
    for _ in range(config.epochs):
        order = rng.permutation(len(episodes))
        for start in range(0, len(order), per_batch):
            batch = [episodes[i] for i in order[start : start + per_batch]]
            observations, actions, mask = _sequence_batch(data, batch)
            index = np.concatenate([np.arange(s.start, s.stop) for s in batch])
            observation, _ = policy.obs_to_tensor(observations)
            starts = torch.zeros(len(actions))  # each sequence is one episode from its start
            state = _zero_state(policy, len(batch))
            distribution, _ = policy.get_distribution(observation, state, starts)
            log_prob = distribution.log_prob(torch.as_tensor(actions))[torch.as_tensor(mask)]
            weighted_nll_step(model, optimizer, log_prob, torch.as_tensor(weights[index]))
    policy.set_training_mode(False)


def scores(
    probabilities: np.ndarray,
    data: RoundData,
    config: ImitationConfig,
    value_bounds: tuple[float, float] | None,
) -> dict[str, float]:
    """Rotation AUC, weighted cross-entropy and accuracy of action probabilities on labels."""
    actions = data.expert_actions
    weights = label_weights(data, config, value_bounds)
    chosen = np.clip(probabilities[np.arange(len(actions)), actions], 1e-12, 1.0)
    return {
        "rotation_auc": rotation_auc_of(probabilities, actions != 0),
        "weighted_nll": float(-(weights * np.log(chosen)).sum() / weights.sum()),
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
    train, test = load_rounds(run, train_rounds), load_rounds(run, test_rounds)
    env = gym.make(config.train.env_id, **config.train.env_kwargs())
    try:
        bounds = value_bounds_s(env)
        seed = config.train.seed
        logger.info("fitting the feed-forward student on %d labels", len(train.expert_actions))
        feedforward = new_student(config, env)
        fit_student(feedforward, train, config, np.random.default_rng([seed, max(train_rounds)]))
        recurrent_train = replace(
            config.train, recurrent=True, ppo=replace(config.train.ppo, first_action_logit_init=0)
        )
        logger.info("fitting the recurrent policy on %d labels", len(train.expert_actions))
        recurrent = new_model(recurrent_train, env)
        fit_recurrent(recurrent, train, config, np.random.default_rng(seed), bounds)
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
    for name, probabilities in (
        ("feedforward", lambda d: action_probabilities(
            feedforward, d, np.arange(len(d.expert_actions)), _EVAL_BATCH)),
        ("recurrent", lambda d: recurrent_probabilities(recurrent, d, episode_slices(d))),
    ):  # fmt: skip
        result[name] = {
            "test": scores(probabilities(test), test, config, bounds),
            "train": scores(probabilities(train), train, config, bounds),
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
    parser.add_argument("run", type=Path, help="a DAgger run folder (imitation.py --out)")
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
