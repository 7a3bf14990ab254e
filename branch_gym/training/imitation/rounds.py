"""The DAgger round loop (:func:`imitate`): label, fit, save, log; an interrupted run resumes.

Every round is saved in the run folder (its labels ``round_K.npz``, the student after it
``model_round_K.zip``, a line of ``rounds.jsonl``), so an interrupted run resumes at the next
round (:func:`finished_rounds`: every round's labels and the last student are enough, the
earlier students may be pruned); the cost-to-go branches of the round under way are kept as
they finish (``round_K.branches.jsonl``) and not run again. Episodes and branches run in
``workers`` processes on the run's training trees
(:func:`branch_gym.training.seeds.train_seed_range`, after the first ``tree_offset`` of them).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import json
import logging
import math
import multiprocessing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from branch_gym.env.layout import VECTOR_KEY, VectorField
from branch_gym.evaluation.ray_backend import BACKENDS, ray_session
from branch_gym.threads import pin_worker_threads
from branch_gym.training.imitation.config import (
    CONFIG_FILE,
    FINAL_MODEL,
    RESUMABLE_CHANGES,
    ROUNDS_LOG,
    ImitationConfig,
)
from branch_gym.training.imitation.cost_to_go import (
    BranchTask,
    action_values,
    distinct_actions,
    sample_steps,
)
from branch_gym.training.imitation.data import (
    RoundData,
    branch_log_path,
    load_round,
    model_path,
    read_outcomes,
    round_path,
)
from branch_gym.training.imitation.fit import (
    fit_student,
    new_student,
    rotation_auc,
    value_bounds_s,
)
from branch_gym.training.imitation.labels import (
    RayLabellers,
    branch_task,
    episode_task,
    init_worker,
)
from branch_gym.training.model_files import ModelFinder, existing_file, load_model
from recon.metrics import pooled_percent

logger = logging.getLogger(__name__)

# A fitted student whose rotation AUC on its own labels is below this has not learned them.
COLLAPSED_AUC = 0.6


def imitate(
    config: ImitationConfig,
    out: str | Path,
    resume: bool = False,
    workers: int = 2,
    progress: bool = False,
    backend: str = "pool",
    address: str | None = None,
    find_model: ModelFinder = existing_file,
) -> Path:
    """Run (or resume) DAgger; returns ``OUT/model.zip``, the student after the last round.

    Args:
        config: The run.
        out: The run folder.
        resume: Continue the run in ``out``.
        workers: Labelling processes (pool), or CPUs of a private local Ray instance.
        progress: Show progress bars.
        backend: "pool" (a process pool here) or "ray" (Ray tasks: a local instance, or the
            cluster at ``address``); the labels are the same either way.
        address: A Ray cluster address ("auto", "HOST:PORT", "ray://HOST:10001"); with "ray".
        find_model: ``config.train.init_model`` -> its file (plain paths by default;
            ``agents.ppo.resolve_model_path`` also knows the shipped models' names).

    Raises:
        FileExistsError: a new run in a folder that already holds one.
        ValueError: resuming with another configuration; a corrupt or missing round file
            (named).
    """
    pin_worker_threads()  # the fits run here while the workers label: one thread each
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
    done = finished_rounds(out, config.rounds)
    rounds = [load_round(out, k) for k in range(done)]
    spaces_env = gym.make(config.train.env_id, **config.train.env_kwargs())
    model = (
        load_model(model_path(out, done - 1))
        if done
        else new_student(config, spaces_env, find_model)
    )
    bounds = value_bounds_s(spaces_env)
    reward = spaces_env.unwrapped.config.reward
    bar = None
    if progress:
        bar = tqdm(total=config.rounds * config.episodes, initial=done * config.episodes)
    try:
        with _labellers(config, workers, backend, address) as pool:
            for round_index in range(done, config.rounds):
                student_path = None if round_index == 0 else str(model_path(out, round_index - 1))
                tasks = [
                    (config.tree_seed(round_index, episode), student_path)
                    for episode in range(config.episodes)
                ]
                results, summaries = [], []
                for data, summary in pool.map(episode_task, tasks):
                    results.append(data)
                    summaries.append(summary)
                    if bar is not None:
                        bar.update(1)
                round_data = RoundData.concatenate(results)
                if config.cost_to_go_states:
                    round_data.action_values = _price_states(
                        pool, config, round_index, results, summaries, student_path, spaces_env,
                        out, progress,
                    )  # fmt: skip
                    log = branch_log_path(out, round_index)
                    round_data.action_outcomes = read_outcomes(round_data, log)
                round_data.save(round_path(out, round_index))
                rounds.append(round_data)
                # The student that played this round, on labels it was not fitted on.
                held_out_auc = math.nan if student_path is None else rotation_auc(model, round_data)
                rng = np.random.default_rng([config.train.seed, round_index])
                if config.from_scratch:
                    model = new_student(config, spaces_env, find_model)
                all_labels = RoundData.concatenate(rounds)
                fit = fit_student(model, all_labels, config, rng, bounds, reward)
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
                model.save(model_path(out, round_index))
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


def finished_rounds(out: Path, most: int) -> int:
    """How many rounds of the run in ``out`` are finished (at most ``most``).

    Rounds 0 .. d - 1 are finished when all their labels are kept and the student fitted after
    round d - 1 is saved: the next round needs only that student, so a kept run may prune the
    students before it. A round whose labels were saved but whose student was not (interrupted
    while fitting) is played again (its cost-to-go branches are not run again).
    """
    labelled = 0
    while labelled < most and round_path(out, labelled).exists():
        labelled += 1
    done = labelled
    while done and not model_path(out, done - 1).exists():
        done -= 1
    later = [k for k in range(done, most) if model_path(out, k).exists()]
    if later:
        raise ValueError(
            f"{out} keeps the student of round {later[-1]} but not the labels of round "
            f"{labelled} ({round_path(out, labelled).name}): a kept run needs every round's labels"
        )
    return done


def _price_states(
    pool: Any,
    config: ImitationConfig,
    round_index: int,
    episodes: list[RoundData],
    summaries: list[dict[str, Any]],
    student_path: str | None,
    env: Any,
    out: Path,
    progress: bool,
) -> np.ndarray:
    """(N, n_actions) cost-to-go values of the round's sampled states (NaN rows elsewhere).

    The branches already in ``round_K.branches.jsonl`` (an interrupted round) are not run again.
    """
    theta_max = env.unwrapped.config.theta_max_deg
    n_actions = int(env.action_space.n)
    jobs: list[tuple[int, list[list[int]], list[BranchTask]]] = []  # (row, groups, tasks)
    offset = 0
    for data, summary in zip(episodes, summaries, strict=True):
        seed = summary["tree_seed"]
        rng = np.random.default_rng([config.train.seed, round_index, seed])
        for step in sample_steps(len(summary["actions"]), config.cost_to_go_states, rng):
            vector = data.observations[VECTOR_KEY][step]
            groups = distinct_actions(env, float(vector[VectorField.ANGLE]) * theta_max)
            tasks = [
                BranchTask(
                    seed,
                    tuple(summary["actions"][:step]),
                    vector,
                    group[0],
                    student_path if config.rollout == "student" else None,
                    rollout_expert=config.rollout == "expert",
                )
                for group in groups
            ]
            jobs.append((offset + int(step), groups, tasks))
        offset += len(data.expert_actions)
    log = branch_log_path(out, round_index)
    done = {}
    if log.exists():
        for line in log.read_text().splitlines():
            row = json.loads(line)
            done[(row["tree_seed"], row["step"], row["action"])] = row["return"]
    pending = [task for _, _, tasks in jobs for task in tasks if _branch_key(task) not in done]
    bar = tqdm(total=len(pending), desc="cost-to-go branches") if progress else None
    with open(log, "a") as handle:
        for task, outcome in zip(pending, pool.map(branch_task, pending), strict=True):
            done[_branch_key(task)] = outcome["return"]
            tree_seed, step, action = _branch_key(task)
            row = {"tree_seed": tree_seed, "step": step, "action": action, **outcome}
            handle.write(json.dumps(row) + "\n")
            handle.flush()
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    values = np.full((offset, n_actions), np.nan)
    for row, groups, tasks in jobs:
        returns = [done[_branch_key(task)] for task in tasks]
        values[row] = action_values(groups, returns, n_actions)
    return values


def _branch_key(task: BranchTask) -> tuple[int, int, int]:
    return int(task.tree_seed), len(task.prefix_actions), int(task.action)


def _log_round(
    out: Path,
    round_index: int,
    expert_played: bool,
    summaries: list[dict[str, Any]],
    fit: dict[str, float],
    labels: int,
    fit_settings: dict[str, Any],
) -> None:
    n_gt = [s["n_gt"] for s in summaries]
    row = {
        "round": round_index,
        "played_by": "expert" if expert_played else "student",
        "episodes": len(summaries),
        "labels": labels,
        "agreement": float(np.mean([s["agreement"] for s in summaries])),
        "expert_rotate_share": float(np.mean([s["expert_rotate_share"] for s in summaries])),
        "rotations": float(np.mean([s["rotations"] for s in summaries])),
        "scan_time_s": float(np.mean([s["scan_time_s"] for s in summaries])),
        "missed_pct": pooled_percent([s["n_missed"] for s in summaries], n_gt),
        **fit,
        **fit_settings,
    }
    logger.info("round %d: %s", round_index, row)
    with open(out / ROUNDS_LOG, "a") as handle:
        handle.write(json.dumps(row) + "\n")


@contextlib.contextmanager
def _labellers(
    config: ImitationConfig, workers: int, backend: str, address: str | None
) -> Iterator[Any]:
    """Something with ``map(function, items)`` that runs the labelling calls in parallel."""
    train = config.train.to_dict()
    if backend == "ray":
        with ray_session(address, workers) as ray:
            yield RayLabellers(ray, train, config.expert)
        return
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if address is not None:
        raise ValueError("a Ray address needs the ray backend")
    with concurrent.futures.ProcessPoolExecutor(
        max_workers=workers,
        initializer=init_worker,
        initargs=(train, config.expert),
        mp_context=_spawn_context(),
    ) as pool:
        yield pool


def _spawn_context() -> Any:
    """Fresh worker processes (no pybullet or torch state forked from this one)."""
    return multiprocessing.get_context("spawn")
