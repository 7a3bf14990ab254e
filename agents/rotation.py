"""Rotation policies: when and how far to turn the camera about the primary branch.

A policy is asked once per modeling iteration for the target rotation angle (deg, yaw about the
world-vertical axis through the branch; 0 = the home orientation). The scan rotates the camera to
it (rotating is motion at the set speed and costs scan time) and then keeps following the branch.

Specs (as ``eval.py --policies`` takes them):

=========================  =============================================================
``none``                   never rotate (the paper's baseline, Table I column 0 / 0)
``periodic:ANGLE:FREQ``    the paper's controller: every (vertical FoV length at z_target) /
                           FREQ of vertical travel, step through +ANGLE, 0, -ANGLE, 0, ...
=========================  =============================================================
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass


@dataclass(frozen=True)
class RotationState:
    """What a rotation policy may look at (all known to the robot, no ground truth).

    Attributes:
        angle_deg: Current rotation about the branch (deg).
        travel_since_rotation_m: Vertical camera travel since the last rotation ended (m).
        vertical_fov_m: Height of the image at z_target (m): the unit of the paper's frequency.
        iteration: Modeling iterations so far.
    """

    angle_deg: float
    travel_since_rotation_m: float
    vertical_fov_m: float
    iteration: int = 0


class RotationPolicy(ABC):
    """Decides the target rotation angle at each modeling iteration."""

    spec: str

    def reset(self) -> None:  # noqa: B027 (stateless policies need nothing)
        """Forget per-scan state (called at the start of every scan)."""

    @abstractmethod
    def target_angle_deg(self, state: RotationState) -> float:
        """The rotation angle (deg) the camera should be at from now on."""


class NoRotation(RotationPolicy):
    """Never rotate: scan straight up the branch."""

    spec = "none"

    def target_angle_deg(self, state: RotationState) -> float:
        return 0.0


class PeriodicRotation(RotationPolicy):
    """The paper's periodic rotation (section V): +angle, 0, -angle, 0, ... every FoV / frequency.

    Args:
        angle_deg: Rotation angle theta (paper: 22.5 or 45 deg).
        frequency: Rotations per vertical FoV of travel (paper: 1.5 or 2.5).
    """

    def __init__(self, angle_deg: float, frequency: float) -> None:
        if not (math.isfinite(angle_deg) and 0 < angle_deg <= 90):
            raise ValueError(f"periodic rotation angle_deg must be in (0, 90], got {angle_deg}")
        if not (math.isfinite(frequency) and frequency > 0):
            raise ValueError(f"periodic rotation frequency must be positive, got {frequency}")
        self.angle_deg = float(angle_deg)
        self.frequency = float(frequency)
        self.spec = f"periodic:{angle_deg:g}:{frequency:g}"
        self._cycle = (self.angle_deg, 0.0, -self.angle_deg, 0.0)
        self._phase = -1  # before the first rotation: at 0, next is +angle

    def reset(self) -> None:
        self._phase = -1

    def target_angle_deg(self, state: RotationState) -> float:
        interval_m = state.vertical_fov_m / self.frequency
        if state.travel_since_rotation_m >= interval_m:
            self._phase = (self._phase + 1) % len(self._cycle)
        return 0.0 if self._phase < 0 else self._cycle[self._phase]


def make_policy(spec: str) -> RotationPolicy:
    """Build a rotation policy from its spec ("none", "periodic:22.5:1.5").

    Raises:
        ValueError: unknown or malformed spec, naming the valid forms.
    """
    kind, *args = spec.split(":")
    if kind == "none" and not args:
        return NoRotation()
    if kind == "periodic" and len(args) == 2:
        try:
            angle, frequency = float(args[0]), float(args[1])
        except ValueError:
            pass
        else:
            return PeriodicRotation(angle, frequency)
    raise ValueError(
        f"unknown rotation policy spec {spec!r}: expected 'none' or 'periodic:ANGLE_DEG:FREQ' "
        "(e.g. 'periodic:22.5:1.5')"
    )
