"""A round's labelled observations (:class:`RoundData`), its file ``round_K.npz``, its episodes.

>>> data = RoundData({"vector": np.zeros((3, 12), np.float32)}, np.array([0, 2, 0]))
>>> data.observations["vector"][:, VectorField.SCAN_TIME] = [0.0, 0.1, 0.0]  # a reset at 2
>>> episode_slices(data)
[slice(0, 2, None), slice(2, 3, None)]
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np

from branch_gym.env.layout import VECTOR_KEY, VectorField


@dataclass
class RoundData:
    """Labelled observations of one round (arrays stacked over steps).

    Attributes:
        observations: Each observation key's (N, ...) array.
        expert_actions: (N,) int64, the expert's action at each step.
        action_values: (N, n_actions) float, the return each action leads to
            (:mod:`~branch_gym.training.imitation.cost_to_go`); NaN rows for the steps not
            priced. None: a run without cost-to-go labels.
    """

    observations: dict[str, np.ndarray]
    expert_actions: np.ndarray
    action_values: np.ndarray | None = None

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
        return cls(
            {key: np.concatenate([r.observations[key] for r in rounds]) for key in keys},
            np.concatenate([r.expert_actions for r in rounds]),
            values,
        )

    def priced(self) -> np.ndarray:
        """Indices of the steps with a value for every action."""
        if self.action_values is None:
            return np.zeros(0, np.int64)
        return np.flatnonzero(np.isfinite(self.action_values).all(axis=1))

    @classmethod
    def load_rounds(cls, run: Path, rounds: list[int]) -> RoundData:
        """The labels of some rounds of a run folder, concatenated in round order.

        Raises:
            FileNotFoundError: a round file is missing (named).
            ValueError: a round file is corrupt (named).
        """
        paths = [round_path(run, k) for k in rounds]
        missing = [str(p) for p in paths if not p.exists()]
        if missing:
            raise FileNotFoundError(f"no labels {', '.join(missing)}")
        return cls.concatenate([cls.load(p) for p in paths])


def round_path(run: Path, round_index: int) -> Path:
    """The labels of one round of a run folder."""
    return Path(run) / f"round_{round_index}.npz"


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
