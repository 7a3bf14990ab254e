"""Segmenter training pairs from a denser, closer orchard row: is the row's density a lever?

A study for issue 32. Behind the scanned tree of the real development frames stands a thicket of
thin upright shoots of the row's other trees, closer and denser than the orchard world draws them
(``OrchardRowConfig``: neighbours 0.6-1.2 m apart, two a side, 10 branches a metre, 1-5 shoots a
branch). This script renders frame pairs exactly as ``python -m branch_gym.segmenter_training
generate-orchard`` does, with the row drawn denser (:data:`DENSE_ROW`), into shards that
``train --data`` reads beside the usual ones. Only the study's shards change: the package's
worlds, and so every table, stay as they are.

    python research/dense_row_data.py --out runs/seg/dense_data --shards 0 15 &   # ~3 min
    python research/dense_row_data.py --out runs/seg/dense_data --shards 15 30    # each half
    python -m branch_gym.segmenter_training train --flow-picture \\
        --init recon/segmentation/weights/orchard_flow.pt --learning-rate 0.002 \\
        --side-branch-weight 3 --no-flow-probability 0.25 --details-as-background \\
        --overcast-probability 0.8 --data runs/seg/orchard_data runs/seg/clean_data \\
        runs/seg/dense_data --validation runs/seg/orchard_eval --run runs/seg/run_dense1 \\
        --seed 9 --steps 3000 --batch-size 8 --export runs/seg/orchard_flow_dense1.pt  # ~13 min

The result is in ``docs/orchard_segmenter.md``, "What was tried".
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

import branch_gym.segmenter_training.orchard_pairs as orchard_pairs
from branch_gym.segmenter_training.generate import shard_path, write_shard
from branch_gym.segmenter_training.orchard_pairs import OrchardPairsConfig, generate_orchard_shard
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.world import WorldConfig

DENSE_ROW = {
    "neighbour_spacing_range_m": (0.45, 0.9),  # default 0.6-1.2 m
    "neighbours_per_side": 3,  # default 2: the row still fills the view at the closer spacing
    "branches_per_m": 13.0,  # default 10
    "twigs_per_branch_range": (2, 8),  # default 1-5
}
"""The row's overrides (``OrchardRowConfig`` fields)."""
DATA_SEED = 7
"""Seed of the data set (the usual shards use 0)."""
TREES = 240


class DenseRowWorldConfig(WorldConfig):
    """``WorldConfig`` whose orchard preset draws the row with :data:`DENSE_ROW`."""

    @classmethod
    def preset(cls, name: str, tree: TreeConfig | None = None) -> WorldConfig:
        config = WorldConfig.preset(name, tree)
        if config.orchard is None:
            return config
        row = replace(config.orchard.row, **DENSE_ROW)
        return replace(config, orchard=replace(config.orchard, row=row))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--shards", type=int, nargs=2, metavar=("FIRST", "END"), default=(0, 30))
    args = parser.parse_args()
    config = OrchardPairsConfig(trees=TREES)
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"seed": DATA_SEED, "world": "orchard", "evaluation": False, "row": DENSE_ROW}
    (args.out / "generate_config.json").write_text(
        json.dumps({**record, **config.to_dict()}, indent=2)
    )
    # render_orchard_pairs builds its world from the module's WorldConfig: this study's row
    orchard_pairs.WorldConfig = DenseRowWorldConfig
    todo = [i for i in range(*args.shards) if not shard_path(args.out, i).exists()]
    for index in tqdm(todo, desc="shards", unit="shard"):
        write_shard(shard_path(args.out, index), generate_orchard_shard(config, DATA_SEED, index))


if __name__ == "__main__":
    main()
