"""Labelling episodes: the student (or the expert) plays, the expert labels every step.

Episodes run in worker processes (:func:`init_worker` builds the run's env and its privileged
expert once per process); :func:`label_episode` plays one tree and returns its labels and a
summary for ``rounds.jsonl``; :func:`branch_task` prices one action of a sampled state
(:mod:`~branch_gym.training.imitation.cost_to_go`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

import branch_gym  # noqa: F401  (registers the env ids in worker processes)
from branch_gym.evaluation.episodes import run_episode
from branch_gym.privileged import SPEC_KIND as PRIVILEGED_SPEC
from branch_gym.privileged import PrivilegedAgent, parse_privileged_spec
from branch_gym.threads import pin_worker_threads
from branch_gym.training.config import TrainConfig
from branch_gym.training.imitation.cost_to_go import (
    BranchTask,
    HoldAgent,
    branch_outcome,
    play_branch,
)
from branch_gym.training.imitation.data import RoundData
from branch_gym.training.model_files import load_model

_WORKER: dict[str, Any] = {}


def init_worker(train_config: dict[str, Any], expert: str = PRIVILEGED_SPEC) -> None:
    """Set up a labelling process: the run's env, its expert (a privileged spec), no student."""
    pin_worker_threads()
    config = TrainConfig.from_dict(train_config)
    env = gym.make(config.env_id, **config.env_kwargs())
    expert_config = parse_privileged_spec(expert)
    if expert_config is None:
        raise ValueError(f"the labelling expert must be a privileged spec, got {expert!r}")
    _WORKER.update(
        env=env,
        expert=PrivilegedAgent.for_env(env, expert_config),
        hold=HoldAgent.for_env(env),
        student=None,
        path=None,
    )


def _student(path: str | None) -> Any:
    """The student of a model file in this worker (loaded once per round), None for none."""
    if path is None:
        return None
    if _WORKER["path"] != path:
        _WORKER.update(student=load_model(path), path=path)
    return _WORKER["student"]


class LabellingAgent:
    """Acts as the student (the expert where None) and records the expert's action at each step.

    A :class:`branch_gym.policy.Policy`, so the project's one episode loop
    (:func:`branch_gym.evaluation.episodes.run_episode`) plays it.

    Args:
        expert: The privileged policy of the env.
        student: A model with SB3's ``predict``, or None to let the expert act.
    """

    def __init__(self, expert: Any, student: Any = None) -> None:
        self.expert, self.student = expert, student
        self.observations: list[dict[str, np.ndarray]] = []
        self.labels: list[int] = []
        self.actions: list[int] = []  # what was played (the replay of a cost-to-go branch)
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
        self.actions.append(action)
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
        (tree seed, steps, agreement with the expert, rotations, scan time, missed branches, the
        actions played).
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
        "actions": agent.actions,
    }
    return agent.round_data(), summary


def episode_task(args: tuple[int, str | None]) -> tuple[RoundData, dict[str, Any]]:
    """:func:`label_episode` of a ``(tree seed, student path)`` task (for ``pool.map``)."""
    return label_episode(*args)


def branch_task(task: BranchTask) -> dict[str, Any]:
    """The return of one cost-to-go branch in this worker (for ``pool.map``), with its end
    (:func:`~branch_gym.training.imitation.cost_to_go.branch_outcome`).

    The roll-out is the task's student, else the expert where ``rollout_expert``, else
    :class:`~branch_gym.training.imitation.cost_to_go.HoldAgent` (before the first student).
    """
    if task.rollout_path is not None:
        rollout = _student(task.rollout_path)
    elif task.rollout_expert:
        rollout = _WORKER["expert"]
    else:
        rollout = _WORKER["hold"]
    return branch_outcome(*play_branch(_WORKER["env"], task, rollout))


class RayLabellers:
    """``pool.map`` over Ray tasks: each Ray worker process sets up the run's env once.

    The labelling functions (:func:`episode_task`, :func:`branch_task`) run as Ray tasks of one
    CPU each, in order of submission, results in order. Student models are read from the run
    folder by path: on a multi-node cluster the run folder must be on a filesystem every node
    mounts at the same path.

    Args:
        ray: The initialised ``ray`` module (:func:`branch_gym.evaluation.ray_backend.ray_session`).
        train_config: The run's ``TrainConfig.to_dict()``.
        expert: The labelling expert's spec (``ImitationConfig.expert``).
    """

    def __init__(
        self, ray: Any, train_config: dict[str, Any], expert: str = PRIVILEGED_SPEC
    ) -> None:
        self._ray = ray
        self._setup = (train_config, expert)
        self._remote = ray.remote(num_cpus=1)(_call_in_worker)

    def map(self, function: Any, items: Any) -> Any:
        """Yield ``function(item)`` for each item, in order, each run as a Ray task."""
        refs = [self._remote.remote(function, self._setup, item) for item in items]
        for ref in refs:
            yield self._ray.get(ref)


def _call_in_worker(function: Any, setup: tuple[dict[str, Any], str], item: Any) -> Any:
    """One labelling call in a Ray worker process, its env built on the first call.

    ``setup`` is ``(train_config, expert)``, the arguments of :func:`init_worker`.
    """
    if _WORKER.get("setup") != setup:
        init_worker(*setup)
        _WORKER["setup"] = setup
    return function(item)
