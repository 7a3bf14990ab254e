"""The privileged state: what the ground truth says about the scan, for a critic during training.

:class:`PrivilegedStateWrapper` adds a ``"privileged"`` entry (:data:`PRIVILEGED_KEY`) to a
``BranchScan`` env's Dict observation: a fixed-size float32 vector read from the simulator's
ground truth and the env's own score (``info["metrics"]["matches"]``, the matching its reward
comes from: no second scoring). Only a critic may read it
(:class:`~branch_gym.training.privileged_critic.PrivilegedCriticPolicy`, ``TrainConfig.
privileged_critic``); the actor, and every policy played in evaluation, sees the plain
observation.

The scored side branches are those the benchmark's score counts (``recon.metrics``'s scope
with ``count_unreached_as_missed``: base height in the scan's scored band,
``branch_gym.scoring.scan_metrics_config``, up to the planned top height plus the base margin;
the env's score, ``info["metrics"]["n_gt"]``, counts the same unless ``paper_scoring``, as in
the v1 and v2 ids, where a branch counts as matched only once the scan has reached its base
height, as the privileged bound reads it). Each
unmatched one is, by its base height against the camera height, in view (within
``view_band_fov`` vertical FoVs: the privileged bound's band,
:class:`branch_gym.privileged.PrivilegedConfig`), passed (below that band: missed so far) or
ahead (above it: not yet seen). Headings follow :mod:`branch_gym.privileged` (0 along +y,
measured against the camera's rotation as :func:`~branch_gym.privileged.choose_angle_deg` does).

Layout (:class:`PrivilegedField`; ``Box(-1, 1, (5 + 4 * heading_slots,), float32)``, 21 entries
with the default 4 slots):

=====  =====================  ===========================================================  =======
index  field                  meaning                                                      range
=====  =====================  ===========================================================  =======
0      ``PENDING_IN_VIEW``    unmatched scored branches in the view band / ``count_scale``  [0, 1]
1      ``MISSED_BELOW``       unmatched scored branches below the view band / scale         [0, 1]
2      ``UNSEEN_AHEAD``       unmatched scored branches above the view band / scale         [0, 1]
3      ``MATCHED``            matched scored branches / scale                               [0, 1]
4      ``PROGRESS``           fraction of the scan height range covered                     [0, 1]
5+4k   slot k ``PRESENT``     1 where slot k holds a pending in-view branch, else 0         {0, 1}
6+4k   slot k ``COS``         cos of its heading relative to the camera's rotation          [-1, 1]
7+4k   slot k ``SIN``         sin of that relative heading                                  [-1, 1]
8+4k   slot k ``HEIGHT``      (base height - camera height) / vertical FoV at z_target      [-1, 1]
=====  =====================  ===========================================================  =======

Counts are clipped to 1. The slots hold the pending in-view branches worst placed first (the
smallest angle between the branch line and the optical axis, as the bound ranks them), the
rest zero; branches beyond ``heading_slots`` count in ``PENDING_IN_VIEW`` only.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from branch_gym.privileged import PrivilegedConfig, branch_heading_rad
from branch_gym.scoring import scan_metrics_config
from branch_gym.sim.validation import require_int, require_positive

PRIVILEGED_KEY = "privileged"
# Per-slot entries: present, cos, sin, height.
SLOT_SIZE = 4


class PrivilegedField(IntEnum):
    """The fixed entries of the privileged vector (the heading slots follow them)."""

    PENDING_IN_VIEW = 0
    MISSED_BELOW = 1
    UNSEEN_AHEAD = 2
    MATCHED = 3
    PROGRESS = 4


# The fields that count branches (divided by ``count_scale``).
COUNT_FIELDS = (
    PrivilegedField.PENDING_IN_VIEW,
    PrivilegedField.MISSED_BELOW,
    PrivilegedField.UNSEEN_AHEAD,
    PrivilegedField.MATCHED,
)


class SlotField(IntEnum):
    """Offsets within one heading slot."""

    PRESENT = 0
    COS = 1
    SIN = 2
    HEIGHT = 3


@dataclass(frozen=True)
class PrivilegedStateConfig:
    """The privileged vector's size and scales.

    Attributes:
        heading_slots: Pending in-view branches whose heading and height are encoded (our
            choice: 4; the view band is one vertical FoV, 0.115 m, and the paper's trees space
            their side branches ~5-10 cm apart, so more than 2-3 pending at once is rare).
        count_scale: Counts are divided by this (the observation's counts use 10,
            ``branch_gym.env.layout.VectorField.MODEL_SECONDARIES``).
        view_band_fov: Half-height of the view band in vertical FoVs (the privileged bound's,
            ``PrivilegedConfig.view_band_fov``, 0.5: the image's half height).
    """

    heading_slots: int = 4
    count_scale: float = 10.0
    view_band_fov: float = PrivilegedConfig().view_band_fov

    def __post_init__(self) -> None:
        require_int(self, "heading_slots", minimum=0)
        require_positive(self, "count_scale", "view_band_fov")

    @property
    def size(self) -> int:
        """Entries of the privileged vector."""
        return len(PrivilegedField) + SLOT_SIZE * self.heading_slots

    def space(self) -> spaces.Box:
        """The privileged entry's space: ``Box(-1, 1, (size,), float32)``."""
        return spaces.Box(-1.0, 1.0, (self.size,), np.float32)


def matched_branches(info: dict[str, Any]) -> set[int]:
    """Indices of the ground-truth secondaries the env's score matched (reset / step info).

    Raises:
        KeyError: an info without ``metrics`` (not a ``BranchScan`` env's).
    """
    return {int(j) for j, _ in json.loads(info["metrics"]["matches"])}


# A pending in-view branch: (angle between its line and the optical axis in [0, pi/2] rad,
# heading relative to the camera's rotation in rad, (base height - camera height) / vertical FoV).
PendingBranch = tuple[float, float, float]


def scored_branch_groups(
    session: Any, matched: set[int], view_band_fov: float
) -> tuple[dict[PrivilegedField, int], list[PendingBranch]]:
    """The scored side branches of a session by group (module docstring), and those in view.

    Args:
        session: A reset :class:`branch_gym.scan.ScanSession`.
        matched: Indices into ``session.tree.secondaries`` of the matched branches.
        view_band_fov: Half-height of the view band in vertical FoVs.

    Returns:
        The count of each of :data:`COUNT_FIELDS`, and the unmatched branches in the view band
        (:data:`PendingBranch`, unsorted).
    """
    counts = dict.fromkeys(COUNT_FIELDS, 0)
    pending: list[PendingBranch] = []
    tree = session.tree
    if tree is None:
        return counts, pending
    rules = scan_metrics_config(session.config)
    top_m = session.config.end_height_m + rules.gt_base_margin_m  # recon.metrics's scope
    camera_m, fov_m = session.camera_height_m, session.vertical_fov_m
    half_band_m = view_band_fov * fov_m
    rotation_rad = math.radians(float(session.angle_deg))
    for j, branch in enumerate(tree.secondaries):
        points = np.asarray(branch.points, float)
        base_m = points[0, 2]
        if not rules.band_min_z_m <= base_m <= top_m:
            continue
        if j in matched:
            counts[PrivilegedField.MATCHED] += 1
        elif base_m < camera_m - half_band_m:
            counts[PrivilegedField.MISSED_BELOW] += 1
        elif base_m > camera_m + half_band_m:
            counts[PrivilegedField.UNSEEN_AHEAD] += 1
        else:
            counts[PrivilegedField.PENDING_IN_VIEW] += 1
            relative = branch_heading_rad(points) - rotation_rad
            folded = abs(math.remainder(relative, math.pi))  # branch line vs optical axis
            pending.append((folded, relative, (base_m - camera_m) / fov_m))
    return counts, pending


def privileged_state(
    session: Any, matched: set[int], config: PrivilegedStateConfig | None = None
) -> np.ndarray:
    """The privileged vector of a scan session (module docstring's layout).

    Args:
        session: A reset :class:`branch_gym.scan.ScanSession`.
        matched: Indices into ``session.tree.secondaries`` of the matched branches.
        config: Size and scales.

    Returns:
        (config.size,) float32 in [-1, 1].
    """
    config = config or PrivilegedStateConfig()
    vector = np.zeros(config.size, np.float32)
    vector[PrivilegedField.PROGRESS] = session.progress
    counts, pending = scored_branch_groups(session, matched, config.view_band_fov)
    for field, count in counts.items():
        vector[field] = min(count / config.count_scale, 1.0)
    start = len(PrivilegedField)
    for k, (_, relative, height) in enumerate(sorted(pending)[: config.heading_slots]):
        slot = start + SLOT_SIZE * k
        vector[slot + SlotField.PRESENT] = 1.0
        vector[slot + SlotField.COS] = math.cos(relative)
        vector[slot + SlotField.SIN] = math.sin(relative)
        vector[slot + SlotField.HEIGHT] = np.clip(height, -1.0, 1.0)
    return vector


def with_privileged_space(
    space: spaces.Dict, config: PrivilegedStateConfig | None = None
) -> spaces.Dict:
    """A Dict observation space with the privileged entry added.

    Raises:
        ValueError: not a Dict space, or one that already has the entry.
    """
    if not isinstance(space, spaces.Dict):
        raise ValueError(
            f"the privileged state extends a Dict observation, got {space} (a flat env id?)"
        )
    if PRIVILEGED_KEY in space.spaces:
        raise ValueError(f"observation space already has a {PRIVILEGED_KEY!r} entry")
    entry = (config or PrivilegedStateConfig()).space()
    return spaces.Dict({**space.spaces, PRIVILEGED_KEY: entry})


def without_privileged_space(space: spaces.Space) -> spaces.Space:
    """The observation space the actor sees: ``space`` without the privileged entry."""
    if isinstance(space, spaces.Dict) and PRIVILEGED_KEY in space.spaces:
        return spaces.Dict({k: v for k, v in space.spaces.items() if k != PRIVILEGED_KEY})
    return space


class PrivilegedStateWrapper(gym.Wrapper):
    """Adds the privileged vector (module docstring) to a single ``BranchScan`` env's Dict
    observation at every reset and step.

    Args:
        env: A single (possibly wrapped) ``BranchScan`` env with Dict observations.
        config: The vector's size and scales.

    Raises:
        ValueError: a flat (Box) observation, or an env without a scan session.
    """

    def __init__(self, env: gym.Env, config: PrivilegedStateConfig | None = None) -> None:
        super().__init__(env)
        self.config = config or PrivilegedStateConfig()
        if getattr(env.unwrapped, "session", None) is None:
            raise ValueError(f"PrivilegedStateWrapper needs a BranchScan env, got {env!r}")
        self.observation_space = with_privileged_space(env.observation_space, self.config)

    def reset(self, **kwargs: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return self._add(obs, info), info

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._add(obs, info), reward, terminated, truncated, info

    def _add(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> dict[str, np.ndarray]:
        state = privileged_state(self.env.unwrapped.session, matched_branches(info), self.config)
        return {**obs, PRIVILEGED_KEY: state}
