"""A round's labelled observations (:class:`RoundData`), its file ``round_K.npz``, its episodes.

>>> data = RoundData({"vector": np.zeros((3, 12), np.float32)}, np.array([0, 2, 0]))
>>> data.observations["vector"][:, VectorField.SCAN_TIME] = [0.0, 0.1, 0.0]  # a reset at 2
>>> episode_slices(data)
[slice(0, 2, None), slice(2, 3, None)]
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np

from branch_gym.env.layout import VECTOR_KEY, VectorField

# What a cost-to-go branch's end holds besides its return (``cost_to_go.branch_outcome``), as the
# columns of ``RoundData.action_outcomes``; "failure" is 1 for a failed scan.
OUTCOME_COLUMNS = ("scan_time_s", "n_matched", "n_spurious", "n_duplicates", "failure")


@dataclass
class RoundData:
    """Labelled observations of one round (arrays stacked over steps).

    Attributes:
        observations: Each observation key's (N, ...) array.
        expert_actions: (N,) int64, the expert's action at each step.
        action_values: (N, n_actions) float, the return each action leads to
            (:mod:`~branch_gym.training.imitation.cost_to_go`); NaN rows for the steps not
            priced. None: a run without cost-to-go labels.
        action_outcomes: (N, n_actions, len(OUTCOME_COLUMNS)) float, what each action's branch
            ended with (scan time, counts, failure), read from the round's branch log
            (:func:`read_outcomes`), so that a label can be priced again at another price; NaN
            where not priced. None: no branch log with outcomes (runs before 2026-12-05).
    """

    observations: dict[str, np.ndarray]
    expert_actions: np.ndarray
    action_values: np.ndarray | None = None
    action_outcomes: np.ndarray | None = None

    def save(self, path: Path) -> None:
        """Write ``path`` (``.npz``) atomically: the observations as ``obs_KEY`` arrays."""
        arrays = {f"obs_{key}": value for key, value in self.observations.items()}
        if self.action_values is not None:
            arrays["action_values"] = self.action_values
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, expert_actions=self.expert_actions, **arrays)
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: Path) -> RoundData:
        """Read a round file.

        Raises:
            ValueError: the file is corrupt (named).
        """
        try:
            with np.load(path) as data:
                observations = {key[4:]: data[key] for key in data.files if key.startswith("obs_")}
                actions = data["expert_actions"]
                values = data["action_values"] if "action_values" in data.files else None
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"imitation round file {path} is corrupt: {exc}") from exc
        return cls(observations, actions, values)

    @classmethod
    def concatenate(cls, rounds: list[RoundData]) -> RoundData:
        """Several rounds' labels as one, in order (unpriced steps: NaN action values).

        Raises:
            ValueError: rounds whose action values have different numbers of actions.
        """
        keys = rounds[0].observations.keys()
        values = None
        widths = {r.action_values.shape[1] for r in rounds if r.action_values is not None}
        if len(widths) > 1:
            raise ValueError(f"rounds price different numbers of actions: {sorted(widths)}")
        outcomes = None
        if widths:
            width = widths.pop()
            values = np.concatenate(
                [
                    np.full((len(r.expert_actions), width), np.nan)
                    if r.action_values is None
                    else r.action_values
                    for r in rounds
                ]
            )
            if any(r.action_outcomes is not None for r in rounds):
                shape = (width, len(OUTCOME_COLUMNS))
                outcomes = np.concatenate(
                    [
                        np.full((len(r.expert_actions), *shape), np.nan)
                        if r.action_outcomes is None
                        else r.action_outcomes
                        for r in rounds
                    ]
                )
        return cls(
            {key: np.concatenate([r.observations[key] for r in rounds]) for key in keys},
            np.concatenate([r.expert_actions for r in rounds]),
            values,
            outcomes,
        )

    def priced(self) -> np.ndarray:
        """Indices of the steps with a value for every action."""
        if self.action_values is None:
            return np.zeros(0, np.int64)
        return np.flatnonzero(np.isfinite(self.action_values).all(axis=1))

    @classmethod
    def load_rounds(cls, run: Path, rounds: list[int]) -> RoundData:
        """The labels of some rounds of a run folder, concatenated in round order.

        A round's branch log (:func:`branch_log_path`) adds its ``action_outcomes`` where it
        records them.

        Raises:
            FileNotFoundError: a round file is missing (named).
            ValueError: a round file is corrupt, or its branch log does not match it (named).
        """
        paths = [round_path(run, k) for k in rounds]
        missing = [str(p) for p in paths if not p.exists()]
        if missing:
            raise FileNotFoundError(f"no labels {', '.join(missing)}")
        return cls.concatenate([load_round(run, k) for k in rounds])


def load_round(run: Path, round_index: int) -> RoundData:
    """One round's labels, with the outcomes of its branch log where it records them.

    Raises:
        ValueError: a corrupt round file, or a branch log that does not match it (named).
    """
    data = RoundData.load(round_path(run, round_index))
    log = branch_log_path(run, round_index)
    if data.action_values is not None and log.exists():
        data.action_outcomes = read_outcomes(data, log)
    return data


def read_outcomes(data: RoundData, log: Path) -> np.ndarray | None:
    """(N, n_actions, len(OUTCOME_COLUMNS)) the outcome of each priced action, from a branch log.

    The log's rows (``tree_seed``, ``step``, ``action`` and :func:`~branch_gym.training.
    imitation.cost_to_go.branch_outcome`'s fields) price states in episode order, the episodes'
    tree seeds rising and their steps sorted, as the round's priced rows are: the k-th state of
    the log, by (seed, step), is the k-th priced row. An action shares the branch of every action
    with the same effect (the same return): each action takes the outcome of the logged branch
    whose return is its value.

    Returns:
        The outcomes, NaN on the rows not priced; None for a log without outcomes (runs before
        2026-12-05 logged the return only).

    Raises:
        ValueError: a log that does not match the round's priced rows (named).
    """
    rows: dict[tuple[int, int, int], dict] = {}
    for line in log.read_text().splitlines():
        row = json.loads(line)
        rows[(row["tree_seed"], row["step"], row["action"])] = row
    if not rows or any(c not in row for row in rows.values() for c in OUTCOME_COLUMNS):
        return None
    states: dict[tuple[int, int], list[dict]] = {}
    for (seed, step, _), row in rows.items():
        states.setdefault((seed, step), []).append(row)
    priced = data.priced()
    if len(priced) != len(states):
        raise ValueError(f"branch log {log} prices {len(states)} states, its round {len(priced)}")
    n_actions = data.action_values.shape[1]
    outcomes = np.full((len(data.expert_actions), n_actions, len(OUTCOME_COLUMNS)), np.nan)
    for index, state in zip(priced, sorted(states), strict=True):
        for action in range(n_actions):
            value = data.action_values[index, action]
            match = [row for row in states[state] if row["return"] == value]
            if not match:
                raise ValueError(
                    f"branch log {log}: no branch of tree {state[0]} step {state[1]} returned "
                    f"action {action}'s value {value}"
                )
            outcomes[index, action] = [
                bool(match[0][c]) if c == "failure" else match[0][c] for c in OUTCOME_COLUMNS
            ]
    return outcomes


def round_path(run: Path, round_index: int) -> Path:
    """The labels of one round of a run folder."""
    return Path(run) / f"round_{round_index}.npz"


def branch_log_path(run: Path, round_index: int) -> Path:
    """The cost-to-go branches of one round of a run folder, one JSON row each."""
    return Path(run) / f"round_{round_index}.branches.jsonl"


def model_path(run: Path, round_index: int) -> Path:
    """The student fitted after one round of a run folder."""
    return Path(run) / f"model_round_{round_index}.zip"


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
