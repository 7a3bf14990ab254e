"""One saved trial: what a scan produced, as a strict-JSON file that can be re-aggregated.

A trial file ``OUT/trials/<policy-slug>/<seed>.json`` holds the scan's flat row (for
``trials.csv``), the full metrics (lossless, :meth:`recon.metrics.TreeMetrics.to_json_dict`), the
reconstruction and the ground truth (for the figures), the hash of the scan configuration it
was run with and the version of the code that ran it (:func:`code_version`). Files are written
atomically (temporary file, then rename): a killed run leaves either a whole trial file or none.

Non-finite floats are written as the strings ``"nan"``, ``"inf"`` and ``"-inf"`` (strict JSON;
``float()`` reads them back, and ``csv`` writes a float NaN as ``nan`` too).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import math
import re
import subprocess
from dataclasses import asdict, dataclass, field, is_dataclass, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from branch_gym.attribution import branch_rows, miss_counts
from branch_gym.files import PARTIAL_WRITE_GLOB, write_json_atomic
from branch_gym.scoring import OUTCOME_PREFIX, STAGE_PREFIX, ScanResult
from branch_gym.sim.tree.ground_truth import TreeGT
from branch_gym.surroundings import surroundings_from_json, surroundings_to_json
from recon.config import REMOVED_MODELER_FIELDS
from recon.metrics import MetricsConfig, TreeMetrics, evaluate
from recon.model import TreeModel

# 2: the structures around the tree and the planned top height are saved, the metrics class
# every reconstructed side branch (recon.metrics); format-1 files predate the classes.
TRIAL_FORMAT = 2
TRIALS_DIR = "trials"
PACKAGE = "branch_gym"  # the distribution whose version names the code outside a git checkout
GIT_TIMEOUT_S = 10.0
Scalar = float | int | str | bool | None


@dataclass
class TrialRecord(ScanResult):
    """A finished trial as saved and reloaded: the scan's :class:`~branch_gym.scoring.ScanResult`
    and where it came from.

    The scan's fields are :class:`~branch_gym.scoring.ScanResult`'s, as saved: ``policy`` the
    spec exactly as given on the command line; ``truth`` without its background clutter (not
    scored, not plotted); ``branches`` with non-finite floats as strings; ``stop_reason``,
    ``n_iterations``, ``outcomes``, ``stage_ms`` and ``wall_time_s`` read back from the row.
    ``surroundings``, with ``model``, ``truth`` and the heights, is all that :meth:`rescored`
    needs.

    Attributes:
        config_hash: :func:`config_hash` of the scan configuration the trial ran with.
        row: The scan's flat row as saved (``ScanResult.to_row()``, the policy as given),
            non-finite floats as strings.
        code_version: :func:`code_version` of the code that ran the trial; None in trial files
            written before it was recorded.
    """

    config_hash: str = field(kw_only=True)
    row: dict[str, Scalar] = field(kw_only=True)
    code_version: str | None = field(default=None, kw_only=True)

    def to_row(self) -> dict:
        """The flat row as saved."""
        return dict(self.row)

    @classmethod
    def from_scan(
        cls, result: ScanResult, policy: str, config_hash: str, code_version: str | None = None
    ) -> TrialRecord:
        """Build a record from a scan's result.

        Args:
            result: The scan's result.
            policy: The policy spec as requested (the row's ``policy`` is set to it).
            config_hash: Hash of the scan configuration it ran with.
            code_version: The code that ran it (:func:`code_version`), if known.
        """
        truth = result.truth
        row = {str(k): json_scalar(v) for k, v in result.to_row().items()}
        row["policy"] = policy
        return cls(
            policy=policy,
            seed=int(result.seed),
            config_hash=config_hash,
            row=row,
            metrics=result.metrics,
            model=result.model,
            truth=TreeGT(truth.primary, list(truth.secondaries), [], truth.seed),
            scan_time_s=float(result.scan_time_s),
            rotations=int(result.rotations),
            failure=None if result.failure is None else str(result.failure),
            **_row_facts(row),
            branches=[{k: json_scalar(v) for k, v in row.items()} for row in result.branches],
            code_version=code_version,
            surroundings=result.surroundings,
            planned_top_z_m=float(result.planned_top_z_m),
        )

    def rescored(self, config: MetricsConfig) -> TrialRecord:
        """The same trial scored again under ``config``, without re-running the scan.

        The metrics, the row's metric columns and the branch rows are recomputed from the saved
        model, ground truth, surroundings and heights (the views' visibility as saved).
        """
        metrics = evaluate(
            self.model,
            self.truth,
            config,
            scanned_top_z_m=self.metrics.scanned_top_z_m,
            surroundings=self.surroundings,
            planned_top_z_m=self.planned_top_z_m,
        )
        row = dict(self.row)
        row.update({str(k): json_scalar(v) for k, v in metrics.to_dict().items()})
        visibility = SimpleNamespace(
            peak_pixels=np.array([int(b["peak_visible_px"]) for b in self.branches], int),
            peak_view_angle_deg=np.array(
                [float(b["peak_view_angle_deg"]) for b in self.branches], float
            ),
        )
        rows = branch_rows(self.truth, metrics, visibility) if self.branches else []
        row.update(miss_counts(rows))
        return replace(
            self,
            metrics=metrics,
            row=row,
            branches=[{k: json_scalar(v) for k, v in r.items()} for r in rows],
        )

    def to_json_dict(self) -> dict:
        """Strict-JSON form (passes ``json.dumps(..., allow_nan=False)``)."""
        return {
            "format": TRIAL_FORMAT,
            "policy": self.policy,
            "seed": self.seed,
            "config_hash": self.config_hash,
            "scan_time_s": json_scalar(self.scan_time_s),
            "rotations": self.rotations,
            "failure": self.failure,
            "row": self.row,
            "metrics": self.metrics.to_json_dict(),
            "model": self.model.to_dict(),
            "truth": self.truth.to_dict(),
            "branches": self.branches,
            "code_version": self.code_version,
            "surroundings": surroundings_to_json(self.surroundings),
            "planned_top_z_m": json_scalar(self.planned_top_z_m),
        }

    @classmethod
    def from_json_dict(cls, data: dict) -> TrialRecord:
        """Inverse of :meth:`to_json_dict`."""
        if data.get("format") == 1:
            raise ValueError(
                "trial file format 1 was written before the classes of reconstructed side "
                "branches (spurs, neighbours, trellis, nothing there) and carries no surroundings"
            )
        if data.get("format") != TRIAL_FORMAT:
            raise ValueError(f"unknown trial file format {data.get('format')!r}")
        return cls(
            policy=str(data["policy"]),
            seed=int(data["seed"]),
            config_hash=str(data["config_hash"]),
            row=dict(data["row"]),
            **_row_facts(data["row"]),
            metrics=TreeMetrics.from_json_dict(data["metrics"]),
            model=TreeModel.from_dict(data["model"]),
            truth=TreeGT.from_dict(data["truth"]),
            scan_time_s=float(data["scan_time_s"]),
            rotations=int(data["rotations"]),
            failure=data["failure"],
            branches=list(data.get("branches", [])),
            code_version=data.get("code_version"),
            surroundings=surroundings_from_json(data["surroundings"]),
            planned_top_z_m=float(data["planned_top_z_m"]),
        )


def _row_facts(row: dict[str, Scalar]) -> dict[str, Any]:
    """The scan's facts that a trial file keeps only in its row (:meth:`ScanResult.to_row`):
    ``stop_reason``, ``n_iterations``, ``outcomes``, ``stage_ms``, ``wall_time_s`` (empty or
    NaN where a row lacks them)."""
    return {
        "stop_reason": str(row.get("stop_reason") or ""),
        "n_iterations": int(row.get("n_iterations") or 0),
        "outcomes": {
            k.removeprefix(OUTCOME_PREFIX): int(v)
            for k, v in row.items()
            if k.startswith(OUTCOME_PREFIX)
        },
        "stage_ms": {
            k.removeprefix(STAGE_PREFIX): float(v)
            for k, v in row.items()
            if k.startswith(STAGE_PREFIX)
        },
        "wall_time_s": float(row.get("wall_time_s", "nan")),
    }


@functools.cache
def code_version() -> str | None:
    """The version of the code that runs trials, as a trial file records it.

    A trial is a pure function of its seed, policy and scan configuration only for one version
    of the code: saved trials are reused under the same configuration hash, so a changed code
    path would otherwise mix old and new trials silently (the evaluation warns instead).

    Returns:
        ``"git:<commit>"`` (``git describe --always --dirty``: ``-dirty`` when tracked files
        differ from the commit) when the package runs from a git checkout, else
        ``"package:<version>"`` of the installed distribution; None when neither is known.
    """
    root = Path(__file__).resolve().parents[2]
    if (root / ".git").exists():
        try:
            described = subprocess.run(
                ["git", "describe", "--always", "--dirty", "--abbrev=12"],
                cwd=root,
                capture_output=True,
                text=True,
                timeout=GIT_TIMEOUT_S,
                check=True,
            ).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            described = ""
        if described:
            return f"git:{described}"
    try:
        return f"package:{importlib.metadata.version(PACKAGE)}"
    except importlib.metadata.PackageNotFoundError:
        return None


def json_scalar(value: Any) -> Scalar:
    """A row value as a strict-JSON scalar: numpy scalars unwrapped, non-finite floats as strings.

    Raises:
        TypeError: not a scalar (lists and dicts do not belong in a flat row).
    """
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        value = float(value)
        return value if math.isfinite(value) else str(value)
    raise TypeError(f"row values must be scalars, got {type(value).__name__}: {value!r}")


def policy_slug(policy: str) -> str:
    """Directory name for a policy spec: ``periodic:22.5:1.5`` -> ``periodic_22.5_1.5``."""
    return re.sub(r"[^A-Za-z0-9.\-]+", "_", policy).strip("_") or "_"


def trial_path(out: Path, policy: str, seed: int) -> Path:
    """Where the trial of ``policy`` on tree ``seed`` is saved."""
    return out / TRIALS_DIR / policy_slug(policy) / f"{seed}.json"


# ScanConfig.curve2d (recon.curve2d.types.Curve2DConfig) as every scan ran it before the 2D stage
# was a scan setting (December 2026): a literal, so that a changed default of the 2D stage hashes
# apart (and changes a benchmark's digest, benchmark.SCAN_FIELDS_ADDED_SINCE). A field added to
# Curve2DConfig later gets its earlier value here.
CURVE2D_BEFORE_SCAN_FIELD = {
    "crossing_level_px": 4.0,
    "extend_secondary_tips": True,
    "inlier_threshold_px": 4.0,
    "max_primary_paths": 100,
    "max_primary_turn_deg": "inf",  # config_to_dict's form of math.inf
    "max_secondary_bend_deg": 120.0,
    "max_secondary_paths": 100,
    "max_spanning_width": 0.5,
    "min_primary_elongation": 4.0,
    "min_primary_length_px": 40.0,
    "min_samples": 3,
    "min_secondary_inlier_fraction": 0.8,
    "min_secondary_length_px": 20.0,
    "motion_direction_uv": [0.0, -1.0],
    "primary_view_span": 0.9,
    "radius_fence_iqr": 1.5,
    "sample_spacing_px": 30.0,
    "score": "unique_rows",
    "secondary_min_samples": 7,
    "secondary_sample_spacing_px": 10.0,
    "skeleton": {
        "border_extension_px": 32,
        "border_px": 10,
        "bridge_max_angle_deg": 30.0,
        "bridge_min_length_px": 20.0,
        "bridge_tangent_px": 12.0,
        "max_gap_px": 6.0,
        "max_hole_area_px": 300,
        "medial_axis_seed": 0,
        "method": "skeletonize",
        "occlusion_gap_radii": 2.0,
        "occlusion_max_angle_deg": 15.0,
        "occlusion_min_elongation": 2.0,
        "occlusion_wide_ends": True,
        "occlusion_width_ratio": 1.5,
        "radius_offset_px": 0.5,
        "spur_prune_factor": 1.5,
    },
    "spanning_min_inlier_fraction": 0.95,
    "tip_extension_radii": 2.0,
    "tip_tangent_px": 10.0,
}

# Fields added after results were published, by dotted path into the config, with the value that
# reproduces the earlier behaviour. ScanConfig.render_tracking_frames (the fast oracle mode):
# True renders every frame, as every scan did before it existed.
# ModelerConfig.secondary_trust_redetected: False is the rule every table was measured with.
# ScanConfig.frame_pairing (FramePairingConfig's defaults): only flow-picture segmenters read it.
HASH_NEUTRAL_DEFAULTS = {
    "render_tracking_frames": True,
    "frame_pairing": {
        "min_translation_m": 0.0075,
        "max_rotation_deg": 0.5,
        "history_travel_m": 0.05,
        "max_history_frames": 128,
    },
    "modeler.secondary_trust_redetected": False,
    "modeler.secondary_trust_tolerance_px": 0.0,  # hashed resolved (ScanConfig.modeler_config)
    "modeler.secondary_min_reach_m": 0.0,  # hashed resolved (ScanConfig.modeler_config)
    "modeler.primary_max_turn_deg": None,
    "modeler.primary_model_vouches": False,
    "world.orchard": None,
    "world.tree.architecture": "paper",
    "world.tree.primary_base_height_m": 0.0,
    # Issue 60's leader stretch and the orchard's cheaper pixels: off, today's scans.
    "world.tree.alley_side_reach_m": None,
    "world.tree.alley_side_half_angle_deg": 70.0,
    "world.orchard.trellis_reach_m": None,
    "world.orchard.camera.jpeg": True,
    "orbit_holds_model": False,  # orchard-v2's fix; off: the scans before it
    "curve2d": CURVE2D_BEFORE_SCAN_FIELD,  # the 2D stage as a scan setting
}


def config_to_dict(config: Any) -> dict:
    """A (possibly nested) config dataclass as a strict-JSON-able dict: non-finite floats as the
    strings ``"inf"``, ``"-inf"`` and ``"nan"`` (as trial files write them; e.g. the 2D stage's
    ``max_primary_turn_deg``)."""
    if not is_dataclass(config):
        raise TypeError(f"expected a dataclass config, got {type(config).__name__}")
    text = json.dumps(asdict(config), sort_keys=True, default=str)
    return json.loads(text, parse_constant=lambda constant: str(float(constant)))


def config_hash(config: Any) -> str:
    """Short stable hash of a config dataclass: trials are comparable only under equal hashes.

    Fields added after results were published (``HASH_NEUTRAL_DEFAULTS``, dotted paths into
    nested configs) are left out while they hold the value that reproduces the earlier
    behaviour, and ModelerConfig fields removed since (``REMOVED_MODELER_FIELDS``) count at the
    value they always held, so that saved trials stay valid.
    """
    data = config_to_dict(config)
    if isinstance(data.get("modeler"), dict):
        for name, removed in REMOVED_MODELER_FIELDS.items():
            data["modeler"].setdefault(name, removed.value)
    for path, neutral in HASH_NEUTRAL_DEFAULTS.items():
        *parents, name = path.split(".")
        section = data
        for parent in parents:
            section = section.get(parent) if isinstance(section, dict) else None
        if isinstance(section, dict) and name in section and section[name] == neutral:
            del section[name]
    text = json.dumps(data, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def remove_partial_writes(out: Path) -> int:
    """Delete temporary files left by a killed run under ``out/trials``; returns how many."""
    partial = list((out / TRIALS_DIR).rglob(PARTIAL_WRITE_GLOB))
    for path in partial:
        path.unlink(missing_ok=True)
    return len(partial)


def save_trial(path: Path, record: TrialRecord) -> None:
    """Save a trial atomically."""
    write_json_atomic(path, record.to_json_dict())


def load_trial(path: Path) -> TrialRecord:
    """Load a saved trial.

    Raises:
        ValueError: the file is not a readable trial file (its path is in the message).
    """
    try:
        return TrialRecord.from_json_dict(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot read trial file {path}: {exc}; delete it to re-run it") from exc
