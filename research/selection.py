"""Checkpoint selection: score saved models with LK tracking on validation trees, keep the best.

(A study, ``python -m research.selection``: the shipped students were chosen with plain
``eval.py`` runs on the validation trees instead, ``docs/results/learned_policies.md``.)

Training evaluates with its own (fast, oracle) tracker; the policy ships into scans with
Lucas-Kanade tracking on rendered images. This step replays candidate models through
``eval.py``'s evaluation (:func:`branch_gym.evaluation.pipeline.run_evaluation`, LK tracking,
clean masks) on the held-out validation trees (:func:`branch_gym.training.seeds.eval_tree_seeds`,
never the benchmark trees of ``eval.py --seed 0``) at a few prices of scan time, and scores each
model by the env's return at those prices::

    score = mean over prices p and trees of
            matched - 0.5 (spurious + duplicates) - scan_time_s / p - failed

(the :class:`branch_gym.env.reward.RewardConfig` weights). The best model is copied to ``--out``
and the table to ``--out`` with ``.selection.json``.

Usage::

    python -m research.selection MODEL.zip [MODEL.zip ...] --out runs/selected.zip \\
        [--trees 10] [--prices 25 100 400] [--workers 2] [--eval-dir DIR]
"""

from __future__ import annotations

import argparse
import logging
import math
import shutil
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from agents.factory import AGENTS
from agents.ppo import PPO_SPEC_PREFIX, PRICE_SEPARATOR
from branch_gym.env.reward import RewardConfig
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.pipeline import run_evaluation
from branch_gym.evaluation.trials import TrialRecord
from branch_gym.files import write_json_atomic
from branch_gym.scan import ScanConfig
from branch_gym.training.seeds import eval_tree_seeds
from recon.metrics import pooled_percent

logger = logging.getLogger(__name__)

# Our choice: the ends and the middle of the v1 price range (branch_gym.V1_BRANCH_VALUE_S).
DEFAULT_PRICES_S = (25.0, 100.0, 400.0)
DEFAULT_TREES = 10


@dataclass(frozen=True)
class ModelScore:
    """One candidate's validation result.

    Attributes:
        model: The model file.
        score: Mean return at the prices (module docstring).
        missed_pct: Missed in-scope secondaries over all its trials (%).
        scan_time_s: Mean scan time (s).
        rotations: Mean rotations per scan.
        failures: Failed scans.
    """

    model: str
    score: float
    missed_pct: float
    scan_time_s: float
    rotations: float
    failures: int


def trial_return(record: TrialRecord, price_s: float, reward: RewardConfig) -> float:
    """The env's episode return of a finished trial at a price (seconds a branch is worth)."""
    return reward.episode_return(
        record.metrics, record.scan_time_s, record.failure is not None, 1.0 / price_s
    )


def score_records(model: Path, records: Sequence[TrialRecord]) -> ModelScore:
    """Score one model from its trials (one per tree and price; the price is in each spec)."""
    reward = RewardConfig()
    returns = []
    for record in records:
        _, _, price = record.policy.rpartition(PRICE_SEPARATOR)
        returns.append(trial_return(record, float(price), reward))
    return ModelScore(
        model=str(model),
        score=float(np.mean(returns)),
        missed_pct=pooled_percent(
            [r.metrics.n_missed for r in records], [r.metrics.n_gt for r in records]
        ),
        scan_time_s=float(np.mean([r.scan_time_s for r in records])),
        rotations=float(np.mean([r.rotations for r in records])),
        failures=sum(r.failure is not None for r in records),
    )


def select_model(
    models: Sequence[Path],
    eval_dir: Path,
    trees: int = DEFAULT_TREES,
    prices_s: Sequence[float] = DEFAULT_PRICES_S,
    workers: int = 1,
    progress: bool = False,
) -> list[ModelScore]:
    """Evaluate every model at every price on the validation trees; best score first.

    Args:
        models: Candidate model files.
        eval_dir: The evaluation folder (resumable: trials already there are reused).
        trees: Validation trees.
        prices_s: Prices of scan time (seconds a found branch is worth).
        workers: Trials run at once.
        progress: Show a progress bar.

    Raises:
        FileNotFoundError: a model file is missing.
        ValueError: no models or prices, or a bad price.
    """
    if not models or not prices_s:
        raise ValueError("checkpoint selection needs at least one model and one price")
    missing = [str(m) for m in models if not Path(m).is_file()]
    if missing:
        raise FileNotFoundError(f"model file(s) not found: {missing}")
    specs = {
        Path(m): [f"{PPO_SPEC_PREFIX}{m}{PRICE_SEPARATOR}{p:g}" for p in prices_s] for m in models
    }
    seeds = eval_tree_seeds(trees)
    config = EvalConfig(
        policies=tuple(s for group in specs.values() for s in group),
        trees=trees,
        seed=seeds[0],
        workers=workers,
        scan=ScanConfig(),  # LK tracking, clean masks: what eval.py's table uses
        policy_factory=AGENTS,
    )
    with tqdm(total=len(config.keys), unit="scan", disable=not progress) as bar:
        outcome = run_evaluation(
            config,
            eval_dir,
            plot_seeds=[],
            on_start=lambda total, done: bar.update(done),
            on_done=lambda key: bar.update(1),
        )
    scores = []
    for model, group in specs.items():
        records = [r for r in outcome.records if r.policy in group]
        scores.append(score_records(model, records))
    return sorted(scores, key=lambda s: -s.score)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("models", nargs="+", type=Path, help="candidate model files (.zip)")
    parser.add_argument("--out", type=Path, required=True, help="where to copy the best model")
    parser.add_argument("--trees", type=int, default=DEFAULT_TREES, help="validation trees")
    parser.add_argument("--prices", type=float, nargs="+", default=list(DEFAULT_PRICES_S))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--eval-dir", type=Path, help="evaluation folder (resumable)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    eval_dir = args.eval_dir or args.out.with_suffix(".selection")
    try:
        scores = select_model(
            args.models, eval_dir, args.trees, args.prices, args.workers, progress=True
        )
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    best = Path(scores[0].model)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if best.resolve() != args.out.resolve():
        shutil.copyfile(best, args.out)
    table = {
        "trees": eval_tree_seeds(args.trees),
        "prices_s": list(args.prices),
        "tracker": "lk",
        "selected": str(best),
        "candidates": [
            {
                k: None if isinstance(v, float) and not math.isfinite(v) else v
                for k, v in row.items()
            }
            for row in map(asdict, scores)
        ],
    }
    write_json_atomic(args.out.with_suffix(".selection.json"), table)
    for s in scores:
        print(
            f"{s.score:8.3f}  missed {s.missed_pct:5.1f} %  {s.scan_time_s:5.1f} s  "
            f"{s.rotations:4.1f} rot  {s.failures} failed  {s.model}"
        )
    print(f"selected {best} -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
