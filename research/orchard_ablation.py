"""What makes the orchard hard: the orchard world with one of its parts taken away.

Usage::

    python research/orchard_ablation.py --variant no_crossing --trees 60 --workers 2 \\
        --out results/orchard_no_crossing

Variants (each the orchard world of ``WorldConfig.preset("orchard")`` with the paper's tree):

* ``no_crossing``: no neighbour branch reaches across the scanned tree on the camera's side;
* ``no_wires``: no trellis wire (nor clip);
* ``no_row``: neither, and no neighbour trees at all (sky, ground, rows behind, posts remain).

Each part is drawn as in the full orchard and then left out, so a variant's scenes are the full
orchard's scenes, tree for tree, without that part.

The policies are no rotation and the paper's 22.5 deg / 1.5; trials resume like ``eval.py``'s.
``--segmenter learned`` takes the masks from pixels (the renderer's labels by default).
The architectures need no script: ``eval.py --world orchard --tree tall_spindle`` (or ``ufo``).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path

from tqdm import tqdm

from agents.factory import AGENTS
from agents.paper import paper_column
from branch_gym.cli_options import add_scan_options, scan_config
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.pipeline import run_evaluation
from branch_gym.evaluation.report import format_comparison
from branch_gym.scan import ScanConfig
from branch_gym.sim.world import WorldConfig

POLICIES = ("none", "periodic:22.5:1.5")
# The parts each variant leaves out (OrchardRowConfig.left_out).
VARIANTS = {
    "no_crossing": ("crossing",),
    "no_wires": ("wires",),
    "no_row": ("neighbours", "crossing", "wires"),
}


def variant_world(name: str) -> WorldConfig:
    """The orchard world without the part ``name`` names (module docstring).

    The parts are drawn as in the full orchard and then left out (``OrchardRowConfig.
    left_out``), so that each variant's scene is the full one's, one part apart.
    """
    world = WorldConfig.preset("orchard")
    if name not in VARIANTS:
        raise ValueError(f"unknown variant {name!r}: {', '.join(VARIANTS)}")
    row = dataclasses.replace(world.orchard.row, left_out=VARIANTS[name])
    return dataclasses.replace(world, orchard=dataclasses.replace(world.orchard, row=row))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--variant", required=True, choices=tuple(VARIANTS))
    parser.add_argument("--trees", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path, required=True)
    add_scan_options(
        parser,
        ("segmenter", "modeler"),
        defaults={"segmenter": "gt"},
        modeler_example="over the defaults, e.g. primary_max_turn_deg=null "
        "primary_model_vouches=false",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    scan = scan_config(args, ScanConfig(world=variant_world(args.variant)))
    config = EvalConfig(POLICIES, args.trees, args.seed, args.workers, scan, policy_factory=AGENTS)
    bar = tqdm(total=len(config.keys), unit="trial")
    outcome = run_evaluation(
        config, args.out, [], lambda total, saved: bar.update(saved), lambda key: bar.update(1)
    )
    bar.close()
    print(format_comparison(outcome.summary, paper_column))


if __name__ == "__main__":
    main()
