"""The reward of :class:`branch_gym.env.BranchScanEnv`: ground-truth scoring, simulation only.

After every step the model is scored against the ground truth (:func:`recon.metrics.evaluate`,
secondary branches in scope up to the height scanned so far) and the reward is the change of a
score::

    r_t = match_reward       * (n_matched_t    - n_matched_{t-1})
        - spurious_penalty   * (n_spurious_t   - n_spurious_{t-1})
        - duplicate_penalty  * (n_duplicates_t - n_duplicates_{t-1})
        - time_penalty_per_s * (scan_time_t    - scan_time_{t-1})
        - failure_penalty    * [the scan failed at this step]

Counts that fall (a spurious branch pruned, a duplicate merged) give the penalty back, so the
return of an episode telescopes to the final score: ``match_reward * n_matched - spurious_penalty *
n_spurious - duplicate_penalty * n_duplicates - time_penalty_per_s * scan_time_s - failure_penalty *
failed``. Rotating costs reward only through the scan time it takes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from branch_gym.config_utils import check_keys
from branch_gym.sim.validation import require_non_negative
from recon.metrics import TreeMetrics

# Names of the terms in ``info["reward_terms"]``.
REWARD_TERMS = ("matched", "spurious", "duplicates", "time", "failure")


@dataclass(frozen=True)
class RewardConfig:
    """Reward weights; all non-negative (penalties are subtracted).

    Attributes:
        match_reward: Per ground-truth secondary branch newly matched by the model (our choice:
            the unit of reward; finding branches is the point of the scan, paper Table I
            "Missed %").
        spurious_penalty: Per spurious branch (our choice: half a match; paper Table I
            "Spurious %" is counted against the same ground-truth total as misses).
        duplicate_penalty: Per duplicate of an already matched branch (our choice: as spurious;
            reference.md "Evaluation" reports them separately).
        time_penalty_per_s: Per second of scan time (our choice: a straight 0.275 -> 0.75 m scan at
            2.5 cm/s, ~19 s, costs 0.19; a 22.5 deg rotation, ~3 s, costs 0.03, so one recovered
            branch pays for about 30 rotations).
        failure_penalty: Once when the scan fails (singularity, joint limit, contact, lost branch;
            our choice: as bad as missing one branch, on top of the branches the scan never saw).
    """

    match_reward: float = 1.0
    spurious_penalty: float = 0.5
    duplicate_penalty: float = 0.5
    time_penalty_per_s: float = 0.01
    failure_penalty: float = 1.0

    def __post_init__(self) -> None:
        require_non_negative(self, *(f.name for f in fields(self)))

    def episode_return(
        self,
        metrics: TreeMetrics,
        scan_time_s: float,
        failed: bool,
        time_penalty_per_s: float | None = None,
    ) -> float:
        """The return of a whole episode: what the step rewards of :class:`RewardTracker` sum to.

        Args:
            metrics: The final model scored against the ground truth.
            scan_time_s: The episode's scan time (s).
            failed: The scan failed.
            time_penalty_per_s: The episode's price of a second (``1 / branch_value_s``); None
                keeps ``time_penalty_per_s``.

        >>> from types import SimpleNamespace
        >>> metrics = SimpleNamespace(n_matched=3, n_spurious=1, n_duplicates=0)
        >>> RewardConfig().episode_return(metrics, scan_time_s=20.0, failed=False)
        2.3
        """
        penalty = self.time_penalty_per_s if time_penalty_per_s is None else time_penalty_per_s
        return (
            self.match_reward * metrics.n_matched
            - self.spurious_penalty * metrics.n_spurious
            - self.duplicate_penalty * metrics.n_duplicates
            - penalty * scan_time_s
            - self.failure_penalty * failed
        )

    @classmethod
    def from_dict(cls, data: dict) -> RewardConfig:
        """Build from ``{weight name: value}``.

        Raises:
            ValueError: an unknown key (named) or a bad value.
        """
        check_keys(cls, data)
        return cls(**data)


class RewardTracker:
    """Turns the metrics after each step into the step reward (see the module docstring).

    Args:
        config: Reward weights.
    """

    def __init__(self, config: RewardConfig) -> None:
        self.config = config
        self.reset()

    def reset(self, time_penalty_per_s: float | None = None) -> None:
        """Start an episode: an empty model, no scan time.

        Args:
            time_penalty_per_s: This episode's price of a second of scan time (the env's
                ``branch_value_s``); None keeps ``config.time_penalty_per_s``.
        """
        self._matched = self._spurious = self._duplicates = 0
        self._scan_time_s = 0.0
        penalty = (
            self.config.time_penalty_per_s if time_penalty_per_s is None else time_penalty_per_s
        )
        self.time_penalty_per_s = float(penalty)

    def step(
        self, metrics: TreeMetrics, scan_time_s: float, failed: bool
    ) -> tuple[float, dict[str, float]]:
        """The reward of one step.

        Args:
            metrics: The model scored after the step.
            scan_time_s: Total simulated scan time after the step (s).
            failed: The scan failed during this step.

        Returns:
            The reward and its terms (``REWARD_TERMS``; they sum to the reward).
        """
        c = self.config
        terms = {
            "matched": c.match_reward * (metrics.n_matched - self._matched),
            "spurious": -c.spurious_penalty * (metrics.n_spurious - self._spurious),
            "duplicates": -c.duplicate_penalty * (metrics.n_duplicates - self._duplicates),
            "time": -self.time_penalty_per_s * (scan_time_s - self._scan_time_s),
            "failure": -c.failure_penalty if failed else 0.0,
        }
        self._matched, self._spurious = metrics.n_matched, metrics.n_spurious
        self._duplicates, self._scan_time_s = metrics.n_duplicates, scan_time_s
        terms = {name: float(value) for name, value in terms.items()}
        return float(sum(terms.values())), terms
