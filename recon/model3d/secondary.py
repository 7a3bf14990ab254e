"""Secondary branches: connection test, association of re-detections, trust and pruning.

Each model secondary keeps the raw lifted points of every detection associated with it and is
refitted from all of them, so that re-detections of one branch strengthen it instead of creating
duplicates (a weakness of the paper's system, reference.md). A trust score (+1 when its projection
lands on the mask, -1 when not; from the authors' code) deletes branches the masks stop supporting.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from recon.camera import project_points
from recon.config import ModelerConfig
from recon.frame import Frame
from recon.geometry.bezier import CubicBezier
from recon.geometry.bezier_fit import fit_bezier, ransac_fit_bezier
from recon.model import BranchModel
from recon.model3d.primary import robust_radius_profile

# Relative slack of the box test of :func:`_boxes_apart` (ours: far above rounding, ~1e-16).
_BOX_MARGIN = 1e-6
# A frame changes a secondary's trust when it shows at least this many of its observed points
# (the paper's "visible branch"; the authors' code).
_VISIBLE_POINTS = 2


@dataclass
class SecondaryDetection:
    """One frame's lifted secondary branch.

    Attributes:
        points: (K, 3) centre points in metres, world frame, ordered from the junction outward.
        radii: (K,) radii in metres.
        junction_px: (2,) pixel (u, v) where its 2D candidate leaves the primary's path in the
            frame it was lifted from, or None (then only the 3D connection test applies).
    """

    points: np.ndarray
    radii: np.ndarray
    junction_px: np.ndarray | None = None


@dataclass
class _Secondary:
    branch_id: int
    observations: np.ndarray  # (K, 3) raw lifted centre points
    radii: np.ndarray  # (K,)
    base_hint: np.ndarray  # (3,) point of the junction side, for ordering
    detections: int = 1
    trust: int = 0
    model: BranchModel | None = None
    junction: np.ndarray | None = None  # (3,) primary point its ray back met (connection test)
    n_extension: int = 0  # leading model points that bridge the junction, not observed


class SecondaryBranches:
    """The set of model secondaries, updated once per Consistent iteration."""

    def __init__(self, config: ModelerConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self._branches: list[_Secondary] = []
        self._next_id = 1
        self._primary_axis: np.ndarray | None = None  # (3,) unit base-to-top of the primary

    def reset(self) -> None:
        self._branches.clear()
        self._next_id = 1
        self._primary_axis = None

    def models(self) -> list[BranchModel]:
        """Reported secondaries: confirmed often enough, still trusted, and reaching
        ``secondary_min_reach_m`` out from the primary."""
        min_reach_m = self.config.secondary_min_reach_m or 0.0
        return [
            b.model
            for b in self._branches
            if b.model is not None
            and b.detections >= self.config.secondary_confirmations
            and (min_reach_m == 0.0 or reach_m(b.model.points, self._primary_axis) >= min_reach_m)
        ]

    def add_detections(
        self,
        detections: list[SecondaryDetection],
        primary: BranchModel | None,
        frame: Frame | None = None,
    ) -> int:
        """Associate each detection with a model branch or create a connected new one.

        Args:
            detections: This frame's lifted secondaries.
            primary: The current primary (for the connection test of new branches).
            frame: The frame the detections were lifted from; when given, detections seen
                end-on (``secondary_min_view_angle_deg``) are dropped, and a detection that fails
                the 3D connection test may connect at its 2D junction (:meth:`_image_junction`).

        Returns:
            Number of new branches created.
        """
        camera_center = None if frame is None else frame.T_world_camera[:3, 3]
        if primary is not None and len(primary.points) >= 2:
            self._primary_axis = primary_axis(primary.points)
        created = 0
        for det in detections:
            if len(det.points) < self.config.secondary_min_points:
                continue
            if camera_center is not None and self._seen_end_on(det.points, camera_center):
                continue
            target = self._associate(det)
            if target is not None:
                self._merge_observations(target, det.points, det.radii)
                target.detections += 1
                continue
            junction = None if primary is None else self._junction(det.points, primary.points)
            if junction is None and primary is not None and frame is not None:
                junction = self._image_junction(det, primary.points, frame)
            if junction is None:
                continue
            branch = _Secondary(
                self._next_id, det.points, det.radii, det.points[0].copy(), junction=junction
            )
            self._next_id += 1
            self._refit(branch)
            if branch.model is not None:
                self._branches.append(branch)
                created += 1
        self._merge_duplicates()
        return created

    def update_trust(self, frame: Frame) -> None:
        """+1 for each visible branch whose projection lands on the mask, -1 otherwise; prune.

        A branch is visible when two of its observed points project into the image (the paper's
        "visible branch").
        """
        cfg = self.config
        kept = []
        for branch in self._branches:
            if branch.model is None:
                continue
            observed = branch.model.points[branch.n_extension :]  # not the bridged junction
            on_mask, visible = _mask_fraction(
                observed, frame, cfg.image_margin_px, cfg.secondary_trust_tolerance_px or 0.0
            )
            if visible >= _VISIBLE_POINTS:
                branch.trust += 1 if on_mask >= 0.5 else -1
                branch.model.trust = branch.trust
            if branch.trust >= cfg.secondary_trust_min:
                kept.append(branch)
        self._branches = kept

    # ----------------------------------------------------------------------------------------
    def _associate(self, det: SecondaryDetection) -> _Secondary | None:
        best, best_dist = None, np.inf
        merge_m = self.config.secondary_merge_distance_m
        for branch in self._branches:
            if _boxes_apart(det.points, branch.model.points, merge_m):
                continue  # its overlap distance is at least merge_m: no match
            dist = _overlap_distance(det.points, branch.model.points)
            if dist < merge_m and dist < best_dist:
                if _angle_deg(_direction(det.points), _direction(branch.model.points)) <= (
                    self.config.secondary_merge_angle_deg
                ):
                    best, best_dist = branch, dist
        return best

    def _seen_end_on(self, points: np.ndarray, camera_center: np.ndarray) -> bool:
        """The branch direction lies within ``secondary_min_view_angle_deg`` of the viewing ray."""
        ray = points.mean(axis=0) - camera_center
        angle = _angle_deg(_direction(points), ray / max(np.linalg.norm(ray), 1e-12))
        return min(angle, 180.0 - angle) < self.config.secondary_min_view_angle_deg

    def _junction(self, points: np.ndarray, primary_points: np.ndarray) -> np.ndarray | None:
        """The primary point nearest to the ray back from the branch start, when the ray passes
        within ``connection_distance_m`` of it (the connection test, paper IV); else None."""
        cfg = self.config
        start = points[0]
        direction = points[min(len(points) - 1, 2)] - start
        norm = np.linalg.norm(direction)
        if norm < 1e-9 or len(primary_points) == 0:
            return None
        back = -direction / norm
        rel = primary_points - start
        s = np.clip(rel @ back, 0.0, cfg.connection_ray_length_m)
        dist = np.linalg.norm(rel - s[:, None] * back, axis=1)
        k = int(np.argmin(dist))
        return primary_points[k].copy() if dist[k] <= cfg.connection_distance_m else None

    def _image_junction(
        self, det: SecondaryDetection, primary_points: np.ndarray, frame: Frame
    ) -> np.ndarray | None:
        """The primary point under the detection's 2D junction, when a straight run from it to
        the detection's first point is plausible; else None.

        The 3D connection test follows the detection's own direction back, which a few lifted
        points near a branch's tip do not give: a branch approaching or receding from the camera
        is hidden in front of or behind the primary over most of its length and only its tip
        lifts (measured: 4 points over 5 mm of a 5.7 cm branch 8 deg off the optical axis, whose
        ray back missed the primary by centimetres). Its 2D candidate still says where it leaves
        the primary. The junction is the point of the model's primary that projects there
        (within ``secondary_junction_px``); the run from it to the first lifted point must be
        shorter than ``connection_ray_length_m`` and project onto the mask (at least
        ``secondary_junction_on_mask`` of its samples): the hidden part of a branch lies in
        front of or behind the primary's silhouette or in its own.
        """
        cfg = self.config
        if det.junction_px is None or len(primary_points) < 2:
            return None
        pixels, depth = project_points(primary_points, frame.T_world_camera, frame.intrinsics)
        start, end = pixels[:-1], pixels[1:]
        valid = (depth[:-1] > 0) & (depth[1:] > 0)
        if not valid.any():
            return None
        segment = end - start
        length_sq = np.maximum(np.sum(segment * segment, axis=1), 1e-12)
        t = np.clip(np.sum((det.junction_px - start) * segment, axis=1) / length_sq, 0.0, 1.0)
        distance_px = np.linalg.norm(start + t[:, None] * segment - det.junction_px, axis=1)
        distance_px[~valid] = np.inf
        k = int(np.argmin(distance_px))
        if distance_px[k] > cfg.secondary_junction_px:
            return None
        junction = primary_points[k] + t[k] * (primary_points[k + 1] - primary_points[k])
        run = det.points[0] - junction
        run_m = float(np.linalg.norm(run))
        if run_m > cfg.connection_ray_length_m:
            return None
        n = max(2, int(np.ceil(run_m / cfg.secondary_sample_spacing_m)))
        along = junction + np.linspace(0.0, 1.0, n + 1)[1:-1, None] * run
        if len(along) == 0:
            return junction
        on_mask, visible = _mask_fraction(along, frame, 0.0)
        if visible == 0:
            return None
        return junction if on_mask >= cfg.secondary_junction_on_mask else None

    def _merge_observations(
        self, branch: _Secondary, points: np.ndarray, radii: np.ndarray
    ) -> None:
        cap = self.config.secondary_max_observations
        branch.observations = np.concatenate([branch.observations, points])[-cap:]
        branch.radii = np.concatenate([branch.radii, radii])[-cap:]
        self._refit(branch)

    def _merge_duplicates(self) -> None:
        merge_m = self.config.secondary_merge_distance_m
        merged = True
        while merged:
            merged = False
            for i, a in enumerate(self._branches):
                for b in self._branches[i + 1 :]:
                    # The cheap tests first: the same decisions, without most of the overlap
                    # distances (each builds two k-d trees).
                    if (
                        _angle_deg(_direction(a.model.points), _direction(b.model.points))
                        <= self.config.secondary_merge_angle_deg
                        and not _boxes_apart(b.model.points, a.model.points, merge_m)
                        and _overlap_distance(b.model.points, a.model.points) < merge_m
                    ):
                        a.detections += b.detections
                        a.trust = max(a.trust, b.trust)
                        if a.junction is None:
                            a.junction = b.junction
                        self._branches.remove(b)
                        self._merge_observations(a, b.observations, b.radii)
                        merged = True
                        break
                if merged:
                    break

    def _refit(self, branch: _Secondary) -> None:
        """Fit a curve through all observations, ordered outward from the junction side (the
        junction itself with ``secondary_order_from_junction``, else the first detection's
        first point)."""
        cfg = self.config
        pts, radii = branch.observations, branch.radii
        anchor = branch.base_hint
        if cfg.secondary_order_from_junction and branch.junction is not None:
            anchor = branch.junction
        order = np.argsort(np.linalg.norm(pts - anchor, axis=1))
        pts, radii = pts[order], radii[order]
        curve: CubicBezier | None = None
        keep = np.ones(len(pts), dtype=bool)
        if len(pts) >= 6:
            fit = ransac_fit_bezier(
                pts,
                inlier_threshold=cfg.ransac_inlier_m,
                min_inlier_fraction=cfg.ransac_min_inlier_fraction,
                rng=self.rng,
                iterations=cfg.ransac_iterations,
            )
            if fit is not None:
                curve, keep = fit.curve, fit.inliers
        elif len(pts) >= 4:
            curve = fit_bezier(pts)
        if curve is None:
            # Too few points for a cubic: the straight segment through the end points.
            p0, p1 = pts[0], pts[-1]
            curve = CubicBezier(np.linspace(p0, p1, 4))
        t_in, _ = curve.closest_params(pts[keep])
        t_lo, t_hi = float(t_in.min()), float(t_in.max())
        if t_hi - t_lo <= 1e-6:
            branch.model = None
            return
        ts = np.linspace(t_lo, t_hi, 200)
        dense = curve(ts)
        seg_len = float(np.linalg.norm(np.diff(dense, axis=0), axis=1).sum())
        n = max(2, int(np.ceil(seg_len / cfg.secondary_sample_spacing_m)) + 1)
        t_out = np.interp(
            np.linspace(0, seg_len, n),
            np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))]),
            ts,
        )
        samples = curve(t_out)
        out_radii = robust_radius_profile(t_in, radii[keep], t_out)
        samples, out_radii, branch.n_extension = self._extend_to_junction(
            samples, out_radii, branch.junction
        )
        branch.model = BranchModel(samples, out_radii, branch.branch_id, branch.trust)

    def _extend_to_junction(
        self, samples: np.ndarray, radii: np.ndarray, junction: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Samples (and radii) with a straight run from the junction on the primary to the first
        observed sample prepended, and how many points were prepended.

        The base of a side branch lies behind or in front of the primary's silhouette (its
        samples there are not lifted); for a branch receding from the camera it stays hidden
        over r / sin(angle to the viewing ray) of its length: ~4 cm at 15 deg for a 1 cm wide
        trunk and branch. Secondaries grow from the primary (the connection test found where).
        """
        cfg = self.config
        if not cfg.secondary_extend_to_junction or junction is None:
            return samples, radii, 0
        gap = float(np.linalg.norm(samples[0] - junction))
        n = int(np.ceil(gap / cfg.secondary_sample_spacing_m))
        if n < 2:
            return samples, radii, 0
        run = np.linspace(junction, samples[0], n + 1)[:-1]
        return np.vstack([run, samples]), np.concatenate([np.full(n, radii[0]), radii]), n


def _mask_fraction(
    points: np.ndarray, frame: Frame, margin_px: float, tolerance_px: float = 0.0
) -> tuple[float, int]:
    """(share of ``points`` that project onto ``frame``'s mask, how many project into the image
    at least ``margin_px`` from its border); the share is NaN when none do.

    With ``tolerance_px`` > 0 a point counts as on the mask when a mask pixel lies within that
    distance of its projection.
    """
    pixels, depth = project_points(points, frame.T_world_camera, frame.intrinsics)
    visible = (depth > 0) & frame.intrinsics.in_image(pixels, margin_px)
    n = int(visible.sum())
    if n == 0:
        return float("nan"), 0
    px = np.rint(pixels[visible]).astype(int)
    if tolerance_px <= 0.0:
        return float(frame.mask[px[:, 1], px[:, 0]].mean()), n
    dy, dx = _disk_offsets(tolerance_px)
    height, width = frame.mask.shape
    rows = np.clip(px[:, 1, None] + dy[None], 0, height - 1)
    cols = np.clip(px[:, 0, None] + dx[None], 0, width - 1)
    return float(frame.mask[rows, cols].any(axis=1).mean()), n


@functools.lru_cache(maxsize=8)
def _disk_offsets(radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) offsets of the pixels within ``radius_px`` of a pixel (itself included)."""
    r = int(np.ceil(radius_px))
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    inside = dy**2 + dx**2 <= radius_px**2
    return dy[inside], dx[inside]


def primary_axis(points: np.ndarray) -> np.ndarray | None:
    """(3,) unit base-to-top direction of a primary's (N, 3) points; None when it has no extent."""
    if len(points) < 2:
        return None
    direction = _direction(points)
    return direction if direction.any() else None


def reach_m(points: np.ndarray, axis: np.ndarray | None) -> float:
    """How far a branch reaches out from the primary: its base-to-tip vector's part
    perpendicular to ``axis`` (metres; the whole base-to-tip length without an axis).

    Args:
        points: (N, 3) branch centerline, base first, metres.
        axis: (3,) unit base-to-top direction of the primary (:func:`primary_axis`), or None.
    """
    span = points[-1] - points[0]
    if axis is not None:
        span = span - float(span @ axis) * axis
    return float(np.linalg.norm(span))


def _direction(points: np.ndarray) -> np.ndarray:
    d = points[-1] - points[0]
    n = np.linalg.norm(d)
    return d / n if n > 0 else d


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def _overlap_distance(a: np.ndarray, b: np.ndarray) -> float:
    """How far apart two lifted branches are where they overlap: the smaller of the two directed
    median distances (m).

    A detection that sees more (or less) of a branch than the model holds lies on it along the
    shorter one's length only; the median from the longer one would count the part the other
    never saw (measured: a 14 cm re-detection of a branch first lifted over 2 cm became a
    duplicate).
    """
    return min(_median_distance(a, b), _median_distance(b, a))


def _boxes_apart(a: np.ndarray, b: np.ndarray, distance_m: float) -> bool:
    """True when the axis-aligned boxes of two point sets lie ``distance_m`` or more apart.

    Every point of one is then at least that far from every point of the other, so
    :func:`_overlap_distance` is too: a test that skips it gives the same decision. The margin
    (``_BOX_MARGIN``, relative) keeps that true under floating-point rounding.

    Args:
        a: (N, 3) points, metres.
        b: (M, 3) points, metres.
        distance_m: The distance, metres.
    """
    if len(a) == 0 or len(b) == 0:
        return False
    gap = np.maximum(np.maximum(a.min(axis=0) - b.max(axis=0), b.min(axis=0) - a.max(axis=0)), 0.0)
    return float(np.sqrt(gap @ gap)) >= distance_m * (1.0 + _BOX_MARGIN)


def _median_distance(points: np.ndarray, reference: np.ndarray) -> float:
    """Median distance (m) from each of ``points`` to the nearest of ``reference``."""
    if len(points) == 0 or len(reference) == 0:
        return np.inf
    dist, _ = cKDTree(reference).query(points)
    return float(np.median(dist))
