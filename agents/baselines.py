"""The paper's rotation policies as agents for :class:`branch_gym.env.BranchScanEnv`.

They act through stable-baselines3's ``predict(obs, state=None, episode_start=None,
deterministic=True) -> (action, state)`` (:class:`branch_gym.policy.Policy`), read the observation
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
from branch_gym.env.layout import THETA_MAX_DEG, VectorField
from branch_gym.policy import BaselineAgent

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
