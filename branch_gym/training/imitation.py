"""Imitation warm start: DAgger from the privileged policy into an SB3 PPO network.

PPO on the scan reward learns slowly: a rotation that pays shows up as ~0.1 found branch per scan
in a return that varies by whole branches from tree to tree (issue 17). The privileged policy
(:mod:`agents.privileged`, reads the ground truth) knows, at every step, whether a rotation pays
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
plays with its state carried through the episode and is fitted on whole episodes (issue 17's
recurrent variant; :mod:`branch_gym.training.memory_probe` measured what memory adds).

Episodes run in ``workers`` processes on the run's training trees
(:func:`branch_gym.training.seeds.train_seed_range`, after the first ``tree_offset`` of them);
every round is saved (its labels ``round_K.npz``, the student after it ``model_round_K.zip``,
a line of ``rounds.jsonl``), so an interrupted run resumes at the next round.

Why not the ``imitation`` library: it pins its own gymnasium / stable-baselines3 ranges and
pulls in sacred, datasets and huggingface-sb3; DAgger with an expert that reads the simulator
needs only the loop below.

Usage (the shipped students' commands are in the README, "Learned rotation policies")::

    python -m branch_gym.training.imitation --out runs/NAME [--rounds 8] [--episodes 96] \\
        [--reference-value 100] [--segmenter noisy:moderate] [--recurrent] [--workers 2] \\
        [--resume]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import copy
import json
import logging
import math
import os
import sys
from dataclasses import asdict, dataclass, field, replace
from itertools import pairwise
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from scipy.stats import mannwhitneyu
from tqdm import tqdm

import branch_gym  # noqa: F401  (registers the env ids in worker processes)
from agents.ppo import load_model
from agents.privileged import PrivilegedAgent
from branch_gym.env.layout import PRICE_KEY, VECTOR_KEY, VectorField
from branch_gym.evaluation.episodes import run_episode
from branch_gym.sim.validation import require_int, require_non_negative, require_positive
from branch_gym.training.config import PPOConfig, TrainConfig
from branch_gym.training.seeds import train_seed_range
from branch_gym.training.train import new_model

logger = logging.getLogger(__name__)

ROUNDS_LOG = "rounds.jsonl"
CONFIG_FILE = "imitation_config.json"
FINAL_MODEL = "model.zip"
# Settings a resumed run may change: the number of rounds and how the labels are fitted.
RESUMABLE_CHANGES = (
    "rounds", "epochs", "batch_size", "learning_rate", "weight_decay", "validation_fraction",
    "from_scratch", "rotation_weight", "reference_value_s",
)  # fmt: skip
_WORKER_THREADS = 1
# A fitted student whose rotation AUC on its own labels is below this has not learned them.
COLLAPSED_AUC = 0.6
_AUC_BATCH = 1024  # observations per forward pass of rotation_auc (memory, not results)


@dataclass(frozen=True)
class ImitationConfig:
    """A DAgger run.

    Attributes:
        train: The env and network settings (its ``env_id``, tracker, segmenter, tree preset,
            ``render_tracking_frames``, ``seed`` and ``ppo`` network shape are used; the PPO
            schedule is not).
        rounds: DAgger rounds (our choice: 8, the shipped students'; round 0 plays the expert).
        episodes: Episodes (trees) per round (our choice: 96, ~4 400 labelled steps, ~2 min on
            2 cores with the oracle tracker).
        epochs: Most passes over all labels after each round (our choice: 10; early stopping
            on the held-out labels keeps the best epoch).
        batch_size: Minibatch size of the fit (our choice: 256).
        learning_rate: Adam step size of the fit (our choice: 3e-4, SB3's PPO default; at BC's
            usual 1e-3 some fits of the v2 students collapsed: the image CNN's features grew
            until the policy MLP's tanh units saturated and the student output the same action
            probabilities for every observation, ranking the expert's rotations no better than
            chance even on the labels it was fitted on; see :func:`rotation_auc`).
        weight_decay: AdamW's decoupled weight decay (our choice: 1e-4, a light regulariser:
            without it our students fitted 99 % of the labels and agreed with the expert on
            89 % of a new round's).
        validation_fraction: Share of the labels held out for early stopping (our choice: 0.1).
        from_scratch: Fit a freshly initialised network after each round (DAgger as Ross et
            al. state it: a new policy on all labels so far), instead of going on from the
            previous round's weights (which sees the first rounds' labels ever more often).
        rotation_weight: Loss weight of a label that rotates (action != 0) relative to "hold"
            (our choice: 1.0, plain behaviour cloning; > 1 makes the student rotate where it is
            unsure).
        reference_value_s: Price conditioning (module docstring): rotation labels weigh
            ``rotation_weight * V / reference_value_s`` for the episode's branch value V
            (needs a v1 env, whose observation shows V); None weighs every episode alike.
            Our choice for the price-conditioned student: 100 s, the v0 reward's price.
        tree_offset: Skip this many of the run's training trees (so a DAgger run and a PPO run
            of the same seed can use different trees).

    With ``train.recurrent`` the student is an sb3-contrib ``RecurrentPPO`` (the same features
    followed by an LSTM, ``MultiInputLstmPolicy``): it plays with its LSTM state carried through
    the episode and is fitted on whole episodes, the state run from each episode's first step
    (:func:`fit_student`); ``validation_fraction`` then holds out whole episodes.
    """

    train: TrainConfig = field(default_factory=TrainConfig)
    rounds: int = 8
    episodes: int = 96
    epochs: int = 10
    batch_size: int = 256
    learning_rate: float = 3e-4
    weight_decay: float = 1e-4
    validation_fraction: float = 0.1
    from_scratch: bool = True
    rotation_weight: float = 1.0
    reference_value_s: float | None = None
    tree_offset: int = 0

    def __post_init__(self) -> None:
        require_int(self, "rounds", "episodes", "epochs", "batch_size", minimum=1)
        require_int(self, "tree_offset", minimum=0)
        require_positive(self, "learning_rate", "rotation_weight")
        require_non_negative(self, "weight_decay")
        if not 0.0 <= self.validation_fraction < 1.0:
            raise ValueError(
                "ImitationConfig.validation_fraction must be in [0, 1), got "
                f"{self.validation_fraction}"
            )
        if self.reference_value_s is not None:
            require_positive(self, "reference_value_s")
        if not self.train.env_id.startswith("BranchScanDiscrete"):
            raise ValueError(
                f"imitation needs a discrete env (BranchScanDiscrete-*), got {self.train.env_id!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["train"] = self.train.to_dict()
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ImitationConfig:
        values = dict(data)
        values["train"] = TrainConfig.from_dict(values.get("train", {}))
        return cls(**values)

    def tree_seed(self, round_index: int, episode: int) -> int:
        """The training tree of one episode of one round."""
        seeds = train_seed_range(self.train.seed)
        seed = seeds.start + self.tree_offset + round_index * self.episodes + episode
        if seed >= seeds.stop:
            raise ValueError(f"imitation run uses more trees than the seed's range {seeds}")
        return seed


@dataclass
class RoundData:
    """Labelled observations of one round (arrays stacked over steps)."""

    observations: dict[str, np.ndarray]
    expert_actions: np.ndarray  # (N,) int64

    def save(self, path: Path) -> None:
        arrays = {f"obs_{key}": value for key, value in self.observations.items()}
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, expert_actions=self.expert_actions, **arrays)
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: Path) -> RoundData:
        try:
            with np.load(path) as data:
                observations = {key[4:]: data[key] for key in data.files if key.startswith("obs_")}
                actions = data["expert_actions"]
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"imitation round file {path} is corrupt: {exc}") from exc
        return cls(observations, actions)

    @classmethod
    def concatenate(cls, rounds: list[RoundData]) -> RoundData:
        keys = rounds[0].observations.keys()
        return cls(
            {key: np.concatenate([r.observations[key] for r in rounds]) for key in keys},
            np.concatenate([r.expert_actions for r in rounds]),
        )


# -- episodes (worker processes) -------------------------------------------------------------

_WORKER: dict[str, Any] = {}


def _init_worker(train_config: dict[str, Any]) -> None:
    os.environ.setdefault("OMP_NUM_THREADS", str(_WORKER_THREADS))
    import cv2
    import torch

    cv2.setNumThreads(_WORKER_THREADS)
    torch.set_num_threads(_WORKER_THREADS)
    config = TrainConfig.from_dict(train_config)
    env = gym.make(config.env_id, **config.env_kwargs())
    _WORKER.update(env=env, expert=PrivilegedAgent.for_env(env), student=None, path=None)


def _student(path: str | None) -> Any:
    if path is None:
        return None
    if _WORKER["path"] != path:
        _WORKER.update(student=load_model(path), path=path)
    return _WORKER["student"]


class LabellingAgent:
    """Acts as the student (the expert where None) and records the expert's action at each step.

    An :class:`agents.protocol.Agent`, so the project's one episode loop
    (:func:`branch_gym.evaluation.episodes.run_episode`) plays it.

    Args:
        expert: The privileged policy of the env.
        student: A model with SB3's ``predict``, or None to let the expert act.
    """

    def __init__(self, expert: Any, student: Any = None) -> None:
        self.expert, self.student = expert, student
        self.observations: list[dict[str, np.ndarray]] = []
        self.labels: list[int] = []
        self.agreed = 0

    def predict(
        self,
        observation: dict[str, np.ndarray],
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[int, Any]:
        expert_action = int(self.expert.predict(observation, episode_start=episode_start)[0])
        action = expert_action
        if self.student is not None:  # a recurrent student's LSTM state goes round in ``state``
            starts = None if episode_start is None else np.asarray(episode_start, bool).reshape(-1)
            student_action, state = self.student.predict(
                observation, state=state, episode_start=starts, deterministic=deterministic
            )
            action = int(np.asarray(student_action).reshape(-1)[0])
        self.agreed += action == expert_action
        self.observations.append({key: np.array(value) for key, value in observation.items()})
        self.labels.append(expert_action)
        return action, state

    def round_data(self) -> RoundData:
        """The recorded observations, stacked, with the expert's action at each."""
        keys = self.observations[0].keys()
        stacked = {key: np.stack([o[key] for o in self.observations]) for key in keys}
        return RoundData(stacked, np.asarray(self.labels, np.int64))


def label_episode(tree_seed: int, student_path: str | None) -> tuple[RoundData, dict[str, Any]]:
    """One labelled episode in this worker: the student acts (the expert if None).

    Returns:
        The visited observations with the expert's action at each, and the episode's summary
        (tree seed, steps, agreement with the expert, rotations, scan time, missed branches).
    """
    agent = LabellingAgent(_WORKER["expert"], _student(student_path))
    result = run_episode(agent, _WORKER["env"], int(tree_seed)).result
    metrics = result.metrics
    summary = {
        "tree_seed": int(tree_seed),
        "steps": len(agent.labels),
        "agreement": agent.agreed / len(agent.labels),
        "expert_rotate_share": float(np.mean(np.asarray(agent.labels) != 0)),
        "rotations": int(result.rotations),
        "scan_time_s": float(result.scan_time_s),
        "n_gt": int(metrics.n_gt),
        "n_missed": int(metrics.n_missed),
    }
    return agent.round_data(), summary


def _episode_task(args: tuple[int, str | None]) -> tuple[RoundData, dict[str, Any]]:
    return label_episode(*args)


# -- fitting -----------------------------------------------------------------------------------


def new_student(config: ImitationConfig, env: Any = None) -> Any:
    """A fresh PPO model of the run's architecture.

    Args:
        config: The run.
        env: An env of the run's spaces; None builds one for the call.
    """
    train = config.train
    own = env is None
    env = gym.make(train.env_id, **train.env_kwargs()) if own else env
    try:
        return new_model(replace(train, ppo=replace(train.ppo, first_action_logit_init=0.0)), env)
    finally:
        if own:
            env.close()


def value_bounds_s(env: Any) -> tuple[float, float] | None:
    """An env's ``branch_value_s`` bounds (s); None for an env without a price."""
    bounds = env.unwrapped.config.branch_value_s
    return None if bounds is None else (float(bounds[0]), float(bounds[1]))


def label_weights(
    data: RoundData, config: ImitationConfig, value_bounds_s: tuple[float, float] | None = None
) -> np.ndarray:
    """(N,) loss weight of each label: 1 for "hold", the rotation weight for a rotation.

    Args:
        data: The labels (and, for price conditioning, the observations' ``price``).
        config: ``rotation_weight`` and ``reference_value_s``.
        value_bounds_s: The env's ``branch_value_s`` (low, high) bounds (s), which the
            observation's price (0 at low, 1 at high, log-scaled) spans; needed with
            ``reference_value_s``.

    Raises:
        ValueError: price conditioning without prices in the observations or without bounds.
    """
    weights = np.where(data.expert_actions != 0, config.rotation_weight, 1.0)
    if config.reference_value_s is None:
        return weights
    if value_bounds_s is None or PRICE_KEY not in data.observations:
        raise ValueError(
            "ImitationConfig.reference_value_s needs a v1 env (a price in the observation)"
        )
    low, high = value_bounds_s
    value_s = low * (high / low) ** data.observations[PRICE_KEY].reshape(-1).astype(float)
    return np.where(data.expert_actions != 0, weights * value_s / config.reference_value_s, 1.0)


def fit_student(
    model: Any,
    data: RoundData,
    config: ImitationConfig,
    rng: np.random.Generator,
    value_bounds_s: tuple[float, float] | None = None,
) -> dict[str, float]:
    """Fit the policy's action distribution to the expert's labels (weighted cross-entropy).

    Args:
        model: The student (SB3 PPO or sb3-contrib RecurrentPPO); its policy is trained in
            place.
        data: All labels so far, whole episodes in play order.
        config: Epochs, batch size, learning rate, label weights.
        rng: Minibatch order.
        value_bounds_s: The env's branch value bounds (s), for price conditioning
            (:func:`label_weights`).

    The units of the fit are single labels for a feed-forward policy and whole episodes for a
    recurrent one (its LSTM state runs from each episode's first step; a minibatch holds as many
    episodes as make about ``config.batch_size`` labels). A random ``validation_fraction`` of
    the units is held out; after each epoch the weighted loss on it is measured, and the
    weights of the best epoch are kept (early stopping).

    Returns:
        The epoch kept, the weighted losses and the accuracies of the deterministic action on
        the fitted and the held-out labels, and the number of held-out labels.
    """
    import torch

    policy = model.policy
    recurrent = is_recurrent_model(model)
    actions = torch.as_tensor(data.expert_actions)
    label_weight = label_weights(data, config, value_bounds_s)
    weights = torch.as_tensor(label_weight, dtype=torch.float32)
    episodes = episode_slices(data) if recurrent else []
    n_units = len(episodes) if recurrent else len(actions)
    per_batch = config.batch_size
    if recurrent:
        per_batch = max(1, round(config.batch_size * n_units / len(actions)))
    n_held_out = round(config.validation_fraction * n_units)
    if n_held_out:
        order = rng.permutation(n_units)
        held_out, train = order[:n_held_out], order[n_held_out:]
    else:  # every label is fitted, for all epochs
        held_out, train = np.zeros(0, np.int64), np.arange(n_units)
    optimizer = torch.optim.AdamW(
        policy.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )

    def labels(units: np.ndarray) -> np.ndarray:
        if not recurrent:
            return units
        ranges = [np.arange(episodes[u].start, episodes[u].stop) for u in units]
        return np.concatenate([np.zeros(0, np.int64), *ranges])

    def log_probabilities(units: np.ndarray) -> Any:
        if recurrent:
            return sequence_log_probabilities(policy, data, [episodes[u] for u in units])
        observation, _ = policy.obs_to_tensor(
            {key: value[units] for key, value in data.observations.items()}
        )
        return policy.evaluate_actions(observation, actions[units])[1]

    def probabilities(units: np.ndarray) -> np.ndarray:
        if recurrent:
            return recurrent_probabilities(model, data, [episodes[u] for u in units])
        return action_probabilities(model, data, units, config.batch_size)

    def weighted_loss(units: np.ndarray) -> float:
        index = labels(units)
        return weighted_nll(probabilities(units), data.expert_actions[index], label_weight[index])

    best_loss, best_state, best_epoch = math.inf, None, 0
    for epoch in range(1, config.epochs + 1):
        policy.set_training_mode(True)
        order = rng.permutation(train)
        for start in range(0, len(order), per_batch):
            part = order[start : start + per_batch]
            log_prob = log_probabilities(part)
            weighted_nll_step(model, optimizer, log_prob, weights[labels(part)])
        policy.set_training_mode(False)
        if n_held_out == 0:
            best_epoch = epoch
            continue
        held_out_loss = weighted_loss(held_out)
        if held_out_loss < best_loss:
            best_loss, best_epoch = held_out_loss, epoch
            best_state = copy.deepcopy(policy.state_dict())
    if best_state is not None:  # early stopping: the epoch with the lowest held-out loss
        policy.load_state_dict(best_state)

    def accuracy(units: np.ndarray) -> float:
        if len(units) == 0:
            return math.nan
        predicted = probabilities(units).argmax(axis=1)
        return float(np.mean(predicted == data.expert_actions[labels(units)]))

    return {
        "epochs_kept": best_epoch,
        "train_loss": weighted_loss(train),
        "held_out_loss": best_loss if n_held_out else math.nan,
        "held_out_labels": len(labels(held_out)),
        "train_accuracy": accuracy(train),
        "held_out_accuracy": accuracy(held_out),
    }


def weighted_nll(probabilities: np.ndarray, actions: np.ndarray, weights: np.ndarray) -> float:
    """The fit's loss on some labels: weighted cross-entropy of the expert's actions.

    Args:
        probabilities: (N, n_actions) the student's action probabilities.
        actions: (N,) the expert's actions.
        weights: (N,) label weights (:func:`label_weights`).
    """
    chosen = np.clip(probabilities[np.arange(len(actions)), actions], 1e-12, 1.0)
    return float(-(weights * np.log(chosen)).sum() / max(float(weights.sum()), 1e-12))


def weighted_nll_step(model: Any, optimizer: Any, log_prob: Any, weights: Any) -> None:
    """One optimiser step on the weighted cross-entropy of some labels (the fit's loss).

    Args:
        model: The SB3 model whose policy is fitted (its ``max_grad_norm`` clips the gradient).
        optimizer: The torch optimiser of the policy's parameters.
        log_prob: (B,) torch log-probabilities of the expert's actions.
        weights: (B,) torch label weights (:func:`label_weights`).
    """
    import torch

    loss = -(weights * log_prob).sum() / weights.sum()
    optimizer.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.policy.parameters(), model.max_grad_norm)
    optimizer.step()


def action_probabilities(
    model: Any, data: RoundData, index: np.ndarray, batch_size: int
) -> np.ndarray:
    """(len(index), n_actions) action probabilities of a student for some labelled observations.

    Args:
        model: The student (SB3 PPO on a discrete env).
        data: Labelled observations.
        index: Which of them, in this order.
        batch_size: Observations per forward pass (memory, not results).
    """
    import torch

    policy = model.policy
    probabilities = [np.zeros((0, model.action_space.n))]
    with torch.no_grad():
        for start in range(0, len(index), batch_size):
            part = index[start : start + batch_size]
            observation, _ = policy.obs_to_tensor(
                {key: value[part] for key, value in data.observations.items()}
            )
            probabilities.append(policy.get_distribution(observation).distribution.probs.numpy())
    return np.concatenate(probabilities)


def rotation_auc(model: Any, data: RoundData) -> float:
    """How well a student ranks the expert's rotations: the area under the ROC curve.

    The score of a state is the student's probability of rotating (1 - P(hold)); 0.5 is a
    student that cannot tell the expert's rotations from its holds, e.g. one whose fit
    collapsed to the same output for every observation (a DAgger run whose students' AUC stays
    at 0.5 has stopped learning). Computed on the labels of the round the student played, which
    it was not fitted on, it is a held-out score.

    Args:
        model: The student (SB3 PPO on a discrete env).
        data: Labelled observations.

    Returns:
        The AUC in [0, 1]; NaN when the labels hold only one class.
    """
    rotates = data.expert_actions != 0
    if rotates.all() or not rotates.any():
        return math.nan
    return rotation_auc_of(student_probabilities(model, data), rotates)


def rotation_auc_of(probabilities: np.ndarray, rotates: np.ndarray) -> float:
    """The AUC of the scores ``1 - P(hold)`` for the states where the expert rotates.

    Args:
        probabilities: (N, n_actions) action probabilities; action 0 is "hold".
        rotates: (N,) bool, the expert's label is a rotation.

    Returns:
        The AUC in [0, 1]; NaN when the labels hold only one class.
    """
    rotates = np.asarray(rotates, bool)
    if rotates.all() or not rotates.any():
        return math.nan
    scores = 1.0 - probabilities[:, 0]
    u_statistic = mannwhitneyu(scores[rotates], scores[~rotates]).statistic
    return float(u_statistic / (rotates.sum() * (~rotates).sum()))


# -- recurrent students (whole episodes) --------------------------------------------------------


def is_recurrent_model(model: Any) -> bool:
    """Whether a student is an sb3-contrib RecurrentPPO (an LSTM policy)."""
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy

    return isinstance(model.policy, RecurrentActorCriticPolicy)


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


def sequence_log_probabilities(policy: Any, data: RoundData, episodes: list[slice]) -> Any:
    """Log-probabilities of the expert's actions under a recurrent policy, whole episodes.

    Args:
        policy: A RecurrentPPO policy (in training mode for a fit).
        data: Labelled observations.
        episodes: Episodes of ``data``, each run from its first step with a zero LSTM state.

    Returns:
        A torch tensor of the log-probabilities of those episodes' labels, in order.
    """
    import torch

    observations, actions, mask = _sequence_batch(data, episodes)
    observation, _ = policy.obs_to_tensor(observations)
    starts = torch.zeros(len(actions))  # each sequence is one episode from its start
    state = _zero_state(policy, len(episodes))
    distribution, _ = policy.get_distribution(observation, state, starts)
    return distribution.log_prob(torch.as_tensor(actions))[torch.as_tensor(mask)]


def student_probabilities(model: Any, data: RoundData) -> np.ndarray:
    """(N, n_actions) a student's action probabilities for every label, in order.

    A recurrent student runs each episode from its start (:func:`episode_slices`).
    """
    if is_recurrent_model(model):
        return recurrent_probabilities(model, data, episode_slices(data))
    return action_probabilities(model, data, np.arange(len(data.expert_actions)), _AUC_BATCH)


# -- the run -----------------------------------------------------------------------------------


def imitate(
    config: ImitationConfig,
    out: str | Path,
    resume: bool = False,
    workers: int = 2,
    progress: bool = False,
) -> Path:
    """Run (or resume) DAgger; returns ``OUT/model.zip``, the student after the last round.

    Raises:
        FileExistsError: a new run in a folder that already holds one.
        ValueError: resuming with another configuration; a corrupt round file (named).
    """
    import torch

    torch.set_num_threads(_WORKER_THREADS)
    out = Path(out)
    config_path = out / CONFIG_FILE
    if config_path.exists() and not resume:
        raise FileExistsError(f"{out} already holds an imitation run: pass --resume")
    if resume and config_path.exists():
        saved = ImitationConfig.from_dict(json.loads(config_path.read_text()))
        old = {k: v for k, v in saved.to_dict().items() if k not in RESUMABLE_CHANGES}
        if old != {k: v for k, v in config.to_dict().items() if k not in RESUMABLE_CHANGES}:
            raise ValueError(
                f"cannot resume {out} with another configuration (only "
                f"{', '.join(RESUMABLE_CHANGES)} may change: they shape the fit, not the data)"
            )
    out.mkdir(parents=True, exist_ok=True)
    config_path.write_text(json.dumps(config.to_dict(), indent=2))
    rounds: list[RoundData] = []
    done = 0
    while (out / f"model_round_{done}.zip").exists() and done < config.rounds:
        rounds.append(RoundData.load(out / f"round_{done}.npz"))
        done += 1
    spaces_env = gym.make(config.train.env_id, **config.train.env_kwargs())
    model = (
        load_model(out / f"model_round_{done - 1}.zip") if done else new_student(config, spaces_env)
    )
    bounds = value_bounds_s(spaces_env)
    bar = None
    if progress:
        bar = tqdm(total=config.rounds * config.episodes, initial=done * config.episodes)
    context = concurrent.futures.ProcessPoolExecutor(
        max_workers=workers,
        initializer=_init_worker,
        initargs=(config.train.to_dict(),),
        mp_context=_spawn_context(),
    )
    try:
        with context as pool:
            for round_index in range(done, config.rounds):
                student_path = (
                    None if round_index == 0 else str(out / f"model_round_{round_index - 1}.zip")
                )
                tasks = [
                    (config.tree_seed(round_index, episode), student_path)
                    for episode in range(config.episodes)
                ]
                results, summaries = [], []
                for data, summary in pool.map(_episode_task, tasks):
                    results.append(data)
                    summaries.append(summary)
                    if bar is not None:
                        bar.update(1)
                round_data = RoundData.concatenate(results)
                round_data.save(out / f"round_{round_index}.npz")
                rounds.append(round_data)
                # The student that played this round, on labels it was not fitted on.
                held_out_auc = math.nan if student_path is None else rotation_auc(model, round_data)
                rng = np.random.default_rng([config.train.seed, round_index])
                if config.from_scratch:
                    model = new_student(config, spaces_env)
                all_labels = RoundData.concatenate(rounds)
                fit = fit_student(model, all_labels, config, rng, bounds)
                fit["student_rotation_auc"] = held_out_auc
                fit["train_rotation_auc"] = rotation_auc(model, all_labels)
                if fit["train_rotation_auc"] < COLLAPSED_AUC:
                    logger.warning(
                        "round %d: the student ranks the expert's rotations on its own labels at "
                        "an AUC of %.2f: its fit collapsed or has not converged (lower the "
                        "learning rate or raise the epochs)",
                        round_index,
                        fit["train_rotation_auc"],
                    )
                model.save(out / f"model_round_{round_index}.zip")
                labels = len(round_data.expert_actions)
                settings = {name: getattr(config, name) for name in RESUMABLE_CHANGES[1:]}
                _log_round(out, round_index, student_path is None, summaries, fit, labels, settings)
    finally:
        spaces_env.close()
        if bar is not None:
            bar.close()
    final = out / FINAL_MODEL
    model.save(final)
    return final


def _log_round(
    out: Path,
    round_index: int,
    expert_played: bool,
    summaries: list[dict[str, Any]],
    fit: dict[str, float],
    labels: int,
    fit_settings: dict[str, Any],
) -> None:
    n_gt = sum(s["n_gt"] for s in summaries)
    row = {
        "round": round_index,
        "played_by": "expert" if expert_played else "student",
        "episodes": len(summaries),
        "labels": labels,
        "agreement": float(np.mean([s["agreement"] for s in summaries])),
        "expert_rotate_share": float(np.mean([s["expert_rotate_share"] for s in summaries])),
        "rotations": float(np.mean([s["rotations"] for s in summaries])),
        "scan_time_s": float(np.mean([s["scan_time_s"] for s in summaries])),
        "missed_pct": 100.0 * sum(s["n_missed"] for s in summaries) / max(n_gt, 1),
        **fit,
        **fit_settings,
    }
    logger.info("round %d: %s", round_index, row)
    with open(out / ROUNDS_LOG, "a") as handle:
        handle.write(json.dumps(row) + "\n")


def _spawn_context() -> Any:
    import multiprocessing

    return multiprocessing.get_context("spawn")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--out", type=Path, required=True, help="run folder")
    parser.add_argument("--env", default="BranchScanDiscrete-v1", help="a discrete env id")
    parser.add_argument("--tracker", default="oracle", choices=("lk", "oracle"))
    parser.add_argument("--segmenter", default="gt")
    parser.add_argument(
        "--all-tracking-frames",
        action="store_true",
        help="render every tracking frame (default: only the modeling frames, oracle tracker)",
    )
    parser.add_argument("--cnn-output-dim", type=int, default=64)
    parser.add_argument(
        "--recurrent",
        action="store_true",
        help="an LSTM student (sb3-contrib RecurrentPPO), fitted on whole episodes",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rounds", type=int, default=ImitationConfig.rounds)
    parser.add_argument("--episodes", type=int, default=ImitationConfig.episodes)
    parser.add_argument("--epochs", type=int, default=ImitationConfig.epochs)
    parser.add_argument("--learning-rate", type=float, default=ImitationConfig.learning_rate)
    parser.add_argument("--weight-decay", type=float, default=ImitationConfig.weight_decay)
    parser.add_argument(
        "--validation-fraction",
        type=float,
        default=ImitationConfig.validation_fraction,
        help="labels held out for early stopping (0: none, every epoch runs)",
    )
    parser.add_argument(
        "--continue-weights",
        action="store_true",
        help="fit each round from the previous round's weights, not from a fresh network",
    )
    parser.add_argument("--rotation-weight", type=float, default=ImitationConfig.rotation_weight)
    parser.add_argument(
        "--reference-value",
        type=float,
        metavar="S",
        help="price-conditioned fit: rotation labels weigh rotation-weight * value / S",
    )
    parser.add_argument("--tree-offset", type=int, default=ImitationConfig.tree_offset)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--resume", action="store_true")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = ImitationConfig(
            train=TrainConfig(
                env_id=args.env,
                tracker=args.tracker,
                segmenter=args.segmenter,
                seed=args.seed,
                render_tracking_frames=args.all_tracking_frames or args.tracker != "oracle",
                recurrent=args.recurrent,
                ppo=PPOConfig(cnn_output_dim=args.cnn_output_dim),
            ),
            rounds=args.rounds,
            episodes=args.episodes,
            epochs=args.epochs,
            learning_rate=args.learning_rate,
            weight_decay=args.weight_decay,
            validation_fraction=args.validation_fraction,
            from_scratch=not args.continue_weights,
            rotation_weight=args.rotation_weight,
            reference_value_s=args.reference_value,
            tree_offset=args.tree_offset,
        )
        final = imitate(config, args.out, args.resume, args.workers, progress=True)
    except (FileExistsError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {final}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
