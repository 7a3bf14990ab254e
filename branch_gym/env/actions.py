"""Actions of :class:`branch_gym.env.BranchScanEnv`: the target rotation angle about the branch.

* continuous: ``Box(-1, 1, (1,), float32)`` (a plain scalar is accepted too); the angle is
  ``a * theta_max_deg``. Finite values outside [-1, 1] are clipped (documented behaviour, as most
  continuous-control envs do); NaN, infinities and other shapes raise ``ValueError``.
* discrete: ``Discrete(n)``; the angle is ``discrete_angles_deg[a]``. A non-integer or
  out-of-range index raises ``ValueError`` (there is no meaningful nearest index to clip to).
* discrete_hold: ``Discrete(1 + len(discrete_angles_deg))``; 0 holds the current angle, ``k >= 1``
  targets ``discrete_angles_deg[k - 1]`` (v1: holding is a choice of its own).
* trigger: ``Discrete(1 + len(trigger_angles_deg))``; 0 holds the current angle, ``k >= 1``
  advances the paper's cycle (+theta, 0, -theta, 0) by one move with theta =
  ``trigger_angles_deg[k - 1]``: from a rotated view back to 0, from 0 to the side opposite the
  last rotation. The paper's periodic controller is "trigger every N fields of view", so this
  action space contains it; a policy only decides when (and how far), which is quick to learn.

Either way the env steps :meth:`branch_gym.scan.ScanSession.step` with that angle (deg).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

# Shapes accepted for one action: a scalar or a length-1 array (what SB3's predict returns).
_ACCEPTED_SHAPES = ((), (1,))
# A trigger from an angle within this of 0 (deg) rotates away from 0, else back to 0 (our choice:
# the scan's rotation tolerance, ScanConfig.rotation_tolerance_deg).
_AT_ZERO_DEG = 0.5


class ActionCodec:
    """Builds the action space and decodes actions into target angles.

    A trigger codec remembers the side of the last rotation: call :meth:`reset` with the env.

    Args:
        action_type: "continuous", "discrete", "discrete_hold" or "trigger".
        theta_max_deg: Angle of the continuous bounds (deg).
        discrete_angles_deg: Angles of the discrete actions (deg).
        trigger_angles_deg: Cycle angles theta of the trigger actions 1.. (deg, positive).
    """

    def __init__(
        self,
        action_type: str,
        theta_max_deg: float,
        discrete_angles_deg: tuple[float, ...],
        trigger_angles_deg: tuple[float, ...] = (),
    ) -> None:
        self.trigger = action_type == "trigger"
        self.hold = action_type == "discrete_hold"
        self.discrete = action_type == "discrete" or self.trigger or self.hold
        self.theta_max_deg = float(theta_max_deg)
        self.angles_deg = tuple(float(a) for a in discrete_angles_deg)
        self.trigger_angles_deg = tuple(float(a) for a in trigger_angles_deg)
        if self.trigger:
            self.space: spaces.Space = spaces.Discrete(1 + len(self.trigger_angles_deg))
        elif self.hold:
            self.space = spaces.Discrete(1 + len(self.angles_deg))
        elif self.discrete:
            self.space = spaces.Discrete(len(self.angles_deg))
        else:
            self.space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.reset()

    def reset(self) -> None:
        """Start an episode: the first triggered rotation goes to +theta (the paper's cycle)."""
        self._next_side = 1.0

    def to_angle_deg(self, action: object, current_angle_deg: float = 0.0) -> float:
        """The target angle (deg) of one action.

        Args:
            action: The action.
            current_angle_deg: The camera's current angle about the branch (trigger actions).

        Raises:
            ValueError: wrong shape, NaN / infinite value, or a bad discrete index.
        """
        value = np.asarray(action)
        if value.shape not in _ACCEPTED_SHAPES:
            expected = "an int index" if self.discrete else "shape (1,)"
            raise ValueError(f"action must be {expected}, got shape {value.shape}: {action!r}")
        if self.trigger:
            return self._trigger_angle(value.reshape(-1)[0], current_angle_deg)
        if self.hold:
            k = self._check_index(value.reshape(-1)[0], 1 + len(self.angles_deg), self.angles_deg)
            return float(current_angle_deg) if k == 0 else self.angles_deg[k - 1]
        if self.discrete:
            return self._discrete_angle(value.reshape(-1)[0])
        if not np.issubdtype(value.dtype, np.number) or np.issubdtype(
            value.dtype, np.complexfloating
        ):
            raise ValueError(f"action must be a real number, got {action!r} ({value.dtype})")
        a = float(value.reshape(-1)[0])
        if not np.isfinite(a):
            raise ValueError(f"action must be finite, got {action!r}")
        return float(np.clip(a, -1.0, 1.0)) * self.theta_max_deg

    def normalised(self, angle_deg: float) -> float:
        """An angle as the observation reports it: ``angle / theta_max`` clipped to [-1, 1]."""
        return float(np.clip(angle_deg / self.theta_max_deg, -1.0, 1.0))

    def _discrete_angle(self, index: np.generic) -> float:
        return self.angles_deg[self._check_index(index, len(self.angles_deg), self.angles_deg)]

    def _trigger_angle(self, index: np.generic, current_angle_deg: float) -> float:
        k = self._check_index(index, 1 + len(self.trigger_angles_deg), self.trigger_angles_deg)
        if k == 0:
            return float(current_angle_deg)
        if abs(current_angle_deg) > _AT_ZERO_DEG:
            return 0.0
        target = self._next_side * self.trigger_angles_deg[k - 1]
        self._next_side = -self._next_side
        return target

    @staticmethod
    def _check_index(index: np.generic, n: int, angles_deg: tuple[float, ...]) -> int:
        if not np.issubdtype(np.asarray(index).dtype, np.integer):
            raise ValueError(f"discrete action must be an integer index, got {index!r}")
        if not 0 <= int(index) < n:
            raise ValueError(
                f"discrete action {int(index)} out of range: expected 0..{n - 1} "
                f"(angles {angles_deg} deg)"
            )
        return int(index)
