"""Evaluation of a reconstruction against ground truth (paper Table I; reference.md "Evaluation").

Primary branch (PB): the ground-truth centerline is resampled densely; every reconstructed primary
point in the scanned band contributes its nearest-neighbour distance (the residual) and its radius
error (reconstructed minus ground-truth radius at that nearest point).

Secondary branches (SB): both sides are resampled every millimetre. Ground-truth branches the scan
could not have seen are out of scope: base (first point) above the scanned top height plus a margin,
or below the band bottom (the simulator places none there; a real scan starts lower). Reconstructed
branches shorter than a minimum horizontal extent are ignored. A reconstructed branch is a
*candidate* for a ground-truth branch when their base-to-tip directions are within an angle and the
median distance of its samples to the ground-truth branch is small. A one-to-one assignment over the
candidates (largest number of pairs, then least total median distance) gives the matches:

* matched to an in-scope branch: a match; matched to an out-of-scope branch: ignored (not spurious);
* not matched but a candidate of some in-scope branch: a duplicate (that branch was taken);
* a candidate of nothing: spurious in the paper's sense. Unmatched in-scope ground-truth branches
  are missed.

Every reconstructed side branch lands in exactly one class (:data:`BRANCH_CLASSES`, one entry per
reconstructed branch in :attr:`TreeMetrics.reconstructed_classes`): ``match``, ``duplicate``,
``out_of_scope`` (matched to, or a candidate of, only a ground-truth branch out of scope),
``short`` (under the minimum horizontal extent, not scored), or, for a candidate of nothing, the
kind of the nearest surrounding structure it lies on (:data:`SURROUNDING_KINDS`: the tree's own
spurs, stubs and buds, a neighbour's branch, a wire or post, the clean world's clutter; median
distance of its samples below ``MetricsConfig.surroundings_max_median_distance_m``), or
``spurious``: nothing there. ``n_spurious`` counts that last class; the paper's spurious (a
candidate of nothing, whatever lies there) is ``n_spurious_paper``. Precision counts against the
reconstruction every branch that is not a distinct side branch of the scanned tree, except the
tree's own details and out-of-scope branches: matched / (matched + duplicates + neighbours +
trellis + clutter + spurious).

Scope (``MetricsConfig.count_unreached_as_missed``): by default a ground-truth branch is in scope
up to the scan's *planned* top height, so a scan that failed or stopped early misses the branches
above where it stopped (``n_unreached`` of its misses). The paper scored up to the height the
camera reached (``count_unreached_as_missed=False``, its replication table).

Percentages follow the authors' code: missed, spurious and duplicates are all divided by the number
of in-scope ground-truth branches. SB residuals and radius errors use the *overlapping* part of each
matched pair: the reconstructed samples whose nearest ground-truth sample is neither end of the
ground-truth branch, i.e. that project inside its arc-length extent. SB completeness is the share
of a matched ground-truth branch's length that lies within a tolerance of its match.

Undefined metrics are NaN (no reconstructed primary point in the band -> PB metrics NaN; no match ->
SB metrics NaN; no in-scope ground-truth branch -> percentages NaN); :func:`aggregate` skips them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from recon.validation import require_non_negative, require_positive

PERCENT = 100.0
# Kinds of structure around the scanned tree that a reconstruction matching no side branch can
# lie on (``surroundings`` of :func:`evaluate`): the tree's own spurs, stubs and buds (the ground
# truth's ``details``), branches of the row's other trees (and a UFO tree's other uprights and
# cordon), trellis wires, clips and posts, and the clean world's clutter.
SURROUNDING_KINDS = ("detail", "neighbour", "trellis", "clutter")
# Every class of a reconstructed side branch (module docstring), in report order.
BRANCH_CLASSES = ("match", "duplicate", *SURROUNDING_KINDS, "spurious", "out_of_scope", "short")
# Classes held against precision: what is not a distinct side branch of the scanned tree.
NOT_PRECISE = ("duplicate", "neighbour", "trellis", "clutter", "spurious")


class BranchLike(Protocol):
    """A centerline with radii: :class:`recon.model.BranchModel` or a ground-truth branch."""

    @property
    def points(self) -> np.ndarray:
        """(N, 3) centerline points in metres, world frame, base to tip."""
        ...

    @property
    def radii(self) -> np.ndarray:
        """(N,) radius in metres at each point."""
        ...


class TreeLike(Protocol):
    """A primary branch and its secondaries: :class:`recon.model.TreeModel` or ground truth."""

    @property
    def primary(self) -> BranchLike | None: ...

    @property
    def secondaries(self) -> Sequence[BranchLike]: ...


@dataclass(frozen=True)
class MetricsConfig:
    """Evaluation parameters, the authors' analysis code (reference.md, "Evaluation").

    Attributes:
        band_min_z_m: Bottom of the scanned band; PB points at or below it are not scored (0.325 m).
        band_max_z_m: Top of the scanned band and default scanned top height (0.75 m); equal
            to ``band_min_z_m``, the band is empty.
        primary_resample_count: Points of the resampled ground-truth primary (10,000).
        secondary_resample_step_m: Resampling step of both SB sets (1 mm).
        gt_base_margin_m: GT branches whose base is above the scanned top height plus this are out
            of scope (2 cm).
        min_horizontal_length_m: Reconstructed branches whose base-to-tip vector is no longer than
            this horizontally are ignored (2.5 cm).
        max_match_angle_deg: Largest angle between base-to-tip vectors of a candidate pair (60 deg).
        max_match_median_distance_m: A candidate's samples lie closer than this (median nearest-
            neighbour distance) to the GT branch (2 cm).
        completeness_tolerance_m: A ground-truth sample of a matched branch is covered when a
            reconstructed sample of its match lies within this (our choice: 1 cm, half the
            matching distance); SB completeness is the covered share of the branch's length.
        surroundings_max_median_distance_m: A reconstruction that is a candidate of no side
            branch is put down to a surrounding structure when the median distance of its
            samples to that kind's structures is below this (our choice: the authors' matching
            distance, 2 cm); otherwise it is spurious (nothing there).
        count_unreached_as_missed: Ground-truth branches are in scope up to the planned top
            height, so those above where a failed scan stopped are missed (default, the
            benchmark's rule); False scores up to the height reached, as the paper's analysis.
    """

    band_min_z_m: float = 0.325
    band_max_z_m: float = 0.75
    primary_resample_count: int = 10_000
    secondary_resample_step_m: float = 0.001
    gt_base_margin_m: float = 0.02
    min_horizontal_length_m: float = 0.025
    max_match_angle_deg: float = 60.0
    max_match_median_distance_m: float = 0.02
    completeness_tolerance_m: float = 0.01
    surroundings_max_median_distance_m: float = 0.02
    count_unreached_as_missed: bool = True

    def __post_init__(self) -> None:
        if not self.band_min_z_m <= self.band_max_z_m:  # equal: an empty band
            raise ValueError(
                f"band_min_z_m ({self.band_min_z_m}) must not be above "
                f"band_max_z_m ({self.band_max_z_m})"
            )
        if self.primary_resample_count < 2:
            raise ValueError(
                f"primary_resample_count must be >= 2, got {self.primary_resample_count}"
            )
        require_positive(
            self,
            "secondary_resample_step_m",
            "max_match_median_distance_m",
            "completeness_tolerance_m",
            "surroundings_max_median_distance_m",
            finite=False,
        )
        require_non_negative(self, "gt_base_margin_m", "min_horizontal_length_m", finite=False)
        if not 0.0 < self.max_match_angle_deg <= 180.0:
            raise ValueError(
                f"max_match_angle_deg must be in (0, 180], got {self.max_match_angle_deg}"
            )


@dataclass
class TreeMetrics:
    """One trial's evaluation. Distances in metres; NaN where undefined (see module docstring).

    Attributes:
        pb_residuals_m: (K,) distance of each reconstructed primary point in the band to the GT.
        pb_radius_errors_m: (K,) reconstructed minus GT radius at the nearest GT point.
        sb_residuals_m: (L,) distances of the overlapping samples of all matched pairs.
        sb_radius_errors_m: (L,) reconstructed minus GT radius at those samples.
        matches: (GT index, reconstructed index) pairs, indices into ``truth.secondaries`` and
            ``model.secondaries``.
        n_gt: In-scope GT secondaries.
        n_matched, n_missed, n_duplicates: Counts as in the module docstring.
        n_spurious: Reconstructed secondaries with nothing there (class ``spurious``).
        n_ignored_reconstructed: Reconstructed secondaries too short, or matched (or only a
            candidate) out of scope.
        scanned_top_z_m: Scanned top height used for the GT scope.
        gt_in_scope: (G,) bool, which GT secondaries are in scope (index as ``truth.secondaries``).
        match_completeness: (len(matches),) share of each matched GT branch's length that its
            match covers (``MetricsConfig.completeness_tolerance_m``), in [0, 1].
        match_residual_m: (len(matches),) mean overlap residual of each matched pair (NaN when
            no sample overlaps).
        reconstructed_classes: The class of each reconstructed secondary (index as
            ``model.secondaries``; :data:`BRANCH_CLASSES`).
        n_unreached: Missed in-scope branches whose base lies above the height the scan reached
            plus the margin (a failed or stopped scan's; 0 when scoring up to the height reached).
        n_unreached_matched: In-scope branches above that height that were matched all the same
            (seen from below); the paper's scope leaves them out.
        class_counts: Reconstructed secondaries per class, every class of
            :data:`BRANCH_CLASSES` (derived).
        n_spurious_paper: The paper's spurious count: candidates of no ground-truth side branch,
            whatever they lie on (derived).
        precision_pct: Matched in % of the reconstructions held against precision (module
            docstring); NaN when there are none (derived).
        missed_paper_pct: Missed % in the paper's scope, up to the height reached (derived).
        pb_residual_mean_m, sb_residual_mean_m: Means of the residuals (derived).
        pb_radius_rmse_m, sb_radius_rmse_m: RMS of the radius errors (derived).
        missed_pct, spurious_pct, duplicate_pct, spurious_paper_pct: Counts in % of ``n_gt``
            (derived).
        sb_completeness_pct: Mean completeness of the matches, % (derived).
    """

    pb_residuals_m: np.ndarray
    pb_radius_errors_m: np.ndarray
    sb_residuals_m: np.ndarray
    sb_radius_errors_m: np.ndarray
    matches: list[tuple[int, int]]
    n_gt: int
    n_matched: int
    n_missed: int
    n_spurious: int
    n_duplicates: int
    n_ignored_reconstructed: int
    scanned_top_z_m: float
    gt_in_scope: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    match_completeness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    match_residual_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reconstructed_classes: list[str] = field(default_factory=list)
    n_unreached: int = 0
    n_unreached_matched: int = 0
    class_counts: dict[str, int] = field(init=False)
    n_spurious_paper: int = field(init=False)
    precision_pct: float = field(init=False)
    spurious_paper_pct: float = field(init=False)
    missed_paper_pct: float = field(init=False)
    pb_residual_mean_m: float = field(init=False)
    pb_radius_rmse_m: float = field(init=False)
    sb_residual_mean_m: float = field(init=False)
    sb_radius_rmse_m: float = field(init=False)
    missed_pct: float = field(init=False)
    spurious_pct: float = field(init=False)
    duplicate_pct: float = field(init=False)
    sb_completeness_pct: float = field(init=False)

    def __post_init__(self) -> None:
        unknown = set(self.reconstructed_classes) - set(BRANCH_CLASSES)
        if unknown:
            raise ValueError(f"unknown reconstructed branch classes {sorted(unknown)}")
        self.class_counts = {
            name: self.reconstructed_classes.count(name) for name in BRANCH_CLASSES
        }
        self.n_spurious_paper = self.n_spurious + sum(
            self.class_counts[kind] for kind in SURROUNDING_KINDS
        )
        self.precision_pct = precision_percent([self])
        self.spurious_paper_pct = pooled_percent([self.n_spurious_paper], [self.n_gt])
        self.missed_paper_pct = missed_paper_percent([self])
        self.pb_residual_mean_m = _mean(self.pb_residuals_m)
        self.pb_radius_rmse_m = _rms(self.pb_radius_errors_m)
        self.sb_residual_mean_m = _mean(self.sb_residuals_m)
        self.sb_radius_rmse_m = _rms(self.sb_radius_errors_m)
        self.missed_pct = pooled_percent([self.n_missed], [self.n_gt])
        self.spurious_pct = pooled_percent([self.n_spurious], [self.n_gt])
        self.duplicate_pct = pooled_percent([self.n_duplicates], [self.n_gt])
        self.sb_completeness_pct = PERCENT * _mean(np.asarray(self.match_completeness, float))

    def to_dict(self) -> dict[str, float | int | str]:
        """Flat JSON-able row (one line of a trials table); NaN stays a float NaN."""
        return {
            "pb_residual_mean_m": self.pb_residual_mean_m,
            "pb_radius_rmse_m": self.pb_radius_rmse_m,
            "pb_n_points": len(self.pb_residuals_m),
            "sb_residual_mean_m": self.sb_residual_mean_m,
            "sb_radius_rmse_m": self.sb_radius_rmse_m,
            "sb_n_samples": len(self.sb_residuals_m),
            "n_gt": self.n_gt,
            "n_matched": self.n_matched,
            "n_missed": self.n_missed,
            "n_spurious": self.n_spurious,
            "n_duplicates": self.n_duplicates,
            "n_ignored_reconstructed": self.n_ignored_reconstructed,
            "missed_pct": self.missed_pct,
            "spurious_pct": self.spurious_pct,
            "duplicate_pct": self.duplicate_pct,
            "n_unreached": self.n_unreached,
            "n_unreached_matched": self.n_unreached_matched,
            "missed_paper_pct": self.missed_paper_pct,
            "n_spurious_paper": self.n_spurious_paper,
            "spurious_paper_pct": self.spurious_paper_pct,
            "precision_pct": self.precision_pct,
            **{f"n_class_{name}": count for name, count in self.class_counts.items()},
            "sb_completeness_pct": self.sb_completeness_pct,
            "scanned_top_z_m": self.scanned_top_z_m,
            "matches": json.dumps([list(pair) for pair in self.matches]),
        }

    def to_json_dict(self) -> dict:
        """Lossless, strict-JSON form: every constructor field, arrays included.

        Floats keep full precision (``json`` writes round-trip ``repr``); non-finite values are
        written as the strings ``"nan"``, ``"inf"`` and ``"-inf"``, so the result passes
        ``json.dumps(..., allow_nan=False)``. Derived fields are recomputed on load.
        """
        return {
            "pb_residuals_m": [_float_to_json(v) for v in self.pb_residuals_m.tolist()],
            "pb_radius_errors_m": [_float_to_json(v) for v in self.pb_radius_errors_m.tolist()],
            "sb_residuals_m": [_float_to_json(v) for v in self.sb_residuals_m.tolist()],
            "sb_radius_errors_m": [_float_to_json(v) for v in self.sb_radius_errors_m.tolist()],
            "matches": [[int(j), int(i)] for j, i in self.matches],
            "n_gt": int(self.n_gt),
            "n_matched": int(self.n_matched),
            "n_missed": int(self.n_missed),
            "n_spurious": int(self.n_spurious),
            "n_duplicates": int(self.n_duplicates),
            "n_ignored_reconstructed": int(self.n_ignored_reconstructed),
            "scanned_top_z_m": _float_to_json(float(self.scanned_top_z_m)),
            "gt_in_scope": [bool(v) for v in self.gt_in_scope],
            "match_completeness": [_float_to_json(v) for v in self.match_completeness.tolist()],
            "match_residual_m": [_float_to_json(v) for v in self.match_residual_m.tolist()],
            "reconstructed_classes": list(self.reconstructed_classes),
            "n_unreached": int(self.n_unreached),
            "n_unreached_matched": int(self.n_unreached_matched),
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> TreeMetrics:
        """Inverse of :meth:`to_json_dict` (also after a ``json.dumps`` / ``json.loads`` trip).

        Raises:
            KeyError: ``data`` was written before the reconstructed branches had classes (its
                ``n_spurious`` is the paper's): re-score the trial (:func:`evaluate`).
        """
        if "reconstructed_classes" not in data:
            raise KeyError(
                "reconstructed_classes: metrics saved before the branch classes; re-score them"
            )
        return cls(
            pb_residuals_m=_array_from_json(data["pb_residuals_m"]),
            pb_radius_errors_m=_array_from_json(data["pb_radius_errors_m"]),
            sb_residuals_m=_array_from_json(data["sb_residuals_m"]),
            sb_radius_errors_m=_array_from_json(data["sb_radius_errors_m"]),
            matches=[(int(j), int(i)) for j, i in data["matches"]],
            n_gt=int(data["n_gt"]),
            n_matched=int(data["n_matched"]),
            n_missed=int(data["n_missed"]),
            n_spurious=int(data["n_spurious"]),
            n_duplicates=int(data["n_duplicates"]),
            n_ignored_reconstructed=int(data["n_ignored_reconstructed"]),
            scanned_top_z_m=float(data["scanned_top_z_m"]),
            gt_in_scope=np.array(data.get("gt_in_scope", []), bool),
            match_completeness=_array_from_json(data.get("match_completeness", [])),
            match_residual_m=_array_from_json(data.get("match_residual_m", [])),
            reconstructed_classes=[str(name) for name in data["reconstructed_classes"]],
            n_unreached=int(data.get("n_unreached", 0)),
            n_unreached_matched=int(data.get("n_unreached_matched", 0)),
        )


@dataclass(frozen=True)
class TruthIndex:
    """A ground-truth tree prepared for scoring: resampled branches and their KD-trees.

    Building it is about half the cost of :func:`evaluate`; a caller scoring many models of
    one tree (the env, after every step) builds it once with :func:`index_truth`.

    Attributes:
        primary: The primary resampled at ``primary_resample_count`` points (points, radii).
        primary_tree: KD-tree of those points.
        secondaries: Each GT secondary, validated (points, radii).
        secondary_samples: Each GT secondary resampled every ``secondary_resample_step_m``.
        secondary_trees: KD-trees of those samples.
        config: The metrics configuration it was built for.
        surroundings: Per surrounding kind (:data:`SURROUNDING_KINDS`), a KD-tree of the samples
            of all its structures (kinds without structures left out).
        scored: What :func:`evaluate` worked out for each reconstructed secondary of the last
            call (by the identity of its points and radii arrays): a model scored after every
            step keeps most of its branches, and their work is not redone.
    """

    primary: Branch
    primary_tree: cKDTree
    secondaries: list[Branch]
    secondary_samples: list[Branch]
    secondary_trees: list[cKDTree]
    config: MetricsConfig
    surroundings: dict[str, cKDTree] = field(default_factory=dict)
    scored: dict[int, _ScoredBranch] = field(default_factory=dict, compare=False, repr=False)


@dataclass
class _ScoredBranch:
    """One reconstructed secondary against every GT branch (:attr:`TruthIndex.scored`).

    Attributes:
        points: The branch's (N, 3) points (the key's array, kept alive and compared by identity).
        radii: Its (N,) radii.
        samples: Resampled (points, radii).
        median_m: (G,) median distance to each GT branch where it is a candidate, else inf.
        pairs: Overlap errors against GT branch j (:func:`_pair_errors`), filled when matched.
    """

    points: np.ndarray
    radii: np.ndarray
    samples: Branch
    median_m: np.ndarray
    pairs: dict[int, tuple[np.ndarray, np.ndarray, float, float]] = field(default_factory=dict)


Surroundings = Mapping[str, Sequence[BranchLike]]


def index_truth(
    truth: TreeLike, config: MetricsConfig | None = None, surroundings: Surroundings | None = None
) -> TruthIndex:
    """Validate and prepare a ground-truth tree for :func:`evaluate`.

    Args:
        truth: The ground-truth tree.
        config: Evaluation parameters; the authors' values by default.
        surroundings: Structures around the tree by kind (:data:`SURROUNDING_KINDS`), each a
            centerline in metres, world frame; None or a kind left out: none of that kind.

    Raises:
        ValueError: no ground-truth primary, malformed branches (see :func:`evaluate`), or an
            unknown surrounding kind.
    """
    config = config or MetricsConfig()
    if truth.primary is None:
        raise ValueError("truth has no primary branch")
    gt_primary = _branch_arrays(truth.primary, "truth.primary", min_points=2)
    primary = _resample(gt_primary, count=config.primary_resample_count)
    gt = [_branch_arrays(b, f"truth.secondaries[{i}]", 2) for i, b in enumerate(truth.secondaries)]
    for i, (points, _) in enumerate(gt):
        if np.allclose(points[-1], points[0]):
            raise ValueError(f"truth.secondaries[{i}] has no base-to-tip extent")
    samples = [_resample(b, step_m=config.secondary_resample_step_m) for b in gt]
    surrounding_trees = {}
    for kind, structures in (surroundings or {}).items():
        if kind not in SURROUNDING_KINDS:
            raise ValueError(
                f"unknown surrounding kind {kind!r}; expected one of {SURROUNDING_KINDS}"
            )
        kind_samples = [
            _resample(
                _branch_arrays(b, f"surroundings[{kind!r}][{i}]", 1),
                step_m=config.secondary_resample_step_m,
            )[0]
            for i, b in enumerate(structures)
        ]
        if kind_samples:
            surrounding_trees[kind] = cKDTree(np.concatenate(kind_samples))
    return TruthIndex(
        primary=primary,
        primary_tree=cKDTree(primary[0]),
        secondaries=gt,
        secondary_samples=samples,
        secondary_trees=[cKDTree(points) for points, _ in samples],
        config=config,
        surroundings=surrounding_trees,
    )


def evaluate(
    model: TreeLike,
    truth: TreeLike,
    config: MetricsConfig | None = None,
    scanned_top_z_m: float | None = None,
    truth_index: TruthIndex | None = None,
    surroundings: Surroundings | None = None,
    planned_top_z_m: float | None = None,
) -> TreeMetrics:
    """Score a reconstructed tree against ground truth.

    Args:
        model: The reconstruction (:class:`recon.model.TreeModel`).
        truth: Ground truth with the same duck type; it must have a primary branch.
        config: Evaluation parameters; the authors' values by default.
        scanned_top_z_m: Highest height the scan reached, metres (e.g. lower after a failure);
            defaults to the planned top.
        truth_index: ``index_truth(truth, config, surroundings)``, built once for many calls on
            one tree (the same numbers, cheaper); None builds it here.
        surroundings: Structures around the tree by kind (:func:`index_truth`); only without
            ``truth_index`` (which holds them).
        planned_top_z_m: The height the scan was to reach, metres; defaults to
            ``config.band_max_z_m``. Ground-truth branches are in scope up to it, or up to
            ``scanned_top_z_m`` with ``config.count_unreached_as_missed`` False.

    Returns:
        The trial's metrics.

    Raises:
        ValueError: malformed branches (shapes, non-finite values, a ground-truth branch with fewer
            than two points or no base-to-tip extent), no ground-truth primary, a non-finite
            top height, or surroundings given with a ``truth_index``.
    """
    config = config or MetricsConfig()
    if truth_index is not None and truth_index.config != config:
        raise ValueError("truth_index was built for another MetricsConfig")
    if truth_index is not None and surroundings is not None:
        raise ValueError("pass surroundings to index_truth when a truth_index is given")
    planned_m = config.band_max_z_m if planned_top_z_m is None else float(planned_top_z_m)
    top_m = planned_m if scanned_top_z_m is None else float(scanned_top_z_m)
    if not (np.isfinite(top_m) and np.isfinite(planned_m)):
        raise ValueError(
            f"scanned_top_z_m and planned_top_z_m must be finite, got {scanned_top_z_m} and "
            f"{planned_top_z_m}"
        )
    index = truth_index or index_truth(truth, config, surroundings)
    model_primary = (
        None if model.primary is None else _branch_arrays(model.primary, "model.primary", 0)
    )
    pb_residuals, pb_radius_errors = _primary_errors(model_primary, index, config)
    reconstructed = [
        _branch_arrays(b, f"model.secondaries[{i}]", 0) for i, b in enumerate(model.secondaries)
    ]
    return TreeMetrics(
        pb_residuals_m=pb_residuals,
        pb_radius_errors_m=pb_radius_errors,
        scanned_top_z_m=top_m,
        **_secondary_metrics(reconstructed, index, top_m, planned_m, config),
    )


def pooled_percent(counts: Iterable[int], totals: Iterable[int]) -> float:
    """A percentage pooled over trials, as Table I's: 100 sum(counts) / sum(totals).

    The missed, spurious and duplicate percentages of an evaluation, a checkpoint selection and
    a DAgger round are all this over their trials (in-scope ground-truth branches the totals);
    NaN when the totals sum to 0.

    >>> pooled_percent([1, 0, 2], [5, 5, 10])
    15.0
    """
    count, total = sum(counts), sum(totals)
    return PERCENT * count / total if total else float("nan")


def missed_paper_percent(trials: Sequence[TreeMetrics]) -> float:
    """Missed % pooled over trials in the paper's scope (in scope up to the height each scan
    reached: its unreached branches, missed or matched, left out); NaN without a branch."""
    missed = sum(t.n_missed - t.n_unreached for t in trials)
    total = sum(t.n_gt - t.n_unreached - t.n_unreached_matched for t in trials)
    return PERCENT * missed / total if total else float("nan")


def precision_percent(trials: Sequence[TreeMetrics]) -> float:
    """Side-branch precision pooled over trials: 100 sum(matched) / sum(matched + held against
    precision) (module docstring); NaN when no trial reconstructed a scored branch."""
    matched = sum(t.class_counts["match"] for t in trials)
    held = sum(t.class_counts[name] for t in trials for name in NOT_PRECISE)
    return PERCENT * matched / (matched + held) if matched + held else float("nan")


def aggregate(trials: Sequence[TreeMetrics]) -> dict[str, float | int]:
    """Mean and standard deviation over trials, as Table I reports them.

    PB and SB residuals are pooled over all points of all trials (as the paper); radius RMSEs are
    averaged over the trials where they are defined; missed / spurious / duplicate percentages are
    totals (sum over trials / sum of in-scope GT branches), precision is pooled
    (:func:`precision_percent`). Standard deviations are population
    (ddof=0). Undefined entries are NaN.

    Raises:
        ValueError: no trials.
    """
    if not trials:
        raise ValueError("aggregate needs at least one trial")
    pb = np.concatenate([t.pb_residuals_m for t in trials])
    sb = np.concatenate([t.sb_residuals_m for t in trials])
    pb_rmse = np.array([t.pb_radius_rmse_m for t in trials])
    sb_rmse = np.array([t.sb_radius_rmse_m for t in trials])
    completeness = np.concatenate([np.asarray(t.match_completeness, float) for t in trials])
    totals = {
        name: int(sum(getattr(t, name) for t in trials))
        for name in (
            "n_gt", "n_matched", "n_missed", "n_spurious", "n_duplicates", "n_spurious_paper",
            "n_unreached", "n_unreached_matched",
        )
    }  # fmt: skip
    classes = {
        f"n_class_{name}": int(sum(t.class_counts[name] for t in trials)) for name in BRANCH_CLASSES
    }
    n_gt = [t.n_gt for t in trials]
    return {
        "n_trials": len(trials),
        "n_trials_without_pb": int(sum(len(t.pb_residuals_m) == 0 for t in trials)),
        "pb_residual_mean_m": _mean(pb),
        "pb_residual_std_m": _std(pb),
        "pb_n_points": len(pb),
        "pb_radius_rmse_mean_m": _mean(pb_rmse[np.isfinite(pb_rmse)]),
        "pb_radius_rmse_std_m": _std(pb_rmse[np.isfinite(pb_rmse)]),
        "sb_residual_mean_m": _mean(sb),
        "sb_residual_std_m": _std(sb),
        "sb_n_samples": len(sb),
        "sb_radius_rmse_mean_m": _mean(sb_rmse[np.isfinite(sb_rmse)]),
        "sb_radius_rmse_std_m": _std(sb_rmse[np.isfinite(sb_rmse)]),
        **totals,
        "missed_pct": pooled_percent([t.n_missed for t in trials], n_gt),
        "spurious_pct": pooled_percent([t.n_spurious for t in trials], n_gt),
        "duplicate_pct": pooled_percent([t.n_duplicates for t in trials], n_gt),
        "spurious_paper_pct": pooled_percent([t.n_spurious_paper for t in trials], n_gt),
        "missed_paper_pct": missed_paper_percent(trials),
        "precision_pct": precision_percent(trials),
        **classes,
        "sb_completeness_pct": PERCENT * _mean(completeness),
    }


Branch = tuple[np.ndarray, np.ndarray]  # (N, 3) points and (N,) radii


def _branch_arrays(branch: BranchLike, name: str, min_points: int) -> Branch:
    """Validated float copies of a branch's points and radii."""
    points = np.asarray(branch.points, dtype=float)
    radii = np.asarray(branch.radii, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}.points must have shape (N, 3), got {points.shape}")
    if radii.shape != (len(points),):
        raise ValueError(f"{name}.radii must have shape ({len(points)},), got {radii.shape}")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(radii))):
        raise ValueError(f"{name} contains NaN or infinite values")
    if len(points) < min_points:
        raise ValueError(f"{name} needs at least {min_points} points, got {len(points)}")
    return points, radii


def _resample(branch: Branch, step_m: float | None = None, count: int | None = None) -> Branch:
    """Resample a polyline and its radii by arc length: every ``step_m`` (tip included) or at
    ``count`` evenly spaced positions."""
    points, radii = branch
    segment = np.linalg.norm(np.diff(points, axis=0), axis=1)
    keep = np.concatenate([[True], segment > 0.0])  # np.interp needs increasing arc lengths
    points, radii = points[keep], radii[keep]
    arc = np.concatenate([[0.0], np.cumsum(segment[segment > 0.0])])
    total = arc[-1]
    if total == 0.0:
        return points[:1], radii[:1]
    if count is not None:
        positions = np.linspace(0.0, total, count)
    else:
        positions = np.append(np.arange(0.0, total, step_m), total)
    columns = np.column_stack([points, radii])
    resampled = np.column_stack([np.interp(positions, arc, c) for c in columns.T])
    return resampled[:, :3], resampled[:, 3]


def _primary_errors(
    model_primary: Branch | None, index: TruthIndex, config: MetricsConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(K,) residuals and (K,) radius errors of the reconstructed primary points in the band."""
    if model_primary is None or len(model_primary[0]) == 0:
        return np.zeros(0), np.zeros(0)
    points, radii = model_primary
    z = points[:, 2]
    in_band = (z > config.band_min_z_m) & (z < config.band_max_z_m)
    distance, nearest = index.primary_tree.query(points[in_band])
    return distance, radii[in_band] - index.primary[1][nearest]


def _secondary_metrics(
    reconstructed: list[Branch],
    index: TruthIndex,
    top_m: float,
    planned_m: float,
    config: MetricsConfig,
) -> dict:
    """Scope, candidates, one-to-one assignment, classes, counts and overlap errors (module
    docstring); ``top_m`` the height reached, ``planned_m`` the height planned.

    Returns:
        The secondary-branch fields of :class:`TreeMetrics`, by name.
    """
    gt, gt_samples, gt_trees = index.secondaries, index.secondary_samples, index.secondary_trees
    base_z = np.array([points[0, 2] for points, _ in gt]).reshape(len(gt))
    scope_top_m = planned_m if config.count_unreached_as_missed else top_m
    in_scope = (base_z >= config.band_min_z_m) & (base_z <= scope_top_m + config.gt_base_margin_m)
    unreached = in_scope & (base_z > top_m + config.gt_base_margin_m)
    kept = [
        i
        for i, (points, _) in enumerate(reconstructed)
        if len(points) >= 2
        and np.linalg.norm((points[-1] - points[0])[:2]) > config.min_horizontal_length_m
    ]
    scored = {}
    for i in kept:
        points, radii = reconstructed[i]
        entry = index.scored.get(id(points))
        if entry is None or entry.points is not points or entry.radii is not radii:
            entry = _score_branch(points, radii, gt, gt_trees, config)
        scored[i] = entry
    index.scored.clear()
    index.scored.update({id(entry.points): entry for entry in scored.values()})
    median_m = np.array([scored[i].median_m for i in kept]).reshape(len(kept), len(gt))
    candidate = np.isfinite(median_m)
    # Non-candidates cost more than all candidates together: the most pairs, then the least cost.
    rows, cols = linear_sum_assignment(
        np.where(candidate, median_m, 1.0 + median_m[candidate].sum())
    )
    paired = candidate[rows, cols]
    rows, cols = rows[paired], cols[paired]

    matches = sorted((int(j), kept[r]) for r, j in zip(rows, cols, strict=True) if in_scope[j])
    classes = ["short"] * len(reconstructed)
    assigned = dict(zip(rows.tolist(), cols.tolist(), strict=True))
    for r, i in enumerate(kept):
        if r in assigned:
            classes[i] = "match" if in_scope[assigned[r]] else "out_of_scope"
        elif np.any(candidate[r] & in_scope):
            classes[i] = "duplicate"
        elif np.any(candidate[r]):
            classes[i] = "out_of_scope"
        else:
            classes[i] = _surrounding_class(scored[i].samples[0], index, config)
    n_duplicates = classes.count("duplicate")
    n_spurious = classes.count("spurious")
    matched_gt = [j for j, _ in matches]
    residuals, radius_errors, completeness, pair_residuals = _pair_errors(
        matches, scored, gt_samples, gt_trees, config.completeness_tolerance_m
    )
    return {
        "gt_in_scope": in_scope,
        "match_completeness": completeness,
        "match_residual_m": pair_residuals,
        "sb_residuals_m": residuals,
        "sb_radius_errors_m": radius_errors,
        "matches": matches,
        "n_gt": int(in_scope.sum()),
        "n_matched": len(matches),
        "n_missed": int(in_scope.sum()) - len(matches),
        "n_spurious": n_spurious,
        "n_duplicates": n_duplicates,
        "n_ignored_reconstructed": classes.count("short") + classes.count("out_of_scope"),
        "reconstructed_classes": classes,
        "n_unreached": int(np.sum(unreached)) - int(np.sum(unreached[matched_gt])),
        "n_unreached_matched": int(np.sum(unreached[matched_gt])),
    }


def _surrounding_class(samples: np.ndarray, index: TruthIndex, config: MetricsConfig) -> str:
    """The surrounding kind whose structures lie closest (median distance of ``samples``, (N, 3)
    in metres) within ``config.surroundings_max_median_distance_m``, or "spurious"."""
    best, best_m = "spurious", config.surroundings_max_median_distance_m
    for kind in SURROUNDING_KINDS:
        tree = index.surroundings.get(kind)
        if tree is None:
            continue
        median_m = float(np.median(tree.query(samples)[0]))
        if median_m < best_m:
            best, best_m = kind, median_m
    return best


def _score_branch(
    points: np.ndarray,
    radii: np.ndarray,
    gt: list[Branch],
    gt_trees: list[cKDTree],
    config: MetricsConfig,
) -> _ScoredBranch:
    """Resample a reconstructed secondary; its median distance to each GT branch it is a
    candidate for (direction within ``max_match_angle_deg``, median below
    ``max_match_median_distance_m``), inf for the others."""
    samples = _resample((points, radii), step_m=config.secondary_resample_step_m)
    median_m = np.full(len(gt), np.inf)
    max_angle_rad = np.radians(config.max_match_angle_deg)
    direction = points[-1] - points[0]
    for j, (gt_points, _) in enumerate(gt):
        if _angle_rad(direction, gt_points[-1] - gt_points[0]) > max_angle_rad:
            continue
        distance_m = np.median(gt_trees[j].query(samples[0])[0])
        if distance_m < config.max_match_median_distance_m:
            median_m[j] = distance_m
    return _ScoredBranch(points, radii, samples, median_m)


def _pair_errors(
    matches: list[tuple[int, int]],
    scored: dict[int, _ScoredBranch],
    gt_samples: list[Branch],
    gt_trees: list[cKDTree],
    tolerance_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Overlap errors of all matched pairs, and per pair its completeness and mean residual.

    The overlap of a pair is the reconstructed samples whose nearest GT sample is neither end of
    the GT branch; a GT sample is covered when a reconstructed sample lies within
    ``tolerance_m``.

    Returns:
        (L,) overlap residuals, (L,) radius errors, (P,) completeness in [0, 1], (P,) mean
        residuals (NaN without overlap).
    """
    residuals, radius_errors = [np.zeros(0)], [np.zeros(0)]
    completeness, pair_residual = np.zeros(len(matches)), np.full(len(matches), np.nan)
    for k, (j, i) in enumerate(matches):
        entry = scored[i]
        if j not in entry.pairs:
            points, radii = entry.samples
            gt_points, gt_radii = gt_samples[j]
            distance, nearest = gt_trees[j].query(points)
            inside = (nearest > 0) & (nearest < len(gt_points) - 1)
            mean_m = float(np.mean(distance[inside])) if inside.any() else np.nan
            covered = float(np.mean(cKDTree(points).query(gt_points)[0] <= tolerance_m))
            entry.pairs[j] = (
                distance[inside],
                radii[inside] - gt_radii[nearest[inside]],
                covered,
                mean_m,
            )
        pair_distance, pair_radius_errors, completeness[k], pair_residual[k] = entry.pairs[j]
        residuals.append(pair_distance)
        radius_errors.append(pair_radius_errors)
    return np.concatenate(residuals), np.concatenate(radius_errors), completeness, pair_residual


def _angle_rad(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in radians between two non-zero 3-vectors."""
    cosine = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.arccos(np.clip(cosine, -1.0, 1.0)))


def _float_to_json(value: float) -> float | str:
    """A finite float as is; NaN and infinities as "nan", "inf", "-inf" (``float`` reads them)."""
    return value if math.isfinite(value) else str(value)


def _array_from_json(values: list[float | str]) -> np.ndarray:
    return np.array([float(v) for v in values], dtype=float)


def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


def _std(values: np.ndarray) -> float:
    return float(np.std(values)) if len(values) else float("nan")


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")
