"""Cost-to-go labels: every action of a sampled state priced by the return it leads to.

DAgger copies the privileged expert's action, and that expert never rotates without a reason it
can see in the ground truth, so its students cannot learn the *blind* rotations that find
branches no frame shows (``docs/results/learned_policies.md``). AggreVaTe (Ross and Bagnell,
2014, "Reinforcement and Imitation Learning via Interactive No-Regret Learning") labels a state
instead with the value of each action: from a sampled state of a played episode, each distinct
action is taken once and a roll-out policy plays the episode to its end; the label of the action
is the episode's return at the episode's own price of scan time (the env's reward:
:meth:`branch_gym.env.reward.RewardConfig.episode_return`).

Which policy rolls out decides what the labels teach. The privileged expert would find a hidden
branch one step later whatever the action (it reads the ground truth), so under its roll-outs a
blind rotation is worth no more than holding. Rolled out by the *student* (the policy that plays
the round; :class:`HoldAgent`, which never turns the camera, before the first student; LOLS-style:
Chang et al., 2015, "Learning to Search Better than Your Teacher"), holding leaves a hidden branch
missed, and the labels price the rotation that finds it above holding, by a branch's worth against
the rotation's scan time.

The env has no state copy: a branch replays the episode's recorded actions up to the sampled
step from ``reset(seed)`` (the env is deterministic: same seed, same trajectory; the replayed
observation is checked against the recorded one), then takes its action. Every branch is an
independent task (:class:`BranchTask`; ``labels.branch_task`` runs it on the labelling
process pool).

The fit (:func:`expected_regret`) minimises the policy's expected regret on the priced states:
``sum_a pi(a | s) (max_b Q(s, b) - Q(s, a))``, cost-sensitive classification at the price the
observation shows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from branch_gym.env.layout import VECTOR_KEY, VectorField
from branch_gym.policy import BaselineAgent

ROLLOUTS = ("student", "expert")


@dataclass(frozen=True)
class BranchTask:
    """One branch of a sampled state: replay, take one action, roll out to the episode's end.

    Attributes:
        tree_seed: The episode's tree (and reset) seed.
        prefix_actions: The actions the episode took before the sampled step, in order.
        expected_vector: The observation vector recorded at the sampled step (replay check).
        action: The action this branch takes at the sampled step.
        rollout_path: The student model that rolls out (None: the rollout is the expert when
            ``rollout_expert``, else :class:`HoldAgent`).
        rollout_expert: Roll out with the privileged expert.
        reset_options: ``reset`` options of the episode (e.g. a given tree); None for a tree
            drawn from its seed.
    """

    tree_seed: int
    prefix_actions: tuple[int, ...]
    expected_vector: np.ndarray
    action: int
    rollout_path: str | None
    rollout_expert: bool = False
    reset_options: dict[str, Any] | None = None


class HoldAgent(BaselineAgent):
    """Never turns the camera: holds whatever angle it finds (the roll-out before any student).

    Unlike :class:`agents.baselines.NoRotationAgent`, which goes back to 0, it keeps a view a
    branch's action turned to, as a student that has not learned to rotate does.
    """

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        return vectors[:, VectorField.ANGLE].astype(float) * self.theta_max_deg, state


def sample_steps(n_steps: int, count: int, rng: np.random.Generator) -> np.ndarray:
    """Up to ``count`` distinct steps of an episode of ``n_steps``, sorted.

    >>> sample_steps(10, 3, np.random.default_rng(0)).tolist()
    [5, 6, 9]
    >>> sample_steps(2, 5, np.random.default_rng(0)).tolist()
    [0, 1]
    """
    return np.sort(rng.choice(n_steps, size=min(count, n_steps), replace=False))


def distinct_actions(env: Any, current_angle_deg: float) -> list[list[int]]:
    """The env's discrete actions grouped by what they do now.

    An action whose target lies within the scan's rotation tolerance of the current angle holds
    it (:meth:`branch_gym.scan.ScanSession.step`), so "hold" and "rotate to where the camera
    is" are one action.

    Args:
        env: A discrete ``BranchScan`` env (possibly wrapped).
        current_angle_deg: The camera's angle about the branch at the sampled step (deg).

    Returns:
        Groups of action indices, one per distinct effect (the first of each group is the one
        a branch takes), in the order of their first action.
    """
    unwrapped = env.unwrapped
    tolerance = unwrapped.config.scan.rotation_tolerance_deg
    groups: dict[float, list[int]] = {}
    for action in range(int(env.action_space.n)):
        target = unwrapped.target_angle_deg(action, current_angle_deg)
        effect = current_angle_deg if abs(target - current_angle_deg) <= tolerance else target
        groups.setdefault(effect, []).append(action)
    return list(groups.values())


def branch_outcome(total: float, info: dict[str, Any]) -> dict[str, Any]:
    """What a branch's end holds besides its return, for the round's branch log.

    With the scan time and the counts, a label can be priced again at another price of scan time
    or of a false branch without replaying it (the return telescopes to the final score:
    :meth:`branch_gym.env.reward.RewardConfig.episode_return`).

    Args:
        total: The branch's return (:func:`play_branch`).
        info: The env's ``info`` of the branch's last step.

    Returns:
        ``return``, ``scan_time_s`` (s), ``n_matched``, ``n_spurious``, ``n_duplicates`` and
        ``failure`` (the failure's name, or "" for a scan that did not fail).
    """
    metrics = info.get("final_metrics", info["metrics"])
    return {
        "return": float(total),
        "scan_time_s": float(info["scan_time_s"]),
        "n_matched": int(metrics["n_matched"]),
        "n_spurious": int(metrics["n_spurious"]),
        "n_duplicates": int(metrics["n_duplicates"]),
        "failure": info["failure"] or "",
    }


def play_branch(env: Any, task: BranchTask, rollout: Any) -> tuple[float, dict[str, Any]]:
    """Play one branch (:class:`BranchTask`) in ``env`` to the episode's end.

    Args:
        env: The run's env (the same settings as the episode's).
        task: The branch.
        rollout: The policy that plays after the branch's action (SB3's ``predict``).

    Returns:
        The branch's return and the env's ``info`` of the last step (``failure``,
        ``final_metrics``, ``scan_time_s``, ...).

    Raises:
        RuntimeError: the replay did not reproduce the recorded observation, or the episode
            ended before the sampled step (the env was not deterministic).
    """
    observation, _ = env.reset(seed=int(task.tree_seed), options=task.reset_options)
    total = 0.0
    for action in task.prefix_actions:
        observation, reward, terminated, truncated, _ = env.step(int(action))
        total += float(reward)
        if terminated or truncated:
            raise RuntimeError(f"replay of tree {task.tree_seed} ended before the sampled step")
    if not np.array_equal(observation[VECTOR_KEY], task.expected_vector):
        raise RuntimeError(
            f"replay of tree {task.tree_seed} diverged from the recorded episode at step "
            f"{len(task.prefix_actions)}"
        )
    observation, reward, terminated, truncated, info = env.step(int(task.action))
    total += float(reward)
    while not (terminated or truncated):
        action, _ = rollout.predict(observation, episode_start=False, deterministic=True)
        observation, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
    return total, info


def action_values(groups: list[list[int]], returns: list[float], n_actions: int) -> np.ndarray:
    """(n_actions,) the return of each action from its group's branch.

    >>> action_values([[0, 3], [1], [2]], [1.5, 0.5, 2.0], 4).tolist()
    [1.5, 0.5, 2.0, 1.5]
    """
    values = np.full(n_actions, np.nan)
    for group, value in zip(groups, returns, strict=True):
        values[group] = value
    return values


def expected_regret(probabilities: Any, values: Any) -> Any:
    """Mean over states of ``sum_a pi(a | s) (max_b Q(s, b) - Q(s, a))``, a torch scalar.

    Args:
        probabilities: (B, A) torch tensor, the policy's action probabilities.
        values: (B, A) torch tensor, the actions' returns (every entry finite).

    >>> import torch
    >>> float(expected_regret(torch.tensor([[0.5, 0.5], [1.0, 0.0]]),
    ...                       torch.tensor([[1.0, 0.0], [0.0, 2.0]])))
    1.25
    """
    regret = values.amax(dim=1, keepdim=True) - values
    return (probabilities * regret).sum(dim=1).mean()
