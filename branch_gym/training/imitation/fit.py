"""Fitting a student to the expert's labels: weighted cross-entropy, early stopping, scores.

A feed-forward student (SB3 ``PPO``) is fitted on single labels; a recurrent one (sb3-contrib
``RecurrentPPO``) on whole episodes, its LSTM state run from each episode's first step. Both go
through one interface, :class:`FitUnits` (:func:`fit_units` picks the kind): how many units the
labels hold, which labels a set of units covers, the policy's log-probabilities of their expert
actions (for a gradient step) and its action probabilities (for scores). :func:`fit_student`
and :func:`student_probabilities` only speak to it.

>>> round(weighted_nll(np.array([[0.5, 0.5], [0.9, 0.1]]), np.array([0, 0]), np.ones(2)), 4)
0.3993
>>> rotation_auc_of(np.array([[0.9, 0.1], [0.2, 0.8], [0.6, 0.4]]), np.array([False, True, True]))
1.0
"""

from __future__ import annotations

import copy
import math
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
from scipy.stats import mannwhitneyu

from branch_gym.env.layout import PRICE_KEY, branch_value_s, price_feature
from branch_gym.env.reward import RewardConfig
from branch_gym.training.imitation.config import ImitationConfig
from branch_gym.training.imitation.cost_to_go import expected_regret
from branch_gym.training.imitation.data import OUTCOME_COLUMNS, RoundData, episode_slices
from branch_gym.training.model_files import ModelFinder, existing_file
from branch_gym.training.train import new_model

_AUC_BATCH = 1024  # observations per forward pass of rotation_auc (memory, not results)


def new_student(
    config: ImitationConfig, env: Any = None, find_model: ModelFinder = existing_file
) -> Any:
    """A fresh PPO model of the run's architecture.

    Args:
        config: The run.
        env: An env of the run's spaces; None builds one for the call.
        find_model: ``config.train.init_model`` -> its file.
    """
    train = config.train
    own = env is None
    env = gym.make(train.env_id, **train.env_kwargs()) if own else env
    try:
        student = replace(train, ppo=replace(train.ppo, first_action_logit_init=0.0))
        return new_model(student, env, find_model=find_model)
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
    value_s = branch_value_s(data.observations[PRICE_KEY].reshape(-1), value_bounds_s)
    return np.where(data.expert_actions != 0, weights * value_s / config.reference_value_s, 1.0)


# The returns a branch log's outcomes give back against the labels' (float rounding of a sum of
# step rewards against the closed form).
_REPRICE_TOLERANCE = 1e-6


class FitUnits:
    """The units a student is fitted on: single labels (feed-forward policies).

    Args:
        model: The student.
        data: Its labels, whole episodes in play order.
    """

    def __init__(self, model: Any, data: RoundData) -> None:
        import torch

        self.model, self.data = model, data
        self.actions = torch.as_tensor(data.expert_actions)

    @property
    def count(self) -> int:
        """How many units the labels hold."""
        return len(self.data.expert_actions)

    def per_batch(self, labels_per_batch: int) -> int:
        """Units per minibatch for about ``labels_per_batch`` labels."""
        return labels_per_batch

    def labels(self, units: np.ndarray) -> np.ndarray:
        """The indices of the labels ``units`` cover, in order."""
        return units

    def log_probabilities(self, units: np.ndarray) -> Any:
        """Torch log-probabilities of the expert's actions of ``units`` (with gradients)."""
        policy = self.model.policy
        observation, _ = policy.obs_to_tensor(
            {key: value[units] for key, value in self.data.observations.items()}
        )
        return policy.evaluate_actions(observation, self.actions[units])[1]

    def probabilities(self, units: np.ndarray, batch_size: int) -> np.ndarray:
        """(len(labels(units)), n_actions) action probabilities, without gradients.

        Args:
            units: Which units.
            batch_size: Observations per forward pass (memory, not results).
        """
        return action_probabilities(self.model, self.data, units, batch_size)


class EpisodeUnits(FitUnits):
    """The units of a recurrent student: whole episodes, each run from a zero LSTM state."""

    def __init__(self, model: Any, data: RoundData) -> None:
        super().__init__(model, data)
        self.episodes = episode_slices(data)

    @property
    def count(self) -> int:
        return len(self.episodes)

    def per_batch(self, labels_per_batch: int) -> int:
        return max(1, round(labels_per_batch * self.count / len(self.data.expert_actions)))

    def labels(self, units: np.ndarray) -> np.ndarray:
        ranges = [np.arange(self.episodes[u].start, self.episodes[u].stop) for u in units]
        return np.concatenate([np.zeros(0, np.int64), *ranges])

    def log_probabilities(self, units: np.ndarray) -> Any:
        return sequence_log_probabilities(
            self.model.policy, self.data, [self.episodes[u] for u in units]
        )

    def probabilities(self, units: np.ndarray, batch_size: int) -> np.ndarray:
        return recurrent_probabilities(self.model, self.data, [self.episodes[u] for u in units])


def fit_units(model: Any, data: RoundData) -> FitUnits:
    """The units ``model`` is fitted on: episodes for a recurrent student, else labels."""
    return EpisodeUnits(model, data) if is_recurrent_model(model) else FitUnits(model, data)


def fit_student(
    model: Any,
    data: RoundData,
    config: ImitationConfig,
    rng: np.random.Generator,
    value_bounds_s: tuple[float, float] | None = None,
    reward: RewardConfig | None = None,
) -> dict[str, float]:
    """Fit the policy to the labels: the expert's actions and the priced states' values.

    Args:
        model: The student (SB3 PPO or sb3-contrib RecurrentPPO); its policy is trained in
            place.
        data: All labels so far, whole episodes in play order.
        config: Epochs, batch size, learning rate, label weights.
        rng: Minibatch order.
        value_bounds_s: The env's branch value bounds (s), for price conditioning
            (:func:`label_weights`) and ``config.price_samples_s``.
        reward: The env's reward weights, to price states again at ``config.price_samples_s``
            (:class:`PriceSamples`).

    The loss is ``expert_label_weight`` x the weighted cross-entropy of the expert's actions
    plus ``cost_to_go_weight`` x the expected regret on the steps priced by cost-to-go
    branches (:func:`~branch_gym.training.imitation.cost_to_go.expected_regret`; feed-forward
    students only). The units of the fit (:func:`fit_units`) are single labels for a
    feed-forward policy and whole episodes for a recurrent one (a minibatch holds as many
    episodes as make about ``config.batch_size`` labels). A random ``validation_fraction`` of
    the units is held out; after each epoch the loss on it is measured, and the weights of the
    best epoch are kept (early stopping).

    Returns:
        The epoch kept, the losses and the accuracies of the deterministic action on the fitted
        and the held-out labels, the number of held-out labels; with priced steps, their number
        and the expected regret of the deterministic policy on them.
    """
    import torch

    policy = model.policy
    units = fit_units(model, data)
    label_weight = label_weights(data, config, value_bounds_s)
    weights = torch.as_tensor(label_weight, dtype=torch.float32)
    is_priced = np.zeros(len(data.expert_actions), bool)
    is_priced[data.priced()] = True
    if is_priced.any() and isinstance(units, EpisodeUnits):
        raise ValueError("cost-to-go labels need a feed-forward student")
    values = None if data.action_values is None else np.nan_to_num(data.action_values)
    samples = PriceSamples(data, config.price_samples_s, value_bounds_s, reward)
    per_batch = units.per_batch(config.batch_size)
    n_held_out = round(config.validation_fraction * units.count)
    if n_held_out:
        order = rng.permutation(units.count)
        held_out, train = order[:n_held_out], order[n_held_out:]
    else:  # every label is fitted, for all epochs
        held_out, train = np.zeros(0, np.int64), np.arange(units.count)
    optimizer = torch.optim.AdamW(
        policy.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )

    def loss_of(part: np.ndarray) -> float:
        index = units.labels(part)
        probabilities = units.probabilities(part, config.batch_size)
        loss = config.expert_label_weight * weighted_nll(
            probabilities, data.expert_actions[index], label_weight[index]
        )
        priced = is_priced[index]
        if priced.any() and config.cost_to_go_weight:
            regret = expected_regret(
                torch.as_tensor(probabilities[priced]), torch.as_tensor(values[index[priced]])
            )
            with torch.no_grad():
                regret = samples.mean_regret(policy, index[priced], regret)
            loss += config.cost_to_go_weight * float(regret)
        return loss

    best_loss, best_state, best_epoch = math.inf, None, 0
    for epoch in range(1, config.epochs + 1):
        policy.set_training_mode(True)
        order = rng.permutation(train)
        for start in range(0, len(order), per_batch):
            part = order[start : start + per_batch]
            index = units.labels(part)
            loss = 0.0
            if config.expert_label_weight:
                log_prob = units.log_probabilities(part)
                loss = config.expert_label_weight * weighted_nll_loss(log_prob, weights[index])
            priced = index[is_priced[index]]
            if len(priced) and config.cost_to_go_weight:
                probabilities = _probabilities_with_grad(policy, data, priced)
                regret = expected_regret(
                    probabilities, torch.as_tensor(values[priced], dtype=torch.float32)
                )
                loss = loss + config.cost_to_go_weight * samples.mean_regret(policy, priced, regret)
            if isinstance(loss, torch.Tensor):
                optimiser_step(model, optimizer, loss)
        policy.set_training_mode(False)
        if n_held_out == 0:
            best_epoch = epoch
            continue
        held_out_loss = loss_of(held_out)
        if held_out_loss < best_loss:
            best_loss, best_epoch = held_out_loss, epoch
            best_state = copy.deepcopy(policy.state_dict())
    if best_state is not None:  # early stopping: the epoch with the lowest held-out loss
        policy.load_state_dict(best_state)

    def accuracy(part: np.ndarray) -> float:
        if len(part) == 0:
            return math.nan
        predicted = units.probabilities(part, config.batch_size).argmax(axis=1)
        return float(np.mean(predicted == data.expert_actions[units.labels(part)]))

    scores = {
        "epochs_kept": best_epoch,
        "train_loss": loss_of(train),
        "held_out_loss": best_loss if n_held_out else math.nan,
        "held_out_labels": len(units.labels(held_out)),
        "train_accuracy": accuracy(train),
        "held_out_accuracy": accuracy(held_out),
    }
    if is_priced.any():
        scores.update(priced_scores(data, units.probabilities(train, config.batch_size), train))
    return scores


class PriceSamples:
    """The priced states again at other prices: ``ImitationConfig.price_samples_s``.

    A priced state's label holds, for each action, what its branch ended with
    (``RoundData.action_outcomes``); at a branch value V its return is the env's
    (:meth:`~branch_gym.env.reward.RewardConfig.episode_return` with ``match_reward / V`` a
    second), and the observation shows V as its ``price``.

    Args:
        data: The labels.
        prices_s: The branch values (s) to price again at; () for none.
        value_bounds_s: The env's branch value bounds (s) (the price feature's range).
        reward: The env's reward weights.

    Raises:
        ValueError: prices without an env price, reward weights or outcomes on every priced
            state, or outcomes that do not give back the labels' own values (named).
    """

    def __init__(
        self,
        data: RoundData,
        prices_s: tuple[float, ...],
        value_bounds_s: tuple[float, float] | None,
        reward: RewardConfig | None,
    ) -> None:
        self.data, self.prices_s = data, tuple(prices_s)
        self.bounds_s, self.reward = value_bounds_s, reward
        priced = data.priced()
        if not self.prices_s or len(priced) == 0:
            return
        if value_bounds_s is None or PRICE_KEY not in data.observations or reward is None:
            raise ValueError(
                "ImitationConfig.price_samples_s needs an env with a price (v1 or later) and "
                "its reward weights"
            )
        outcomes = data.action_outcomes
        if outcomes is None or not np.isfinite(outcomes[priced]).all():
            raise ValueError(
                "ImitationConfig.price_samples_s needs every priced state's branch outcomes "
                "(round_K.branches.jsonl with scan times and counts: runs from 2026-12-05)"
            )
        own_s = branch_value_s(data.observations[PRICE_KEY][priced].reshape(-1), value_bounds_s)
        again = self.values(priced, own_s[:, None])
        error = np.abs(again - data.action_values[priced]).max()
        if error > _REPRICE_TOLERANCE:
            raise ValueError(
                f"the branch outcomes give back the labels' values only within {error:.2g} "
                f"(> {_REPRICE_TOLERANCE}): the branch log does not match the labels"
            )

    def values(self, index: np.ndarray, branch_value_s: Any) -> np.ndarray:
        """(len(index), n_actions) the returns of the priced rows ``index`` at branch values.

        Args:
            index: Priced rows.
            branch_value_s: The branch value (s), a scalar or (len(index), 1).
        """
        outcomes = self.data.action_outcomes[index]
        columns = dict(zip(OUTCOME_COLUMNS, np.moveaxis(outcomes, -1, 0), strict=True))
        metrics = SimpleNamespace(**{k: columns[k] for k in OUTCOME_COLUMNS[1:4]})
        time_penalty = self.reward.match_reward / np.asarray(branch_value_s, float)
        return self.reward.episode_return(
            metrics, columns["scan_time_s"], columns["failure"], time_penalty
        )

    def mean_regret(self, policy: Any, index: np.ndarray, own_regret: Any) -> Any:
        """The expected regret on priced rows averaged over their own price and the samples.

        Args:
            policy: The student's policy.
            index: Priced rows.
            own_regret: Their expected regret at their own price (a torch scalar).
        """
        import torch

        if not self.prices_s:
            return own_regret
        total = own_regret
        for value_s in self.prices_s:
            observations = {key: value[index] for key, value in self.data.observations.items()}
            price = price_feature(value_s, self.bounds_s)
            observations[PRICE_KEY] = np.full_like(observations[PRICE_KEY], price)
            probabilities = policy_probabilities(policy, observations)
            values = torch.as_tensor(self.values(index, value_s), dtype=torch.float32)
            total = total + expected_regret(probabilities, values)
        return total / (1 + len(self.prices_s))


def priced_scores(
    data: RoundData, probabilities: np.ndarray, index: np.ndarray
) -> dict[str, float]:
    """How a policy's deterministic choices fare on the priced steps among ``index``.

    Args:
        data: Labels with action values.
        probabilities: (len(index), n_actions) the policy's action probabilities there.
        index: Which labels.

    Returns:
        ``priced_states``; ``priced_rotation_best_share``: the share of them where holding
        (action 0) is worse than the best action; ``priced_regret``: the mean regret of the
        policy's most likely action (returns: a found branch is 1).
    """
    priced = np.isin(index, data.priced())
    if not priced.any():
        return {"priced_states": 0}
    values = data.action_values[index[priced]]
    best = values.max(axis=1)
    chosen = values[np.arange(len(values)), probabilities[priced].argmax(axis=1)]
    return {
        "priced_states": int(priced.sum()),
        "priced_rotation_best_share": float(np.mean(values[:, 0] < best)),
        "priced_regret": float(np.mean(best - chosen)),
    }


def _probabilities_with_grad(policy: Any, data: RoundData, index: np.ndarray) -> Any:
    """(len(index), n_actions) torch action probabilities of a feed-forward policy."""
    return policy_probabilities(
        policy, {key: value[index] for key, value in data.observations.items()}
    )


def policy_probabilities(policy: Any, observations: dict[str, np.ndarray]) -> Any:
    """(B, n_actions) torch action probabilities (with gradients) of a feed-forward policy."""
    tensors, _ = policy.obs_to_tensor(observations)
    return policy.get_distribution(tensors).distribution.probs


def student_probabilities(model: Any, data: RoundData) -> np.ndarray:
    """(N, n_actions) a student's action probabilities for every label, in order.

    A recurrent student runs each episode from its start (:class:`EpisodeUnits`).
    """
    units = fit_units(model, data)
    return units.probabilities(np.arange(units.count), _AUC_BATCH)


def weighted_nll(probabilities: np.ndarray, actions: np.ndarray, weights: np.ndarray) -> float:
    """The fit's loss on some labels: weighted cross-entropy of the expert's actions.

    Args:
        probabilities: (N, n_actions) the student's action probabilities.
        actions: (N,) the expert's actions.
        weights: (N,) label weights (:func:`label_weights`).
    """
    chosen = np.clip(probabilities[np.arange(len(actions)), actions], 1e-12, 1.0)
    return float(-(weights * np.log(chosen)).sum() / max(float(weights.sum()), 1e-12))


def weighted_nll_loss(log_prob: Any, weights: Any) -> Any:
    """The weighted cross-entropy of some labels, a torch scalar.

    Args:
        log_prob: (B,) torch log-probabilities of the expert's actions.
        weights: (B,) torch label weights (:func:`label_weights`).
    """
    return -(weights * log_prob).sum() / weights.sum()


def optimiser_step(model: Any, optimizer: Any, loss: Any) -> None:
    """One optimiser step on a loss of the policy (``max_grad_norm`` clips the gradient)."""
    import torch

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


def is_recurrent_model(model: Any) -> bool:
    """Whether a student is an sb3-contrib RecurrentPPO (an LSTM policy)."""
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy

    return isinstance(model.policy, RecurrentActorCriticPolicy)


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
