"""The registered environment ids as data: one row per id, from which everything else reads.

Registration (``import branch_gym``), the id table of ``docs/env.md``, the trainers' checks and
the agents (a saved model records its env id; :func:`agents.factory.spec_env_kwargs` builds the
env of that row) all read :data:`ENV_VERSIONS`. A row names the id's action type
(:data:`branch_gym.env.layout.ACTION_TYPES`) and the features of its observation
(:data:`OBSERVATION_FEATURES`); :meth:`EnvVersion.env_kwargs` turns them into the
:class:`branch_gym.env.BranchScanEnv` keywords the id is registered with.

Following Gymnasium's rule, a change to what an id observes or how it acts gets a new version and
the old id stays registered (``make`` warns that a newer version exists); every row says what its
version changed (:func:`version_history`).

>>> env_version("BranchScanDiscrete-v2").action_type
'discrete_hold'
>>> env_version("BranchScanDiscrete-v2").features
('image', 'vector', 'coverage', 'price', 'in_front')
>>> env_version("BranchScan-v2").retired, env_version("BranchScan-v3").retired
(True, False)
>>> sorted(env_version("BranchScan-v1").env_kwargs())
['action_type', 'branch_value_s', 'coverage', 'paper_scoring']

``tests/test_env_versions.py`` checks that ``docs/env.md`` shows :func:`markdown_table` and
:func:`version_history` as they are.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from gymnasium.envs.registration import register, registry

from branch_gym.env.coverage import CoverageConfig
from branch_gym.env.layout import ACTION_DESCRIPTIONS, ACTION_TYPES

# Seconds of scan time a found branch is worth, drawn log-uniformly per v1/v2 episode (our choice:
# around v0's implicit 100 s, from rotating almost never to rotating at every chance).
V1_BRANCH_VALUE_S = (25.0, 400.0)
# Step limit of the registered ids (gymnasium's TimeLimit; our choice: generous, a full scan at
# the paper's settings takes ~48 steps, ~100 with frequent rotations).
MAX_EPISODE_STEPS = 200
ENTRY_POINT = "branch_gym.env.scan_env:BranchScanEnv"  # a string: importing stays light

# What an observation can hold, in the order of the Dict (and of the flat vector): key ->
# (short label for the id table, meaning).
OBSERVATION_FEATURES = {
    "image": (
        "image",
        "`(3, 60, 80) uint8`: the latest mask, the model projected into the current view, the "
        "2D side-branch candidates the model does not explain",
    ),
    "vector": ("vector", "`(12,) float32`: the scan state (`branch_gym.env.layout.VectorField`)"),
    "coverage": (
        "coverage",
        "`(128,) float32`: the view-coverage memory, 16 height bins x 8 channels (seen from each "
        "rotation sector, unconfirmed candidates, model secondaries, disagreements)",
    ),
    "price": (
        "price",
        "`(1,) float32`: the episode's value of a found branch, 25-400 s (drawn per episode, or "
        '`reset(options={"branch_value_s": v})` within that range)',
    ),
    "in_front": (
        "IN_FRONT",
        "a ninth coverage channel (`coverage` is `(144,)`): the tracked primary points that "
        "triangulated in front of the model",
    ),
    "flat": ("flat", "one float32 vector: the 12 vector fields, then the image / 255"),
}
_V0 = ("image", "vector")
_V1 = (*_V0, "coverage", "price")
_V2 = (*_V1, "in_front")
# The Flat and Trigger ids have one version: what they lack of the newest BranchScan ids.
_AT_V0 = (
    "at v0: the v0 observation (no coverage memory, price or IN_FRONT channel) and the paper's "
    "reward scoring"
)
_ID = re.compile(r"^(?P<name>[A-Za-z]+)-v(?P<version>\d+)$")


@dataclass(frozen=True)
class EnvVersion:
    """One registered id.

    Attributes:
        env_id: The Gymnasium id, ``Name-vN``.
        action_type: One of :data:`branch_gym.env.layout.ACTION_TYPES`.
        features: The observation's parts (keys of :data:`OBSERVATION_FEATURES`).
        change: What this version changed against the previous one of its name (the Version
            History line).
        paper_scoring: The reward scores as the paper (``EnvConfig.paper_scoring``: any
            reconstruction matching no side branch is spurious, spurs and neighbours included;
            branches in scope up to the height reached); False from v3 on.
        note: Said after "current" in the table: what a current id lacks of the newest
            features (the Flat and Trigger ids stayed at v0).
    """

    env_id: str
    action_type: str
    features: tuple[str, ...]
    change: str
    paper_scoring: bool = True
    note: str = ""

    def __post_init__(self) -> None:
        if _ID.match(self.env_id) is None:
            raise ValueError(f"EnvVersion.env_id must look like Name-vN, got {self.env_id!r}")
        if self.action_type not in ACTION_TYPES:
            raise ValueError(f"EnvVersion.action_type must be one of {ACTION_TYPES}")
        unknown = sorted(set(self.features) - set(OBSERVATION_FEATURES))
        if unknown:
            raise ValueError(f"EnvVersion.features: unknown {unknown}")

    @property
    def name(self) -> str:
        """The id without its version (``BranchScanDiscrete``)."""
        return _ID.match(self.env_id)["name"]

    @property
    def version(self) -> int:
        """The version number N of ``Name-vN``."""
        return int(_ID.match(self.env_id)["version"])

    @property
    def retired(self) -> bool:
        """A newer version of the same name exists (the id stays registered)."""
        return any(v.name == self.name and v.version > self.version for v in ENV_VERSIONS)

    def env_kwargs(self) -> dict[str, Any]:
        """The :class:`branch_gym.env.BranchScanEnv` keywords this id is registered with."""
        kwargs: dict[str, Any] = {"action_type": self.action_type}
        if self.paper_scoring:
            kwargs["paper_scoring"] = True
        if "flat" in self.features:
            kwargs["flatten"] = True
        if "coverage" in self.features:
            kwargs["coverage"] = CoverageConfig(in_front_channel="in_front" in self.features)
        if "price" in self.features:
            kwargs["branch_value_s"] = V1_BRANCH_VALUE_S
        return kwargs


ENV_VERSIONS: tuple[EnvVersion, ...] = (
    EnvVersion("BranchScan-v0", "continuous", _V0, "initial: the pipeline's state"),
    EnvVersion("BranchScanDiscrete-v0", "discrete", _V0, "initial"),
    EnvVersion(
        "BranchScanFlat-v0",
        "continuous",
        ("flat",),
        "initial (MLP-only libraries)",
        note=_AT_V0,
    ),
    EnvVersion("BranchScanTrigger-v0", "trigger", _V0, "initial", note=_AT_V0),
    EnvVersion(
        "BranchScan-v1",
        "continuous",
        _V1,
        "the coverage memory and the price of scan time, drawn per episode",
    ),
    EnvVersion(
        "BranchScanDiscrete-v1",
        "discrete_hold",
        _V1,
        "as BranchScan-v1; the action holds or picks an angle",
    ),
    EnvVersion(
        "BranchScan-v2",
        "continuous",
        _V2,
        "the coverage memory's IN_FRONT channel (a branch pointing at the lens)",
    ),
    EnvVersion("BranchScanDiscrete-v2", "discrete_hold", _V2, "as BranchScan-v2"),
    EnvVersion(
        "BranchScan-v3",
        "continuous",
        _V2,
        "the reward's spurious branch is one with nothing there (a reconstructed spur, stub, "
        "neighbour's branch or wire is classed as such and not charged); every branch up to the "
        "planned end height is in scope (recon.metrics)",
        paper_scoring=False,
    ),
    EnvVersion(
        "BranchScanDiscrete-v3", "discrete_hold", _V2, "as BranchScan-v3", paper_scoring=False
    ),
)
ENV_IDS = tuple(v.env_id for v in ENV_VERSIONS)


def same_spaces(env_id: str, other_id: str) -> bool:
    """Whether two ids observe and act alike (they may differ in the reward): a policy of one
    plays the other, and a run on one may start from a model of the other."""
    a, b = env_version(env_id), env_version(other_id)
    return (a.action_type, a.features) == (b.action_type, b.features)


def env_version(env_id: str) -> EnvVersion:
    """The row of a registered id.

    Raises:
        ValueError: not one of :data:`ENV_IDS` (named, with the ids).
    """
    for version in ENV_VERSIONS:
        if version.env_id == env_id:
            return version
    raise ValueError(f"unknown env id {env_id!r}: expected one of {ENV_IDS}")


def current_env_id(name: str) -> str:
    """The current (newest) id of a name: ``current_env_id("BranchScan")`` -> ``BranchScan-vN``.

    Raises:
        ValueError: no registered id has this name (named, with the ids).
    """
    versions = [v for v in ENV_VERSIONS if v.name == name]
    if not versions:
        raise ValueError(f"no env id is named {name!r}: expected one of {ENV_IDS}")
    return max(versions, key=lambda v: v.version).env_id


def register_envs() -> None:
    """Register every id with Gymnasium (idempotent: re-imports and reloads are fine)."""
    for version in ENV_VERSIONS:
        if version.env_id not in registry:
            register(
                id=version.env_id,
                entry_point=ENTRY_POINT,
                max_episode_steps=MAX_EPISODE_STEPS,
                kwargs=version.env_kwargs(),
            )


def markdown_table() -> str:
    """The id table of ``docs/env.md``: action and observation of every id, then the features."""
    rows = ["| id | action | observation | status |", "|---|---|---|---|"]
    for version in ENV_VERSIONS:
        observation = " + ".join(OBSERVATION_FEATURES[f][0] for f in version.features)
        status = "retired (kept registered)" if version.retired else "current"
        if version.note and not version.retired:
            status += f", {version.note}"
        rows.append(
            f"| `{version.env_id}` | {ACTION_DESCRIPTIONS[version.action_type]} | "
            f"{observation} | {status} |"
        )
    rows.append("")
    rows += [f"- **{label}**: {meaning}" for label, meaning in OBSERVATION_FEATURES.values()]
    return "\n".join(rows)


def version_history() -> str:
    """Gymnasium's "Version History" list: each version and what it changed, newest first."""
    lines = []
    for version in sorted(ENV_VERSIONS, key=lambda v: (-v.version, v.env_id)):
        lines.append(f"* `{version.env_id}`: {version.change}")
    return "\n".join(lines)
