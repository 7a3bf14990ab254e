"""Benchmarks as versioned data, and their results page on constructed trials."""

from __future__ import annotations

from dataclasses import replace

import pytest

from branch_gym.evaluation.benchmark import (
    BENCHMARKS,
    HELD_OUT_SEED_END,
    HELD_OUT_SEED_START,
    VERSION_HISTORY,
    BenchmarkOutcome,
    Stratum,
    TrialRow,
    benchmark,
    load_rows,
    outcome_from_rows,
    save_rows,
)
from branch_gym.evaluation.benchmark_page import benchmark_results, format_page
from branch_gym.training.seeds import MAX_EVAL_TREES, eval_tree_seeds, train_seed_range
from recon.metrics import BRANCH_CLASSES


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
                first, count = stratum.seeds(split)
                assert HELD_OUT_SEED_START <= first < first + count <= HELD_OUT_SEED_END
    # Training's trees and its evaluation trees lie above every held-out seed.
    assert min(eval_tree_seeds(MAX_EVAL_TREES)) >= HELD_OUT_SEED_END
    assert train_seed_range(0).start >= HELD_OUT_SEED_END
    paper = benchmark("paper-v1")
    clash = Stratum("again", "paper", paper.strata[0].test_seeds, (400_000, 5))
    with pytest.raises(ValueError, match="overlap"):
        replace(paper, strata=(*paper.strata, clash))
    with pytest.raises(ValueError, match="held-out seeds"):
        replace(paper, strata=(Stratum("low", "paper", (5, 5), (400_000, 5)),))
    with pytest.raises(ValueError, match="held-out seeds"):
        replace(paper, strata=(Stratum("high", "paper", (HELD_OUT_SEED_END, 5), (400_000, 5)),))
    with pytest.raises(ValueError, match="unknown benchmark 'nope'"):
        benchmark("nope")


def _row(policy: str, seed: int, n_gt: int, missed: int, time_s: float) -> TrialRow:
    classes = dict.fromkeys(BRANCH_CLASSES, 0) | {"match": n_gt - missed, "detail": 1}
    return TrialRow("paper", policy, seed, n_gt, missed, 0, 0, classes, time_s, None)


def test_the_results_page_pairs_every_policy_with_the_references() -> None:
    bench = benchmark("paper-v1")
    seeds = range(100_000, 100_040)
    # 40 trees of 10 branches: none misses 2 a tree, the paper's 1, the bound 0 on every tree.
    rows = [
        _row(p, s, 10, m, t)
        for p, m, t in (("none", 2, 20.0), ("periodic:22.5:1.5", 1, 35.0), ("privileged", 0, 25.0))
        for s in seeds
    ]
    outcome = BenchmarkOutcome(bench, "test", rows)
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


def test_rows_are_the_record_a_later_session_resumes_from(tmp_path) -> None:
    paper = benchmark("paper-v1")
    rows = [_row("none", 100_000 + k, 3, k % 2, 20.0) for k in range(3)]
    save_rows(tmp_path, paper, rows)
    loaded = load_rows(tmp_path, paper)
    assert list(loaded.values()) == rows
    assert loaded["paper", "none", 100_001].n_missed == 1
    other = replace(paper, name="paper-v2", scan_changes=(("speed_mps", 0.05),))
    with pytest.raises(ValueError, match="holds rows of paper-v1 digest"):
        load_rows(tmp_path, other)
    (tmp_path / "rows.jsonl").write_text(
        (tmp_path / "rows.jsonl").read_text() + '{"policy": "none"}\n'
    )
    with pytest.raises(ValueError, match="line 5: not a trial row"):
        load_rows(tmp_path, paper)


def test_a_page_from_rows_compares_the_first_trees_every_policy_has(tmp_path, capsys) -> None:
    from agents.commands import evaluate

    paper = benchmark("paper-v1")
    references = ("none", "periodic:22.5:1.5", "privileged")
    # The references on trees 0-4, the extra policy on 0-2 and 4 (a run in progress): 3 trees.
    rows = [_row(p, 100_000 + k, 4, k % 2, 20.0) for p in references for k in range(5)]
    rows += [_row("ftl:22.5:1", 100_000 + k, 4, 1, 30.0) for k in (0, 1, 2, 4)]
    save_rows(tmp_path, paper, rows)
    outcome, trees = outcome_from_rows(paper, ["ftl:22.5:1"], "test", tmp_path)
    assert trees == 3
    assert {(r.policy, r.seed - 100_000) for r in outcome.rows} == {
        (p, k) for p in (*references, "ftl:22.5:1") for k in range(3)
    }
    assert evaluate(["--benchmark", "paper-v1", "--from-rows", "--out", str(tmp_path),
                     "--policies", "ftl:22.5:1"]) == 0  # fmt: skip
    page = (tmp_path / "benchmark.md").read_text()
    assert "**Partial**: the first 3 trees" in page and "--from-rows" in page
    assert "![missed against scan time](missed_vs_scan_time.png)" in page
    assert (tmp_path / "missed_vs_scan_time.png").stat().st_size > 0
    assert load_rows(tmp_path, paper) == {(r.stratum, r.policy, r.seed): r for r in rows}
    with pytest.raises(ValueError, match="no tree of the test split with a row of every policy"):
        outcome_from_rows(paper, ["disagreement"], "test", tmp_path)


@pytest.mark.slow
def test_a_benchmark_runs_resumes_from_its_rows_and_writes_its_page(tmp_path) -> None:
    import shutil

    from agents.factory import AGENTS
    from branch_gym.evaluation.benchmark import run_benchmark
    from branch_gym.evaluation.benchmark_page import benchmark_results, write_benchmark_page

    tiny = replace(
        benchmark("paper-v1"),
        name="tiny-v1",
        strata=(Stratum("paper", "paper", (100_000, 2), (100_100, 1)),),
        tracker="oracle",
        scan_changes=(("end_height_m", 0.4),),
    )
    outcome = run_benchmark(tiny, ["none"], "test", tmp_path, AGENTS)
    assert len(outcome.computed) == 6  # none, the paper's controller, the bound: 2 trees each
    assert {r.policy for r in outcome.rows} == {"none", "periodic:22.5:1.5", "privileged"}
    for row in outcome.rows:
        assert sum(row.classes.values()) >= 0 and 0 <= row.n_missed <= row.n_gt
    shutil.rmtree(tmp_path / "paper" / "trials")  # a later session has the rows, not the trials
    again = run_benchmark(tiny, ["none"], "test", tmp_path, AGENTS)
    assert again.computed == [] and again.rows == outcome.rows
    files = write_benchmark_page(tmp_path, benchmark_results(again), "python eval.py ...")
    assert "| `none` |" in files[1].read_text()
