"""The pipeline's output: a tree model of 3D centerlines with radii."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class BranchModel:
    """One branch as an ordered 3D centerline with a radius per point.

    Attributes:
        points: (N, 3) centerline points in metres, world frame, ordered base to tip
            (for the primary: bottom to top).
        radii: (N,) radius in metres at each point.
        branch_id: Stable identifier within its tree model.
        trust: Evidence count (+1 when its projection lands on the mask, -1 when not).
    """

    points: np.ndarray
    radii: np.ndarray
    branch_id: int = 0
    trust: int = 0

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 3)
        self.radii = np.asarray(self.radii, dtype=float).reshape(-1)
        if len(self.points) != len(self.radii):
            raise ValueError(
                f"points ({len(self.points)}) and radii ({len(self.radii)}) lengths differ"
            )
        if not (np.all(np.isfinite(self.points)) and np.all(np.isfinite(self.radii))):
            raise ValueError("branch model points and radii must be finite")

    @property
    def length_m(self) -> float:
        """Polyline length in metres."""
        if len(self.points) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())

    def to_dict(self) -> dict:
        return {
            "points": self.points.tolist(),
            "radii": self.radii.tolist(),
            "branch_id": self.branch_id,
            "trust": self.trust,
        }

    @classmethod
    def from_dict(cls, data: dict) -> BranchModel:
        return cls(
            np.asarray(data["points"], float),
            np.asarray(data["radii"], float),
            int(data.get("branch_id", 0)),
            int(data.get("trust", 0)),
        )


@dataclass
class TreeModel:
    """A reconstructed (or ground-truth) tree: one primary branch and its secondary branches."""

    primary: BranchModel | None = None
    secondaries: list[BranchModel] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "primary": None if self.primary is None else self.primary.to_dict(),
            "secondaries": [b.to_dict() for b in self.secondaries],
        }

    @classmethod
    def from_dict(cls, data: dict) -> TreeModel:
        primary = data.get("primary")
        return cls(
            None if primary is None else BranchModel.from_dict(primary),
            [BranchModel.from_dict(b) for b in data.get("secondaries", [])],
        )
