"""Tests of the evaluation: metrics JSON, trial files, aggregation, tables, resume, the CLI."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from agents.factory import AGENTS
from agents.paper import paper_column
from branch_gym.control import FollowControllerConfig
from branch_gym.env.reward import RewardConfig
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.plots import write_figures
from branch_gym.evaluation.report import (
    TABLE_ROWS,
    build_summary,
    format_cell,
    format_comparison,
    format_table,
    summarise_policy,
    write_report,
)
from branch_gym.evaluation.runner import (
    ConfigMismatchError,
    check_output_folder,
    load_records,
    pending_trials,
)
from branch_gym.evaluation.trials import (
    TrialRecord,
    code_version,
    config_hash,
    config_to_dict,
    json_scalar,
    load_trial,
    policy_slug,
    remove_partial_writes,
    save_trial,
    trial_path,
)
from branch_gym.scan import ScanConfig
from branch_gym.scoring import ScanResult
from branch_gym.sim.tree.ground_truth import BranchGT, TreeGT
from branch_gym.sim.world import WorldConfig
from recon.config import LEARNED_MASK_MIN_REACH_M, ModelerConfig, modeler_overrides
from recon.io.folder import ScanFolder
from recon.metrics import TreeMetrics, aggregate
from recon.model import BranchModel, TreeModel
from research.selection import score_records, select_model, trial_return

ROOT = Path(__file__).resolve().parents[1]
POLICIES = ("none", "periodic:22.5:1.5")
SUMMARY_KEYS = {
    "trials",
    "failures",
    "pb_residual_mm",
    "pb_radius_rmse_mm",
    "sb_residual_mm",
    "sb_radius_mm",
    "spurious_pct",
    "missed_pct",
    "spurious_paper_pct",
    "missed_paper_pct",
    "precision_pct",
    "classes",
    "duplicate_pct",
    "missed_seen_pct",
    "missed_never_seen_pct",
    "sb_completeness_pct",
    "misses_by_axis_angle",
    "missed_pct_ci",
    "scan_time_s_ci",
    "scan_time_s",
    "rotations",
}
MEAN_STD_KEYS = {
    "pb_residual_mm",
    "pb_radius_rmse_mm",
    "sb_residual_mm",
    "sb_radius_mm",
    "scan_time_s",
    "rotations",
}
SHORT_SCAN = ["--end-height", "0.45"]  # ~7 s of simulated scan, 1.5-3.5 s of CPU per trial


def _load_cli():
    """eval.py as a module (it is a script at the repository root, not a package)."""
    spec = importlib.util.spec_from_file_location("eval_cli", ROOT / "eval.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


eval_cli = _load_cli()


# ----------------------------------------------------------------------------- hand-made trials
def _metrics(pb_mm: list[float], sb_mm: list[float], counts: tuple[int, int, int, int]):
    """Metrics with the given residuals (mm); radius errors are a tenth of them."""
    n_gt, n_matched, n_spurious, n_duplicates = counts
    pb, sb = np.array(pb_mm) / 1e3, np.array(sb_mm) / 1e3
    return TreeMetrics(
        pb_residuals_m=pb,
        pb_radius_errors_m=pb / 10.0,
        sb_residuals_m=sb,
        sb_radius_errors_m=sb / 10.0,
        matches=[(j, j) for j in range(n_matched)],
        n_gt=n_gt,
        n_matched=n_matched,
        n_missed=n_gt - n_matched,
        n_spurious=n_spurious,
        n_duplicates=n_duplicates,
        n_ignored_reconstructed=0,
        scanned_top_z_m=0.75,
    )


def _record(
    policy: str,
    seed: int,
    metrics: TreeMetrics,
    scan_time_s: float = 20.0,
    rotations: int = 0,
    failure: str | None = None,
    config_hash: str = "h",
) -> TrialRecord:
    z = np.linspace(0.0, 1.0, 11)
    primary = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    side = np.array([[0.0, 0.0, 0.5], [0.05, 0.0, 0.52], [0.1, 0.0, 0.55]])
    truth = TreeGT(BranchGT(primary, np.full(11, 0.005)), [BranchGT(side, np.full(3, 0.004))])
    model = TreeModel(BranchModel(primary[3:8] + 0.001, np.full(5, 0.0051)), [])
    row = {"seed": seed, "policy": policy, "failure": failure or "", **metrics.to_dict()}
    return TrialRecord(
        policy=policy,
        seed=seed,
        config_hash=config_hash,
        row={k: json_scalar(v) for k, v in row.items()},
        metrics=metrics,
        model=model,
        truth=truth,
        scan_time_s=scan_time_s,
        rotations=rotations,
        failure=failure,
        stop_reason=failure or "end_height",
        n_iterations=40,
        outcomes={"consistent": 40},
        stage_ms={},
        wall_time_s=1.0,
    )


def _records() -> list[TrialRecord]:
    return [
        _record("none", 0, _metrics([1.0, 3.0], [2.0], (4, 3, 1, 0)), 18.0),
        _record("none", 1, _metrics([2.0], [], (2, 2, 0, 1)), 22.0, failure="singularity"),
        _record("periodic:22.5:1.5", 0, _metrics([4.0], [5.0], (4, 4, 0, 0)), 30.0, 4),
        _record("periodic:22.5:1.5", 1, _metrics([], [], (2, 1, 0, 0)), 34.0, 6),
    ]


def _nan_equal(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


# ----------------------------------------------------------------------------- metrics JSON
def test_tree_metrics_json_round_trip_is_lossless_and_nan_safe() -> None:
    metrics = TreeMetrics(
        pb_residuals_m=np.array([0.1 + 0.2, 1e-17, np.nan, np.inf]),
        pb_radius_errors_m=np.array([-1.0 / 3.0, -np.inf, 0.0, 2.5]),
        sb_residuals_m=np.zeros(0),
        sb_radius_errors_m=np.zeros(0),
        matches=[(0, 2), (1, 0)],
        n_gt=3,
        n_matched=2,
        n_missed=1,
        n_spurious=1,
        n_duplicates=0,
        n_ignored_reconstructed=1,
        scanned_top_z_m=0.7312345678901234,
    )
    text = json.dumps(metrics.to_json_dict(), allow_nan=False)  # strict JSON
    back = TreeMetrics.from_json_dict(json.loads(text))
    for name in ("pb_residuals_m", "pb_radius_errors_m", "sb_residuals_m", "sb_radius_errors_m"):
        np.testing.assert_array_equal(getattr(back, name), getattr(metrics, name))
    assert back.matches == metrics.matches
    # Derived fields (NaN for the empty SB arrays) and the flat row are the same.
    row, back_row = metrics.to_dict(), back.to_dict()
    assert back_row.keys() == row.keys()
    for key, value in row.items():
        assert (
            _nan_equal(back_row[key], value) if isinstance(value, float) else back_row[key] == value
        )
    assert back.scanned_top_z_m == metrics.scanned_top_z_m


def test_aggregate_of_reloaded_metrics_is_identical() -> None:
    trials = [r.metrics for r in _records()]
    reloaded = [
        TreeMetrics.from_json_dict(json.loads(json.dumps(t.to_json_dict()))) for t in trials
    ]
    original, again = aggregate(trials), aggregate(reloaded)
    assert original.keys() == again.keys()
    assert all(_nan_equal(original[k], again[k]) for k in original)


# ----------------------------------------------------------------------------- trial files
def test_trial_file_round_trip_and_atomic_write(tmp_path: Path) -> None:
    record = _records()[1]
    path = trial_path(tmp_path, record.policy, record.seed)
    save_trial(path, record)
    assert path == tmp_path / "trials" / "none" / "1.json"
    assert [p.name for p in path.parent.iterdir()] == ["1.json"]  # no temporary file left
    back = load_trial(path)
    assert back.to_json_dict() == record.to_json_dict()
    older = back.to_json_dict()
    del older["code_version"]  # trial files written before the code version was recorded
    assert TrialRecord.from_json_dict(older).code_version is None
    assert back.failure == "singularity" and back.row["sb_residual_mean_m"] == "nan"
    stale = path.with_name(".2.json.abc123.tmp")  # left by a run killed while writing
    stale.write_text("{")
    assert remove_partial_writes(tmp_path) == 1 and not stale.exists() and path.exists()
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"cannot read trial file .*1\.json"):
        load_trial(path)


def test_a_saved_trial_is_the_scan_result_it_was_made_from(tmp_path: Path) -> None:
    template = _records()[2]
    result = ScanResult(
        template.seed, "periodic:22.5:1.5", template.metrics, template.model, template.truth,
        30.0, 4, None, "end_height", 42, {"consistent": 40, "inconsistent": 2},
        {"curve2d": 3.5}, 2.0, planned_top_z_m=0.75,
    )  # fmt: skip
    record = TrialRecord.from_scan(result, "periodic:22.5:1.5", "h", "git:abc")
    path = trial_path(tmp_path, record.policy, record.seed)
    save_trial(path, record)
    back = load_trial(path)
    assert isinstance(back, ScanResult) and back.to_row() == record.row
    for name in ("stop_reason", "n_iterations", "outcomes", "stage_ms", "wall_time_s", "rotations"):
        assert getattr(back, name) == getattr(result, name), name
    assert back.scan_time_s == result.scan_time_s and back.planned_top_z_m == 0.75


def test_json_scalar_and_policy_slug() -> None:
    assert json_scalar(np.float32(0.5)) == 0.5 and json_scalar(np.int64(3)) == 3
    assert json_scalar(float("nan")) == "nan" and json_scalar(-math.inf) == "-inf"
    assert json_scalar(None) is None and json_scalar("x") == "x"
    with pytest.raises(TypeError):
        json_scalar([1, 2])
    assert policy_slug("periodic:22.5:1.5") == "periodic_22.5_1.5"
    assert policy_slug("ppo:models/x.zip") == "ppo_models_x.zip"


# ----------------------------------------------------------------------------- aggregation
def test_summary_values_and_shape_on_hand_made_trials() -> None:
    config = EvalConfig(POLICIES, trees=2, policy_factory=AGENTS)
    summary = build_summary(config, _records())
    assert list(summary["policies"]) == list(POLICIES)
    assert summary["config"]["seeds"] == [0, 1] and "workers" not in summary["config"]
    for entry in summary["policies"].values():
        assert set(entry) == SUMMARY_KEYS
        assert all(set(entry[k]) == {"mean", "std"} for k in MEAN_STD_KEYS)
    none = summary["policies"]["none"]
    assert (none["trials"], none["failures"]) == (2, 1)  # the failed scan still counts
    # PB residual pooled over the points of both trials, in mm: mean(1, 3, 2) = 2.
    assert none["pb_residual_mm"]["mean"] == pytest.approx(2.0)
    assert none["pb_residual_mm"]["std"] == pytest.approx(np.std([1.0, 3.0, 2.0]))
    rmse_mm = [math.sqrt(5.0) / 10.0, 0.2]  # per trial, then mean over trials
    assert none["pb_radius_rmse_mm"]["mean"] == pytest.approx(np.mean(rmse_mm))
    assert none["sb_residual_mm"]["mean"] == pytest.approx(2.0)
    assert none["sb_radius_mm"] == {"mean": pytest.approx(0.2), "std": pytest.approx(0.0)}
    # Totals over trials: 1 missed, 1 spurious, 1 duplicate of 6 in-scope GT branches.
    assert none["missed_pct"] == none["spurious_pct"] == none["duplicate_pct"]
    assert none["missed_pct"] == pytest.approx(100.0 / 6.0)
    assert none["scan_time_s"] == {"mean": 20.0, "std": 2.0}
    periodic = summary["policies"]["periodic:22.5:1.5"]
    assert periodic["rotations"] == {"mean": 5.0, "std": 1.0}
    # Undefined values are null, and the summary is strict JSON.
    assert summarise_policy(_records()[3:])["pb_residual_mm"] == {"mean": None, "std": None}
    json.dumps(summary, allow_nan=False)


def test_intervals_do_not_depend_on_the_other_policies_of_the_run() -> None:
    """A policy's interval and a pair's comparison are the same whatever else the run holds."""
    missed = {"none": [2, 0, 3, 1, 0, 2, 1, 3], "periodic:22.5:1.5": [0, 1, 1, 0, 0, 2, 0, 1],
              "privileged": [0, 0, 1, 0, 1, 0, 0, 0]}  # fmt: skip
    records = [
        _record(policy, seed, _metrics([1.0], [], (4, 4 - count, 0, 0)), 20.0 + seed + count)
        for policy, counts in missed.items()
        for seed, count in enumerate(counts)
    ]
    alone = build_summary(
        EvalConfig(("none", "periodic:22.5:1.5"), trees=8, policy_factory=AGENTS), records
    )
    more = build_summary(
        EvalConfig(("privileged", "none", "periodic:22.5:1.5"), trees=8, policy_factory=AGENTS),
        records,
    )
    for policy in ("none", "periodic:22.5:1.5"):
        for key in ("missed_pct_ci", "scan_time_s_ci"):
            assert alone["policies"][policy][key] == more["policies"][policy][key]
    pair = [
        p for p in more["paired"] if (p["policy"], p["against"]) == ("periodic:22.5:1.5", "none")
    ]
    assert pair == alone["paired"]
    low, high = alone["policies"]["none"]["missed_pct_ci"]
    assert low < alone["policies"]["none"]["missed_pct"] < high  # a real, non-degenerate interval


def test_table_layout_and_formatting() -> None:
    summary = build_summary(EvalConfig(POLICIES, trees=2, policy_factory=AGENTS), _records())
    lines = format_table(summary).splitlines()
    assert [c.strip() for c in lines[0].strip("|").split("|")] == ["", *POLICIES]
    labels = [line.strip("|").split("|")[0].strip() for line in lines[2:]]
    assert labels == [label for label, _ in TABLE_ROWS]
    cells = {line.split("|")[1].strip(): line.split("|")[2].strip() for line in lines[2:]}
    assert cells["PB residual (mm)"] == "2.0 (0.8)"
    assert cells["Missed %, unreached included"] == cells["Missed % (paper's scope)"] == "16.7"
    assert (cells["Trials"], cells["Failures"]) == ("2", "1")
    assert format_cell({"mean": None, "std": None}) == "n/a"
    assert format_cell({"mean": 3.14159, "std": None}) == "3.1"
    assert format_cell(None) == "n/a" and format_cell(12) == "12" and format_cell(4.25) == "4.2"


def test_comparison_shows_the_paper_values_where_the_paper_has_the_column() -> None:
    records = [*_records(), _record("periodic:30:1", 0, _metrics([1.0], [], (1, 1, 0, 0)))]
    records += [_record("periodic:30:1", 1, _metrics([1.0], [], (1, 1, 0, 0)))]
    config = EvalConfig((*POLICIES, "periodic:30:1"), trees=2, policy_factory=AGENTS)
    rows = format_comparison(build_summary(config, records), paper_column).splitlines()
    header = [c.strip() for c in rows[0].strip("|").split("|")]
    assert header == ["", "none", "paper", "periodic:22.5:1.5", "paper", "periodic:30:1", "paper"]
    pb = [c.strip() for c in rows[2].strip("|").split("|")]
    assert pb[2] == "3.5 (4.0)" and pb[4] == "4.2 (4.9)" and pb[6] == "-"
    missed = next(r for r in rows if r.startswith("| Missed"))
    assert [c.strip() for c in missed.strip("|").split("|")][2:5:2] == ["7.0", "3.4"]


def test_report_files_on_hand_made_trials(tmp_path: Path) -> None:
    config = EvalConfig(POLICIES, trees=2, policy_factory=AGENTS)
    records = _records()
    summary = write_report(tmp_path, config, records)
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    table = (tmp_path / "table.md").read_text()
    assert "| PB residual (mm)" in table
    assert "Failure reasons: none: singularity 1\n" in table
    lines = (tmp_path / "trials.csv").read_text().splitlines()
    assert len(lines) == 5 and lines[0].startswith("seed,policy,failure,")
    assert lines[2].startswith("1,none,singularity,")
    files = write_figures(tmp_path, summary, records, [1], AGENTS)
    assert [f.name for f in files] == ["missed_vs_scan_time.png", "tree_1.png"]
    assert all(f.read_bytes()[:4] == b"\x89PNG" for f in files)


# ----------------------------------------------------------------------------- validation
def test_unknown_policy_is_refused_before_any_work(tmp_path: Path, capsys) -> None:
    with pytest.raises(ValueError, match="unknown policy spec 'spin:3'"):
        EvalConfig(("none", "spin:3"), trees=1, policy_factory=AGENTS)
    with pytest.raises(ValueError, match="repeated"):
        EvalConfig(("none", "none"), trees=1, policy_factory=AGENTS)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        eval_cli.main(["--policies", "none", "periodic:22.5", "--trees", "1", "--out", str(out)])
    assert exit_info.value.code == eval_cli.EXIT_USAGE
    assert "policy spec 'periodic:22.5'" in capsys.readouterr().err
    assert not out.exists()


def test_plot_seed_outside_the_run_is_refused(tmp_path: Path, capsys) -> None:
    argv = ["--policies", "none", "--trees", "2", "--seed", "5", "--out", str(tmp_path / "o")]
    assert eval_cli.main([*argv, "--plot-trees", "0"]) == eval_cli.EXIT_USAGE
    assert "not among the evaluated seeds 5..6" in capsys.readouterr().err
    assert not (tmp_path / "o" / "trials").exists()


def test_output_folder_of_another_config_is_refused(tmp_path: Path) -> None:
    check_output_folder(EvalConfig(POLICIES, trees=1, policy_factory=AGENTS), tmp_path)
    check_output_folder(
        EvalConfig(POLICIES[:1], trees=3, workers=2, policy_factory=AGENTS), tmp_path
    )  # same scan
    faster = EvalConfig(POLICIES, trees=1, scan=ScanConfig(speed_mps=0.05), policy_factory=AGENTS)
    with pytest.raises(ConfigMismatchError, match=r"different scan configuration.*speed_mps"):
        check_output_folder(faster, tmp_path)
    oracle = ScanConfig(tracker="oracle", controller=FollowControllerConfig(k_u=2.0))
    with pytest.raises(ConfigMismatchError) as error:
        check_output_folder(
            EvalConfig(POLICIES, trees=1, scan=oracle, policy_factory=AGENTS), tmp_path
        )
    assert "controller.k_u: 1.0 -> 2.0, tracker: 'lk' -> 'oracle')" in str(error.value)


def test_trials_of_a_model_file_changed_in_place_are_refused(tmp_path: Path) -> None:
    # Retraining into the same models/NAME.zip must not reuse the old model's saved trials.
    model = tmp_path / "model.zip"
    model.write_bytes(b"first model")
    config = EvalConfig(("none", f"ppo:{model}"), trees=1, policy_factory=AGENTS)
    out = tmp_path / "out"
    check_output_folder(config, out)
    check_output_folder(config, out)  # unchanged: fine
    model.write_bytes(b"retrained model")
    with pytest.raises(ConfigMismatchError, match=r"another model file.*delete .*ppo_"):
        check_output_folder(config, out)
    check_output_folder(
        EvalConfig(("none",), trees=1, policy_factory=AGENTS), out
    )  # other policies are unaffected


def test_trials_of_other_segmenter_weights_are_refused(tmp_path: Path) -> None:
    # "learned" names the shipped weights, not which ones: a retrained file must not mix in.
    weights = tmp_path / "seg.pt"
    weights.write_bytes(b"first weights")
    config = EvalConfig(
        ("none",), trees=1, scan=ScanConfig(segmenter=f"learned:{weights}"), policy_factory=AGENTS
    )
    out = tmp_path / "out"
    check_output_folder(config, out)
    check_output_folder(config, out)  # unchanged: fine
    weights.write_bytes(b"retrained weights")
    with pytest.raises(ConfigMismatchError, match=r"segmented by other weights"):
        check_output_folder(config, out)


def test_trial_file_of_another_config_is_refused(tmp_path: Path) -> None:
    config = EvalConfig(("none",), trees=2, policy_factory=AGENTS)
    for seed in (0, 1):
        record = _record("none", seed, _metrics([1.0], [], (1, 1, 0, 0)))
        record.config_hash = config.scan_hash if seed == 0 else "0123456789abcdef"
        save_trial(trial_path(tmp_path, "none", seed), record)
    assert pending_trials(config, tmp_path) == []
    with pytest.raises(ConfigMismatchError, match=r"1\.json was run under scan configuration"):
        load_records(config, tmp_path)


# ----------------------------------------------------------------------------- real scans
def _cli(out: Path, trees: int, workers: int, *extra: str) -> list[str]:
    return [
        "--policies",
        *POLICIES,
        "--trees",
        str(trees),
        "--seed",
        "0",
        "--workers",
        str(workers),
        "--out",
        str(out),
        *SHORT_SCAN,
        *extra,
    ]


@pytest.mark.slow
def test_cli_outputs_on_real_scans(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    assert eval_cli.main(_cli(out, trees=2, workers=1)) == 0
    stdout = capsys.readouterr().out
    assert "4 trials run, 0 loaded" in stdout and "3.5 (4.0)" in stdout  # the paper beside ours

    summary = json.loads((out / "summary.json").read_text())
    assert set(summary) == {"policies", "paired", "config"}
    assert list(summary["policies"]) == list(POLICIES)  # the CLI specs, in CLI order
    for entry in summary["policies"].values():
        assert set(entry) == SUMMARY_KEYS and entry["trials"] == 2
        assert all(set(entry[k]) == {"mean", "std"} for k in MEAN_STD_KEYS)
        assert 0.0 <= entry["pb_residual_mm"]["mean"] < 20.0  # mm, not m
    assert summary["policies"]["periodic:22.5:1.5"]["rotations"]["mean"] >= 1.0
    assert summary["config"]["scan"]["end_height_m"] == 0.45

    table = (out / "table.md").read_text()
    assert "| Failures" in table and "periodic:22.5:1.5" in table
    rows = (out / "trials.csv").read_text().splitlines()
    assert [tuple(r.split(",")[:2]) for r in rows[1:]] == [
        ("0", "none"),
        ("1", "none"),
        ("0", "periodic:22.5:1.5"),
        ("1", "periodic:22.5:1.5"),
    ]
    for name in ("missed_vs_scan_time.png", "tree_0.png", "tree_1.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    trial = json.loads((out / "trials" / "periodic_22.5_1.5" / "1.json").read_text())
    assert trial["policy"] == "periodic:22.5:1.5" and trial["seed"] == 1
    assert {"row", "metrics", "model", "truth", "config_hash"} <= set(trial)

    # Another scan configuration into the same folder: refused before any scan.
    before = {p: p.stat().st_mtime_ns for p in (out / "trials").rglob("*.json")}
    assert eval_cli.main(_cli(out, 2, 1, "--speed", "0.03")) == eval_cli.EXIT_USAGE
    error = capsys.readouterr().err
    assert "different scan configuration" in error and "speed_mps: 0.025 -> 0.03" in error
    assert {p: p.stat().st_mtime_ns for p in (out / "trials").rglob("*.json")} == before


@pytest.mark.slow
def test_resume_runs_only_new_trials_and_results_do_not_depend_on_workers(
    tmp_path: Path, capsys
) -> None:
    out = tmp_path / "run"
    assert eval_cli.main(_cli(out, trees=1, workers=2)) == 0
    old = sorted((out / "trials").rglob("0.json"))
    mtimes = [p.stat().st_mtime_ns for p in old]
    assert len(old) == 2 and "2 trials run, 0 loaded" in capsys.readouterr().out

    assert eval_cli.main(_cli(out, trees=2, workers=2)) == 0  # in a pool of 2
    assert "2 trials run, 2 loaded" in capsys.readouterr().out
    assert [p.stat().st_mtime_ns for p in old] == mtimes  # the old trials were not re-run
    first = (out / "summary.json").read_bytes()

    # Re-run one trial in this process instead of a pool: the summary is identical.
    (out / "trials" / "none" / "0.json").unlink()
    assert eval_cli.main(_cli(out, trees=2, workers=1)) == 0
    assert "1 trials run, 3 loaded" in capsys.readouterr().out
    assert (out / "summary.json").read_bytes() == first


def test_a_trial_that_raises_ends_the_run_with_one_line(tmp_path: Path, capsys) -> None:
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"not a zip file")
    out = tmp_path / "out"
    status = eval_cli.main(["--policies", f"ppo:{corrupt}", "--trees", "1", "--out", str(out)])
    assert status == eval_cli.EXIT_TRIAL_FAILED
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error")]
    assert len(lines) == 1
    assert f"trial 'ppo:{corrupt}' seed 0" in lines[0] and "not a readable" in lines[0]
    assert "Traceback" in (out / eval_cli.ERROR_LOG).read_text()


def test_trials_run_by_other_code_are_reused_with_a_warning_and_rerun_on_request(
    tmp_path: Path, capsys, caplog
) -> None:
    # The cache keys on the scan configuration: a code change keeps the hash, so the trial
    # records the code that ran it, and a reuse under other code says so.
    out = tmp_path / "out"
    argv = ["--policies", "none", "--trees", "1", "--out", str(out), "--end-height", "0.36"]
    assert eval_cli.main(argv) == 0
    path = trial_path(out, "none", 0)
    data = json.loads(path.read_text())
    assert data["code_version"] == code_version() is not None
    data["code_version"] = "git:0123456789ab"  # as if an older commit had run it
    path.write_text(json.dumps(data))
    first = (out / "summary.json").read_bytes()

    assert eval_cli.main(argv) == 0
    assert "0 trials run, 1 loaded" in capsys.readouterr().out
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert any("1 of 1 trials" in m and "git:0123456789ab" in m for m in warnings)
    caplog.clear()

    assert eval_cli.main([*argv, "--rerun"]) == 0
    assert "1 trials run, 0 loaded" in capsys.readouterr().out
    assert json.loads(path.read_text())["code_version"] == code_version()
    assert not [r for r in caplog.records if r.levelname == "WARNING"]
    assert (out / "summary.json").read_bytes() == first  # the same code gives the same trial


def test_record_writes_a_replayable_scan_folder_per_trial(tmp_path: Path) -> None:
    out, record = tmp_path / "out", tmp_path / "scans"
    argv = ["--policies", "none", "--trees", "1", "--seed", "3", "--out", str(out)]
    assert eval_cli.main([*argv, "--end-height", "0.36", "--record", str(record)]) == 0
    folder = record / "none" / "seed_0003"
    scan = ScanFolder(folder)
    assert len(scan) > 10
    assert (folder / "truth.json").is_file() and (folder / "metadata.json").is_file()


# ----------------------------------------------------------------------- checkpoint selection
def test_selection_scores_a_trial_by_the_env_return_at_its_price() -> None:
    metrics = _metrics([1.0], [2.0], (4, 3, 1, 1))  # 3 matched, 1 spurious, 1 duplicate
    record = _record("ppo:m.zip@50", 0, metrics, scan_time_s=25.0, failure="collision")
    expected = 3 - 0.5 - 0.5 - 25.0 / 50 - 1.0
    assert trial_return(record, 50.0, RewardConfig()) == pytest.approx(expected)
    cheap = _record("ppo:m.zip@25", 1, _metrics([1.0], [2.0], (2, 2, 0, 0)), scan_time_s=25.0)
    score = score_records(Path("m.zip"), [record, cheap])
    assert score.score == pytest.approx((expected + (2 - 1.0)) / 2)
    assert score.missed_pct == pytest.approx(100 * 1 / 6) and score.failures == 1


def test_selection_rejects_missing_models_and_empty_prices(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"nope\.zip"):
        select_model([tmp_path / "nope.zip"], tmp_path / "eval")
    with pytest.raises(ValueError, match="at least one model"):
        select_model([tmp_path / "m.zip"], tmp_path / "eval", prices_s=[])


def test_fields_added_at_their_neutral_value_keep_saved_config_hashes() -> None:
    import hashlib
    from dataclasses import replace

    default = ScanConfig()
    default = default.replace(modeler=default.modeler_config())  # hashed as run (EvalConfig)
    # The published trials ran the paper's primary rule, no longer the default.
    config = replace(
        default,
        modeler=replace(default.modeler, primary_max_turn_deg=None, primary_model_vouches=False),
    )
    before = config_to_dict(config)  # the config as published before the fields existed
    before["modeler"].update(  # ... and with the fields removed since, at their only value
        model_reprojection_px=4.0, primary_sample_spacing_m=0.005, secondary_trust_in_view=0.0
    )
    del before["render_tracking_frames"]
    del before["modeler"]["secondary_trust_tolerance_px"]
    del before["modeler"]["secondary_min_reach_m"]
    del before["modeler"]["primary_max_turn_deg"], before["modeler"]["primary_model_vouches"]
    del before["frame_pairing"], before["curve2d"]
    del before["world"]["orchard"], before["world"]["tree"]["architecture"]
    del before["world"]["tree"]["primary_base_height_m"]
    del before["world"]["tree"]["alley_side_reach_m"]
    del before["world"]["tree"]["alley_side_half_angle_deg"]
    published = hashlib.sha256(json.dumps(before, sort_keys=True).encode()).hexdigest()[:16]
    assert config_hash(config) == published
    reach = replace(config, modeler=replace(config.modeler, secondary_min_reach_m=0.03))
    assert config_hash(reach) != published
    turn = replace(config, modeler=replace(config.modeler, primary_max_turn_deg=30.0))
    assert config_hash(turn) != published
    turn_2d = replace(config, curve2d=replace(config.curve2d, max_primary_turn_deg=45.0))
    assert config_hash(turn_2d) != published
    assert config_hash(default) not in {published, config_hash(turn)}  # a new rule: new trials


def test_the_clean_and_orchard_evaluations_keep_their_hashes() -> None:
    """Fields added to the scan since (the tree's alley face, the orchard camera's JPEG switch)
    hash as absent at their earlier values: the trials that ``eval.py`` saved for the clean world
    and for the orchard from pixels (hashes as written by the code of December 2026) stay valid
    for the scans that ran them (``orbit_holds_model=False``). The orbit hold, on by default,
    changes rotating scans: its trials hash apart and are never mixed with those."""
    clean = ScanConfig(world=WorldConfig.preset("clean"), orbit_holds_model=False)
    orchard = ScanConfig(
        world=WorldConfig.preset("orchard"), segmenter="learned", orbit_holds_model=False
    )

    def scan_hash(scan: ScanConfig) -> str:
        return EvalConfig(("none",), 1, scan=scan, policy_factory=AGENTS).scan_hash

    assert [scan_hash(clean), scan_hash(orchard)] == ["0b7c0f4524858f99", "a95befb214ab854a"]
    for before in (clean, orchard):
        assert scan_hash(before.replace(orbit_holds_model=True)) != scan_hash(before)


@pytest.mark.parametrize(
    ("field_name", "learned_value"),
    [("secondary_trust_tolerance_px", 4.0), ("secondary_min_reach_m", LEARNED_MASK_MIN_REACH_M)],
)
def test_trials_of_learned_masks_before_a_mask_source_setting_are_not_mixed_with_new_ones(
    field_name: str, learned_value: float
) -> None:
    """A setting left to the mask source hashes as resolved: unchanged for the renderer's labels
    (0, hash-neutral), changed for a learned segmenter (its trials saved before the setting ran
    0); ``--modeler FIELD=0`` hashes as those trials (the published-hash test above)."""
    from dataclasses import replace

    def scan_hash(scan: ScanConfig) -> str:
        return EvalConfig(("none",), 1, 0, 1, scan, policy_factory=AGENTS).scan_hash

    exact = ModelerConfig(**{field_name: 0.0})
    labels = ScanConfig()
    assert scan_hash(labels) == scan_hash(replace(labels, modeler=exact))
    learned = ScanConfig(segmenter="learned")
    assert getattr(learned.modeler_config(), field_name) == learned_value
    assert scan_hash(learned) != scan_hash(replace(learned, modeler=exact))


def test_modeler_settings_from_the_command_line() -> None:
    items = ["secondary_trust_tolerance_px=0", "secondary_extend_to_junction=false"]
    assert modeler_overrides(items) == {
        "secondary_trust_tolerance_px": 0,
        "secondary_extend_to_junction": False,
    }
    for bad, message in (
        ("bogus=1", "unknown ModelerConfig field 'bogus'"),
        ("secondary_trust_in_view=0.5", "field 'secondary_trust_in_view' was removed"),
        ("model_reprojection_px=4", "field 'model_reprojection_px' was removed"),
        ("secondary_trust_min", "not FIELD=VALUE"),
        ("secondary_trust_min=low", "not a JSON value"),
    ):
        with pytest.raises(ValueError, match=message):
            modeler_overrides([bad])


def test_eval_cli_refuses_a_bad_modeler_setting(tmp_path: Path, capsys) -> None:
    from agents.commands import evaluate as main

    argv = ["--policies", "none", "--trees", "1", "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, "--modeler", "secondary_trust_tolerance_px=-1"])
    assert exit_info.value.code == 2
    assert "secondary_trust_tolerance_px must be >= 0" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
