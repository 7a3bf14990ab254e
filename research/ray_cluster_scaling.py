"""Ray on a ``ray start`` cluster: the scaling from one node to two, and Ray's cost per trial.

Issue 60 (throughput) asks that the evaluation run on a Ray cluster with the command the docs give
(``eval.py --backend ray --address HEAD:PORT``), with its scaling and Ray's overhead per trial.
``bench/bench_ray.py`` measures a private local instance (``ray.init(address="local")``); this
study builds a real cluster with the ``ray start`` CLI on this machine, two nodes standing in for
two machines:

- a head: ``ray start --head --num-cpus 1 --port P`` (the dashboard on, as ``ray start`` has it);
- a second node: ``ray start --address 127.0.0.1:P --num-cpus 1``. Two raylets on one host need
  only their own dashboard-agent port (fixed at 52365 by default); the others are picked free
  (here every port is chosen free, and each node gets half of Ray's default worker-port range).

Every ``ray start`` runs in its own process group, so a node is stopped by signalling its group
(SIGTERM, then SIGKILL after a grace period), never with ``ray stop`` (which ends every Ray
process on the machine, other people's included). The cluster is stopped in a ``finally`` block:
after an error, Ctrl-C or SIGTERM too. It uses a private ``--temp-dir`` under /tmp and a private
authentication token (``RAY_AUTH_MODE=token``, ``RAY_AUTH_TOKEN``, set for this process and the
nodes it starts): Ray 2.60's ``ray start --head`` turns token authentication on by itself when
``~/.ray/auth_token`` exists, and a node joining without the token fails with
``InvalidAuthToken``.

The same small evaluation (``bench_ray.py``'s: policies ``none`` and ``periodic:22.5:1.5``, a
depth-oracle scan ending at 0.4 m, ~1 s a trial; or, with ``--benchmark-scan``, the
orchard-v2 benchmark's own scan from pixels on its validation trees, ~10-20 s a trial) runs
through the project's own code path, :func:`branch_gym.evaluation.runner.run_trials`, each time
into a fresh folder, in four configurations:

- ``pool_w1``: the pool backend, 1 worker (this process, as ``eval.py --workers 1``);
- ``pool_w2``: the pool backend, 2 worker processes;
- ``ray_1node_w1``: the Ray backend on the head alone (1 CPU), 1 trial in flight;
- ``ray_2nodes_w2``: the Ray backend on head + second node (2 CPUs), 2 trials in flight.

A Ray configuration's wall time is what ``eval.py --backend ray --address`` spends: connect to the
cluster, run the trials as tasks (each a new job: its worker processes start and import the
project), disconnect. It is timed in a spawned child process, the Ray driver, as a command line
would be (a process that ran ``ray.init`` dies on SIGTERM without its ``finally`` blocks; this
process, which owns the cluster, never connects). ``pool_w1`` runs in this process with the
project already imported, so at 1 worker Ray's overhead includes its worker's start-up; at 2
both backends start worker processes inside the run. Each repeat runs the pool configurations
first with no Ray process on the machine, then starts the head, runs ``ray_1node_w1``, starts
the second node, runs ``ray_2nodes_w2`` and stops the cluster (so each repeat has a fresh
cluster, and the pool never shares the CPUs with idle Ray daemons). Figures are medians over
the repeats of each repeat's value:

- ``wall_s``: each configuration's wall time;
- ``scaling``: ``ray_1_to_2_nodes`` = ``ray_1node_w1 / ray_2nodes_w2``, next to the pool's
  ``pool_1_to_2_workers`` = ``pool_w1 / pool_w2`` (2 at best; few trials of unequal length
  bring it down for both);
- ``ray_overhead``, per number of workers W: ``ms_per_trial`` = (Ray wall - pool wall at W) /
  trials (``bench_ray.py``'s measure), ``share_of_trial`` = (Ray wall - pool wall) / pool wall:
  the extra time a trial costs over a trial's own time when the trials keep the W workers busy
  (issue 60's budget: under 5 %);
- ``trial_s``: a trial's time, ``pool_w1 / trials``;
- ``ray_connect_s``: the fixed part of the Ray wall time, a driver's ``ray.init(address)`` +
  ``ray.shutdown()`` on the running cluster, timed apart after each Ray configuration;
- ``trials_by_node``: how many trials each node ran (by Ray's state API: each ``trial_json``
  task's node), summed over the repeats; ``both_nodes_ran_trials`` checks that the second node
  worked. ``nodes_alive`` is the number of alive nodes (1 CPU each) each Ray configuration saw.

Printed: the JSON on stdout, a Markdown table on stderr (after the logs); ``--out DIR`` also
writes both as files. Usage (on free cores: each node is one CPU, the machine needs 2 free)::

    # realistic trials (orchard-v2's scan, ~10-20 s each): ~9 min on 2 free cores
    .venv/bin/python -m research.ray_cluster_scaling --benchmark-scan --trials-per-policy 2 \\
        --repeats 3 --out results/ray_cluster_scaling_orchard
    # many short trials (Ray's cost per trial at its most visible): ~8 min
    .venv/bin/python -m research.ray_cluster_scaling --trials-per-policy 20 --repeats 4 \\
        --out results/ray_cluster_scaling_cheap

A run with ``--repeats 1 --trials-per-policy 2`` (the check of the code) takes ~45 s.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import multiprocessing
import os
import secrets
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from types import FrameType
from typing import Any

from agents.factory import AGENTS
from branch_gym.evaluation.benchmark import benchmark
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.runner import run_trials
from branch_gym.scan import ScanConfig

logger = logging.getLogger(__name__)

LOG_FORMAT = "%(asctime)s %(name)s: %(message)s"

POLICIES = ("none", "periodic:22.5:1.5")  # bench/bench_ray.py's
CHEAP_SCAN = ScanConfig(tracker="oracle", end_height_m=0.4)  # bench/bench_ray.py's: ~1 s a trial
BENCHMARK = "orchard-v2"  # --benchmark-scan: this benchmark's scan, on its validation trees
BENCHMARK_SPLIT = "validation"  # timing only: the test trees stay unseen
TRIALS_PER_POLICY = 2
REPEATS = 3
CPUS_PER_NODE = 1  # a node stands for a machine; 2 nodes on the 2-core machine
NODES = ("head", "second")
# Ray's minimum object store is 75 MiB; a trial's record is a few kB (its default, 30 % of the
# memory per node, only reserves /dev/shm).
OBJECT_STORE_BYTES = 100 * 2**20
# Ray's default worker ports are 10002-19999; two raylets on one host get a half each.
WORKER_PORTS = {"head": (10002, 14999), "second": (15000, 19999)}
STOP_GRACE_S = 5.0  # SIGTERM, then SIGKILL (ray stop waits 16 s; the GCS outlives SIGTERM)
START_TIMEOUT_S = 120.0  # a `ray start` normally returns in 3-5 s
NODES_WAIT_S = 60.0  # for the cluster to report the nodes alive (or the stopped one dead)
TASK_EVENTS_WAIT_S = 30.0  # Ray reports task events to its GCS about every second
POLL_S = 0.5
TRIAL_TASK = "trial_json"  # the Ray task of a trial (branch_gym.evaluation.ray_backend)
CONFIGS = ("pool_w1", "pool_w2", "ray_1node_w1", "ray_2nodes_w2")
LABELS = {
    "pool_w1": "pool, 1 worker",
    "pool_w2": "pool, 2 workers",
    "ray_1node_w1": "Ray, head alone (1 CPU), 1 worker",
    "ray_2nodes_w2": "Ray, head + second node (2 CPUs), 2 workers",
}


def free_port() -> int:
    """A TCP port free on this machine now (the OS's pick)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def ray_executable() -> Path:
    """The ``ray`` CLI of this Python's environment (next to ``sys.executable``), else on PATH.

    Raises:
        FileNotFoundError: no ``ray`` command (Ray is not installed: ``pip install '.[ray]'``).
    """
    beside = Path(sys.executable).with_name("ray")
    if beside.exists():
        return beside
    found = shutil.which("ray")
    if found is None:
        raise FileNotFoundError("no `ray` command: pip install '.[ray]'")
    return Path(found)


def _stat(pid: str) -> list[str]:
    """Fields of ``/proc/PID/stat`` after the command name (state, ppid, pgrp, ...)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()
    except OSError:
        return []


def _group_alive(pgid: int) -> bool:
    """Whether a live (not zombie) process is in process group ``pgid``."""
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat(entry.name)
            if len(fields) > 2 and fields[2] == str(pgid) and fields[0] != "Z":
                return True
    return False


def _stop_group(pgid: int) -> None:
    """SIGTERM a process group, SIGKILL it after :data:`STOP_GRACE_S` if any member is left."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        if sig == signal.SIGKILL:
            logger.info("process group %d outlived SIGTERM by %.0f s: SIGKILL", pgid, STOP_GRACE_S)
        try:
            os.killpg(pgid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + STOP_GRACE_S
        while _group_alive(pgid) and time.monotonic() < deadline:
            time.sleep(POLL_S)
        if not _group_alive(pgid):
            return


def _processes_under(root: Path) -> list[int]:
    """Live processes whose command line names ``root`` (this study's Ray temp dir)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if str(root) in cmdline and _stat(entry.name)[:1] not in ([], ["Z"]):
            pids.append(int(entry.name))
    return pids


@dataclass
class LocalCluster:
    """A Ray cluster of ``ray start`` nodes on this machine, each node its own process group.

    Attributes:
        root: The nodes' ``--temp-dir`` (logs, sockets, the session).
        ray: The ``ray`` CLI.
        port: The head's GCS port; the cluster's address is ``127.0.0.1:port``.
    """

    root: Path
    ray: Path
    port: int

    def __post_init__(self) -> None:
        self._groups: dict[str, int] = {}  # node -> process group of its `ray start`

    @property
    def address(self) -> str:
        """The address ``ray start --address`` and ``ray.init`` join."""
        return f"127.0.0.1:{self.port}"

    def start(self, node: str) -> None:
        """Start ``node`` ("head" or "second") with ``ray start`` and wait until it is alive.

        Raises:
            RuntimeError: ``ray start`` failed (the message has its output's end) or the
                cluster did not report the node within :data:`NODES_WAIT_S`.
        """
        low, high = WORKER_PORTS[node]
        args = [
            "--num-cpus", str(CPUS_PER_NODE),
            "--temp-dir", str(self.root),
            "--disable-usage-stats",
            "--object-store-memory", str(OBJECT_STORE_BYTES),
            "--dashboard-agent-listen-port", str(free_port()),
            "--min-worker-port", str(low),
            "--max-worker-port", str(high),
        ]  # fmt: skip
        if node == "head":
            args += [
                "--head",
                "--port", str(self.port),
                "--dashboard-port", str(free_port()),
                "--ray-client-server-port", str(free_port()),
            ]  # fmt: skip
        else:
            args += ["--address", self.address]
        log = self.root / f"ray_start_{node}.log"
        start = time.perf_counter()
        with log.open("w") as out:
            proc = subprocess.Popen(
                [str(self.ray), "start", *args],
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # its own process group: every daemon it starts joins it
            )
            self._groups[node] = proc.pid
            try:
                code = proc.wait(timeout=START_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                code = None
        if code != 0:
            tail = log.read_text()[-3000:]
            raise RuntimeError(f"`ray start` of the {node} node failed ({code}):\n{tail}")
        self.wait_alive(len(self._groups))
        logger.info("%s node started in %.1f s", node, time.perf_counter() - start)

    def stop(self, node: str) -> None:
        """Stop ``node`` (its process group); the cluster keeps running without it."""
        pgid = self._groups.pop(node, None)
        if pgid is not None:
            _stop_group(pgid)

    def stop_all(self) -> None:
        """Stop every node (the second first, the head last) and any process left under root."""
        for node in reversed(list(self._groups)):
            self.stop(node)
        left = _processes_under(self.root)
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        if left:  # not seen so far: Ray's processes stay in the group of their `ray start`
            logger.warning("killed %d Ray processes left after their groups: %s", len(left), left)

    def alive_nodes(self) -> list[Any]:
        """The nodes the cluster reports alive (Ray's state API, through the dashboard)."""
        from ray.util.state import list_nodes

        return list_nodes(address=self.address, filters=[("state", "=", "ALIVE")])

    def wait_alive(self, count: int) -> list[Any]:
        """Wait until exactly ``count`` nodes are alive.

        Raises:
            RuntimeError: not so within :data:`NODES_WAIT_S`.
        """
        deadline = time.monotonic() + NODES_WAIT_S
        error: Exception | None = None
        while time.monotonic() < deadline:
            try:
                nodes = self.alive_nodes()
            except Exception as exc:  # the dashboard is still starting
                error = exc
            else:
                if len(nodes) == count:
                    return nodes
            time.sleep(POLL_S)
        raise RuntimeError(f"the cluster did not report {count} alive nodes: {error!r}")


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Turn SIGTERM into KeyboardInterrupt for the block, so ``finally`` blocks run."""

    def interrupt(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def use_private_token() -> None:
    """Token authentication with a new token, for this process and the nodes it starts."""
    os.environ["RAY_AUTH_MODE"] = "token"
    os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)  # Ray's own generator's format


def wall_s(config: EvalConfig) -> float:
    """Wall time of running all trials of ``config`` into a fresh folder (s)."""
    with tempfile.TemporaryDirectory(prefix="ray_cluster_scaling_") as out:
        start = time.perf_counter()
        run_trials(config, Path(out), config.keys)
        return time.perf_counter() - start


def connect_s(address: str) -> float:
    """Wall time of a driver's ``ray.init(address)`` + ``ray.shutdown()`` on a running cluster."""
    import ray

    start = time.perf_counter()
    ray.init(address=address)
    ray.shutdown()
    return time.perf_counter() - start


def ray_run(study: Study, address: str, workers: int) -> tuple[float, float]:
    """One Ray configuration as ``eval.py --backend ray --address`` runs it.

    Returns:
        The wall time of the evaluation (connect, run the trials, disconnect) and of a
        connect + disconnect alone (s).
    """
    return wall_s(study.config(workers, address)), connect_s(address)


def _child_main(conn: Connection, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
    """Body of :func:`in_child`'s process: ``fn(*args)``, sent back as ("ok", value)."""
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # Ray prints its workers' output there
            conn.send(("ok", fn(*args)))
    except BaseException:
        conn.send(("error", traceback.format_exc()))
        raise


def in_child(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a new (spawned) process, as a command line would run it.

    A process that ran ``ray.init`` dies on SIGTERM without running its ``finally`` blocks (Ray's
    driver installs its own handler, which aborts): so the Ray driver is a child and this
    process, which owns the cluster, never connects to it.

    Raises:
        RuntimeError: ``fn`` raised (the message has its traceback) or the process died.
    """
    context = multiprocessing.get_context("spawn")
    receive, send = context.Pipe(duplex=False)
    proc = context.Process(target=_child_main, args=(send, fn, args))
    proc.start()
    send.close()
    try:
        status, value = receive.recv()
    except EOFError:
        proc.join()
        status, value = "error", f"it died (exit code {proc.exitcode})"
    except BaseException:  # Ctrl-C, SIGTERM: the child goes too
        proc.terminate()
        raise
    finally:
        proc.join()
    if status != "ok":
        raise RuntimeError(f"{getattr(fn, '__name__', fn)} failed in its process:\n{value}")
    return value


def trial_tasks(address: str) -> dict[str, str]:
    """Every finished trial task the cluster knows: task id -> node id."""
    from ray.util.state import list_tasks

    tasks = list_tasks(
        address=address,
        filters=[("name", "=", TRIAL_TASK), ("state", "=", "FINISHED")],
        limit=10_000,  # the state API's maximum
        raise_on_missing_output=False,
    )
    return {t.task_id: t.node_id for t in tasks}


def new_trial_nodes(address: str, seen: dict[str, str], count: int) -> list[str]:
    """The nodes of the ``count`` trial tasks not in ``seen`` (which gains them).

    Ray reports task events to its GCS in batches: waits up to :data:`TASK_EVENTS_WAIT_S` for
    all of them, then returns those reported (with a warning).
    """
    deadline = time.monotonic() + TASK_EVENTS_WAIT_S
    while True:
        new = {k: v for k, v in trial_tasks(address).items() if k not in seen}
        if len(new) >= count or time.monotonic() > deadline:
            break
        time.sleep(POLL_S)
    if len(new) != count:
        logger.warning("Ray reported %d of the run's %d trial tasks", len(new), count)
    seen.update(new)
    return list(new.values())


@dataclass(frozen=True)
class Study:
    """What to evaluate.

    Attributes:
        policies: Policy specs.
        trees: Trees per policy.
        seed: First tree seed.
        scan: The scan every trial runs.
        scan_name: The scan, in words (for the report).
    """

    policies: tuple[str, ...]
    trees: int
    seed: int
    scan: ScanConfig
    scan_name: str

    def config(self, workers: int, address: str | None = None) -> EvalConfig:
        """The evaluation on the pool (``address`` None) or on the Ray cluster at ``address``."""
        ray = {} if address is None else {"backend": "ray", "address": address}
        return EvalConfig(
            self.policies,
            self.trees,
            self.seed,
            workers,
            self.scan,
            policy_factory=AGENTS,
            **ray,
        )


def study_of(trials_per_policy: int, benchmark_scan: bool) -> Study:
    """The cheap scan of ``bench_ray.py``, or the benchmark's scan on its validation trees."""
    if not benchmark_scan:
        return Study(POLICIES, trials_per_policy, 0, CHEAP_SCAN, "oracle tracker, end 0.4 m")
    bench = benchmark(BENCHMARK)
    stratum = bench.strata[0]
    first, count = stratum.seeds(BENCHMARK_SPLIT)
    return Study(
        POLICIES,
        min(trials_per_policy, count),
        first,
        bench.scan_config(stratum),
        f"{BENCHMARK} {stratum.name} ({BENCHMARK_SPLIT} trees from {first})",
    )


def measure(study: Study, repeats: int, root: Path) -> dict[str, Any]:
    """Run the four configurations ``repeats`` times (see the module docstring).

    Args:
        study: The evaluation.
        repeats: Repeats; each starts and stops its own cluster.
        root: An empty folder for the clusters' temp dirs (short: Ray's socket paths are
            limited to ~107 characters).

    Returns:
        Per configuration the wall times of the repeats (s); the connect times (s); the trial
        counts per node role; the alive nodes each Ray configuration saw.
    """
    ray_exe = ray_executable()
    walls: dict[str, list[float]] = {name: [] for name in CONFIGS}
    connects: list[float] = []
    by_node: dict[str, Counter[str]] = {"ray_1node_w1": Counter(), "ray_2nodes_w2": Counter()}
    alive: dict[str, list[int]] = {"ray_1node_w1": [], "ray_2nodes_w2": []}
    trials = len(study.config(1).keys)
    for repeat in range(repeats):
        walls["pool_w1"].append(wall_s(study.config(1)))
        walls["pool_w2"].append(wall_s(study.config(2)))
        cluster = LocalCluster(root / f"r{repeat}", ray_exe, free_port())
        cluster.root.mkdir()
        seen: dict[str, str] = {}
        try:
            cluster.start("head")
            roles = {cluster.alive_nodes()[0].node_id: "head"}
            for name, node, workers in (
                ("ray_1node_w1", None, 1),
                ("ray_2nodes_w2", "second", 2),
            ):
                if node is not None:
                    cluster.start(node)
                    for n in cluster.alive_nodes():
                        roles.setdefault(n.node_id, node)
                alive[name].append(len(cluster.alive_nodes()))
                wall, connect = in_child(ray_run, study, cluster.address, workers)
                walls[name].append(wall)
                connects.append(connect)
                nodes = new_trial_nodes(cluster.address, seen, trials)
                by_node[name].update(roles.get(n, f"other:{n}") for n in nodes)
        finally:
            cluster.stop_all()
        logger.info(
            "repeat %d: %s",
            repeat + 1,
            ", ".join(f"{name} {walls[name][-1]:.2f} s" for name in CONFIGS),
        )
    return {"walls": walls, "connects": connects, "by_node": by_node, "alive": alive}


def summarise(study: Study, repeats: int, raw: dict[str, Any]) -> dict[str, Any]:
    """The report (see the module docstring) from :func:`measure`'s output."""
    walls: dict[str, list[float]] = raw["walls"]
    trials = len(study.config(1).keys)

    def median_of(f: Callable[[int], float]) -> float:
        return statistics.median(f(r) for r in range(repeats))

    overhead = {}
    for workers, pool, ray in ((1, "pool_w1", "ray_1node_w1"), (2, "pool_w2", "ray_2nodes_w2")):
        overhead[f"w{workers}"] = {
            "ms_per_trial": median_of(lambda r, p=pool, q=ray: (walls[q][r] - walls[p][r]) / trials)
            * 1e3,
            "share_of_trial": median_of(
                lambda r, p=pool, q=ray: (walls[q][r] - walls[p][r]) / walls[p][r]
            ),
        }
    by_node = {name: dict(counts) for name, counts in raw["by_node"].items()}
    import ray

    return {
        "settings": {
            "policies": list(study.policies),
            "trees": study.trees,
            "first_seed": study.seed,
            "trials": trials,
            "scan": study.scan_name,
            "repeats": repeats,
            "cpus_per_node": CPUS_PER_NODE,
            "ray_version": ray.__version__,
            "machine_cpus": os.cpu_count(),
        },
        "wall_s": {name: statistics.median(walls[name]) for name in CONFIGS},
        "wall_s_repeats": walls,
        "scaling": {
            "ray_1_to_2_nodes": median_of(
                lambda r: walls["ray_1node_w1"][r] / walls["ray_2nodes_w2"][r]
            ),
            "pool_1_to_2_workers": median_of(lambda r: walls["pool_w1"][r] / walls["pool_w2"][r]),
        },
        "ray_overhead": overhead,
        "trial_s": median_of(lambda r: walls["pool_w1"][r] / trials),
        "ray_connect_s": statistics.median(raw["connects"]),
        "trials_by_node": by_node,
        "both_nodes_ran_trials": all(by_node["ray_2nodes_w2"].get(n, 0) > 0 for n in NODES),
        "nodes_alive": raw["alive"],
    }


def markdown(report: dict[str, Any]) -> str:
    """The report as a small Markdown table."""
    s = report["settings"]
    rows = [
        f"{s['trials']} trials ({', '.join(s['policies'])}; {s['trees']} trees; {s['scan']}), "
        f"median of {s['repeats']} repeats, Ray {s['ray_version']}, {s['machine_cpus']} cores; "
        f"a trial {report['trial_s']:.2f} s, Ray's connect + disconnect "
        f"{report['ray_connect_s']:.2f} s",
        "",
        "| configuration | wall (s) | 1 -> 2 scaling | Ray overhead per trial (ms) "
        "| share of a trial | trials on head / second node |",
        "|---|---|---|---|---|---|",
    ]
    scaling = report["scaling"]
    for name in CONFIGS:
        workers = name[-2:]
        is_ray = name.startswith("ray")
        ratio = ""
        if workers == "w2":
            key = "ray_1_to_2_nodes" if is_ray else "pool_1_to_2_workers"
            ratio = f"{scaling[key]:.2f}x"
        cost = report["ray_overhead"][workers] if is_ray else None
        counts = report["trials_by_node"].get(name, {})
        rows.append(
            f"| {LABELS[name]} | {report['wall_s'][name]:.2f} | {ratio} | "
            + (
                f"{cost['ms_per_trial']:+.0f} | {100 * cost['share_of_trial']:+.1f} % | "
                if cost
                else "| | "
            )
            + (" / ".join(str(counts.get(n, 0)) for n in NODES) if is_ray else "")
            + " |"
        )
    return "\n".join(rows) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--trials-per-policy",
        type=int,
        default=TRIALS_PER_POLICY,
        help=f"trees per policy (default {TRIALS_PER_POLICY}; 2 policies)",
    )
    parser.add_argument("--repeats", type=int, default=REPEATS, help=f"default {REPEATS}")
    parser.add_argument(
        "--benchmark-scan",
        action="store_true",
        help=f"{BENCHMARK}'s scan from pixels on its {BENCHMARK_SPLIT} trees "
        "(default: the cheap oracle scan of bench_ray.py)",
    )
    parser.add_argument("--out", type=Path, help="also write the JSON and the table here")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    use_private_token()  # before Ray is imported: Ray reads the mode when it loads
    study = study_of(args.trials_per_policy, args.benchmark_scan)
    start = time.perf_counter()
    # Ray prints its workers' output on this process's stdout: keep stdout for the JSON.
    with (
        sigterm_as_interrupt(),
        contextlib.redirect_stdout(sys.stderr),
        tempfile.TemporaryDirectory(prefix="rcs_", dir="/tmp") as root,
    ):
        raw = measure(study, args.repeats, Path(root))
    report = summarise(study, args.repeats, raw)
    report["settings"]["study_wall_s"] = time.perf_counter() - start
    text = json.dumps(report, indent=2)
    table = markdown(report)
    print(text)
    sys.stderr.write("\n" + table)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "ray_cluster_scaling.json").write_text(text + "\n")
        (args.out / "ray_cluster_scaling.md").write_text(table)


if __name__ == "__main__":
    main()
