"""Evaluate rotation policies on simulated trees and compare with the paper's Table I.

The command line of :func:`branch_gym.evaluation.pipeline.run_evaluation`. The policies and the
paper's columns are handed in by the command that composes it (:mod:`agents.commands`:
``eval.py`` at the repository root and the installed ``branch-gym-eval``), where ``ppo:NAME``
plays a shipped model (``ppo:ppo_dagger_v2@100``).

Usage::

    python eval.py --policies none periodic:22.5:1.5 periodic:45:1.5 periodic:22.5:2.5 \\
        periodic:45:2.5 --trees 60 --seed 0 --workers 2 --out results/NAME \\
        [--world clean|orchard] [--tree paper|tall_spindle|ufo|...] \\
        [--tracker lk|oracle] [--segmenter gt|noisy:mild|learned|...] [--speed 0.025] \\
        [--plot-trees 0 1 2] [--end-height 0.75] [--backend pool|ray] [--address ADDR] \\
        [--record DIR]

Every policy scans the same trees (seeds SEED .. SEED+TREES-1). Each finished trial is saved at
once under OUT/trials/, and re-running the same command resumes: saved trials are loaded, not
re-run. OUT then holds summary.json, table.md, trials.csv, missed_vs_scan_time.png and one
tree_SEED.png per plotted tree. See branch_gym/evaluation/ for the definitions. ``--record DIR``
writes each trial run as a scan folder that ``python -m recon.replay`` reads (docs/replay.md).

``--benchmark NAME`` evaluates the policies on a named, versioned benchmark (``orchard-v2``,
``paper-v1``: :mod:`branch_gym.evaluation.benchmark`) instead: its world, trees, segmenter,
tracker and scan limits, on ``--split test`` (default) or ``validation``, with its reference
policies added; OUT then also holds ``benchmark.md`` (the results page: missed %, precision, scan
time, failures and paired intervals against the paper's controller and the privileged bound)
and ``benchmark.json``. The scan options and ``--seed`` are refused with it.

``--variant SECTION.FIELD=VALUE ...`` (with ``--benchmark``) tries a change of the
reconstruction on the benchmark's trees: ``modeler.FIELD`` or ``curve2d.FIELD`` (``ScanConfig``'s
``modeler`` and ``curve2d``), e.g. ``--variant curve2d.max_primary_turn_deg=45``, or a candidate
segmenter's weights, ``--variant 'segmenter="learned:PATH"'`` (its SHA-256 in the digest). It runs a
derived definition, ``NAME+curve2d.max_primary_turn_deg=45``, with its own digest: give it its
own ``--out`` (the benchmark's refuses its rows); its page says it is a variant, and with
``--base-out DIR`` (the benchmark's own ``--out`` of the same split) pairs each policy with
itself there.

``--backend ray`` runs the trials as Ray tasks (``pip install .[ray]``): on a private local Ray
instance of --workers CPUs, or on the cluster at --address; the results are the same as the
default process pool's (docs/integrations/ray.md).
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from tqdm import tqdm

from branch_gym.cli_options import add_scan_options, scan_config
from branch_gym.evaluation.benchmark import (
    BENCHMARKS,
    ROWS_FILE,
    SPLITS,
    Benchmark,
    TrialRow,
    benchmark,
    load_rows,
    outcome_from_rows,
    run_benchmark,
)
from branch_gym.evaluation.benchmark_page import benchmark_results, write_benchmark_page
from branch_gym.evaluation.config import EvalConfig, TrialError
from branch_gym.evaluation.pipeline import run_evaluation
from branch_gym.evaluation.ray_backend import (
    RayUnavailableError,
    add_backend_arguments,
    import_ray,
)
from branch_gym.evaluation.report import failure_reasons, format_comparison
from branch_gym.evaluation.runner import ConfigMismatchError
from branch_gym.policy import PolicyFactory

EXIT_USAGE = 2
EXIT_TRIAL_FAILED = 1
ERROR_LOG = "error.log"  # under --out: the traceback of a trial that raised
EXIT_INTERRUPTED = 130
DEFAULT_TREES = 60
# What a benchmark fixes: these options are refused beside --benchmark.
_FIXED_BY_BENCHMARK = (
    "--seed", "--world", "--tree", "--tracker", "--segmenter", "--speed", "--end-height",
    "--modeler", "--record", "--plot-trees",
)  # fmt: skip
# Of those, what a variant varies instead (Benchmark.with_variant).
_VARIED_BY_VARIANT = {
    "--modeler": "modeler.FIELD=VALUE",
    "--segmenter": "'segmenter=\"learned:PATH\"'",
}


def build_parser(factory: PolicyFactory) -> argparse.ArgumentParser:
    """The options; ``factory.spec_forms`` lists the policy specs in ``--help``."""
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n", 1)[0],
        epilog="Trials already saved in --out (same policy, seed and scan configuration) are "
        "loaded instead of re-run (with a warning when other code ran them; --rerun runs them "
        "again); --out holding trials of another configuration is refused.",
    )
    parser.add_argument(
        "--policies",
        nargs="+",
        required=True,
        metavar="SPEC",
        help=f"rotation policies (table columns, in this order): {factory.spec_forms}",
    )
    parser.add_argument(
        "--trees",
        type=int,
        help=f"trees per policy (default {DEFAULT_TREES}; with --benchmark: only the first "
        "TREES of each stratum's split, a quick look)",
    )
    parser.add_argument("--seed", type=int, help="first tree seed (default 0)")
    parser.add_argument(
        "--benchmark",
        choices=sorted(BENCHMARKS),
        help="evaluate on this benchmark: its world, trees, segmenter, tracker, scan limits and "
        "seeds (docs/results/benchmark.md)",
    )
    parser.add_argument(
        "--split", choices=SPLITS, default="test", help="the benchmark's split (default test)"
    )
    parser.add_argument(
        "--variant",
        nargs="+",
        metavar="SECTION.FIELD=VALUE",
        help="with --benchmark: run a variant of it, a derived definition with its own name and "
        "digest (give it its own --out) with reconstruction settings changed: modeler.FIELD "
        "(recon.config.ModelerConfig) or curve2d.FIELD (recon.curve2d.types.Curve2DConfig), "
        "JSON values, e.g. curve2d.max_primary_turn_deg=45; or segmenter='\"learned:PATH\"' "
        "(candidate weights, pinned by their SHA-256)",
    )
    parser.add_argument(
        "--base-out",
        type=Path,
        metavar="DIR",
        help="with --variant: the benchmark's own --out of the same split; the page pairs each "
        "policy with its rows there (variant minus benchmark, on the trees both have)",
    )
    parser.add_argument(
        "--from-rows",
        action="store_true",
        help="with --benchmark: write the results page from OUT/rows.jsonl, running nothing (each "
        "policy's first trees it has a row for, pairs on the trees both have: a run in progress, "
        "or committed rows)",
    )
    add_backend_arguments(parser, 1, "trials run at once: worker processes, or Ray tasks in flight")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    add_scan_options(parser, defaults={"world": "clean", "tree": "paper"})
    parser.add_argument(
        "--record",
        type=Path,
        metavar="DIR",
        help="also record every trial run as a scan folder DIR/POLICY/seed_SEED "
        "(replay with python -m recon.replay; docs/replay.md)",
    )
    parser.add_argument(
        "--rerun",
        action="store_true",
        help="run every trial again, replacing those saved in --out (e.g. after a code change)",
    )
    parser.add_argument(
        "--plot-trees",
        type=int,
        nargs="*",
        metavar="SEED",
        help="tree seeds to draw, one figure each (default: the first two seeds)",
    )
    return parser


def main(
    argv: list[str] | None,
    factory: PolicyFactory,
    paper_column: Callable[[str], dict | None],
) -> int:
    """Run the command line; returns the exit status.

    Args:
        argv: The arguments (None: ``sys.argv[1:]``).
        factory: Reads the policy specs (``agents.factory.AGENTS``).
        paper_column: A spec -> the paper's Table I column printed beside it, or None
            (``agents.paper.paper_column``).
    """
    parser = build_parser(factory)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.benchmark is not None:
        fixed = [f for f in _FIXED_BY_BENCHMARK if any(a.split("=")[0] == f for a in argv)]
        if fixed:
            varied = [_VARIED_BY_VARIANT[f] for f in fixed if f in _VARIED_BY_VARIANT]
            verb = "varies it" if len(varied) == 1 else "vary them"
            hint = f" (--variant {' '.join(varied)} {verb})" if varied else ""
            parser.error(f"--benchmark fixes the scan and the trees: drop {' '.join(fixed)}{hint}")
        if args.trees is not None and args.trees < 1:
            parser.error(f"--trees must be >= 1, got {args.trees}")
        bench = benchmark(args.benchmark)
        if args.variant:
            try:
                bench = bench.with_variant(args.variant)
            except ValueError as exc:
                parser.error(str(exc))
        elif args.base_out is not None:
            parser.error("--base-out pairs a variant with its benchmark: it needs --variant")
        return _run_benchmark(bench, args, argv, factory)
    if args.from_rows:
        parser.error("--from-rows reads a benchmark's rows: it needs --benchmark")
    if args.variant or args.base_out is not None:
        parser.error("--variant and --base-out vary a benchmark: they need --benchmark")
    try:
        scan = scan_config(args)
        config = EvalConfig(
            tuple(args.policies),
            DEFAULT_TREES if args.trees is None else args.trees,
            0 if args.seed is None else args.seed,
            args.workers,
            scan,
            backend=args.backend,
            address=args.address,
            record_dir=args.record,
            policy_factory=factory,
        )
    except (ValueError, TypeError) as exc:
        parser.error(str(exc))
    if not _backend_ready(config.backend):
        return EXIT_USAGE
    progress = _Progress()
    try:
        outcome = run_evaluation(
            config, args.out, args.plot_trees, progress.start, progress.done, rerun=args.rerun
        )
    except (ConfigMismatchError, ValueError, ConnectionError, TrialError, KeyboardInterrupt) as exc:
        return _failed(exc, args.out, progress)
    finally:
        progress.close()

    loaded = len(outcome.records) - len(outcome.computed)
    print(f"\n{len(outcome.computed)} trials run, {loaded} loaded from {args.out / 'trials'}")
    print("\nOurs next to the paper's Table I (simulated, 60 trials per column):\n")
    print(format_comparison(outcome.summary, paper_column))
    print(f"\nFailure reasons: {failure_reasons(outcome.records, config.policies)}")
    print("\nwrote " + ", ".join(str(path) for path in outcome.files))
    return 0


def _run_benchmark(
    bench: Benchmark, args: argparse.Namespace, argv: list[str], factory: PolicyFactory
) -> int:
    """``--benchmark`` (or a variant of it): run (or resume) the split, write the results page,
    print it."""
    try:  # the benchmark's own rows (--base-out) are read first: a bad folder costs no run
        base_rows = () if args.base_out is None else _base_rows(bench, args.base_out)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.from_rows:
        try:
            outcome = outcome_from_rows(bench, args.policies, args.split, args.out, args.trees)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_USAGE
    else:
        if not _backend_ready(args.backend):
            return EXIT_USAGE
        progress = _Progress()
        try:
            outcome = run_benchmark(
                bench, args.policies, args.split, args.out, factory, args.workers, args.backend,
                args.address, args.trees, progress.start, progress.done,
            )  # fmt: skip
        except (
            ConfigMismatchError, ValueError, ConnectionError, TrialError, KeyboardInterrupt
        ) as exc:  # fmt: skip
            return _failed(exc, args.out, progress)
        finally:
            progress.close()
    results = benchmark_results(outcome, base_rows=base_rows)
    if base_rows and not any("vs_base" in row for row in results["policies"].values()):
        print(f"warning: no policy shares a tree with {args.base_out}", file=sys.stderr)
    if args.trees is not None:
        results["trees_limit"] = args.trees
    command = "python eval.py " + shlex.join(argv)
    files = write_benchmark_page(args.out, results, command, factory)
    print(f"\n{len(outcome.computed)} trials run\n")
    print(files[1].read_text())
    print("wrote " + ", ".join(str(path) for path in files))
    return 0


def _base_rows(variant: Benchmark, out: Path) -> list[TrialRow]:
    """The rows of the benchmark ``variant`` derives from, saved under ``out``.

    Raises:
        ValueError: ``out`` holds no rows, or rows of another definition (a variant's).
    """
    rows = load_rows(out, benchmark(variant.base_name))
    if not rows:
        raise ValueError(f"--base-out {out} holds no {ROWS_FILE} of {variant.base_name}")
    return list(rows.values())


def _backend_ready(backend: str) -> bool:
    """Whether the backend can run: Ray is imported before any output is written."""
    if backend != "ray":
        return True
    try:
        import_ray()
    except RayUnavailableError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return False
    return True


class _Progress:
    """A progress bar over the trials, one per evaluation (a benchmark: one per stratum)."""

    def __init__(self) -> None:
        self.bar: tqdm | None = None

    def start(self, total: int, saved: int) -> None:
        self.close()
        self.bar = tqdm(total=total, initial=saved, unit="trial", desc="trials", smoothing=0.0)

    def done(self, key: tuple[str, int]) -> None:
        self.bar.set_postfix_str(f"{key[0]} seed {key[1]}", refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _failed(exc: BaseException, out: Path, progress: _Progress) -> int:
    """Report a failed evaluation in one line; returns the exit status."""
    progress.close()  # the message goes on a line of its own
    if isinstance(exc, KeyboardInterrupt):
        print(
            f"\ninterrupted: finished trials are saved under {out}; run the same command again "
            "to resume",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    if isinstance(exc, TrialError):  # one line naming the trial and the cause; the traceback
        log = out / ERROR_LOG
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text("".join(traceback.format_exception(exc)))
        print(f"error: {exc} (traceback in {log})", file=sys.stderr)
        return EXIT_TRIAL_FAILED
    print(f"error: {exc}", file=sys.stderr)  # a bad folder, value or Ray address
    return EXIT_USAGE
