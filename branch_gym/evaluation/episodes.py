"""The one episode loop: an agent acts in a ``BranchScan`` env until the scan ends.

Like stable-baselines3's ``evaluate_policy``, :func:`evaluate_policy` plays one deterministic
episode per tree and is what every evaluation uses: ``eval.py`` (through
:func:`run_trial`), held-out evaluation during training, the demo and the Ray backend.

    from branch_gym.env import BranchScanEnv
    from branch_gym.evaluation.episodes import evaluate_policy

    env = BranchScanEnv()
    episodes = evaluate_policy(make_agent("periodic:22.5:1.5", env), env, tree_seeds=range(5))
    print([e.result.metrics.missed_pct for e in episodes])

(``make_agent`` is ``agents.factory.make_agent``: the policies live in the package above the gym.)
"""

from __future__ import annotations

from collections.abc import Iterable
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from branch_gym.env.scan_env import BranchScanEnv
from branch_gym.policy import Policy, PolicyFactory
from branch_gym.recording import recording
from branch_gym.scan import ScanConfig
from branch_gym.scoring import ScanResult


@dataclass(frozen=True)
class Recording:
    """Where and how a trial's frames are recorded (recon's scan folder format).

    Attributes:
        out_dir: The scan folder to create (it appears only when complete).
        image_format: "png" (lossless: the replay reproduces the model exactly) or "jpg".
        jpeg_quality: JPEG quality 0-100.
        overwrite: Replace an existing folder (a resumed evaluation re-records its trials).
    """

    out_dir: Path
    image_format: str = "png"
    jpeg_quality: int = 95
    overwrite: bool = False


@dataclass
class Episode:
    """One finished episode.

    Attributes:
        seed: The tree seed.
        episode_return: Sum of the rewards.
        steps: Env steps taken.
        terminated: The scan ended (end height or failure), not a step limit (truncation).
        result: The scan scored against the ground truth (up to where it got).
    """

    seed: int
    episode_return: float
    steps: int
    terminated: bool
    result: ScanResult


def run_episode(
    agent: Policy,
    env: Any,
    seed: int,
    policy: str = "",
    deterministic: bool = True,
    options: dict[str, Any] | None = None,
) -> Episode:
    """Play one episode of ``env`` on the tree of ``seed`` with ``agent``.

    Args:
        agent: Anything with SB3's ``predict`` (:class:`branch_gym.policy.Policy`).
        env: A single (not vectorised) ``BranchScan`` env, possibly wrapped (e.g. RecordVideo).
        seed: The tree seed passed to ``reset``.
        policy: Name recorded in the result (e.g. the spec).
        deterministic: Passed to ``predict``.
        options: ``reset`` options (e.g. a fixed ``branch_value_s`` for a v1 env).

    Returns:
        The episode, scored with the scan's own ground truth.

    The state ``predict`` returns (a recurrent model's LSTM state, a baseline's phase) is
    passed back with the next observation; ``episode_start`` is True at the first step only.
    """
    observation, _ = env.reset(seed=seed, options=options)
    state: Any = None
    episode_start, terminated, truncated, total, steps = True, False, False, 0.0, 0
    while not (terminated or truncated):
        action, state = agent.predict(
            observation, state=state, episode_start=episode_start, deterministic=deterministic
        )
        observation, reward, terminated, truncated, _ = env.step(action)
        total += float(reward)
        steps += 1
        episode_start = False
    result = env.unwrapped.result()
    result.policy = policy
    return Episode(int(seed), total, steps, bool(terminated), result)


def evaluate_policy(
    agent: Policy, env: Any, tree_seeds: Iterable[int], policy: str = ""
) -> list[Episode]:
    """One deterministic episode per tree seed, in order (see :func:`run_episode`)."""
    return [run_episode(agent, env, seed, policy) for seed in tree_seeds]


def run_trial(
    seed: int,
    policy: str,
    scan: ScanConfig,
    factory: PolicyFactory,
    record: Recording | None = None,
) -> ScanResult:
    """One evaluation trial: the agent of a policy spec scans the tree of ``seed``.

    The env is built for the trial (no step limit: a scan ends at its end height, on a failure or
    at the scan's own time limit) and closed after it. Baselines act in the continuous env; a
    trained model in the env of its action space: the scan is the same either way.

    Args:
        seed: Tree seed.
        policy: Policy spec.
        scan: Scan settings.
        factory: Reads the spec (``agents.factory.AGENTS``).
        record: Also write the scan's frames, ground truth and metadata as a scan folder.

    Raises:
        ValueError, FileNotFoundError: a bad spec or model file.
    """
    env = BranchScanEnv(scan=scan, **factory.env_kwargs(policy))
    try:
        agent = factory.make(policy, env)
        recorder = nullcontext() if record is None else recording(
            env.session, record.out_dir, seed, policy, record.image_format,
            record.jpeg_quality, record.overwrite,
        )  # fmt: skip
        with recorder:
            return run_episode(
                agent, env, seed, policy, options=factory.reset_options(policy)
            ).result
    finally:
        env.close()


def run_scan(
    seed: int,
    agent: Policy,
    config: ScanConfig | None = None,
    action_type: str = "continuous",
    policy: str = "",
) -> ScanResult:
    """Scan the tree of ``seed`` with ``agent`` and score it (a fresh env, closed after).

    Args:
        seed: Tree seed (and the seed of every random draw of the scan).
        agent: The decision maker, built for an env of ``action_type`` (e.g. with
            ``agents.baselines.PeriodicAgent(22.5, 1.5)`` or ``agents.factory.make_agent``).
        config: Scan settings.
        action_type: "continuous", "discrete" or "trigger": the env the agent acts in.
        policy: Name recorded in the result.
    """
    env = BranchScanEnv(scan=config or ScanConfig(), action_type=action_type)
    try:
        return run_episode(agent, env, seed, policy).result
    finally:
        env.close()
