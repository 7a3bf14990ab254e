"""The Gymnasium environment for active branch scanning (ids registered on ``import branch_gym``).

====================  ==================================================================
``versions.py``       the registered ids as data: action type and observation of each
``layout.py``         action and observation layout as named constants (pure numpy)
``config.py``         ``EnvConfig``, ``ObservationConfig``, the keyword parser
``actions.py``        action spaces; action -> target rotation angle
``observation.py``    pipeline state -> image channels + vector (drawn by ``recon.overlay``)
``coverage.py``       the view-coverage memory of the v1 and v2 observations
``reward.py``         ``RewardConfig`` and the ground-truth reward
``info.py``           the flat ``info`` dicts
``rendering.py``      ``render()``: overlaid camera frames, the pybullet GUI
``scan_env.py``       ``BranchScanEnv``: wires the above around ``branch_gym.scan.ScanSession``
====================  ==================================================================

Importing this package stays light (the layout constants only); ``BranchScanEnv`` and the configs
load the simulator on first access.
"""

from __future__ import annotations

from typing import Any

from branch_gym.env.layout import (
    DISCRETE_ANGLES_DEG,
    THETA_MAX_DEG,
    VECTOR_SIZE,
    ImageChannel,
    VectorField,
    vector_part,
)

_LAZY = {
    "BranchScanEnv": "branch_gym.env.scan_env",
    "EnvConfig": "branch_gym.env.config",
    "ObservationConfig": "branch_gym.env.config",
    "RewardConfig": "branch_gym.env.reward",
}

__all__ = [
    "DISCRETE_ANGLES_DEG",
    "THETA_MAX_DEG",
    "VECTOR_SIZE",
    "BranchScanEnv",
    "EnvConfig",
    "ImageChannel",
    "ObservationConfig",
    "RewardConfig",
    "VectorField",
    "vector_part",
]


def __getattr__(name: str) -> Any:
    """Load the simulator-backed names on first access."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
