"""The 2D stage as a scan setting, and variants: a change tried on a benchmark's trees as a derived
definition (its own name and digest, refused in the benchmark's rows, said on its page)."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, replace

import numpy as np
import pytest

from branch_gym.evaluation.benchmark import (
    BENCHMARKS,
    VERSION_HISTORY,
    BenchmarkOutcome,
    TrialRow,
    benchmark,
    load_rows,
    save_rows,
)
from branch_gym.evaluation.benchmark_page import benchmark_results, format_page
from branch_gym.evaluation.trials import config_hash
from branch_gym.scan import ScanConfig, ScanSession
from recon.curve2d.types import Curve2DConfig
from recon.metrics import BRANCH_CLASSES
from recon.replay import curve_settings

TURN_45 = "curve2d.max_primary_turn_deg=45"
REFERENCES = ("none", "periodic:22.5:1.5", "privileged")


def _row(policy: str, seed: int, missed: int, time_s: float = 30.0, n_gt: int = 10) -> TrialRow:
    classes = dict.fromkeys(BRANCH_CLASSES, 0) | {"match": n_gt - missed}
    return TrialRow("paper", policy, seed, n_gt, missed, 0, 0, classes, time_s, None)


def test_a_scan_builds_its_modeler_with_its_2d_stage() -> None:
    turn = Curve2DConfig(max_primary_turn_deg=45.0)
    scan = ScanConfig(segmenter="learned", curve2d=turn)
    modeler = scan.make_modeler()
    assert modeler.curve_config == turn
    assert modeler.config == scan.modeler_config()  # resolved for the learned masks
    assert ScanConfig().make_modeler().curve_config == Curve2DConfig()
    session = ScanSession(ScanConfig(curve2d=turn))  # no scan runs: the world is not reset
    try:
        assert session.modeler.curve_config.max_primary_turn_deg == 45.0
    finally:
        session.close()
    with pytest.raises(ValueError, match=r"ScanConfig\.curve2d must be a Curve2DConfig"):
        ScanConfig(curve2d={"max_primary_turn_deg": 45.0})


def test_the_default_2d_stage_keeps_published_digests_and_hashes_and_a_change_does_not() -> None:
    published = {row.name: row.digest for row in VERSION_HISTORY}
    for name, bench in BENCHMARKS.items():
        assert bench.digest() == published[name]
        assert "variant" not in bench.to_json_dict()
    default = ScanConfig()
    turned = default.replace(curve2d=Curve2DConfig(max_primary_turn_deg=45.0))
    assert config_hash(turned) != config_hash(default)
    # A changed default of the 2D stage is a new scan: it would hash apart, not as before.
    skeleton = replace(default.curve2d.skeleton, max_gap_px=5.0)
    assert config_hash(default.replace(curve2d=replace(default.curve2d, skeleton=skeleton))) != (
        config_hash(default)
    )


def test_a_variant_is_a_derived_definition_with_its_own_name_and_digest() -> None:
    bench = benchmark("orchard-v2")
    variant = bench.with_variant([TURN_45])
    assert variant.name == "orchard-v2+curve2d.max_primary_turn_deg=45"
    assert variant.base_name == "orchard-v2" and variant.variant_items == [TURN_45]
    assert variant.digest() != bench.digest()
    assert variant.name not in BENCHMARKS
    assert variant.name not in {row.name for row in VERSION_HISTORY}
    assert "not the benchmark" in variant.description
    for stratum in variant.strata:
        scan = variant.scan_config(stratum)
        assert scan.curve2d.max_primary_turn_deg == 45.0
        assert scan == bench.scan_config(stratum).replace(curve2d=scan.curve2d)
    # One change, one definition: 45 and 45.0 alike; a second setting is a second definition.
    assert bench.with_variant(["curve2d.max_primary_turn_deg=45.0"]).digest() == variant.digest()
    both = bench.with_variant([TURN_45, "modeler.primary_max_turn_deg=null"])
    assert both.name == variant.name + "+modeler.primary_max_turn_deg=null"
    assert both.scan_config(both.strata[0]).modeler.primary_max_turn_deg is None
    assert both.digest() not in {bench.digest(), variant.digest()}
    nested = bench.with_variant(["curve2d.skeleton.max_gap_px=4"])
    assert nested.scan_config(nested.strata[0]).curve2d.skeleton.max_gap_px == 4.0
    # A variant is named as one, and only a variant.
    with pytest.raises(ValueError, match="a variant's name, and only a variant's"):
        replace(bench, name="orchard-v2+mine")
    with pytest.raises(ValueError, match="a variant's name, and only a variant's"):
        replace(variant, name="orchard-v3")


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("curve2d.max_primary_turn_deg=0", "max_primary_turn_deg must be > 0"),
        ("curve2d.max_primary_turn_deg=-5", "max_primary_turn_deg must be > 0"),
        ("curve2d.max_primary_turn_deg=wide", "'wide' is not a JSON value"),
        ("curve2d.max_primary_turn_deg", "is not FIELD=VALUE"),
        ("curve2d.max_primary_turn=45", "Curve2DConfig has no field 'max_primary_turn'"),
        ("curve2d.skeleton=3", "Curve2DConfig.skeleton is a section"),
        ("curve2d.score.x=1", "Curve2DConfig.score has no fields"),
        ("modeler.bogus=1", "ModelerConfig has no field 'bogus'"),
        ("modeler.model_reprojection_px=4", "field 'model_reprojection_px' was removed"),
        ("modeler.consistency_min_fraction=2", "consistency_min_fraction is a fraction"),
        ("segmenter.x=1", "vary a field of modeler or curve2d"),
        ('segmenter="gt"', "a segmenter variant names a weights file"),
        ('segmenter="learned"', "a segmenter variant names a weights file"),
        ("segmenter=3", "a segmenter variant names a weights file"),
        ('segmenter="learned:no/such.pt"', "no weights file no/such.pt"),
        ("max_primary_turn_deg=45", "vary a field of modeler or curve2d"),
        ("curve2d.max_primary_turn_deg=Infinity", "changes nothing: orchard-v2 has it"),
    ],
)
def test_bad_variant_settings_are_refused_with_the_reason(item: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        benchmark("orchard-v2").with_variant([item])


def test_a_segmenter_variant_scans_with_its_weights_pinned_by_their_bytes(tmp_path) -> None:
    weights = tmp_path / "candidate.pt"
    weights.write_bytes(b"first weights")
    bench = benchmark("orchard-v2")
    item = f'segmenter="learned:{weights}"'
    variant = bench.with_variant([item])
    assert variant.name == f"orchard-v2+{item}"
    for stratum in variant.strata:
        scan = variant.scan_config(stratum)
        assert scan.segmenter == f"learned:{weights}"
        assert scan == bench.scan_config(stratum).replace(segmenter=scan.segmenter)
    first = variant.digest()
    assert first != bench.digest() and "segmenter_weights_sha256" not in bench.to_json_dict()
    # Other bytes at the same path are another definition: their rows would not mix.
    weights.write_bytes(b"retrained weights")
    assert variant.digest() != first
    weights.unlink()
    with pytest.raises(ValueError, match="no weights file"):
        variant.digest()


def test_a_setting_given_twice_or_none_is_refused() -> None:
    bench = benchmark("orchard-v2")
    with pytest.raises(ValueError, match="set twice"):
        bench.with_variant([TURN_45, "curve2d.max_primary_turn_deg=30"])
    with pytest.raises(ValueError, match="at least one"):
        bench.with_variant([])


def test_a_variants_rows_and_trials_are_refused_in_the_benchmarks_folder(tmp_path) -> None:
    from agents.factory import AGENTS
    from branch_gym.evaluation.config import EvalConfig
    from branch_gym.evaluation.runner import ConfigMismatchError, check_output_folder

    paper = benchmark("paper-v1")
    variant = paper.with_variant([TURN_45])
    save_rows(tmp_path, paper, [_row("none", 100_000, 1)])
    with pytest.raises(
        ValueError, match=r"holds rows of paper-v1 digest .* not of paper-v1\+curve2d"
    ):
        load_rows(tmp_path, variant)
    save_rows(tmp_path / "v", variant, [_row("none", 100_000, 0)])
    with pytest.raises(ValueError, match=r"holds rows of paper-v1\+curve2d"):
        load_rows(tmp_path / "v", paper)
    # The trial files too: the variant's scans hash apart from the benchmark's.
    stratum = paper.strata[0]

    def trials(bench) -> EvalConfig:
        return EvalConfig(
            ("none",), 1, 100_000, scan=bench.scan_config(stratum), policy_factory=AGENTS
        )

    check_output_folder(trials(paper), tmp_path / "paper")
    with pytest.raises(ConfigMismatchError):
        check_output_folder(trials(variant), tmp_path / "paper")


def test_a_variants_page_says_so_and_pairs_each_policy_with_the_benchmark() -> None:
    paper = benchmark("paper-v1")
    variant = paper.with_variant([TURN_45])
    seeds = range(100_000, 100_020)
    # Under the variant, none misses 1 a tree; under the benchmark 2, on trees 0-14 only.
    rows = [_row(p, s, 1 if p == "none" else 0) for p in REFERENCES for s in seeds]
    base = [_row(p, s, 2 if p == "none" else 0, 25.0) for p in REFERENCES for s in seeds[:15]]
    results = benchmark_results(BenchmarkOutcome(variant, "test", rows), base_rows=base)
    json.dumps(results, allow_nan=False)  # benchmark.json is strict JSON
    assert results["variant"] == {"of": "paper-v1", "settings": [TURN_45]}
    vs_base = results["policies"]["none"]["vs_base"]
    assert vs_base["trees"] == 15
    assert vs_base["missed_pct_diff"] == pytest.approx(-10.0)
    assert (vs_base["wins"], vs_base["losses"]) == (15, 0)
    page = format_page(results, "python eval.py --benchmark paper-v1 --variant ...")
    assert "# `paper-v1+curve2d.max_primary_turn_deg=45`, test split" in page
    assert f"**A variant, not the benchmark**: `paper-v1` with `{TURN_45}`" in page
    assert "| `none` | 15 | -10.0 [-10.0, -10.0] | 15 / 0 | 30.0 vs 25.0 |" in page
    plain = benchmark_results(BenchmarkOutcome(paper, "test", rows))
    assert "variant" not in plain and "vs_base" not in plain["policies"]["none"]
    assert "A variant" not in format_page(plain, "python eval.py --benchmark paper-v1")


def test_the_command_runs_a_variant_in_its_own_folder(tmp_path, capsys) -> None:
    from agents.commands import evaluate

    paper = benchmark("paper-v1")
    variant = paper.with_variant([TURN_45])
    seeds = range(100_000, 100_004)
    save_rows(tmp_path / "base", paper, [_row(p, s, 2) for p in REFERENCES for s in seeds])
    save_rows(tmp_path / "turn", variant, [_row(p, s, 1) for p in REFERENCES for s in seeds])
    common = ["--benchmark", "paper-v1", "--policies", "none", "--from-rows"]
    assert evaluate([*common, "--variant", TURN_45, "--out", str(tmp_path / "turn"),
                     "--base-out", str(tmp_path / "base")]) == 0  # fmt: skip
    page = (tmp_path / "turn" / "benchmark.md").read_text()
    assert "**A variant, not the benchmark**" in page and "| `none` | 4 | -10.0" in page
    # The benchmark's folder refuses the variant's rows, and the variant's the benchmark's.
    assert evaluate([*common, "--variant", TURN_45, "--out", str(tmp_path / "base")]) == 2
    assert "holds rows of paper-v1 digest" in capsys.readouterr().err
    assert evaluate([*common, "--out", str(tmp_path / "turn")]) == 2
    assert evaluate([*common, "--variant", TURN_45, "--out", str(tmp_path / "turn"),
                     "--base-out", str(tmp_path / "turn")]) == 2  # fmt: skip
    for argv, message in (
        ([*common, "--variant", "curve2d.max_primary_turn_deg=0"], "must be > 0"),
        ([*common, "--variant", "curve2d.nope=1"], "Curve2DConfig has no field 'nope'"),
        ([*common, "--base-out", str(tmp_path / "base")], "--base-out pairs a variant"),
        ([*common, "--modeler", "ransac_iterations=10"], "--variant modeler.FIELD=VALUE"),
        (["--policies", "none", "--variant", TURN_45], "they need --benchmark"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            evaluate([*argv, "--out", str(tmp_path / "other")])
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "other").exists()


def test_a_replay_takes_the_2d_stage_its_recording_ran(caplog) -> None:
    turn = Curve2DConfig(max_primary_turn_deg=45.0)
    recorded = json.loads(json.dumps({"modeler": {"curve2d": asdict(turn)}}))  # metadata.json
    assert curve_settings(recorded, None) == turn
    default = json.loads(json.dumps({"modeler": {"curve2d": asdict(Curve2DConfig())}}))
    assert math.isinf(curve_settings(default, None).max_primary_turn_deg)
    assert curve_settings(default, None) == Curve2DConfig()
    assert curve_settings({"modeler": {"seed": 0}}, None) == Curve2DConfig()  # recorded before
    strict = {"modeler": {"curve2d": {"max_primary_turn_deg": "inf", "min_samples": 4}}}
    assert curve_settings(strict, None) == Curve2DConfig(min_samples=4)
    assert curve_settings(recorded, Curve2DConfig()) == Curve2DConfig()  # given wins
    recorded["modeler"]["curve2d"]["retired_rule"] = 1
    with caplog.at_level(logging.WARNING):
        assert curve_settings(recorded, None) == turn
    assert "retired_rule" in caplog.text


def test_a_recorded_scan_replays_with_the_2d_stage_it_ran(tmp_path) -> None:
    """A short recorded scan under a turn limit replays to the same model with the same limit."""
    from replay_fixtures import SHORT_END_HEIGHT_M

    from agents.factory import AGENTS
    from branch_gym.evaluation.record import record_scan
    from recon.replay import replay

    turn = Curve2DConfig(max_primary_turn_deg=45.0)
    scan = ScanConfig(end_height_m=SHORT_END_HEIGHT_M, curve2d=turn)
    result = record_scan(0, "none", scan, tmp_path / "scan", factory=AGENTS)
    replayed = replay(tmp_path / "scan", tmp_path / "out", progress=False)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["curve_config"]["max_primary_turn_deg"] == 45.0
    np.testing.assert_array_equal(replayed.model.primary.points, result.model.primary.points)
