"""Actions of :class:`branch_gym.env.BranchScanEnv`: the target rotation angle about the branch.

* continuous: ``Box(-1, 1, (1,), float32)`` (a plain scalar is accepted too); the angle is
  ``a * theta_max_deg``. Finite values outside [-1, 1] are clipped (documented behaviour, as most
  continuous-control envs do); NaN, infinities and other shapes raise ``ValueError``.
* discrete: ``Discrete(n)``; the angle is ``discrete_angles_deg[a]``. A non-integer or
  out-of-range index raises ``ValueError`` (there is no meaningful nearest index to clip to).

Either way the env steps :meth:`branch_gym.scan.ScanSession.step` with that angle (deg).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

# Shapes accepted for one action: a scalar or a length-1 array (what SB3's predict returns).
_ACCEPTED_SHAPES = ((), (1,))


class ActionCodec:
    """Builds the action space and decodes actions into target angles.

    Args:
        action_type: "continuous" or "discrete".
        theta_max_deg: Angle of the continuous bounds (deg).
        discrete_angles_deg: Angles of the discrete actions (deg).
    """

    def __init__(
        self, action_type: str, theta_max_deg: float, discrete_angles_deg: tuple[float, ...]
    ) -> None:
        self.discrete = action_type == "discrete"
        self.theta_max_deg = float(theta_max_deg)
        self.angles_deg = tuple(float(a) for a in discrete_angles_deg)
        self.space: spaces.Space = (
            spaces.Discrete(len(self.angles_deg))
            if self.discrete
            else spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        )

    def to_angle_deg(self, action: object) -> float:
        """The target angle (deg) of one action.

        Raises:
            ValueError: wrong shape, NaN / infinite value, or a bad discrete index.
        """
        value = np.asarray(action)
        if value.shape not in _ACCEPTED_SHAPES:
            expected = "an int index" if self.discrete else "shape (1,)"
            raise ValueError(f"action must be {expected}, got shape {value.shape}: {action!r}")
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
        if not np.issubdtype(np.asarray(index).dtype, np.integer):
            raise ValueError(f"discrete action must be an integer index, got {index!r}")
        if not 0 <= int(index) < len(self.angles_deg):
            last = len(self.angles_deg) - 1
            raise ValueError(
                f"discrete action {int(index)} out of range: expected 0..{last} "
                f"(angles {self.angles_deg} deg)"
            )
        return self.angles_deg[int(index)]
