"""Run every policy on the same trees, in a process pool or on Ray, resuming from saved trials.

Each (policy, tree seed) pair is one trial: the policy's agent plays one episode of the Gymnasium
environment (:func:`branch_gym.evaluation.episodes.run_trial`, the one episode loop).
A finished trial is saved at once (:mod:`branch_gym.evaluation.trials`); a later run with the same
output folder loads the trials already there instead of re-running them, so an interrupted
evaluation loses at most the trials that were running. Trials are only comparable under one scan
configuration: the folder records its configuration hash, and a run with another is refused.

Results do not depend on the number of workers, the backend (``"pool"``: this process or a
process pool; ``"ray"``: Ray tasks, :mod:`branch_gym.evaluation.ray_backend`) or on completion
order: every trial is a pure function of (seed, policy, scan configuration), and records are
returned sorted by policy (in the given order) then seed.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from branch_gym.config_utils import flatten_dict
from branch_gym.evaluation.config import EvalConfig, TrialError, TrialKey
from branch_gym.evaluation.episodes import Recording, run_trial
from branch_gym.evaluation.ray_backend import run_trials_ray
from branch_gym.evaluation.trials import (
    TRIALS_DIR,
    TrialRecord,
    code_version,
    config_to_dict,
    load_trial,
    policy_slug,
    save_trial,
    trial_path,
)
from branch_gym.files import write_json_atomic
from branch_gym.policy import PolicyFactory
from branch_gym.scan import ScanConfig
from recon.segmentation.onnx_network import weights_digest
from recon.segmentation.segmenter import weights_path_of
from recon.segmentation.spec import is_learned_segmenter

logger = logging.getLogger(__name__)

CONFIG_FILE = "config.json"
# Digest of a learned policy's files, next to its trials (trials/<policy>/model.json).
MODEL_FILE = "model.json"
SEGMENTER_FILE = "segmenter.json"
"""Beside the trials: the learned segmenter's weights file and digest (folder-wide)."""
# Recorded trials (eval.py --record): JPEG frames, ~4x smaller than PNG; the replay of a JPEG
# recording is close to, not identical with, the online model (docs/replay.md).
RECORD_IMAGE_FORMAT = "jpg"
RECORD_JPEG_QUALITY = 90
PARENT_POLL_S = 1.0  # how often a worker checks that the evaluation process is alive


class ConfigMismatchError(RuntimeError):
    """The output folder holds trials run under another scan configuration."""


def check_output_folder(config: EvalConfig, out: Path) -> None:
    """Record the scan configuration and the learned policies' files in ``out``, or refuse a
    folder made under another configuration or with other model files at the same paths.

    Raises:
        ConfigMismatchError: ``out`` holds trials of a different scan configuration, or trials of
            a ``ppo:PATH`` policy whose model file has changed since (e.g. retrained in place).
    """
    path = out / TRIALS_DIR / CONFIG_FILE
    ours = {"scan_config_hash": config.scan_hash, "scan": config_to_dict(config.scan)}
    if path.exists():
        theirs = json.loads(path.read_text())
        if theirs.get("scan_config_hash") != ours["scan_config_hash"]:
            raise ConfigMismatchError(_mismatch_message(out, theirs, ours))
    else:
        write_json_atomic(path, ours)
    for policy in config.policies:
        files = config.policy_factory.files(policy)
        if files:
            _check_model_files(policy, files, out)
    if is_learned_segmenter(config.scan.segmenter):
        _check_segmenter_weights(config.scan.segmenter, out)


def _check_segmenter_weights(spec: str, out: Path) -> None:
    """Record the digest of a learned segmenter's weights next to the trials, or refuse a change.

    The scan configuration names the segmenter (``"learned"``), not its weights: without this, a
    folder's trials of the weights shipped before would be mixed with the new weights' ones.
    """
    weights = weights_path_of(spec)
    if not weights.is_file():
        raise FileNotFoundError(f"segmenter {spec!r}: weights file {weights} does not exist")
    ours = {"segmenter": spec, "weights": str(weights), "sha256": weights_digest(weights)}
    _record_digest(
        out / TRIALS_DIR / SEGMENTER_FILE,
        ours,
        f"{out} holds trials segmented by other weights than {weights} holds now",
        "use another --out, or delete its trials/ folder to start over",
    )


def _record_digest(record: Path, ours: dict, mismatch: str, remedy: str) -> None:
    """Write ``ours`` (with its ``sha256``) to ``record``, or refuse a recorded other digest.

    Raises:
        ConfigMismatchError: ``record`` holds another ``sha256`` (the message: ``mismatch``, both
            digests, ``remedy``).
    """
    if not record.exists():
        write_json_atomic(record, ours)
        return
    theirs = json.loads(record.read_text())
    if theirs.get("sha256") != ours["sha256"]:
        raise ConfigMismatchError(
            f"{mismatch} (sha256 {str(theirs.get('sha256'))[:12]} there, "
            f"{ours['sha256'][:12]} now): {remedy}."
        )


def _check_model_files(policy: str, files: Sequence[Path], out: Path) -> None:
    """Record the digest of a learned policy's files (the model first) next to its trials, or
    refuse a change."""
    model = files[0]
    digest = hashlib.sha256()
    for path in files:
        digest.update(path.read_bytes())
    ours = {"model": str(model), "sha256": digest.hexdigest()}
    record = out / TRIALS_DIR / policy_slug(policy) / MODEL_FILE
    _record_digest(
        record,
        ours,
        f"{out} holds trials of {policy!r} made with another model file than {model} holds now",
        f"delete {record.parent} to re-run them, or use another --out",
    )


def _mismatch_message(out: Path, theirs: dict, ours: dict) -> str:
    old, new = flatten_dict(theirs.get("scan", {})), flatten_dict(ours["scan"])
    changed = sorted(k for k in old.keys() | new.keys() if old.get(k) != new.get(k))
    details = ", ".join(f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed) or "unknown"
    return (
        f"{out} holds trials of a different scan configuration (hash "
        f"{theirs.get('scan_config_hash')} there, {ours['scan_config_hash']} now; {details}). "
        "Use another --out, or delete its trials/ folder to start over."
    )


def pending_trials(config: EvalConfig, out: Path) -> list[TrialKey]:
    """The trials of ``config`` that have no saved file in ``out`` yet, in table order."""
    return [key for key in config.keys if not trial_path(out, *key).exists()]


def run_trials(
    config: EvalConfig,
    out: Path,
    keys: Sequence[TrialKey],
    on_done: Callable[[TrialKey], None] | None = None,
) -> list[TrialKey]:
    """Run and save the given trials (a process pool when ``config.workers > 1``, or Ray tasks).

    Args:
        config: The evaluation.
        out: Output folder; each trial is saved there as soon as it finishes.
        keys: The trials to run (e.g. :func:`pending_trials`).
        on_done: Called after each trial is saved (e.g. to advance a progress bar).

    Returns:
        The trials run, in completion order.

    Raises:
        TrialError: a trial raised; the trials already finished stay saved.
        RayUnavailableError: the ray backend was chosen and Ray is not installed.
    """
    on_done = on_done or (lambda key: None)
    if config.backend == "ray":
        return run_trials_ray(config, out, keys, on_done)
    tasks = [
        _Task(
            policy,
            seed,
            config.scan,
            config.scan_hash,
            out,
            config.policy_factory,
            code_version(),
            config.record_dir,
        )
        for policy, seed in keys
    ]
    done: list[TrialKey] = []
    if config.workers == 1 or len(tasks) <= 1:
        for task in tasks:
            done.append(_run_task(task))
            on_done(done[-1])
        return done
    context = multiprocessing.get_context("spawn")
    workers = min(config.workers, len(tasks))
    pool = cf.ProcessPoolExecutor(
        workers, mp_context=context, initializer=_init_worker, initargs=(os.getpid(),)
    )
    try:
        futures = [pool.submit(_run_task, task) for task in tasks]
        for future in cf.as_completed(futures):
            done.append(future.result())
            on_done(done[-1])
    except BaseException:  # a failed trial or Ctrl-C: stop at once, the saved trials stay
        _stop_pool(pool)
        raise
    pool.shutdown()
    return done


def load_records(config: EvalConfig, out: Path) -> list[TrialRecord]:
    """All trials of ``config`` from ``out``, policy order then seed.

    Raises:
        FileNotFoundError: a trial has not been run.
        ConfigMismatchError: a trial file was made under another scan configuration.
        ValueError: a trial file is unreadable, or holds another trial than its name says.
    """
    records = []
    for policy, seed in config.keys:
        path = trial_path(out, policy, seed)
        if not path.exists():
            raise FileNotFoundError(f"trial {policy!r} seed {seed} has not been run ({path})")
        record = load_trial(path)
        if record.config_hash != config.scan_hash:
            raise ConfigMismatchError(
                f"trial file {path} was run under scan configuration {record.config_hash}, "
                f"not {config.scan_hash}; use another --out or delete the file"
            )
        if (record.policy, record.seed) != (policy, seed):
            raise ValueError(
                f"trial file {path} holds policy {record.policy!r} seed {record.seed}, "
                f"expected {policy!r} seed {seed}"
            )
        records.append(record)
    return records


@dataclass(frozen=True)
class _Task:
    """Everything a worker process needs for one trial (picklable)."""

    policy: str
    seed: int
    scan: ScanConfig
    scan_hash: str
    out: Path
    factory: PolicyFactory
    code_version: str | None = None
    record_dir: Path | None = None

    def recording(self) -> Recording | None:
        """Where this trial's frames go, if the evaluation records."""
        if self.record_dir is None:
            return None
        folder = self.record_dir / policy_slug(self.policy) / f"seed_{self.seed:04d}"
        return Recording(folder, RECORD_IMAGE_FORMAT, RECORD_JPEG_QUALITY, overwrite=True)


def _stop_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel the queued trials and end the workers now, dropping the trials they were running."""
    processes = list((pool._processes or {}).values())  # no public API for this before 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    logger.warning("stopped %d workers; their running trials were dropped", len(processes))


def _init_worker(parent_pid: int) -> None:
    """Worker set-up: Ctrl-C is the parent's to handle, and the worker ends with the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def exit_when_orphaned() -> None:  # the parent was killed: its pool will never read results
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=exit_when_orphaned, daemon=True).start()


def _run_task(task: _Task) -> TrialKey:
    """Run one scan and save it (in a worker process, or in this one)."""
    start = time.perf_counter()
    try:
        result = run_trial(task.seed, task.policy, task.scan, task.factory, task.recording())
    except Exception as exc:
        raise TrialError(f"trial {task.policy!r} seed {task.seed} raised {exc!r}") from exc
    save_trial(
        trial_path(task.out, task.policy, task.seed),
        TrialRecord.from_scan(result, task.policy, task.scan_hash, task.code_version),
    )
    logger.info(
        "trial %s seed %d: %.1f s, failure %s",
        task.policy,
        task.seed,
        time.perf_counter() - start,
        result.failure,
    )
    return task.policy, task.seed
