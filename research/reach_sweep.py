"""Re-score saved trials with only the secondaries that reach far enough out from the primary.

The study behind ``ModelerConfig.secondary_min_reach_m`` (``LEARNED_MASK_MIN_REACH_M``): the
setting only decides which of the model's secondaries are reported, so for policies that
do not read the model (none, periodic) the saved reconstruction of a trial run without it,
filtered and scored again, equals the trial run with it. Run the trials without the filter
(``--modeler secondary_min_reach_m=0``), then:

    python research/reach_sweep.py results/val_reach0 --policies none periodic_22.5_1.5 \
        --reach 0 0.025 0.03 0.035 0.04

The primary's axis is its saved model's base-to-top direction (the live filter takes the
primary of the latest iteration: the same up to the model's last refits).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from branch_gym.evaluation.trials import TRIALS_DIR, load_trial
from recon.metrics import evaluate
from recon.model3d.secondary import primary_axis, reach_m


def sweep(folder: Path, reaches_m: list[float]) -> dict[float, dict[str, int]]:
    """Pooled counts (n_gt, n_missed, n_spurious, n_duplicates) per reach over one policy's trials.

    Args:
        folder: ``OUT/trials/POLICY`` of an eval.py run.
        reaches_m: Reaches to try, metres (0 reports every secondary: the trials as run).
    """
    totals = {
        r: dict.fromkeys(("n_gt", "n_missed", "n_spurious", "n_duplicates"), 0) for r in reaches_m
    }
    for path in sorted(folder.glob("*.json")):
        record = load_trial(path)
        model = record.model
        axis = None if model.primary is None else primary_axis(model.primary.points)
        top_m = record.metrics.scanned_top_z_m
        for reach in reaches_m:
            kept = [s for s in model.secondaries if reach_m(s.points, axis) >= reach]
            metrics = evaluate(
                replace(model, secondaries=kept), record.truth, scanned_top_z_m=top_m
            )
            for key in totals[reach]:
                totals[reach][key] += getattr(metrics, key)
    return totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="an eval.py --out folder")
    parser.add_argument("--policies", nargs="+", required=True, help="policy folder names")
    parser.add_argument("--reach", nargs="+", type=float, default=[0.0, 0.03], help="metres")
    args = parser.parse_args()
    for policy in args.policies:
        for reach, t in sweep(args.out / TRIALS_DIR / policy, args.reach).items():
            gt = max(t["n_gt"], 1)
            print(
                f"{policy} reach >= {100 * reach:.1f} cm: missed {100 * t['n_missed'] / gt:.1f} % "
                f"({t['n_missed']}/{t['n_gt']}), spurious {100 * t['n_spurious'] / gt:.1f} %, "
                f"duplicates {100 * t['n_duplicates'] / gt:.1f} %"
            )


if __name__ == "__main__":
    main()
