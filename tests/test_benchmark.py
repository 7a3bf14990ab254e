"""Benchmarks as versioned data, and their results page on constructed trials."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from branch_gym.evaluation.benchmark import (
    BENCHMARKS,
    HELD_OUT_SEED_START,
    VERSION_HISTORY,
    BenchmarkOutcome,
    Stratum,
    benchmark,
    training_seeds,
)
from branch_gym.evaluation.benchmark_page import benchmark_results, format_page
from recon.metrics import TreeMetrics


def test_a_benchmark_definition_cannot_change_without_its_version() -> None:
    published = {row.name: row.digest for row in VERSION_HISTORY}
    for name, bench in BENCHMARKS.items():
        assert name in published, f"{name} has no Version History row (VERSION_HISTORY)"
        assert bench.digest() == published[name], (
            f"the definition of {name} changed (digest {bench.digest()}, published "
            f"{published[name]}): publish it as a new version with its own name"
        )
    # Any change to what decides the figures changes the digest.
    paper = benchmark("paper-v1")
    assert replace(paper, segmenter="learned").digest() != paper.digest()
    assert replace(paper, scan_changes=(("speed_mps", 0.05),)).digest() != paper.digest()
    assert replace(paper, metrics_changes=()).digest() != paper.digest()


def test_splits_are_held_out_from_training_and_do_not_overlap() -> None:
    for bench in BENCHMARKS.values():
        for stratum in bench.strata:
            for split in ("test", "validation"):
                assert stratum.seeds(split)[0] >= HELD_OUT_SEED_START
    assert training_seeds(10).stop <= HELD_OUT_SEED_START
    with pytest.raises(ValueError, match="must lie in"):
        training_seeds(10, HELD_OUT_SEED_START - 5)
    paper = benchmark("paper-v1")
    clash = Stratum("again", "paper", paper.strata[0].test_seeds, (400_000, 5))
    with pytest.raises(ValueError, match="overlap"):
        replace(paper, strata=(*paper.strata, clash))
    with pytest.raises(ValueError, match="held-out seeds"):
        replace(paper, strata=(Stratum("low", "paper", (5, 5), (400_000, 5)),))
    with pytest.raises(ValueError, match="unknown benchmark 'nope'"):
        benchmark("nope")


def _trial(policy: str, seed: int, n_gt: int, missed: int, time_s: float, spur: bool = False):
    classes = ["match"] * (n_gt - missed) + (["detail"] if spur else [])
    metrics = TreeMetrics(
        pb_residuals_m=np.zeros(1),
        pb_radius_errors_m=np.zeros(1),
        sb_residuals_m=np.zeros(0),
        sb_radius_errors_m=np.zeros(0),
        matches=[],
        n_gt=n_gt,
        n_matched=n_gt - missed,
        n_missed=missed,
        n_spurious=0,
        n_duplicates=0,
        n_ignored_reconstructed=0,
        scanned_top_z_m=0.75,
        reconstructed_classes=classes,
    )
    return SimpleNamespace(policy=policy, seed=seed, metrics=metrics, scan_time_s=time_s,
                           failure=None)  # fmt: skip


def test_the_results_page_pairs_every_policy_with_the_references() -> None:
    bench = benchmark("paper-v1")
    seeds = range(100_000, 100_040)
    # 40 trees of 10 branches: none misses 2 a tree, the paper's 1, the bound 0 on every tree.
    records = [
        _trial(p, s, 10, m, t, spur=True)
        for p, m, t in (("none", 2, 20.0), ("periodic:22.5:1.5", 1, 35.0), ("privileged", 0, 25.0))
        for s in seeds
    ]
    outcome = BenchmarkOutcome(bench, "test", {"paper": records})
    results = benchmark_results(outcome, seed=0)
    none = results["policies"]["none"]
    assert none["missed_pct"] == pytest.approx(20.0)
    assert none["vs_reference"]["missed_pct_diff"] == pytest.approx(10.0)
    assert none["vs_reference"]["missed_pct_diff_ci"] == pytest.approx([10.0, 10.0])
    assert none["vs_bound"]["missed_pct_diff"] == pytest.approx(20.0)
    assert none["precision_pct"] == 100.0  # the spurs seen are not held against it
    assert none["classes"]["detail"] == 40
    assert none["cost_branches_per_tree"] == pytest.approx(2 + 20.0 / bench.branch_value_s)
    assert none["power"]["trees_for_1_point"] == 2  # no spread: the same on every tree
    assert results["headroom"]["missed_pct_diff"] == pytest.approx(20.0)
    assert "vs_reference" not in results["policies"]["periodic:22.5:1.5"]
    page = format_page(results, "python eval.py --benchmark paper-v1 ...")
    assert "| `none` | 20.0 [20.0, 20.0] | +10.0 [10.0, 10.0] | +20.0 [20.0, 20.0] |" in page
    assert "Headroom (`none` minus `privileged`): +20.0" in page


def test_the_command_refuses_scan_options_beside_a_benchmark(tmp_path, capsys) -> None:
    from agents.commands import evaluate

    with pytest.raises(SystemExit) as exit_info:
        evaluate(["--benchmark", "paper-v1", "--policies", "none", "--world", "orchard",
                  "--seed", "3", "--out", str(tmp_path)])  # fmt: skip
    assert exit_info.value.code == 2
    assert (
        "--benchmark fixes the scan and the trees: drop --seed --world" in capsys.readouterr().err
    )
    with pytest.raises(SystemExit):
        evaluate(["--benchmark", "nope-v9", "--policies", "none", "--out", str(tmp_path)])
