"""What the gym asks of a decision maker, and what the commands hand in to get one.

- :class:`Policy`: anything with stable-baselines3's ``predict`` (SB3 models, the paper's
  controllers, loaded PPO policies); the one episode loop
  (:func:`branch_gym.evaluation.episodes.run_episode`) plays it.
- :class:`PolicyFactory`: policy specs (``"periodic:22.5:1.5"``, ``"ppo:NAME@100"``) to
  policies. The gym does not know the specs: the package above it (``agents``) implements the
  factory and the composing commands (``eval.py``, ``branch-gym-eval``) hand it in, so imports
  run one way, ``agents`` -> ``branch_gym``.
- :class:`BaselineAgent`: the base of rule-based policies that pick a target angle, encoded as
  the actions of a continuous, discrete or trigger env (the paper's controllers in ``agents``,
  the privileged bound in :mod:`branch_gym.privileged`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from branch_gym.control import ROTATION_TOLERANCE_DEG
from branch_gym.env.layout import OUTCOME_FIELDS, THETA_MAX_DEG, VectorField, vector_part


@runtime_checkable
class Policy(Protocol):
    """A rotation policy acting in a ``BranchScan`` env (SB3's ``BasePolicy.predict`` signature)."""

    def predict(
        self,
        observation: dict | np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """The action(s) for one observation or a batch, and the policy's next state.

        Args:
            observation: One observation or a batch (Dict or flat, as the env gives them).
            state: The recurrent state returned by the previous call (None at the start).
            episode_start: (N,) bools, True where an episode starts with this observation.
            deterministic: Take the most likely action (evaluation) instead of sampling.
        """
        ...


class PolicyFactory(Protocol):
    """Policy specs to policies: what an evaluation asks of the package that defines the specs.

    It travels with an :class:`~branch_gym.evaluation.config.EvalConfig` into worker processes
    and Ray tasks, so an implementation must pickle (a module-level class does).
    """

    spec_forms: str
    """The spec forms, for a command's ``--help`` and error messages."""

    def check(self, spec: str) -> None:
        """Validate a spec without building anything.

        Raises:
            ValueError: an unknown or malformed spec (naming the valid forms), or one whose
                model file does not exist.
        """
        ...

    def make(self, spec: str, env: Any) -> Policy:
        """The policy of ``spec``, set up for ``env``'s action space (possibly wrapped)."""
        ...

    def env_kwargs(self, spec: str) -> dict[str, Any]:
        """The ``BranchScanEnv`` settings (action type, observation) the policy acts in."""
        ...

    def reset_options(self, spec: str) -> dict[str, Any] | None:
        """``reset`` options of a spec (e.g. a fixed price of scan time), or None."""
        ...

    def files(self, spec: str) -> tuple[Path, ...]:
        """The files that define the policy (a trained model's): a changed file is refused
        beside trials made with the old one. Empty for a rule."""
        ...

    def is_learned(self, spec: str) -> bool:
        """A trained policy (the figures draw the learned ones apart)."""
        ...

    def label(self, spec: str) -> str:
        """The spec as figures name it (a model path shortened, say)."""
        ...


class BaselineAgent:
    """Encodes target angles as actions of a continuous, discrete or trigger env.

    Args:
        theta_max_deg: The env's ``theta_max_deg`` (continuous action = angle / theta_max).
        action_angles_deg: The env's ``discrete_angles_deg`` for a discrete env (actions are
            indices into it); None for a continuous env.
        trigger_angles_deg: The env's ``trigger_angles_deg`` for a trigger env (hold, or advance
            the rotation cycle: the agent's cycle must be the env's +theta, 0, -theta, 0).
        hold_tolerance_deg: The env scan's ``rotation_tolerance_deg``: targets this close to
            the current angle hold it.
    """

    # A "discrete_hold" env (v1): action 0 holds, k >= 1 targets action_angles_deg[k - 1].
    hold_action = False

    def __init__(
        self,
        theta_max_deg: float = THETA_MAX_DEG,
        action_angles_deg: tuple[float, ...] | None = None,
        trigger_angles_deg: tuple[float, ...] | None = None,
        hold_tolerance_deg: float = ROTATION_TOLERANCE_DEG,
    ) -> None:
        if not (math.isfinite(theta_max_deg) and theta_max_deg > 0):
            raise ValueError(f"theta_max_deg must be positive, got {theta_max_deg}")
        if action_angles_deg is not None and trigger_angles_deg is not None:
            raise ValueError("give action_angles_deg (discrete) or trigger_angles_deg, not both")
        self.theta_max_deg = float(theta_max_deg)
        self.action_angles_deg = (
            None if action_angles_deg is None else tuple(float(a) for a in action_angles_deg)
        )
        self.trigger_angles_deg = (
            None if trigger_angles_deg is None else tuple(float(a) for a in trigger_angles_deg)
        )
        self.hold_tolerance_deg = float(hold_tolerance_deg)

    @classmethod
    def for_env(cls, env: Any, *args: Any, **kwargs: Any) -> BaselineAgent:
        """An agent matching a (possibly wrapped or vector) BranchScanEnv's action settings."""
        config = _env_config(env)
        discrete = config.action_type in ("discrete", "discrete_hold")
        trigger = config.action_type == "trigger"
        agent = cls(
            *args,
            theta_max_deg=config.theta_max_deg,
            action_angles_deg=config.discrete_angles_deg if discrete else None,
            trigger_angles_deg=config.trigger_angles_deg if trigger else None,
            hold_tolerance_deg=config.scan.rotation_tolerance_deg,
            **kwargs,
        )
        agent.hold_action = config.action_type == "discrete_hold"
        return agent

    @classmethod
    def for_session_env(cls, env: Any, *args: Any) -> Any:
        """An agent that reads a single (possibly wrapped) env's scan session.

        ``cls(session, *args, **action_settings)`` with the env's action settings.

        Raises:
            ValueError: ``env`` is not a single ``BranchScan`` env (a vector env, another env).
        """
        session = getattr(getattr(env, "unwrapped", env), "session", None)
        if session is None:
            raise ValueError(f"{cls.__name__} needs a single BranchScan env, got {env!r}")
        base = BaselineAgent.for_env(env)
        agent = cls(
            session,
            *args,
            theta_max_deg=base.theta_max_deg,
            action_angles_deg=base.action_angles_deg,
            trigger_angles_deg=base.trigger_angles_deg,
            hold_tolerance_deg=base.hold_tolerance_deg,
        )
        agent.hold_action = base.hold_action  # discrete_hold: action 0 holds
        return agent

    def predict(
        self,
        observation: dict | np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | bool | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """The action(s) for one observation or a batch (SB3's signature; always deterministic).

        Returns:
            Actions: (1,) float32 or a 0-d int index for one observation; (N, 1) float32 or (N,)
            int for a batch. The agent's state (the argument back, or the periodic phases).
        """
        vector = vector_part(observation)
        batched = vector.ndim == 2
        vectors = vector if batched else vector[None]
        starts = np.zeros(len(vectors), bool)
        if episode_start is not None:
            starts |= np.broadcast_to(np.asarray(episode_start, bool).reshape(-1), starts.shape)
        starts |= ~np.any(vectors[:, list(OUTCOME_FIELDS)] > 0, axis=1)
        angles, state = self._angles_deg(vectors, starts, state)
        current = vectors[:, VectorField.ANGLE] * self.theta_max_deg
        actions = self._encode(angles, current)
        return (actions if batched else actions[0]), state

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        """(N,) target angles (deg) for (N, VECTOR_SIZE) observation vectors."""
        raise NotImplementedError

    def _encode(self, angles_deg: np.ndarray, current_deg: np.ndarray) -> np.ndarray:
        if self.trigger_angles_deg is not None:
            return self._encode_trigger(angles_deg, current_deg)
        if self.action_angles_deg is None:
            return (angles_deg / self.theta_max_deg).astype(np.float32)[:, None]
        choices = np.asarray(self.action_angles_deg)
        index = np.abs(angles_deg[:, None] - choices[None, :]).argmin(axis=1)
        if not self.hold_action:
            return index.astype(np.int64)
        hold = np.abs(angles_deg - current_deg) <= self.hold_tolerance_deg
        return np.where(hold, 0, index + 1).astype(np.int64)

    def _encode_trigger(self, angles_deg: np.ndarray, current_deg: np.ndarray) -> np.ndarray:
        """0 where the target is the current angle; else the trigger of the target's |angle|."""
        actions = np.zeros(len(angles_deg), np.int64)
        thetas = np.asarray(self.trigger_angles_deg)
        for i, (target, current) in enumerate(zip(angles_deg, current_deg, strict=True)):
            if abs(target - current) <= self.hold_tolerance_deg:
                continue
            if abs(target) <= self.hold_tolerance_deg:  # back to 0: any trigger does it
                actions[i] = 1
                continue
            match = np.flatnonzero(np.abs(thetas - abs(target)) <= self.hold_tolerance_deg)
            if len(match) == 0:
                raise ValueError(
                    f"target angle {target} deg is not a trigger angle {self.trigger_angles_deg}"
                )
            actions[i] = match[0] + 1
        return actions


def _env_config(env: Any) -> Any:
    """The EnvConfig of a BranchScanEnv, possibly wrapped or vectorised."""
    for candidate in (env, getattr(env, "unwrapped", None)):
        config = getattr(candidate, "config", None)
        if config is not None and hasattr(config, "action_type"):
            return config
    get_attr = getattr(env, "get_attr", None)  # gymnasium / SB3 vector envs
    if get_attr is not None:
        return get_attr("config")[0]
    raise ValueError(f"{env!r} is not a BranchScanEnv (no EnvConfig found)")
