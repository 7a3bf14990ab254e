"""The paper's rotation policies as agents for :class:`branch_gym.env.BranchScanEnv`.

They act through stable-baselines3's ``predict(obs, state=None, episode_start=None,
deterministic=True) -> (action, state)`` (:class:`agents.protocol.Agent`), read the observation
vector by field name (:class:`branch_gym.env.layout.VectorField`), and accept single or batched
(vector env) observations, Dict or flattened:

=========================  =================================  ==========================
agent                      decision                           spec (``eval.py``)
=========================  =================================  ==========================
``NoRotationAgent()``      always angle 0 (paper Table I,     ``none``
                           column 0 / 0)
``PeriodicAgent(a, f)``    +a, 0, -a, 0, ... every 1 / f      ``periodic:a:f``
                           vertical FoVs of travel (paper
                           section V)
=========================  =================================  ==========================

A new episode starts (the periodic phase resets) where ``episode_start`` is True, and on an
observation from before any modeling iteration (all ``OUTCOME_*`` fields 0: what ``reset()``
returns, also after a vector env's autoreset).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from branch_gym.control import ROTATION_TOLERANCE_DEG
from branch_gym.env.layout import OUTCOME_FIELDS, THETA_MAX_DEG, VectorField, vector_part

NO_ROTATION_SPEC = "none"
PERIODIC_KIND = "periodic"
_NO_PHASE = -1  # before the first rotation of an episode


def parse_periodic_spec(spec: str) -> tuple[float, float] | None:
    """(angle_deg, frequency) of a ``periodic:ANGLE:FREQ`` spec; None for another kind of spec.

    >>> parse_periodic_spec("periodic:22.5:1.5")
    (22.5, 1.5)
    >>> parse_periodic_spec("none") is None
    True

    Raises:
        ValueError: a malformed ``periodic`` spec or bad parameters (naming the valid form).
    """
    return parse_angle_frequency_spec(spec, PERIODIC_KIND, "periodic:22.5:1.5")


def parse_angle_frequency_spec(spec: str, kind: str, example: str) -> tuple[float, float] | None:
    """(angle_deg, frequency) of a ``KIND:ANGLE:FREQ`` spec; None for a spec of another kind.

    Raises:
        ValueError: a malformed spec of ``kind`` or bad parameters (naming the valid form).
    """
    spec_kind, *args = spec.split(":")
    if spec_kind != kind:
        return None
    try:
        angle_deg, frequency = (float(arg) for arg in args)
    except ValueError:
        raise ValueError(
            f"malformed policy spec {spec!r}: expected '{kind}:ANGLE_DEG:FREQ' (e.g. '{example}')"
        ) from None
    check_periodic(angle_deg, frequency, THETA_MAX_DEG)
    return angle_deg, frequency


def check_periodic(angle_deg: float, frequency: float, theta_max_deg: float) -> None:
    """Raise a ValueError unless 0 < angle <= theta_max and the frequency is positive."""
    if not (math.isfinite(angle_deg) and 0 < angle_deg <= theta_max_deg):
        raise ValueError(
            f"periodic rotation angle_deg must be in (0, theta_max_deg={theta_max_deg}], "
            f"got {angle_deg}"
        )
    if not (math.isfinite(frequency) and frequency > 0):
        raise ValueError(f"periodic rotation frequency must be positive, got {frequency}")


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


class NoRotationAgent(BaselineAgent):
    """Never rotate: scan straight up the branch (the paper's baseline)."""

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        return np.zeros(len(vectors)), state


class PeriodicAgent(BaselineAgent):
    """The paper's periodic rotation (section V): +angle, 0, -angle, 0, ... every FoV / frequency.

    Every ``1 / frequency`` vertical FoVs of travel since the last rotation the target steps
    through +angle, 0, -angle, 0, ... The phase of each batch entry is the agent's state: it is
    returned by :meth:`predict`, used when passed back, and kept internally otherwise.

    Args:
        angle_deg: Rotation angle (paper: 22.5 or 45 deg); at most ``theta_max_deg``.
        frequency: Rotations per vertical FoV of travel (paper: 1.5 or 2.5).
        theta_max_deg: The env's ``theta_max_deg``.
        action_angles_deg: The env's ``discrete_angles_deg`` (discrete env), holding 0 and
            +-angle; None for a continuous env.
        trigger_angles_deg: The env's ``trigger_angles_deg`` (trigger env), holding angle.
        hold_tolerance_deg: The env scan's ``rotation_tolerance_deg``.
    """

    def __init__(
        self,
        angle_deg: float,
        frequency: float,
        theta_max_deg: float = THETA_MAX_DEG,
        action_angles_deg: tuple[float, ...] | None = None,
        trigger_angles_deg: tuple[float, ...] | None = None,
        hold_tolerance_deg: float = ROTATION_TOLERANCE_DEG,
    ) -> None:
        super().__init__(theta_max_deg, action_angles_deg, trigger_angles_deg, hold_tolerance_deg)
        check_periodic(angle_deg, frequency, self.theta_max_deg)
        self.cycle_deg = np.array([angle_deg, 0.0, -angle_deg, 0.0])
        if self.action_angles_deg is not None and not set(self.cycle_deg) <= set(
            self.action_angles_deg
        ):
            raise ValueError(
                f"action_angles_deg {self.action_angles_deg} must hold 0 and +-{angle_deg}"
            )
        if self.trigger_angles_deg is not None and angle_deg not in self.trigger_angles_deg:
            raise ValueError(f"trigger_angles_deg {self.trigger_angles_deg} must hold {angle_deg}")
        self.interval_fov = 1.0 / float(frequency)
        self._phases = np.zeros(0, np.int64)

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        if state is not None:
            phases = np.array(state, np.int64).reshape(-1)
        elif len(self._phases) == len(vectors):
            phases = self._phases.copy()
        else:
            phases = np.full(len(vectors), _NO_PHASE, np.int64)
        if len(phases) != len(vectors):
            raise ValueError(f"state holds {len(phases)} phases for {len(vectors)} observations")
        phases[starts] = _NO_PHASE
        due = vectors[:, VectorField.TRAVEL_FOV] >= self.interval_fov
        phases[due] = (phases[due] + 1) % len(self.cycle_deg)
        angles = np.where(phases < 0, 0.0, self.cycle_deg[np.maximum(phases, 0)])
        self._phases = phases
        return angles, phases.copy()


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
