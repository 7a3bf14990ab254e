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
    check_default_weights,
    load_rows,
    outcome_from_rows,
    run_benchmark,
    save_rows,
)
from branch_gym.evaluation.benchmark_page import benchmark_results, format_page
from branch_gym.training.seeds import MAX_EVAL_TREES, eval_tree_seeds, train_seed_range
from recon.metrics import BRANCH_CLASSES
from recon.segmentation import spec as spec_module


def test_a_version_from_pixels_is_run_on_the_weights_it_was_published_with(
    tmp_path, monkeypatch
) -> None:
    import hashlib

    shipped = spec_module.default_weights_path()
    for row in VERSION_HISTORY:
        learned = benchmark(row.name).segmenter == "learned"
        assert (row.default_weights_sha256 is not None) == learned, row.name
        if learned:  # a retrained default fails here: publish it as a new version
            assert hashlib.sha256(shipped.read_bytes()).hexdigest() == row.default_weights_sha256
            check_default_weights(benchmark(row.name))
    other = tmp_path / "retrained.pt"
    other.write_bytes(b"other weights")
    monkeypatch.setattr(spec_module, "default_weights_path", lambda: other)
    orchard = benchmark("orchard-v2")
    with pytest.raises(ValueError, match="orchard-v2 was run with other default segmenter"):
        check_default_weights(orchard)
    with pytest.raises(ValueError, match="new benchmark version"):  # a variant of it, too
        check_default_weights(orchard.with_variant(["curve2d.max_primary_turn_deg=45"]))
    from agents.factory import AGENTS

    with pytest.raises(ValueError, match="new benchmark version"):  # before any scan runs
        run_benchmark(orchard, ["none"], "validation", tmp_path / "rows", AGENTS)
    assert not (tmp_path / "rows").exists()
    check_default_weights(benchmark("paper-v1"))  # the renderer's labels: no weights
    check_default_weights(orchard.with_variant([f'segmenter="learned:{other}"']))  # pinned


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
    assert "| `none` | 40 | 20.0 [20.0, 20.0] | +10.0 [10.0, 10.0] | +20.0 [20.0, 20.0] |" in page
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


def test_a_page_from_rows_pairs_each_policy_on_the_trees_it_shares(tmp_path, capsys) -> None:
    from agents.commands import evaluate

    paper = benchmark("paper-v1")
    references = ("none", "periodic:22.5:1.5", "privileged")
    # The references on trees 0-4, the extra policy on 0-2 and 4 (a run in progress): its first 3.
    rows = [_row(p, 100_000 + k, 4, k % 2, 20.0) for p in references for k in range(5)]
    rows += [_row("ftl:22.5:1", 100_000 + k, 4, 1, 30.0) for k in (0, 1, 2, 4)]
    save_rows(tmp_path, paper, rows)
    outcome = outcome_from_rows(paper, ["ftl:22.5:1"], "test", tmp_path)
    assert {(r.policy, r.seed - 100_000) for r in outcome.rows} == {
        (p, k) for p in references for k in range(5)
    } | {("ftl:22.5:1", k) for k in range(3)}
    results = benchmark_results(outcome)
    assert results["policies"]["none"]["trees"] == 5
    ftl = results["policies"]["ftl:22.5:1"]
    assert ftl["trees"] == 3
    # Paired on trees 0-2: ftl misses 3 of 12, the paper's 1 (tree 1): +16.7 points.
    assert ftl["vs_reference"]["missed_pct_diff"] == pytest.approx(100 * 2 / 12)
    limited = outcome_from_rows(paper, ["ftl:22.5:1"], "test", tmp_path, trees=2)
    assert {r.seed - 100_000 for r in limited.rows} == {0, 1}
    assert evaluate(["--benchmark", "paper-v1", "--from-rows", "--out", str(tmp_path),
                     "--policies", "ftl:22.5:1"]) == 0  # fmt: skip
    page = (tmp_path / "benchmark.md").read_text()
    assert "**Partial**: a policy with fewer than the split's" in page and "--from-rows" in page
    assert "| `ftl:22.5:1` | 3 |" in page
    assert "![missed against scan time](missed_vs_scan_time.png)" in page
    assert (tmp_path / "missed_vs_scan_time.png").stat().st_size > 0
    assert load_rows(tmp_path, paper) == {(r.stratum, r.policy, r.seed): r for r in rows}
    with pytest.raises(ValueError, match="no row of disagreement on the first tree"):
        outcome_from_rows(paper, ["disagreement"], "test", tmp_path)


def test_claims_pair_learned_policies_with_each_fixed_schedule() -> None:
    """A student that misses less in less time beats a schedule; one at 0.7x the time of another
    and +0 points beats it as cheaper; the cheap end's share of no rotation's misses."""
    bench = benchmark("paper-v1")
    seeds = range(100_000, 100_040)
    spec = {  # policy: (missed a tree of 10, scan time s)
        "none": (4, 20.0),
        "periodic:22.5:1.5": (1, 35.0),
        "privileged": (0, 25.0),
        "periodic:45:2.5": (2, 70.0),
        "ftl:45:1": (2, 40.0),
        "ftl:22.5:1": (0, 30.0),
        "ppo:student@25": (2, 25.0),
        "ppo:student@100": (1, 50.0),
    }
    rows = [_row(p, s, 10, m, t) for p, (m, t) in spec.items() for s in seeds]
    results = benchmark_results(BenchmarkOutcome(bench, "test", rows), seed=0)
    claims = {c["fixed"]: c for c in results["claims"]["fixed_schedules"]}
    assert set(claims) == {"periodic:22.5:1.5", "periodic:45:2.5", "ftl:45:1", "ftl:22.5:1"}
    assert claims["periodic:45:2.5"]["verdict"] == "faster_fewer"  # @100: 1 < 2 in 50 < 70 s
    assert claims["periodic:45:2.5"]["learned"] == "ppo:student@100"
    assert claims["ftl:45:1"]["verdict"] == "cheaper"  # @25: 2 = 2 in 25 <= 0.8 x 40 s
    assert claims["ftl:22.5:1"]["verdict"] == ""  # nobody misses less than 0 in 30 s
    assert claims["ftl:22.5:1"]["learned"] == "ppo:student@25"  # the one within its time
    assert claims["periodic:22.5:1.5"]["comparison"]["missed_pct_diff"] == pytest.approx(10.0)
    (cheap,) = results["claims"]["cheap_end"]  # @25 at 1.25x none's time; @100 at 2.5x
    assert cheap["learned"] == "ppo:student@25"
    assert cheap["fewer"] == pytest.approx(0.5) and cheap["meets"]
    page = format_page(results, "python eval.py --benchmark paper-v1 ...")
    assert "| `periodic:45:2.5` | 20.0 / 70.0 | `ppo:student@100` | 0.71 |" in page
    assert "- `ppo:student@25` at 1.25x: 50 % [50, 50] fewer misses (meets 25 %)" in page


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
