"""Ground truth of a generated tree: dense branch centerlines with radii, and JSON round trips.

:class:`BranchGT` is one branch (points base -> tip, radius per point); :class:`TreeGT` is the
scanned primary, its secondaries, the background clutter (``sim/tree/generator.py`` makes them)
and the scanned tree's unscored details (``sim/tree/details.py`` grows them).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(eq=False)
class BranchGT:
    """Ground truth of one branch: a dense centerline with a radius per point.

    Attributes:
        points: (N, 3) dense centerline in metres, world frame, ordered base -> tip
            (primary: bottom -> top), N >= 2.
        radii: (N,) radius in metres at each point, all positive.
    """

    points: np.ndarray
    radii: np.ndarray

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=float)
        self.radii = np.asarray(self.radii, dtype=float)
        if self.points.ndim != 2 or self.points.shape[1] != 3 or len(self.points) < 2:
            raise ValueError(f"points must have shape (N >= 2, 3), got {self.points.shape}")
        if self.radii.shape != (len(self.points),):
            raise ValueError(f"radii must have shape ({len(self.points)},), got {self.radii.shape}")
        if not (np.all(np.isfinite(self.points)) and np.all(np.isfinite(self.radii))):
            raise ValueError("points and radii must be finite")
        if np.any(self.radii <= 0):
            raise ValueError("radii must be positive")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BranchGT):
            return NotImplemented
        return np.array_equal(self.points, other.points) and np.array_equal(self.radii, other.radii)

    __hash__ = None  # type: ignore[assignment]  # mutable arrays: not hashable

    @property
    def length_m(self) -> float:
        """Polyline length in metres."""
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def to_dict(self) -> dict:
        return {"points": self.points.tolist(), "radii": self.radii.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> BranchGT:
        return cls(np.asarray(data["points"], dtype=float), np.asarray(data["radii"], dtype=float))


@dataclass
class TreeGT:
    """Ground truth of one generated tree.

    Attributes:
        primary: The scanned primary branch (bottom -> top).
        secondaries: Side branches, each starting on the primary centerline at its base.
        clutter: Background trees and trellis wires: rendered, not part of the scanned tree.
        seed: The seed the tree was generated from, when known.
        details: The scanned tree's small parts (fruiting spurs, pruning stubs, buds), each a
            short branch starting on the primary's or a secondary's centerline: rendered as
            part of the scanned tree, never scored as side branches. ``generate_tree`` leaves
            it empty; ``details.grow_details`` fills it from the world's own random stream.
    """

    primary: BranchGT
    secondaries: list[BranchGT] = field(default_factory=list)
    clutter: list[BranchGT] = field(default_factory=list)
    seed: int | None = None
    details: list[BranchGT] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Plain JSON-able values; ``details`` only when there are some (older files match)."""
        data = {
            "seed": self.seed,
            "primary": self.primary.to_dict(),
            "secondaries": [b.to_dict() for b in self.secondaries],
            "clutter": [b.to_dict() for b in self.clutter],
        }
        if self.details:
            data["details"] = [b.to_dict() for b in self.details]
        return data

    @classmethod
    def from_dict(cls, data: dict) -> TreeGT:
        """Inverse of :meth:`to_dict`; a missing ``details`` key (older files) means none."""
        seed = data.get("seed")
        return cls(
            primary=BranchGT.from_dict(data["primary"]),
            secondaries=[BranchGT.from_dict(b) for b in data.get("secondaries", [])],
            clutter=[BranchGT.from_dict(b) for b in data.get("clutter", [])],
            seed=None if seed is None else int(seed),
            details=[BranchGT.from_dict(b) for b in data.get("details", [])],
        )

    def save_json(self, path: str | Path) -> None:
        """Write the tree as JSON; floats are written with round-trip exact precision."""
        Path(path).write_text(json.dumps(self.to_dict()))

    @classmethod
    def load_json(cls, path: str | Path) -> TreeGT:
        return cls.from_dict(json.loads(Path(path).read_text()))
