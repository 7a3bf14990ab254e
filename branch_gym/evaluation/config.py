"""What one evaluation is: policies x tree seeds under one scan configuration."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from branch_gym.evaluation.trials import config_hash, config_to_dict, policy_slug
from branch_gym.policy import PolicyFactory
from branch_gym.scan import ScanConfig

TrialKey = tuple[str, int]  # (policy spec, tree seed)
BACKENDS = ("pool", "ray")


class TrialError(RuntimeError):
    """A trial raised; the message names the trial (policy, seed) and the cause."""


@dataclass(frozen=True)
class EvalConfig:
    """One evaluation: every policy on trees ``seed .. seed + trees - 1``.

    Attributes:
        policies: Policy specs, in table order.
        trees: Number of trees (tree seeds) per policy.
        seed: First tree seed.
        workers: Trials run at once: worker processes of the pool backend (1 runs the trials
            in this process), Ray tasks in flight (and the CPUs of a local Ray instance).
        scan: Scan configuration shared by all trials.
        backend: "pool" (this process or a process pool) or "ray" (Ray tasks; ``pip install
            .[ray]``). Like ``workers``, it does not change the results.
        address: Ray cluster address for ``ray.init`` ("auto", "HOST:PORT", "ray://HOST:PORT");
            None starts a private local Ray instance. Ray backend only.
        record_dir: Record every trial run (not those loaded from saved trials) as a scan folder
            ``record_dir/<policy-slug>/seed_<SEED>`` (JPEG frames, ``docs/replay.md``). Does
            not change the results. Pool backend only.
        policy_factory: What reads the specs (keyword only): ``agents.factory.AGENTS``, handed
            in by the command that composes the evaluation (the gym does not import
            ``agents``).
    """

    policies: tuple[str, ...]
    trees: int
    seed: int = 0
    workers: int = 1
    scan: ScanConfig = field(default_factory=ScanConfig)
    backend: str = "pool"
    address: str | None = None
    record_dir: Path | None = None
    policy_factory: PolicyFactory = field(kw_only=True, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "policies", tuple(self.policies))
        validate_policies(self.policies, self.policy_factory)
        if self.trees < 1:
            raise ValueError(f"trees must be >= 1, got {self.trees}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.record_dir is not None and self.backend == "ray":
            raise ValueError("recording trials (record_dir) needs the pool backend, not ray")
        if self.address is not None and self.backend != "ray":
            raise ValueError(f"a Ray address ({self.address!r}) needs the ray backend")

    @property
    def seeds(self) -> range:
        """The tree seeds, the same for every policy."""
        return range(self.seed, self.seed + self.trees)

    @property
    def keys(self) -> list[TrialKey]:
        """All trials, policy order then seed."""
        return [(policy, seed) for policy in self.policies for seed in self.seeds]

    @property
    def scan_hash(self) -> str:
        """Hash of the scan settings as run (those left to the mask source resolved)."""
        return config_hash(self.scan.replace(modeler=self.scan.modeler_config()))

    def to_json_dict(self) -> dict:
        """What determines the results (the worker count and the backend do not)."""
        return {
            "policies": list(self.policies),
            "trees": self.trees,
            "seed": self.seed,
            "seeds": list(self.seeds),
            "scan": config_to_dict(self.scan),
            "scan_config_hash": self.scan_hash,
        }


def validate_policies(policies: Sequence[str], factory: PolicyFactory) -> None:
    """Check every spec before any work.

    Raises:
        ValueError: no policy, an unknown or malformed spec, a repeated spec, or two specs that
            would share a trial folder.
    """
    if not policies:
        raise ValueError("at least one policy is needed")
    slugs: dict[str, str] = {}
    for policy in policies:
        factory.check(policy)
        slug = policy_slug(policy)
        if slug in slugs:
            raise ValueError(
                f"policies {slugs[slug]!r} and {policy!r} are repeated or share the trial "
                f"folder name {slug!r}"
            )
        slugs[slug] = policy
