"""Parameters of the 3D modeler, with the paper's values as defaults.

Every threshold cites its source: the paper (section IV) or ``reference.md`` (which also records
where the authors' code differs).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

from recon.validation import require_positive

# ModelerConfig.secondary_min_reach_m for a learned segmenter's masks (ours): the largest reach
# that left every policy's missed branches unchanged on 30 validation trees of the orchard world
# from pixels (seeds 10,000,000+, never the tables'), re-scored from the saved models. Spurious:
# none 70.6 -> 45.6 %, periodic 22.5 deg / 1.5 109 -> 86 %, 45 deg / 1.5 157 -> 120 %; 3.5 cm
# cost 45 deg / 1.5 one of 61 branches (docs/results/orchard.md, "Short false side branches").
# Tall spindle: no branch lost. UFO: one of 64-66 lost under none and 22.5 deg / 1.5 (steep
# thin side branches reach little): there, 0 keeps every branch.
LEARNED_MASK_MIN_REACH_M = 0.03


@dataclass(frozen=True)
class ModelerConfig:
    """Thresholds and schedules of :class:`recon.modeler.Modeler`.

    Attributes:
        iteration_spacing_m: Camera motion between modeling iterations (paper IV: 10 mm).
        tracking_frames: Frames per tracking window, M (paper IV-C: M = 8).
        tracking_spacing_m: Camera motion between stored tracking frames (paper IV-C: 1.0 mm;
            the authors' code: 7.5 mm / 8).
        consistency_min_fraction: Fraction of projected model points that must land in the mask
            and near the 2D curve (paper IV: 60 %).
        consistency_tolerance_px: Distance to the 2D curve for a consistent point (paper IV: 4 px;
            the authors' code used 25 px).
        primary_max_turn_deg: A 2D primary that agrees with the model's projection but leaves
            it at a larger angle beyond the model's last visible point is never chosen
            (:meth:`recon.curve2d.primary.PrimaryPrior.turns_away`; ours: where an occluder
            cuts the primary's mask, the path through the model's pixels into a side branch
            or a crossing branch took the scan off the trunk). With a limit, when the only
            agreeing path is the model's stub below a cut, too short to be a primary, the best
            path that does not turn off the model is taken (:func:`recon.curve2d.fit.
            fit_mask_curves`): the modeler restarts on it. Ours: 30 degrees, fixed on validation
            trees (``docs/results/orchard.md``); None: no limit (the paper's rule).
        primary_model_vouches: A 2D primary that agrees with the model's projection needs only
            ``Curve2DConfig.min_primary_length_px``, not the elongation and view-span tests that
            keep a blob from starting a model (ours: an occluder across a thick trunk, e.g. a
            tall spindle's, leaves pieces shorter than four diameters; with no primary for 20
            iterations the scan was lost). Ours: True; False: the paper's rule.
        restart_after_inconsistent: The n-th Inconsistent in a row is a Restart (paper IV: 3rd).
        max_depth_m: Lifted points deeper than this are dropped (paper IV: 1 m).
        max_reprojection_px: Lifted points with a larger reprojection error are dropped
            (paper IV: 4 px).
        ransac_inlier_m: RANSAC inlier threshold for the 3D Bezier fit (paper IV: 3 cm).
        ransac_min_inlier_fraction: Below this inlier fraction the frame is Inconsistent
            (paper IV: 60 %).
        ransac_iterations: RANSAC hypotheses per fit (our choice: enough for 40 % outliers).
        min_lifted_points: Fewest lifted points to (re)initialise the primary (our choice: a cubic
            needs 4; one more gives RANSAC a check).
        primary_depth_gate_m: Newly lifted primary points farther than this in camera depth
            from the model's primary where it agrees with the mask are dropped before the refit
            (ours: the RANSAC inlier distance; a side branch pointing at the camera covers the
            trunk in the mask and was lifted as primary; 0 disables).
        primary_front_depth_gate_m: The same gate for points in front of the model (nearer the
            camera), and for steps toward the camera beyond it (ours, measured: at 3 cm a branch
            approaching the camera over the trunk still pulled the primary 3-5 cm toward it,
            seeds 18 and 130, at 1.5 cm no longer; behind the model the gate stays at 3 cm).
            0 uses ``primary_depth_gate_m``.
        primary_spacing_px: Target spacing of model points when projected (paper IV: ~30 px).
        image_margin_px: Model points are "visible" when projected this far inside the image
            (reference.md: the 2D stage drops pixels within 10 px of the border).
        radius_from_paper_formula: Use the paper's r = z r_px / f (True) or its first-order
            correction for the depth of the silhouette, r = z r_px / (f - r_px) (False, default:
            the surface point is r nearer than the axis).
        connection_distance_m: A new secondary must point within this of the primary centerline
            (paper IV: 3 cm).
        connection_ray_length_m: How far back from its start a secondary's ray is followed (our
            choice: the longest secondary is 15 cm, reference.md).
        secondary_junction_px: A detection that fails the connection test connects at its 2D
            candidate's junction when the model's primary projects within this of it (ours:
            twice ``consistency_tolerance_px``; the skeleton's junction node sits a few pixels
            off the axis toward the branch).
        secondary_junction_on_mask: ... and when at least this fraction of the straight run from
            that junction to the first lifted point projects onto the mask (ours).
        secondary_min_points: Fewest lifted points to create a secondary (our choice).
        secondary_merge_distance_m: A detection whose samples lie (median) this close to a model
            secondary is the same branch (our choice: half the metric's 2 cm match radius); the
            median is taken from the shorter of the two onto the longer, so that a detection
            seeing more of a branch than the model holds still joins it.
        secondary_merge_angle_deg: ... and whose direction differs by at most this (our choice).
        secondary_min_view_angle_deg: A secondary detection whose base-to-tip direction lies closer
            than this to the viewing ray is dropped: seen end-on, its depth along the branch is
            ill-conditioned and lifted tips overshoot (measured: after 45 deg rotations, branches
            pointing away from the camera came out up to 4x too long). 0 disables it, the default:
            at 30 deg it removed 2 of 5 spurious branches with periodic:45:1.5 but cost 3 of 29
            detections without rotation on 12 trees.
        secondary_max_foreshortening: A lifted secondary is cut before the first step between
            samples that is longer in 3D than this times its image length at its depth, i.e. a
            branch receding within asin(1/6) ~ 10 deg of the viewing ray (our choice, measured:
            lifted tips of receding branches otherwise stretched branches up to 4x; the former
            3, ~19 deg, cut correctly lifted branches receding at 15-25 deg from the viewing
            ray, measured ratios 3.2-3.8 on seed 105, and dropped them).
        secondary_extend_to_junction: Report each secondary from its junction on the primary
            (where its connection ray met it) to its first observed point (ours: the base of a
            side branch is hidden by the primary's silhouette, and for receding branches over
            several cm; off, secondaries start where the first lifted sample is).
        secondary_trust_min: A secondary whose trust falls below this is deleted (the authors'
            code kept a trust score, reference.md; threshold our choice).
        secondary_trust_tolerance_px: A secondary's projected point counts as on the mask for its
            trust when a mask pixel lies within this distance; 0 is the pixel itself (the
            authors' code). None (the default) is resolved by :meth:`for_masks` where the mask
            source is known: 0 for exact masks (the renderer's labels, recorded masks) and
            ``consistency_tolerance_px`` (paper IV's 4 px) for a learned segmenter's. A learned
            mask cuts a thin side branch short or a few pixels narrow, most of all in the
            rotated views, whose model then projects beside it: the branch lost trust there and
            was deleted although found (measured, orchard world from pixels, periodic 22.5 deg
            / 1.5, 30 validation trees, seeds 10,000,000+, replayed on the recorded masks:
            missed 8 of 68 branches at 0 px, 3 at 2 px, 2 at 4 and 6 px; spurious 110 -> 119 %.
            On the renderer's labels of the same trees 4 px missed 3 instead of 2 and kept more
            spurious branches, 82 -> 96 %: exact masks keep 0). A Modeler given None uses 0.
        secondary_order_from_junction: Order a secondary's observations for its curve fit by
            their distance from its junction on the primary (where it has one) instead of from
            its first detection's first point (ours; off reproduces the tables before commit
            2045f15). A branch first lifted in its outer part and extended toward the trunk by
            later views has that point mid-branch, where distance interleaves the inner and
            outer observations and the cubic fit folds (measured, seed 16: every observation
            within 4.3 mm of the branch, the fit 61 mm off). On the 60 benchmark trees: periodic
            45 deg / 1.5 missed 5.2 -> 0.6 %, the v2 student 2.6 -> 1.3 %, no rotation unchanged.
        secondary_confirmations: Observations a secondary needs to be reported (our choice:
            1 keeps the paper's behaviour of reporting every connected detection).
        secondary_min_reach_m: A secondary is reported only while its base-to-tip vector reaches
            at least this far out from the primary (its part perpendicular to the primary's
            base-to-top direction). 0 reports every secondary, as the paper. None (the default)
            is resolved by :meth:`for_masks`: 0 for exact masks, and
            ``LEARNED_MASK_MIN_REACH_M`` for a learned segmenter's, whose masks add short false
            side branches along the trunk (spurs, a neighbour's twig, the mask's ragged edge).
            The authors' evaluation already ignores reconstructed branches shorter than 2.5 cm
            horizontally (reference.md, "Evaluation"); the generator's secondaries are 5 cm or
            longer, and a reported one starts at its junction on the primary's axis. Measured:
            ``LEARNED_MASK_MIN_REACH_M``'s comment.
        secondary_max_observations: Most raw lifted points kept per secondary (memory bound).
        secondary_sample_spacing_m: Spacing of the reported secondary centerline points.
    """

    iteration_spacing_m: float = 0.010
    tracking_frames: int = 8
    tracking_spacing_m: float = 0.001
    consistency_min_fraction: float = 0.6
    consistency_tolerance_px: float = 4.0
    primary_max_turn_deg: float | None = 30.0  # ours (docs/results/orchard.md, lost scans)
    primary_model_vouches: bool = True  # ours (docs/results/orchard.md, lost scans)
    restart_after_inconsistent: int = 3
    max_depth_m: float = 1.0
    max_reprojection_px: float = 4.0
    ransac_inlier_m: float = 0.03
    ransac_min_inlier_fraction: float = 0.6
    ransac_iterations: int = 40
    min_lifted_points: int = 5
    primary_depth_gate_m: float = 0.03
    primary_front_depth_gate_m: float = 0.015
    primary_spacing_px: float = 30.0
    image_margin_px: float = 10.0
    radius_from_paper_formula: bool = False
    connection_distance_m: float = 0.03
    connection_ray_length_m: float = 0.15
    secondary_junction_px: float = 8.0
    secondary_junction_on_mask: float = 0.9
    secondary_min_points: int = 3
    secondary_merge_distance_m: float = 0.01
    secondary_merge_angle_deg: float = 45.0
    secondary_min_view_angle_deg: float = 0.0
    secondary_max_foreshortening: float = 6.0
    secondary_extend_to_junction: bool = True
    secondary_trust_min: int = -2
    secondary_trust_tolerance_px: float | None = None
    secondary_order_from_junction: bool = True
    secondary_confirmations: int = 1
    secondary_min_reach_m: float | None = None
    secondary_max_observations: int = 400
    secondary_sample_spacing_m: float = 0.005

    def __post_init__(self) -> None:
        not_positive = (
            "primary_max_turn_deg",
            "secondary_min_reach_m",
            "secondary_trust_min",
            "secondary_trust_tolerance_px",
            "secondary_min_view_angle_deg",
            "primary_depth_gate_m",
            "primary_front_depth_gate_m",
        )
        positive = [
            f.name
            for f in fields(self)
            if f.name not in not_positive and not isinstance(getattr(self, f.name), bool)
        ]
        require_positive(self, *positive, finite=False)
        for name in (
            "consistency_min_fraction",
            "ransac_min_inlier_fraction",
            "secondary_junction_on_mask",
        ):
            if getattr(self, name) > 1:
                raise ValueError(f"ModelerConfig.{name} is a fraction in (0, 1]")
        for name in ("primary_depth_gate_m", "primary_front_depth_gate_m"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"ModelerConfig.{name} must be >= 0")
        reach = self.secondary_min_reach_m
        if reach is not None and not (isinstance(reach, (int, float)) and 0.0 <= reach < math.inf):
            raise ValueError(
                "ModelerConfig.secondary_min_reach_m must be a finite number >= 0 or None "
                f"(resolved by the mask source), got {reach!r}"
            )
        turn = self.primary_max_turn_deg
        if turn is not None and not (isinstance(turn, (int, float)) and 0.0 < turn < 180.0):
            raise ValueError(
                "ModelerConfig.primary_max_turn_deg must be in (0, 180) degrees or None (no "
                f"limit), got {turn!r}"
            )
        tolerance = self.secondary_trust_tolerance_px
        if tolerance is not None and not tolerance >= 0.0:
            raise ValueError(
                "ModelerConfig.secondary_trust_tolerance_px must be >= 0 or None (resolved by the "
                f"mask source), got {tolerance!r}"
            )
        if not 0.0 <= self.secondary_min_view_angle_deg < 90.0:
            raise ValueError("ModelerConfig.secondary_min_view_angle_deg must be in [0, 90)")
        if self.tracking_frames < 2:
            raise ValueError("ModelerConfig.tracking_frames must be at least 2 to triangulate")
        window_m = (self.tracking_frames - 1) * self.tracking_spacing_m
        if window_m > self.iteration_spacing_m:
            raise ValueError(
                "ModelerConfig: the tracking window (tracking_frames - 1) * tracking_spacing_m "
                f"= {window_m} m must fit within iteration_spacing_m = {self.iteration_spacing_m} m"
            )

    def for_masks(self, learned: bool) -> ModelerConfig:
        """This config with the settings that depend on its mask source resolved.

        ``secondary_trust_tolerance_px`` and ``secondary_min_reach_m``, where None.

        Args:
            learned: The masks come from a learned segmenter (else exact: the renderer's labels,
                recorded masks).

        Returns:
            ``self`` when both are set; else a copy with the tolerance 0 px (exact masks) or
            ``consistency_tolerance_px`` (learned masks), and the reach 0 (exact masks) or
            ``LEARNED_MASK_MIN_REACH_M`` (learned masks).
        """
        resolved: dict[str, float] = {}
        if self.secondary_trust_tolerance_px is None:
            resolved["secondary_trust_tolerance_px"] = (
                self.consistency_tolerance_px if learned else 0.0
            )
        if self.secondary_min_reach_m is None:
            resolved["secondary_min_reach_m"] = LEARNED_MASK_MIN_REACH_M if learned else 0.0
        return replace(self, **resolved) if resolved else self


@dataclass(frozen=True)
class RemovedField:
    """A :class:`ModelerConfig` field that is gone; a setting of it is refused, naming it.

    Attributes:
        value: The value every published result ran with: today's code behaves as it did (trial
            hashes count the field at this value, ``branch_gym.evaluation.trials.config_hash``).
        why: Why it went.
    """

    value: object
    why: str


_DROPPED_TRUST = "a dropped experiment: docs/results/history.md, 'Trust options'"
REMOVED_MODELER_FIELDS: dict[str, RemovedField] = {
    "model_reprojection_px": RemovedField(4.0, "nothing read it"),
    "primary_sample_spacing_m": RemovedField(0.005, "nothing read it"),
    "secondary_trust_in_view": RemovedField(0.0, _DROPPED_TRUST),
    "secondary_trust_redetected": RemovedField(False, _DROPPED_TRUST),
}
"""Field name -> what it was, for the settings and recordings that still name it."""


def removed_field_message(name: str) -> str:
    """Why a setting of the removed ModelerConfig field ``name`` is not taken."""
    removed = REMOVED_MODELER_FIELDS[name]
    return (
        f"ModelerConfig field {name!r} was removed ({removed.why}); the modeler runs as it did "
        f"at {name}={json.dumps(removed.value)}"
    )


def add_modeler_argument(parser: argparse.ArgumentParser, example: str) -> None:
    """Add ``--modeler FIELD=VALUE ...`` to a command line (read it with :func:`modeler_overrides`).

    Args:
        parser: The command's parser.
        example: What the settings apply over, with an example, for the help text.
    """
    parser.add_argument(
        "--modeler",
        nargs="+",
        default=[],
        metavar="FIELD=VALUE",
        help=f"reconstruction settings (recon.config.ModelerConfig fields, JSON values) {example}",
    )


def modeler_overrides(items: Sequence[str]) -> dict[str, object]:
    """``KEY=VALUE`` strings (command lines) as ModelerConfig field values.

    Args:
        items: Each ``FIELD=VALUE`` with VALUE in JSON (``4``, ``0.5``, ``true``, ``null``).

    Returns:
        Field name -> value, for ``dataclasses.replace(config, **overrides)`` (which validates).

    Raises:
        ValueError: An item without ``=``, a removed field (:data:`REMOVED_MODELER_FIELDS`,
            named as removed), an unknown field (the message lists them) or a value that is not
            JSON.
    """
    known = {f.name for f in fields(ModelerConfig)}
    overrides: dict[str, object] = {}
    for item in items:
        key, value = parse_setting(item, "modeler setting")
        if key in REMOVED_MODELER_FIELDS:
            raise ValueError(f"modeler setting {item!r}: {removed_field_message(key)}")
        if key not in known:
            raise ValueError(
                f"unknown ModelerConfig field {key!r}; fields: {', '.join(sorted(known))}"
            )
        overrides[key] = value
    return overrides


def parse_setting(item: str, what: str) -> tuple[str, object]:
    """One ``NAME=VALUE`` string of a command line, VALUE in JSON (``4``, ``0.5``, ``true``,
    ``null``, ``Infinity``).

    Args:
        item: The string.
        what: What it is, for the error message (``"modeler setting"``).

    Returns:
        (NAME, the value).

    Raises:
        ValueError: no ``=``, or a value that is not JSON (both name ``what`` and ``item``).
    """
    key, sep, text = item.partition("=")
    if not sep:
        raise ValueError(f"{what} {item!r} is not FIELD=VALUE")
    try:
        return key, json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{what} {item!r}: {text!r} is not a JSON value") from error
