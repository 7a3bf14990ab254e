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

``--backend ray`` runs the trials as Ray tasks (``pip install .[ray]``): on a private local Ray
instance of --workers CPUs, or on the cluster at --address; the results are the same as the
default process pool's (docs/integrations/ray.md).
"""

from __future__ import annotations

import argparse
import logging
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from tqdm import tqdm

from branch_gym.cli_options import add_scan_options, scan_config
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
    parser.add_argument("--trees", type=int, default=60, help="trees per policy (default 60)")
    parser.add_argument("--seed", type=int, default=0, help="first tree seed (default 0)")
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
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        scan = scan_config(args)
        config = EvalConfig(
            tuple(args.policies),
            args.trees,
            args.seed,
            args.workers,
            scan,
            backend=args.backend,
            address=args.address,
            record_dir=args.record,
            policy_factory=factory,
        )
    except (ValueError, TypeError) as exc:
        parser.error(str(exc))
    if config.backend == "ray":
        try:
            import_ray()  # before any output is written
        except RayUnavailableError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_USAGE

    bar = None

    def on_start(total: int, saved: int) -> None:
        nonlocal bar
        bar = tqdm(total=total, initial=saved, unit="trial", desc="trials", smoothing=0.0)

    def on_done(key: tuple[str, int]) -> None:
        bar.set_postfix_str(f"{key[0]} seed {key[1]}", refresh=False)
        bar.update(1)

    try:
        outcome = run_evaluation(
            config, args.out, args.plot_trees, on_start, on_done, rerun=args.rerun
        )
    except (ConfigMismatchError, ValueError, ConnectionError) as exc:  # Connection: Ray address
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except TrialError as exc:  # one line naming the trial and the cause; the traceback in a file
        if bar is not None:
            bar.close()  # the message goes on a line of its own
        log = args.out / ERROR_LOG
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text("".join(traceback.format_exception(exc)))
        print(f"error: {exc} (traceback in {log})", file=sys.stderr)
        return EXIT_TRIAL_FAILED
    except KeyboardInterrupt:
        print(
            f"\ninterrupted: finished trials are saved in {args.out / 'trials'}; "
            "run the same command again to resume",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    finally:
        if bar is not None:
            bar.close()

    loaded = len(outcome.records) - len(outcome.computed)
    print(f"\n{len(outcome.computed)} trials run, {loaded} loaded from {args.out / 'trials'}")
    print("\nOurs next to the paper's Table I (simulated, 60 trials per column):\n")
    print(format_comparison(outcome.summary, paper_column))
    print(f"\nFailure reasons: {failure_reasons(outcome.records, config.policies)}")
    print("\nwrote " + ", ".join(str(path) for path in outcome.files))
    return 0
