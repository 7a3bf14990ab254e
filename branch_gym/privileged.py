"""A privileged rotation policy: it reads the ground truth (simulation only), an upper bound.

:class:`PrivilegedAgent` knows where every side branch is and what the model has found. At each
modeling iteration it looks at the ground-truth secondaries whose base lies in the camera's view
band and that the current model does not match yet (:func:`recon.metrics.evaluate`). If the
current view shows each of them at a good angle (the branch's horizontal direction at least
``good_view_deg`` from the optical axis: not hidden behind the primary, not pointing at the lens)
it holds; otherwise it rotates to the nearest candidate angle that shows them all well (a
rotation costs scan time in proportion to its angle), or, where none does, to the one that shows
the worst-placed branch best. With nothing pending it holds. Its points on the missed-vs-scan-time
plot bound what a policy that sees only the pipeline's observation can reach.

With ``return_home`` it turns back to the home angle (0) once nothing is pending, where the
paper's schedule comes back too: an expert for students that cannot see what is pending, who
would otherwise learn to stay at a turned angle that hides what the home view shows.

It lives with the simulator, not in ``agents``: it reads the simulator's ground truth, as the
``gt`` segmenter and the ``oracle`` tracker do, and the DAgger expert
(:mod:`branch_gym.training.imitation`) is this policy. Specs (``agents.factory``):
``privileged``, ``privileged:home`` (``return_home``). It needs a single, unwrapped-able env (not
vectorised).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from branch_gym.env.layout import DISCRETE_ANGLES_DEG
from branch_gym.policy import BaselineAgent
from branch_gym.scoring import scan_metrics_config
from branch_gym.sim.validation import require_positive
from recon.metrics import TruthIndex, evaluate, index_truth

SPEC_KIND = "privileged"
HOME_SPEC = "privileged:home"
_VIEW_DECIMALS = 6


@dataclass(frozen=True)
class PrivilegedConfig:
    """When and where the privileged policy rotates.

    Attributes:
        candidate_angles_deg: Angles it may rotate to (the discrete env's, the paper's +-22.5
            and +-45 deg and 0).
        good_view_deg: A branch whose horizontal direction is at least this far from the
            optical axis is well in view (our choice: 45 deg; the misses of the no-rotation
            scan all lie within 45 deg of the home optical axis, issue 13).
        view_band_fov: Branches whose base lies within this many vertical FoVs of the camera
            height are the ones in view (our choice: 0.5, the image's half height).
        return_home: With nothing pending, turn back to 0 instead of holding (our choice for
            the bound: False, the cheapest scan; True for an expert that students copy, issue
            34: students that held a turned angle hid branches the home view shows).
    """

    candidate_angles_deg: tuple[float, ...] = DISCRETE_ANGLES_DEG
    good_view_deg: float = 45.0
    view_band_fov: float = 0.5
    return_home: bool = False

    def __post_init__(self) -> None:
        if not self.candidate_angles_deg or 0.0 not in self.candidate_angles_deg:
            raise ValueError("PrivilegedConfig.candidate_angles_deg must hold 0")
        if not 0.0 < self.good_view_deg <= 90.0:
            raise ValueError(
                f"PrivilegedConfig.good_view_deg must be in (0, 90], got {self.good_view_deg}"
            )
        require_positive(self, "view_band_fov")


class PrivilegedAgent(BaselineAgent):
    """Rotate to show ground-truth branches that no frame has shown well (module docstring).

    Args:
        session: The env's :class:`branch_gym.scan.ScanSession` (``env.unwrapped.session``).
        config: When and where to rotate.
        theta_max_deg, action_angles_deg, trigger_angles_deg, hold_tolerance_deg: The env's
            action settings (see :meth:`BaselineAgent.for_env`).
    """

    def __init__(
        self, session: Any, config: PrivilegedConfig | None = None, **action_settings: Any
    ) -> None:
        super().__init__(**action_settings)
        self.session = session
        self.config = config or PrivilegedConfig()
        self._truth: tuple[Any, TruthIndex] | None = None  # (tree, its index), once per tree
        too_far = [a for a in self.config.candidate_angles_deg if abs(a) > self.theta_max_deg]
        if too_far:
            raise ValueError(
                f"candidate angles {too_far} exceed theta_max_deg {self.theta_max_deg}"
            )

    @classmethod
    def for_env(cls, env: Any, config: PrivilegedConfig | None = None) -> PrivilegedAgent:
        """The agent for a single (possibly wrapped) ``BranchScan`` env."""
        return cls.for_session_env(env, config)

    def target_angle_deg(self) -> float:
        """The target angle for the session's current state (deg)."""
        current = float(self.session.angle_deg)
        config = self.config
        pending = self._pending_directions_rad()
        if config.return_home and len(pending) == 0:
            return 0.0
        return choose_angle_deg(pending, current, config.candidate_angles_deg, config.good_view_deg)

    def _pending_directions_rad(self) -> np.ndarray:
        """Headings (rad, 0 along +y) of the in-view branches the model does not match yet."""
        session, config = self.session, self.config
        tree = session.tree
        if tree is None:
            return np.zeros(0)
        if self._truth is None or self._truth[0] is not tree:
            # The scan's band; matches in scope up to the height reached, as the bound always
            # read them (a branch above it counts as pending while in view).
            rules = scan_metrics_config(session.config, count_unreached_as_missed=False)
            self._truth = (tree, index_truth(tree, rules))
        index = self._truth[1]
        metrics = evaluate(
            session.model, tree, index.config, scanned_top_z_m=session.camera_height_m,
            truth_index=index,
        )  # fmt: skip
        matched = {j for j, _ in metrics.matches}
        half_band_m = config.view_band_fov * session.vertical_fov_m
        headings = []
        for j, branch in enumerate(tree.secondaries):
            points = np.asarray(branch.points, float)
            if j in matched or abs(points[0, 2] - session.camera_height_m) > half_band_m:
                continue
            headings.append(branch_heading_rad(points))
        return np.array(headings)

    def _angles_deg(
        self, vectors: np.ndarray, starts: np.ndarray, state: Any
    ) -> tuple[np.ndarray, Any]:
        if len(vectors) != 1:
            raise ValueError("the privileged policy acts in a single env, not a batch")
        return np.array([self.target_angle_deg()]), state


def branch_heading_rad(points: np.ndarray) -> float:
    """Horizontal heading of a side branch, base to tip (rad, 0 along +y, positive toward -x).

    Args:
        points: (N, 3) its centerline in metres, world frame, base first.
    """
    direction = points[-1] - points[0]
    return math.atan2(-direction[0], direction[1])


def parse_privileged_spec(spec: str) -> PrivilegedConfig | None:
    """The config of ``privileged`` or ``privileged:home``; None for any other spec."""
    if spec == SPEC_KIND:
        return PrivilegedConfig()
    if spec == HOME_SPEC:
        return PrivilegedConfig(return_home=True)
    return None


def choose_angle_deg(
    headings_rad: np.ndarray,
    current_deg: float,
    candidate_angles_deg: tuple[float, ...],
    good_view_deg: float,
) -> float:
    """The privileged policy's target angle for the pending branches' headings.

    Hold where nothing is pending or the current view shows every pending branch at least
    ``good_view_deg`` from the optical axis; else the nearest candidate angle that does (a
    rotation costs scan time in proportion to its angle); where none does, the candidate that
    shows the worst-placed branch best (nearest first), if it beats the current view.

    Args:
        headings_rad: (P,) horizontal headings of the pending branches (rad, 0 along +y).
        current_deg: The current rotation (deg).
        candidate_angles_deg: Angles it may rotate to (deg).
        good_view_deg: The angle from the optical axis that counts as well in view (deg).

    Returns:
        The target angle (deg); ``current_deg`` to hold.
    """
    if len(headings_rad) == 0 or _worst_view_deg(headings_rad, current_deg) >= good_view_deg:
        return current_deg
    # Rounded to a micro-degree so that mirror-image views tie and the nearer angle wins.
    views = {
        angle: round(_worst_view_deg(headings_rad, angle), _VIEW_DECIMALS)
        for angle in candidate_angles_deg
    }
    good = [angle for angle, view in views.items() if view >= good_view_deg]
    if good:
        return float(min(good, key=lambda angle: abs(angle - current_deg)))
    best = max(views, key=lambda angle: (views[angle], -abs(angle - current_deg)))
    current_view = round(_worst_view_deg(headings_rad, current_deg), _VIEW_DECIMALS)
    return current_deg if views[best] <= current_view else float(best)


def _worst_view_deg(headings_rad: np.ndarray, rotation_deg: float) -> float:
    """Smallest angle (deg, in [0, 90]) between any branch line and the view axis at a rotation."""
    difference = np.abs(np.remainder(headings_rad - math.radians(rotation_deg), math.pi))
    folded = np.minimum(difference, math.pi - difference)
    return float(np.degrees(folded.min()))
