"""The bag's transforms: TF frames chained and interpolated to an image's time.

:class:`TransformSeries` holds the samples of one transform parent -> child and interpolates
them (linear translation, slerp rotation); :class:`TransformTree` chains the static and dynamic
transforms of ``/tf`` and ``/tf_static`` between any two connected frames.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from recon.camera import invert_pose
from recon.io.folder import ScanFormatError

logger = logging.getLogger(__name__)


def quaternion_slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (x, y, z, w) at fraction ``a``."""
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    d = float(q0 @ q1)
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
    else:
        theta = math.acos(d)
        q = (math.sin((1 - a) * theta) * q0 + math.sin(a * theta) * q1) / math.sin(theta)
    return q / np.linalg.norm(q)


def pose_matrix(translation: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a (3,) translation and a (4,) quaternion (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(quaternion_xyzw, float)).as_matrix()
    T[:3, 3] = translation
    return T


@dataclass
class TransformSeries:
    """Time samples of one transform parent -> child (the child's pose in the parent).

    Attributes:
        parent: Parent frame id.
        child: Child frame id.
        times_ns: (N,) sample times, ns, increasing.
        translations: (N, 3) metres.
        quaternions: (N, 4) unit quaternions (x, y, z, w).
    """

    parent: str
    child: str
    times_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    translations: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    quaternions: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))

    @classmethod
    def from_samples(cls, parent: str, child: str, samples: list) -> TransformSeries:
        """From (t_ns, (3,), (4,)) samples in any order; a repeated time keeps the last one."""
        by_time = {int(t): (tr, q) for t, tr, q in samples}
        times = np.array(sorted(by_time), dtype=np.int64)
        return cls(
            parent,
            child,
            times,
            np.array([by_time[t][0] for t in times], float).reshape(-1, 3),
            np.array([by_time[t][1] for t in times], float).reshape(-1, 4),
        )

    def at(
        self, t_ns: int, tolerance_ns: int, max_gap_ns: int
    ) -> tuple[np.ndarray | None, str | None]:
        """The (4, 4) transform at ``t_ns``, interpolated; or (None, reason)."""
        times = self.times_ns
        if len(times) == 0:
            return None, f"no samples of {self.parent} -> {self.child}"
        i = int(np.searchsorted(times, t_ns))
        if i < len(times) and times[i] == t_ns:
            return pose_matrix(self.translations[i], self.quaternions[i]), None
        if i == 0 or i == len(times):
            j = 0 if i == 0 else len(times) - 1
            off = abs(int(times[j]) - t_ns)
            if off <= tolerance_ns:
                return pose_matrix(self.translations[j], self.quaternions[j]), None
            return None, (
                f"no transform {self.parent} -> {self.child} within {tolerance_ns / 1e9:g} s "
                f"(nearest sample {off / 1e9:.3f} s away)"
            )
        t0, t1 = int(times[i - 1]), int(times[i])
        if t1 - t0 > max_gap_ns:
            return None, (
                f"transform {self.parent} -> {self.child} has a {(t1 - t0) / 1e9:.3f} s gap "
                f"around the image time (max {max_gap_ns / 1e9:g} s)"
            )
        a = (t_ns - t0) / (t1 - t0)
        translation = (1 - a) * self.translations[i - 1] + a * self.translations[i]
        q = quaternion_slerp(self.quaternions[i - 1], self.quaternions[i], a)
        return pose_matrix(translation, q), None


class TransformTree:
    """TF frames: static and dynamic transforms, chained between any two connected frames."""

    def __init__(self) -> None:
        self._samples: dict[tuple[str, str], list] = {}
        self._static: dict[tuple[str, str], np.ndarray] = {}
        self.dynamic: dict[str, TransformSeries] = {}
        self.parents: dict[str, str] = {}

    def add(self, parent: str, child: str, t_ns: int, translation, quaternion, static: bool):
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if static:
            self._static[(parent, child)] = pose_matrix(translation, quaternion)
        else:
            self._samples.setdefault((parent, child), []).append((t_ns, translation, quaternion))

    def finalize(self) -> None:
        """Index the transforms by child frame (call after the last :meth:`add`)."""
        self.dynamic = {
            child: TransformSeries.from_samples(parent, child, samples)
            for (parent, child), samples in self._samples.items()
        }
        self.parents = {child: parent for parent, child in self._static}
        for (parent, child), _ in self._samples.items():
            if child in self.parents and self.parents[child] != parent:
                logger.warning("frame %s has two parents (%s, %s)", child, parent, child)
            self.parents[child] = parent

    @property
    def frames(self) -> set[str]:
        return set(self.parents) | set(self.parents.values())

    def _ancestors(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self.parents and len(chain) <= len(self.parents) + 1:
            chain.append(self.parents[chain[-1]])
        return chain

    def check_chain(self, world: str, camera: str, topics: str) -> None:
        """Raise :class:`ScanFormatError` unless ``world`` and ``camera`` are connected."""
        for frame in (world, camera):
            if frame not in self.frames:
                raise ScanFormatError(
                    f"frame {frame!r} appears in no transform of {topics} "
                    f"(frames there: {sorted(self.frames) or 'none'})"
                )
        if not set(self._ancestors(world)) & set(self._ancestors(camera)):
            raise ScanFormatError(
                f"no transform chain between {world!r} and {camera!r} in {topics}: "
                f"{' -> '.join(self._ancestors(camera))} and {' -> '.join(self._ancestors(world))}"
            )

    def _root_to(self, frame: str, root: str, t_ns: int, tol: int, gap: int):
        """T_root_frame at t (product down the chain), or (None, reason)."""
        T = np.eye(4)
        f = frame
        while f != root:
            parent = self.parents[f]
            if f in self.dynamic and self.dynamic[f].parent == parent:
                edge, reason = self.dynamic[f].at(t_ns, tol, gap)
                if edge is None:
                    return None, reason
            else:
                edge = self._static[(parent, f)]
            T = edge @ T
            f = parent
        return T, None

    def lookup(
        self, world: str, camera: str, t_ns: int, tolerance_ns: int, max_gap_ns: int
    ) -> tuple[np.ndarray | None, str | None]:
        """T_world_camera at ``t_ns`` (see :meth:`check_chain`), or (None, reason)."""
        up_world = self._ancestors(world)
        common = next(f for f in self._ancestors(camera) if f in set(up_world))
        T_root_camera, reason = self._root_to(camera, common, t_ns, tolerance_ns, max_gap_ns)
        if T_root_camera is None:
            return None, reason
        T_root_world, reason = self._root_to(world, common, t_ns, tolerance_ns, max_gap_ns)
        if T_root_world is None:
            return None, reason
        return invert_pose(T_root_world) @ T_root_camera, None
