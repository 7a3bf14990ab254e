"""A non-learned rotation agent driven by disagreement between the masks and the 3D model.

The paper (section VI) names the limitation of its periodic rotation: it rotates whether or not
there is anything to see, and suggests driving rotation by inconsistencies between the
segmentation masks and the 3D model instead. :class:`DisagreementAgent` does that with what the
observation vector says (:class:`branch_gym.env.layout.VectorField`):

- *evidence*: 2D side-branch candidates that no 3D secondary explains
  (``UNCONFIRMED_CANDIDATES`` > 0), or an inconsistent / restart modeling outcome;
- when the evidence persists for ``persist_iterations`` iterations in a row, the camera is at 0
  and it has travelled at least ``min_travel_fov`` vertical FoVs since its last rotation, it
  rotates to +angle (the next time to -angle, alternating);
- after ``check_travel_fov`` FoVs of travel at the rotated view (the view has been checked: the
  modeler has had iterations to triangulate what it shows) it rotates back to 0.

A clean scan (consistent iterations, every candidate explained) never rotates. Spec (as
``agents.factory.make_agent`` and ``eval.py --policies`` take it): ``disagreement`` or
``disagreement:ANGLE``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.baselines import BaselineAgent
from branch_gym.control import ROTATION_TOLERANCE_DEG
from branch_gym.env.layout import THETA_MAX_DEG, VectorField

SPEC_KIND = "disagreement"
_STREAK, _SIGN = 0, 1  # columns of the agent's per-entry state


@dataclass(frozen=True)
class DisagreementConfig:
    """When the disagreement agent rotates.

    Attributes:
        angle_deg: Rotation angle (our choice: the paper's smaller angle, 22.5 deg, Table I:
            it costs half the time of 45 deg and already reveals branches hidden behind the
            primary's silhouette).
        persist_iterations: Iterations in a row with evidence before rotating (our choice: 2;
            a candidate seen in one iteration only is usually a branch entering the image that
            the next iteration confirms).
        min_travel_fov: Vertical FoVs of travel since the previous rotation (the return to 0
            included) before the next one (our choice: 0.5, ~6 cm at z_target: at most one
            rotation pair per FoV, fewer than the paper's 1.5 per FoV).
        check_travel_fov: FoVs of travel at the rotated view before going back to 0 (our
            choice: 0.35, ~4 cm: ~4 modeling iterations of 10 mm to triangulate the branch).
        use_outcomes: Count inconsistent and restart outcomes as evidence too (our choice:
            yes; the 2D primary disagreeing with the model is often a branch crossing it).
    """

    angle_deg: float = 22.5
    persist_iterations: int = 2
    min_travel_fov: float = 0.5
    check_travel_fov: float = 0.35
    use_outcomes: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.angle_deg) and 0 < self.angle_deg <= THETA_MAX_DEG):
            raise ValueError(
                f"DisagreementConfig.angle_deg must be in (0, {THETA_MAX_DEG}], "
                f"got {self.angle_deg!r}"
            )
        if not (isinstance(self.persist_iterations, int) and self.persist_iterations >= 1):
            raise ValueError(
                "DisagreementConfig.persist_iterations must be an int >= 1, "
                f"got {self.persist_iterations!r}"
            )
        for name in ("min_travel_fov", "check_travel_fov"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"DisagreementConfig.{name} must be >= 0, got {value!r}")


def parse_disagreement_spec(spec: str) -> DisagreementConfig:
    """The config of a ``disagreement`` or ``disagreement:ANGLE`` spec.

    Raises:
        ValueError: a malformed spec or a bad angle (naming the valid forms).
    """
    kind, *args = spec.split(":")
    if kind == SPEC_KIND and len(args) <= 1:
        if not args:
            return DisagreementConfig()
        try:
            angle = float(args[0])
        except ValueError:
            pass
        else:
            return DisagreementConfig(angle_deg=angle)
    raise ValueError(
        f"malformed disagreement policy spec {spec!r}: expected 'disagreement' or "
        "'disagreement:ANGLE_DEG' (e.g. 'disagreement:22.5')"
    )


class DisagreementAgent(BaselineAgent):
    """Rotate only when the observation shows unexplained evidence (see the module docstring).

    The state of each batch entry is ``(evidence streak, sign of the next rotation)``: returned
    by :meth:`predict` as an (N, 2) int array, used when passed back, kept internally otherwise.

    Args:
        config: When to rotate.
        theta_max_deg: The env's ``theta_max_deg``.
        action_angles_deg: The env's ``discrete_angles_deg`` (discrete env), holding 0 and
            +-angle; None for a continuous env.
        trigger_angles_deg: The env's ``trigger_angles_deg`` (trigger env), holding angle.
        hold_tolerance_deg: The env scan's ``rotation_tolerance_deg``: current angles closer
            to 0 than this count as the home view.
    """

    def __init__(
        self,
        config: DisagreementConfig | None = None,
        theta_max_deg: float = THETA_MAX_DEG,
        action_angles_deg: tuple[float, ...] | None = None,
        trigger_angles_deg: tuple[float, ...] | None = None,
        hold_tolerance_deg: float = ROTATION_TOLERANCE_DEG,
    ) -> None:
        super().__init__(theta_max_deg, action_angles_deg, trigger_angles_deg, hold_tolerance_deg)
        self.config = config or DisagreementConfig()
        angle = self.config.angle_deg
        if angle > self.theta_max_deg:
            raise ValueError(f"angle_deg {angle} exceeds theta_max_deg {self.theta_max_deg}")
        if self.action_angles_deg is not None and not {0.0, angle, -angle} <= set(
            self.action_angles_deg
        ):
            raise ValueError(
                f"action_angles_deg {self.action_angles_deg} must hold 0 and +-{angle}"
            )
        self._state = np.zeros((0, 2), np.int64)

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        n = len(vectors)
        if state is not None:
            state = np.array(state, np.int64).reshape(-1, 2)
        elif len(self._state) == n:
            state = self._state.copy()
        else:
            state = np.tile([0, 1], (n, 1)).astype(np.int64)
        if len(state) != n:
            raise ValueError(f"state holds {len(state)} entries for {n} observations")
        state[starts] = (0, 1)
        config = self.config
        current_deg = vectors[:, VectorField.ANGLE] * self.theta_max_deg
        travel = vectors[:, VectorField.TRAVEL_FOV]
        rotated = np.abs(current_deg) > self.hold_tolerance_deg
        evidence = vectors[:, VectorField.UNCONFIRMED_CANDIDATES] > 0
        if config.use_outcomes:
            evidence |= vectors[:, VectorField.OUTCOME_INCONSISTENT] > 0
            evidence |= vectors[:, VectorField.OUTCOME_RESTART] > 0
        streak = np.where(evidence & ~rotated, state[:, _STREAK] + 1, 0)
        trigger = ~rotated & (streak >= config.persist_iterations)
        trigger &= travel >= config.min_travel_fov
        angles = np.zeros(n)
        hold = rotated & (travel < config.check_travel_fov)
        angles[hold] = current_deg[hold]
        angles[trigger] = state[trigger, _SIGN] * config.angle_deg
        state[:, _STREAK] = np.where(trigger, 0, streak)
        state[trigger, _SIGN] *= -1
        self._state = state
        return angles, state.copy()
