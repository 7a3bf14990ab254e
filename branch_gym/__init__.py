"""branch_gym: simulator and learning testbed for active branch scanning in orchard robotics.

Importing it pins the BLAS / OpenMP threads of this process (and of the worker processes it
starts, which inherit the variable) to :data:`BLAS_THREADS`, unless ``OMP_NUM_THREADS`` is set
already, and registers the environment ids of :mod:`branch_gym.env.versions`.
"""

from __future__ import annotations

import os

# The one place the threads are pinned: before numpy / torch load below (our choice: the scans
# are small and the workers run side by side on 2 cores; more threads only add overhead).
BLAS_THREADS = 1
os.environ.setdefault("OMP_NUM_THREADS", str(BLAS_THREADS))

# The table is pure (gymnasium and numpy): `import branch_gym` stays light.
from branch_gym.env.versions import (  # noqa: E402
    ENV_IDS,
    MAX_EPISODE_STEPS,
    V1_BRANCH_VALUE_S,
    current_env_id,
    register_envs,
)

# The current ids (the newest version of each name; docs/env.md lists them all).
ENV_ID = current_env_id("BranchScan")  # continuous target angle, Dict observation
DISCRETE_ENV_ID = current_env_id("BranchScanDiscrete")  # hold, or one of a few fixed angles
# Flat and Trigger have one version, v0: the v0 observation (no coverage memory, price of scan
# time or IN_FRONT channel, which came with BranchScan-v1 and -v2).
FLAT_ENV_ID = "BranchScanFlat-v0"  # continuous target angle, flat float32 observation
TRIGGER_ENV_ID = "BranchScanTrigger-v0"  # hold, or advance the paper's rotation cycle
ENV_ID_V0 = "BranchScan-v0"  # the first observation: the latest mask and the vector
DISCRETE_ENV_ID_V0 = "BranchScanDiscrete-v0"  # one of a few fixed angles (no hold action)
ENV_ID_V1 = "BranchScan-v1"  # + the coverage memory and the price of scan time
DISCRETE_ENV_ID_V1 = "BranchScanDiscrete-v1"
ENV_ID_V2 = "BranchScan-v2"  # + the coverage memory's IN_FRONT channel
DISCRETE_ENV_ID_V2 = "BranchScanDiscrete-v2"

__all__ = [
    "BLAS_THREADS",
    "DISCRETE_ENV_ID",
    "DISCRETE_ENV_ID_V0",
    "DISCRETE_ENV_ID_V1",
    "DISCRETE_ENV_ID_V2",
    "ENV_ID",
    "ENV_IDS",
    "ENV_ID_V0",
    "ENV_ID_V1",
    "ENV_ID_V2",
    "FLAT_ENV_ID",
    "MAX_EPISODE_STEPS",
    "TRIGGER_ENV_ID",
    "V1_BRANCH_VALUE_S",
]

register_envs()
