"""Run evaluation trials as Ray tasks: on a private local Ray instance, or on a Ray cluster.

Each trial is one Ray task that plays the episode (:func:`run_scan_in_env`, as the pool backend
does) and returns the trial's record as its strict-JSON dict. This process (the driver) saves
every record under ``OUT/trials/`` as soon as its task finishes, so the files land on the
driver's disk even when the task ran on another node, the progress callback advances per trial,
and an interrupted evaluation resumes like one of the pool backend. A trial is a pure function of
(policy, seed, scan configuration): the records equal the pool backend's, wall-clock timings
aside, and a folder started with one backend resumes with the other.

Ray is an optional dependency (``pip install .[ray]``), imported here on first use only. Every
node of a cluster must have this project and its dependencies installed (e.g. in the cluster's
container image): tasks refer to the trial function by its module.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

from branch_gym.evaluation.config import EvalConfig, TrialError, TrialKey
from branch_gym.evaluation.episodes import run_trial
from branch_gym.evaluation.trials import TrialRecord, code_version, trial_path
from branch_gym.files import write_json_atomic
from branch_gym.policy import PolicyFactory
from branch_gym.scan import ScanConfig

logger = logging.getLogger(__name__)

INSTALL_HINT = "pip install '.[ray]'"
# ray.init's address for a new private instance on this machine (never an existing cluster).
LOCAL_ADDRESS = "local"
# CPUs a trial reserves: a trial is single-threaded (one BLAS thread, like the pool's workers).
CPUS_PER_TRIAL = 1.0
BACKENDS = ("pool", "ray")


def add_backend_arguments(
    parser: argparse.ArgumentParser, workers_default: int, workers_help: str
) -> None:
    """``--workers``, ``--backend {pool,ray}`` and ``--address`` of a command that runs its work
    on a process pool or on Ray (``eval.py``, the imitation runs)."""
    parser.add_argument(
        "--workers",
        type=int,
        default=workers_default,
        help=f"{workers_help} (default {workers_default})",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="pool",
        help="pool: this process or a process pool (default); ray: Ray tasks (pip install .[ray])",
    )
    parser.add_argument(
        "--address",
        metavar="ADDR",
        help="Ray cluster address (auto | HOST:PORT | ray://HOST:10001); with --backend ray; "
        "default: a private local Ray instance",
    )


class RayUnavailableError(ImportError):
    """The ray backend was asked for, but Ray is not installed."""


def import_ray() -> ModuleType:
    """Import Ray.

    Raises:
        RayUnavailableError: Ray is not installed; the message says how to install it.
    """
    try:
        import ray
    except ImportError as exc:
        raise RayUnavailableError(
            f"the ray backend needs Ray, which is not installed: {INSTALL_HINT} "
            "(or pip install 'ray[default]')"
        ) from exc
    return ray


@contextmanager
def ray_session(address: str | None, num_cpus: int) -> Iterator[ModuleType]:
    """Connect this process to Ray for the duration of the block.

    Args:
        address: Cluster address for ``ray.init`` ("auto", "HOST:PORT", "ray://HOST:10001");
            None starts a new private local instance.
        num_cpus: CPUs of a new local instance (unused when connecting to a cluster).

    Yields:
        The ``ray`` module, initialised. A session this process already had (``ray.init``
        called by the caller) is used as it is and left running; one started here is shut down.

    Raises:
        RayUnavailableError: Ray is not installed.
        ConnectionError: no cluster answers at ``address``.
    """
    ray = import_ray()
    if ray.is_initialized():
        if address is not None:
            logger.warning("Ray is already initialised in this process: address %r unused", address)
        yield ray
        return
    if address is None:
        init_local(ray, num_cpus)
    else:
        ray.init(address=address)
    logger.info("Ray resources: %s", ray.cluster_resources())
    try:
        yield ray
    finally:
        ray.shutdown()


def init_local(ray: ModuleType, num_cpus: int) -> None:
    """Start a new private Ray instance on this machine with ``num_cpus`` CPUs."""
    # The dashboard only costs start-up time and memory for a short-lived private instance.
    ray.init(address=LOCAL_ADDRESS, num_cpus=num_cpus, include_dashboard=False)


def trial_json(
    policy: str,
    seed: int,
    scan: ScanConfig,
    scan_hash: str,
    factory: PolicyFactory,
    code_version: str | None = None,
) -> dict[str, Any]:
    """Run one trial and return its record as strict JSON (the body of a Ray task).

    ``factory`` reads the policy spec (pickled by reference: the workers import its package).
    ``code_version`` is the driver's (:func:`~branch_gym.evaluation.trials.code_version`): a
    cluster's workers need not run from a git checkout.

    Raises:
        TrialError: the trial raised (the message names it).
    """
    try:
        result = run_trial(seed, policy, scan, factory)
    except Exception as exc:
        raise TrialError(f"trial {policy!r} seed {seed} raised {exc!r}") from exc
    return TrialRecord.from_scan(result, policy, scan_hash, code_version).to_json_dict()


def run_trials_ray(
    config: EvalConfig,
    out: Path,
    keys: Sequence[TrialKey],
    on_done: Callable[[TrialKey], None],
) -> list[TrialKey]:
    """Run and save the given trials as Ray tasks, at most ``config.workers`` at a time.

    Args:
        config: The evaluation (``config.address``: the cluster, None for a local instance of
            ``config.workers`` CPUs).
        out: Output folder; each trial is saved there (by this process) as soon as it finishes.
        keys: The trials to run.
        on_done: Called after each trial is saved.

    Returns:
        The trials run, in completion order.

    Raises:
        RayUnavailableError: Ray is not installed.
        TrialError: a trial raised; the trials already finished stay saved, the running ones
            are cancelled.
    """
    done: list[TrialKey] = []
    if not keys:
        return done
    workers = min(config.workers, len(keys))
    with ray_session(config.address, workers) as ray:
        task = ray.remote(num_cpus=CPUS_PER_TRIAL)(trial_json)
        version = code_version()
        queue = list(reversed(keys))  # popped from the end: table order
        running: dict[Any, TrialKey] = {}
        try:
            while queue or running:
                while queue and len(running) < workers:
                    policy, seed = queue.pop()
                    ref = task.remote(
                        policy, seed, config.scan, config.scan_hash, config.policy_factory, version
                    )
                    running[ref] = (policy, seed)
                (ready,), _ = ray.wait(list(running), num_returns=1)
                key = running.pop(ready)
                data = _result(ray, ready, key)
                write_json_atomic(trial_path(out, *key), data)
                done.append(key)
                on_done(key)
        except BaseException:  # a failed trial or Ctrl-C: stop at once, the saved trials stay
            for ref in running:
                ray.cancel(ref, force=True)
            if running:
                logger.warning("cancelled %d running Ray trials", len(running))
            raise
    return done


def _result(ray: ModuleType, ref: Any, key: TrialKey) -> dict[str, Any]:
    """A finished task's record, or a TrialError naming the trial (not Ray's wrapper)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        raise TrialError(f"trial {key[0]!r} seed {key[1]} failed in Ray: {exc}") from exc
