"""A recording from a camera of higher resolution, replayed natively and at the pipeline's focal.

A study for issue 32's users: the shipped segmenter and the paper's pixel thresholds were made
for the authors' 320x240 camera (416.8 px focal length), and ``python -m recon.replay
--working-focal-px pipeline`` resizes a recording to it (``recon.io.rescale``). How much does
that matter to the tree a replay builds? For each tree this script records a scan of the
orchard world seen by the simulated camera at ``--factor`` times the resolution
(``CameraSpec.scaled``: the same field of view, that many times the focal length in pixels;
the renderer's labels drive the recorded scan), the same scan at the pipeline's own camera as a
reference, and replays them with the learned segmenter: the reference, the large recording
as recorded, and the large recording at the pipeline's focal length. All are scored against the
truth (``recon.metrics``).

    python research/replay_resolution.py --trees 6 --work runs/replay_resolution &
    python research/replay_resolution.py --trees 6 --first 6 --work runs/replay_resolution
    python research/replay_resolution.py --trees 12 --work runs/replay_resolution --table

Every recording and replay is kept in ``--work`` and skipped when it is there (resumable, and
two processes can take disjoint trees). ``--table`` prints the markdown table of the trees
found there.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

from agents.factory import AGENTS
from branch_gym.evaluation.record import record_scan
from branch_gym.scan import ScanConfig
from branch_gym.sim.world import WorldConfig
from recon.io.rescale import PIPELINE_FOCAL_PX
from recon.replay import replay

VARIANTS = {  # replay name: (recording, working focal length)
    "pipeline camera": ("x1", None),
    "large camera, as recorded": ("large", None),
    "large camera, --working-focal-px pipeline": ("large", PIPELINE_FOCAL_PX),
}


def record_tree(work: Path, seed: int, factor: float) -> None:
    """Record tree ``seed`` with the pipeline's camera and the large one (skips existing)."""
    orchard = WorldConfig.preset("orchard")
    for name, camera in (("x1", orchard.camera), ("large", orchard.camera.scaled(factor))):
        out = work / f"{name}_{seed}"
        if not out.exists():
            world = replace(orchard, camera=camera)
            record_scan(
                seed, "none", ScanConfig(world=world), out, image_format="jpg", factory=AGENTS
            )


def replay_tree(work: Path, seed: int) -> None:
    """Replay tree ``seed``'s recordings with the learned segmenter (skips existing)."""
    for k, (recording, focal_px) in enumerate(VARIANTS.values()):
        source, out = work / f"{recording}_{seed}", work / f"replay{k}_{seed}"
        if not out.exists():
            replay(source, out, truth=source / "truth.json", segmenter="learned",
                   progress=False, working_focal_px=focal_px)  # fmt: skip


def table(work: Path, seeds: list[int]) -> str:
    """The markdown table of the replays of ``seeds`` found in ``work``."""
    lines = [
        "| replay | trees | camera seen | missed side branches | spurious | primary residual mm "
        "| replay s a tree |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, name in enumerate(VARIANTS):
        summaries = [
            json.loads(path.read_text())
            for seed in seeds
            if (path := work / f"replay{k}_{seed}" / "summary.json").exists()
        ]
        if not summaries:
            continue
        metrics = [s["metrics"] for s in summaries]
        n_gt = sum(m["n_gt"] for m in metrics)
        missed = sum(m["n_missed"] for m in metrics)
        spurious = sum(m["n_spurious"] for m in metrics)
        residuals = [float(r) for m in metrics for r in m["pb_residuals_m"]]
        residual_mm = 1e3 * sum(residuals) / max(len(residuals), 1)
        camera = summaries[0]["camera"]
        wall = sum(s["wall_time_s"] for s in summaries) / len(summaries)
        lines.append(
            f"| {name} | {len(summaries)} | {camera['width']}x{camera['height']} | "
            f"{missed} of {n_gt} | {spurious} | {residual_mm:.1f} | {wall:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="recordings and replays")
    parser.add_argument("--first", type=int, default=0, help="first tree seed")
    parser.add_argument("--trees", type=int, default=6)
    parser.add_argument("--factor", type=float, default=2.0, help="the large camera's scale")
    parser.add_argument("--table", action="store_true", help="print the table only")
    args = parser.parse_args()
    seeds = list(range(args.first, args.first + args.trees))
    if not args.table:
        args.work.mkdir(parents=True, exist_ok=True)
        for seed in tqdm(seeds, desc="trees", unit="tree"):
            record_tree(args.work, seed, args.factor)
            replay_tree(args.work, seed)
    print(table(args.work, seeds))


if __name__ == "__main__":
    main()
