"""branch_gym: simulator and learning testbed for active branch scanning in orchard robotics."""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from branch_gym.env.coverage import CoverageConfig  # pure numpy: `import branch_gym` stays light

ENV_ID = "BranchScan-v0"  # continuous target angle, Dict observation
DISCRETE_ENV_ID = "BranchScanDiscrete-v0"  # one of a few fixed angles, Dict observation
FLAT_ENV_ID = "BranchScanFlat-v0"  # continuous target angle, flat float32 observation
TRIGGER_ENV_ID = "BranchScanTrigger-v0"  # hold, or advance the paper's rotation cycle
# v1: a view-coverage memory and the price of scan time in the observation, the price drawn per
# episode; actions choose the target angle freely (continuous) or hold / pick one (discrete).
ENV_ID_V1 = "BranchScan-v1"
DISCRETE_ENV_ID_V1 = "BranchScanDiscrete-v1"
# v2: v1 plus the coverage memory's IN_FRONT channel (points found in front of the primary).
ENV_ID_V2 = "BranchScan-v2"
DISCRETE_ENV_ID_V2 = "BranchScanDiscrete-v2"
ENV_IDS = (
    ENV_ID, DISCRETE_ENV_ID, FLAT_ENV_ID, TRIGGER_ENV_ID, ENV_ID_V1, DISCRETE_ENV_ID_V1,
    ENV_ID_V2, DISCRETE_ENV_ID_V2,
)  # fmt: skip
# Seconds of scan time a found branch is worth, drawn log-uniformly per v1 episode (our choice:
# around v0's implicit 100 s, from rotating almost never to rotating at every chance).
V1_BRANCH_VALUE_S = (25.0, 400.0)
# Step limit of the registered ids (gymnasium's TimeLimit; our choice: generous, a full scan at
# the paper's settings takes ~48 steps, ~100 with frequent rotations).
MAX_EPISODE_STEPS = 200
_ENTRY_POINT = "branch_gym.env.scan_env:BranchScanEnv"  # a string: importing stays light


def _v1_kwargs() -> dict:
    """The observation and reward settings the v1 ids add to v0."""
    return {"coverage": CoverageConfig(), "branch_value_s": V1_BRANCH_VALUE_S}


def _v2_kwargs() -> dict:
    """The v1 settings with the coverage memory's ``IN_FRONT`` channel."""
    return {**_v1_kwargs(), "coverage": CoverageConfig(in_front_channel=True)}


def _register_envs() -> None:
    """Register the environment ids (idempotent: re-imports and reloads are fine)."""
    kwargs = {
        ENV_ID: {"action_type": "continuous"},
        DISCRETE_ENV_ID: {"action_type": "discrete"},
        FLAT_ENV_ID: {"action_type": "continuous", "flatten": True},
        TRIGGER_ENV_ID: {"action_type": "trigger"},
        ENV_ID_V1: {"action_type": "continuous", **_v1_kwargs()},
        DISCRETE_ENV_ID_V1: {"action_type": "discrete_hold", **_v1_kwargs()},
        ENV_ID_V2: {"action_type": "continuous", **_v2_kwargs()},
        DISCRETE_ENV_ID_V2: {"action_type": "discrete_hold", **_v2_kwargs()},
    }
    for env_id, env_kwargs in kwargs.items():
        if env_id not in registry:
            register(
                id=env_id,
                entry_point=_ENTRY_POINT,
                max_episode_steps=MAX_EPISODE_STEPS,
                kwargs=env_kwargs,
            )


_register_envs()
