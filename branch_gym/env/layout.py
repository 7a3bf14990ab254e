"""The action and observation layout of :class:`branch_gym.env.BranchScanEnv`, as named constants.

Policies read observation fields by name (``obs["vector"][..., VectorField.TRAVEL_FOV]``), never by
magic index. This module is pure numpy: agents import it without pulling in the simulator.

Flattened observations (``flatten=True``, ``BranchScanFlat-v0``) put the vector first, then the
image scaled to [0, 1] in channel-first order, so the vector fields keep the same indices in both
layouts (:func:`vector_part` reads either).
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

# Largest rotation of the paper's experiments (Table I: 22.5 and 45 deg): the continuous action
# [-1, 1] spans [-THETA_MAX_DEG, THETA_MAX_DEG].
THETA_MAX_DEG = 45.0
# The discrete action picks one of these target angles (deg): the paper's +-22.5, +-45 and 0.
DISCRETE_ANGLES_DEG = (-45.0, -22.5, 0.0, 22.5, 45.0)
# The trigger action holds the angle (0) or advances the paper's rotation cycle (+theta, 0,
# -theta, 0; section V) by one move with one of these theta (deg): the paper's two angles.
TRIGGER_ANGLES_DEG = (22.5, 45.0)
# The action types (``EnvConfig.action_type``), each with its space and meaning: the one list
# (``branch_gym.env.actions`` decodes them, ``branch_gym.env.versions`` gives one to every id).
ACTION_DESCRIPTIONS = {
    "continuous": "`Box(-1, 1, (1,))`: target angle / 45 deg",
    "discrete": "`Discrete(5)`: -45, -22.5, 0, 22.5, 45 deg",
    "discrete_hold": "`Discrete(6)`: hold, or -45, -22.5, 0, 22.5, 45 deg",
    "trigger": "`Discrete(3)`: 0 holds the angle, 1 / 2 advance the paper's cycle "
    "(+θ, 0, -θ, 0) with θ = 22.5 / 45 deg",
}
ACTION_TYPES = tuple(ACTION_DESCRIPTIONS)


class VectorField(IntEnum):
    """Index of each entry of the observation vector (float32, all normalised)."""

    ANGLE = 0  # current rotation about the branch / theta_max, in [-1, 1]
    TRAVEL_FOV = 1  # vertical travel since the last rotation, in vertical FoVs at z_target
    PROGRESS = 2  # fraction of the scan height range covered, in [0, 1]
    OUTCOME_CONSISTENT = 3  # one-hot outcome of the latest modeling iteration
    OUTCOME_INCONSISTENT = 4
    OUTCOME_RESTART = 5
    MODEL_SECONDARIES = 6  # secondary branches in the 3D model / count_scale
    MODEL_SECONDARIES_IN_VIEW = 7  # ... of which project into the current image / count_scale
    CANDIDATES_2D = 8  # 2D side-branch candidates in the latest mask / count_scale
    UNCONFIRMED_CANDIDATES = 9  # ... not explained by a projected 3D secondary / count_scale
    PREVIOUS_ACTION = 10  # previous target angle / theta_max, in [-1, 1] (0 after reset)
    SCAN_TIME = 11  # scan time so far / the scan-time limit, in [0, 1]


VECTOR_SIZE = len(VectorField)
OUTCOME_FIELDS = (
    VectorField.OUTCOME_CONSISTENT,
    VectorField.OUTCOME_INCONSISTENT,
    VectorField.OUTCOME_RESTART,
)
COUNT_FIELDS = (
    VectorField.MODEL_SECONDARIES,
    VectorField.MODEL_SECONDARIES_IN_VIEW,
    VectorField.CANDIDATES_2D,
    VectorField.UNCONFIRMED_CANDIDATES,
)


class ImageChannel(IntEnum):
    """Channels of the (3, H, W) uint8 observation image (255 = fully covered pixel)."""

    MASK = 0  # the latest segmentation mask (cleaned, as the 2D stage used it)
    MODEL = 1  # the 3D model projected into the current view, lines as wide as the branches
    UNCONFIRMED = 2  # 2D side-branch candidates that no projected 3D secondary explains


N_CHANNELS = len(ImageChannel)
IMAGE_KEY = "image"
VECTOR_KEY = "vector"
# v1 observations add the view-coverage memory (branch_gym/env/coverage.py) and the price of scan
# time (the seconds a found branch is worth, normalised); flattened after the image, in this order.
COVERAGE_KEY = "coverage"
PRICE_KEY = "price"
EXTRA_KEYS = (COVERAGE_KEY, PRICE_KEY)
PIXEL_FULL = 255.0  # the flat observation holds the image / 255


def price_feature(branch_value_s: float, bounds_s: tuple[float, float]) -> float:
    """The observation's ``price`` of a branch value: 0 at the low bound, 1 at the high, log-scaled.

    >>> price_feature(100.0, (25.0, 400.0))
    0.5
    """
    low, high = bounds_s
    span = np.log(high / low)
    return float(np.clip(np.log(branch_value_s / low) / span, 0.0, 1.0)) if span > 0 else 0.0


def branch_value_s(price: np.ndarray, bounds_s: tuple[float, float]) -> np.ndarray:
    """The branch values (s) of observed prices, the inverse of :func:`price_feature`.

    >>> branch_value_s(np.array([0.0, 0.5]), (25.0, 400.0)).tolist()
    [25.0, 100.0]
    """
    low, high = bounds_s
    return low * (high / low) ** np.asarray(price, float)


def vector_bounds(travel_clip_fov: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) float32 bounds of the observation vector.

    Args:
        travel_clip_fov: Upper bound of :attr:`VectorField.TRAVEL_FOV` (vertical FoVs).
    """
    low = np.zeros(VECTOR_SIZE, dtype=np.float32)
    high = np.ones(VECTOR_SIZE, dtype=np.float32)
    low[VectorField.ANGLE] = low[VectorField.PREVIOUS_ACTION] = -1.0
    high[VectorField.TRAVEL_FOV] = travel_clip_fov
    return low, high


def vector_part(obs: dict | np.ndarray) -> np.ndarray:
    """The observation vector(s) from a Dict or a flattened observation, single or batched.

    Args:
        obs: ``{"image": ..., "vector": (..., VECTOR_SIZE)}`` or a flat (..., D) array whose first
            ``VECTOR_SIZE`` entries are the vector.

    Returns:
        (VECTOR_SIZE,) or (N, VECTOR_SIZE) float array (a view where possible).

    Raises:
        ValueError: the observation holds no vector of the expected size.
    """
    vector = obs[VECTOR_KEY] if isinstance(obs, dict) else obs
    vector = np.asarray(vector)
    if vector.ndim not in (1, 2) or vector.shape[-1] < VECTOR_SIZE:
        raise ValueError(
            f"observation vector must have shape (D,) or (N, D) with D >= {VECTOR_SIZE}, "
            f"got {vector.shape}"
        )
    if isinstance(obs, dict) and vector.shape[-1] != VECTOR_SIZE:
        raise ValueError(
            f"obs[{VECTOR_KEY!r}] must have {VECTOR_SIZE} entries, got {vector.shape[-1]}"
        )
    return vector[..., :VECTOR_SIZE]


def flatten_observation(observation: dict) -> np.ndarray:
    """A Dict observation (single or batched) as the flat env gives it.

    Order: the vector, the image / 255 (channel-first), then the v1 extras (``EXTRA_KEYS``) that
    the observation holds, each flattened. The vector fields keep their indices.
    """
    vector = np.asarray(observation[VECTOR_KEY], np.float32)
    batch = vector.shape[:-1]
    image = np.asarray(observation[IMAGE_KEY]).reshape(*batch, -1).astype(np.float32) / PIXEL_FULL
    parts = [vector, image]
    parts += [
        np.asarray(observation[key], np.float32).reshape(*batch, -1)
        for key in EXTRA_KEYS
        if key in observation
    ]
    return np.concatenate(parts, axis=-1)
