"""A benchmark's results: the table, the paired intervals, the headroom and the power, as data
and as a Markdown page (``OUT/benchmark.md``, ``OUT/benchmark.json``).

Every policy scans the same trees. Per policy: missed % of the in-scope side branches (a failed
scan misses the branches above where it stopped) with its bootstrap interval over trees,
precision, spurious % (nothing there) beside the paper's spurious %, mean scan time, failed
scans, and the cost (missed branches + scan time / the benchmark's price, per tree). Against the
paper's controller and against the privileged bound: the paired difference of missed % with its
95 % interval (:func:`branch_gym.evaluation.statistics.paired_comparison`). The headroom is the
paired difference between no rotation and the bound. The power section gives, per policy, the
half-width its interval against the paper's controller has and the trees that +-1 point would
take (:mod:`branch_gym.evaluation.power`). A variant's page (``eval.py --variant``) says it is one
and, given the benchmark's own rows, pairs each policy with itself under the benchmark.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from branch_gym.evaluation.benchmark import BenchmarkOutcome, TrialRow
from branch_gym.evaluation.claims import (
    ClaimRules,
    cheap_end_claims,
    compare,
    fixed_schedule_claims,
    on_common_trees,
)
from branch_gym.evaluation.plots import plot_missed_vs_scan_time
from branch_gym.evaluation.power import PairedSample, predicted_half_width, trees_for_half_width
from branch_gym.evaluation.statistics import (
    PERCENT,
    BootstrapConfig,
    bootstrap_ci,
)
from branch_gym.files import write_json_atomic
from branch_gym.policy import PolicyFactory
from recon.metrics import BRANCH_CLASSES, NOT_PRECISE, SURROUNDING_KINDS

PAGE = "benchmark.md"
RESULTS = "benchmark.json"
FRONT = "missed_vs_scan_time.png"
TARGET_HALF_WIDTH_PCT = 1.0  # issue 60: the interval of a policy near the paper's, +-1 point


def benchmark_results(
    outcome: BenchmarkOutcome, seed: int = 0, base_rows: Sequence[TrialRow] = ()
) -> dict:
    """The results as JSON-able data (module docstring).

    Args:
        outcome: A finished :func:`branch_gym.evaluation.benchmark.run_benchmark`.
        seed: Seeds the bootstrap resampling (the same command gives the same intervals).
        base_rows: A variant's: the rows of the benchmark it derives from (its ``OUT/rows.jsonl``,
            :func:`branch_gym.evaluation.benchmark.load_rows`). Each policy that has rows there
            gets ``vs_base``: its missed % here minus there, paired on the trees both have.
    """
    bench = outcome.benchmark
    by_policy = _pooled(outcome)
    policies = list(by_policy)
    reference = by_policy[bench.reference_policy]
    bound = by_policy[bench.bound_policy]
    base_by_policy: dict[str, list[TrialRow]] = {}
    for row in base_rows:
        base_by_policy.setdefault(row.policy, []).append(row)
    rows = {}
    for policy in policies:
        records = by_policy[policy]
        ci = bootstrap_ci(records, np.random.default_rng(seed))
        time_s = np.array([r.scan_time_s for r in records])
        missed = np.array([r.n_missed for r in records])
        n_gt = sum(r.n_gt for r in records)
        classes = {name: sum(r.classes.get(name, 0) for r in records) for name in BRANCH_CLASSES}
        held = sum(classes[name] for name in NOT_PRECISE)
        row = {
            "trees": len(records),
            "n_gt": n_gt,
            "n_missed": int(missed.sum()),
            "missed_pct": _percent(missed.sum(), n_gt),
            "missed_pct_ci": ci["missed_pct_ci"],
            "precision_pct": _percent(classes["match"], classes["match"] + held),
            "spurious_pct": _percent(classes["spurious"], n_gt),
            "spurious_paper_pct": _percent(
                classes["spurious"] + sum(classes[kind] for kind in SURROUNDING_KINDS), n_gt
            ),
            "duplicate_pct": _percent(classes["duplicate"], n_gt),
            "n_unreached": sum(r.n_unreached for r in records),
            "scan_time_s": float(time_s.mean()),
            "scan_time_s_ci": ci["scan_time_s_ci"],
            "failures": sum(r.failure is not None for r in records),
            "cost_branches_per_tree": float(np.mean(missed + time_s / bench.branch_value_s)),
            "classes": classes,
        }
        for name, other in (("reference", reference), ("bound", bound)):
            if policy == (bench.reference_policy if name == "reference" else bench.bound_policy):
                continue
            row[f"vs_{name}"] = compare(records, other, seed)
        if policy != bench.reference_policy:
            row["power"] = _power(*on_common_trees(records, reference))
        if on_common_trees(records, base_by_policy.get(policy, []))[0]:
            row["vs_base"] = compare(records, base_by_policy[policy], seed)
        rows[policy] = row
    headroom = compare(by_policy[bench.baseline_policy], bound, seed)
    variant = {"of": bench.base_name, "settings": bench.variant_items} if bench.variant else {}
    return {
        **({"variant": variant} if variant else {}),
        "benchmark": bench.name,
        "digest": bench.digest(),
        "split": outcome.split,
        "strata": _trees_by_stratum(outcome),
        "branch_value_s": bench.branch_value_s,
        "reference_policy": bench.reference_policy,
        "bound_policy": bench.bound_policy,
        "baseline_policy": bench.baseline_policy,
        "split_trees": sum(stratum.seeds(outcome.split)[1] for stratum in bench.strata),
        "policies": rows,
        "headroom": headroom,
        "claims": {
            "fixed_schedules": fixed_schedule_claims(by_policy, seed),
            "cheap_end": cheap_end_claims(by_policy, bench.baseline_policy, seed),
        },
        "bootstrap": {"resamples": BootstrapConfig().resamples, "seed": seed},
    }


def write_benchmark_page(
    out: Path, results: dict, command: str, factory: PolicyFactory | None = None
) -> list[Path]:
    """Write ``OUT/benchmark.json``, ``OUT/benchmark.md`` and, given the factory that reads the
    specs, the front (``OUT/missed_vs_scan_time.png``, linked from the page); returns their
    paths."""
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / RESULTS, results)
    paths = [out / RESULTS, out / PAGE]
    if factory is not None:
        paths.append(out / FRONT)
        plot_missed_vs_scan_time(_as_summary(results), paths[-1], factory)
    (out / PAGE).write_text(format_page(results, command, front=factory is not None))
    return paths


def _as_summary(results: dict) -> dict:
    """The per-policy points in the form :func:`plot_missed_vs_scan_time` reads."""
    return {
        "policies": {
            policy: {
                "scan_time_s": {"mean": row["scan_time_s"], "std": None},
                "scan_time_s_ci": row["scan_time_s_ci"],
                "missed_pct": row["missed_pct"],
                "missed_pct_ci": row["missed_pct_ci"],
            }
            for policy, row in results["policies"].items()
        }
    }


def format_page(results: dict, command: str, front: bool = False) -> str:
    """The results page: the command, the table, the headroom and the power (and the front
    figure's link when ``front``)."""
    rows = results["policies"]
    reference, bound = results["reference_policy"], results["bound_policy"]
    trees, n_gt = rows[reference]["trees"], rows[reference]["n_gt"]
    split_trees = results.get("split_trees", trees)
    lines = [
        f"# `{results['benchmark']}`, {results['split']} split",
        "",
        "```bash",
        command,
        "```",
        "",
        f"Definition digest `{results['digest']}`; {trees} trees of the paper's controller "
        f"({', '.join(f'{k} {v}' for k, v in results['strata'].items())} in all), {n_gt} side "
        f"branches in scope on them. Cost = missed branches + scan time / "
        f"{results['branch_value_s']:g} s, per tree. Intervals: 95 %, bootstrap over trees; "
        "differences paired on the trees both policies have "
        f"(policy minus `{reference}`, the paper's controller, and minus `{bound}`).",
        "",
        *_variant_lines(results),
    ]
    if "trees_limit" in results:
        lines += [
            f"**Partial**: the first {results['trees_limit']} trees of each stratum's split only "
            "(`--trees`); the same command without it runs the rest.",
            "",
        ]
    elif any(row["trees"] < split_trees for row in rows.values()):
        lines += [
            f"**Partial**: a policy with fewer than the split's {split_trees} trees has its first "
            "trees only (the rows so far, `--from-rows`); each difference pairs the trees both "
            "policies have. The command without `--from-rows` runs the rest.",
            "",
        ]
    lines += [
        "| policy | trees | missed % [95 %] | vs paper's [95 %] | vs bound [95 %] | precision % | "
        "spurious % (paper's) | scan time s | failures | cost |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for policy, row in rows.items():
        lines.append(
            f"| `{policy}` | {row['trees']} | {_pct(row['missed_pct'])} "
            f"{_ci(row['missed_pct_ci'])} | "
            f"{_diff(row.get('vs_reference'))} | {_diff(row.get('vs_bound'))} | "
            f"{_pct(row['precision_pct'])} | {_pct(row['spurious_pct'])} "
            f"({_pct(row['spurious_paper_pct'])}) | {row['scan_time_s']:.1f} | "
            f"{row['failures']} | {row['cost_branches_per_tree']:.2f} |"
        )
    headroom = results["headroom"]
    lines += [
        "",
        f"Headroom (`{results['baseline_policy']}` minus `{bound}`): "
        f"{_diff(headroom)} points of missed %.",
        "",
        *(
            [
                f"![missed against scan time]({FRONT}) Missed % against scan time, 95 % "
                "intervals over trees: fixed schedules circles, learned policies squares on "
                "their front, the bound a star.",
                "",
            ]
            if front
            else []
        ),
        *_claims_lines(results),
        "Power: the half-width of each policy's interval against the paper's controller on these "
        "trees, and the trees that +-1 point would take (delta method on the paired per-tree "
        "differences, `branch_gym/evaluation/power.py`):",
        "",
        "| policy | half-width (points) | trees for +-1 point |",
        "|---|---|---|",
    ]
    for policy, row in rows.items():
        if row.get("power"):
            power = row["power"]
            lines.append(
                f"| `{policy}` | {power['half_width_pct']:.2f} | {power['trees_for_1_point']} |"
            )
    lines += [
        "",
        "Classes of the reconstructed side branches, all policies: "
        + ", ".join(
            f"{name} {sum(row['classes'][name] for row in rows.values())}"
            for name in next(iter(rows.values()))["classes"]
        )
        + ".",
        "",
    ]
    return "\n".join(lines)


def _variant_lines(results: dict) -> list[str]:
    """A variant's notice and, given the benchmark's rows, each policy against itself there."""
    variant = results.get("variant")
    if not variant:
        return []
    base = variant["of"]
    settings = ", ".join(f"`{item}`" for item in variant["settings"])
    lines = [
        f"**A variant, not the benchmark**: `{base}` with {settings}, a derived definition "
        f"(`eval.py --variant`) with its own digest, never in the Version History; its figures "
        f"are not `{base}`'s.",
        "",
    ]
    paired = {
        policy: row["vs_base"] for policy, row in results["policies"].items() if "vs_base" in row
    }
    if paired:
        lines += [
            f"Each policy against itself under `{base}` (its rows given with `--base-out`), "
            "paired on the trees both have: missed % difference (variant minus benchmark), "
            "trees the variant missed fewer / more branches on, and both mean scan times.",
            "",
            "| policy | trees | missed % difference [95 %] | fewer / more | scan time s |",
            "|---|---|---|---|---|",
        ]
        for policy, comparison in paired.items():
            lines.append(
                f"| `{policy}` | {comparison['trees']} | {_diff(comparison)} | "
                f"{comparison['wins']} / {comparison['losses']} | "
                f"{comparison['scan_time_s']:.1f} vs {comparison['other_scan_time_s']:.1f} |"
            )
        lines.append("")
    return lines


def _claims_lines(results: dict) -> list[str]:
    """The claims section: each fixed schedule against the learned policies, the cheap end."""
    claims = results.get("claims", {})
    fixed = [c for c in claims.get("fixed_schedules", []) if c["learned"] is not None]
    if not fixed:
        return []
    rows, rules = results["policies"], ClaimRules()
    cheaper = f"<= {rules.cheaper_time_factor:g}x its time, <= +{rules.cheaper_slack_points:g}"
    verdicts = {"faster_fewer": "**yes**: in its time, fewer", "cheaper": f"**yes**: {cheaper}"}
    lines = [
        "Learned policies against each fixed schedule (`branch_gym/evaluation/claims.py`): the "
        "learned policy that beats it, else the closest; the difference in missed % (learned "
        "minus fixed) paired on the trees both have. Beats: at most its scan time, fewer misses "
        f"and the interval's upper end <= 0, or at most {rules.cheaper_time_factor:g}x its time "
        f"and the upper end <= +{rules.cheaper_slack_points:g} point.",
        "",
        "| fixed schedule | missed % / scan time s | learned policy | time ratio | "
        "missed % difference [95 %] | trees | beats |",
        "|---|---|---|---|---|---|---|",
    ]
    for claim in fixed:
        comparison, schedule = claim["comparison"], rows[claim["fixed"]]
        lines.append(
            f"| `{claim['fixed']}` | {_pct(schedule['missed_pct'])} / "
            f"{schedule['scan_time_s']:.1f} | `{claim['learned']}` | "
            f"{comparison['time_ratio']:.2f} | {_diff(comparison)} | {comparison['trees']} | "
            f"{verdicts.get(claim['verdict'], 'no')} |"
        )
    lines.append("")
    cheap = claims.get("cheap_end", [])
    baseline = results["baseline_policy"]
    budget, goal = f"{rules.cheap_end_time_factor:g}x", f"{100 * rules.cheap_end_fewer:.0f} %"
    if cheap:
        lines += [
            f"Within {budget} the scan time of `{baseline}`, the share of its misses a learned "
            f"policy avoids (1 - the ratio of the misses, paired interval; the goal {goal}):",
            "",
        ]
        for claim in cheap:
            fewer, interval = claim["fewer"], claim["fewer_ci"]
            share = "-" if fewer is None else f"{100 * fewer:.0f} %"
            if interval is not None:
                share += f" [{100 * interval[0]:.0f}, {100 * interval[1]:.0f}]"
            lines.append(
                f"- `{claim['learned']}` at {claim['comparison']['time_ratio']:.2f}x: {share} "
                f"fewer misses ({'meets' if claim['meets'] else 'short of'} {goal}); "
                f"{_diff(claim['comparison'])} points."
            )
        lines.append("")
    else:
        lines += [f"No learned policy scans within {budget} the time of `{baseline}`.", ""]
    return lines


def _pooled(outcome: BenchmarkOutcome) -> dict[str, list[TrialRow]]:
    """Policy -> its trials over every stratum, in stratum then seed order."""
    pooled: dict[str, list[TrialRow]] = {}
    for row in outcome.rows:
        pooled.setdefault(row.policy, []).append(row)
    return pooled


def _trees_by_stratum(outcome: BenchmarkOutcome) -> dict[str, int]:
    """Stratum -> its trees in the outcome."""
    trees: dict[str, set[int]] = {}
    for row in outcome.rows:
        trees.setdefault(row.stratum, set()).add(row.seed)
    return {name: len(seeds) for name, seeds in trees.items()}


def _percent(count: float, total: float) -> float | None:
    return float(PERCENT * count / total) if total else None


def _power(a: Sequence[TrialRow], b: Sequence[TrialRow]) -> dict | None:
    """The power entry of ``a`` against ``b``; None with under two trees or no branch."""
    try:
        sample = _paired_sample(a, b)
    except ValueError:
        return None
    return {
        "half_width_pct": predicted_half_width(sample, len(a)),
        "trees_for_1_point": trees_for_half_width(sample, TARGET_HALF_WIDTH_PCT),
    }


def _paired_sample(a: Sequence[TrialRow], b: Sequence[TrialRow]) -> PairedSample:
    a_sorted, b_sorted = sorted(a, key=lambda r: r.seed), sorted(b, key=lambda r: r.seed)
    if [r.seed for r in a_sorted] != [r.seed for r in b_sorted]:
        raise ValueError("a paired sample needs both policies on the same tree seeds")
    return PairedSample(
        np.array([r.n_missed for r in a_sorted], float),
        np.array([r.n_missed for r in b_sorted], float),
        np.array([r.n_gt for r in a_sorted], float),
    )


def _pct(value: float | None) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.1f}"


def _ci(interval: Sequence[float] | None) -> str:
    return "" if interval is None else f"[{interval[0]:.1f}, {interval[1]:.1f}]"


def _diff(comparison: dict | None) -> str:
    if comparison is None or comparison["missed_pct_diff"] is None:
        return "-"
    return f"{comparison['missed_pct_diff']:+.1f} {_ci(comparison['missed_pct_diff_ci'])}"


def load_results(out: Path) -> dict:
    """``OUT/benchmark.json`` as written by :func:`write_benchmark_page`."""
    return json.loads((out / RESULTS).read_text())
