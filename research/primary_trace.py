"""Why a scan lost its branch: each iteration's mask, skeleton, 2D primary and the model's prior.

Runs one scan (a policy spec on one tree seed, as ``eval.py`` would) with the modeler
instrumented and draws one tile per modeling iteration: the cleaned mask (grey), its skeleton
(white), occlusion bridges (green rings), the 3D model's primary projected into the frame, which
guides the 2D choice (blue), the 2D primary the iteration chose (red) and its side branches
(green), with the outcome and its reason. It prints the same per iteration, with the camera's
x and height (world frame, metres), so that the iteration where the camera left the scanned
trunk stands out.

    python research/primary_trace.py --seed 19 --policy none --world orchard \
        --segmenter learned --first 9 --last 30 --out /tmp/s19_trace.png
    python research/primary_trace.py --seed 19 --policy none --world orchard \
        --segmenter learned --modeler primary_max_turn_deg=30 --first 9 --last 30 \
        --out /tmp/s19_trace_turn30.png

The live scan, not a replay of a recording: ``eval.py --record`` keeps JPEG frames, and point
tracking on them can take other iterations than the live run's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

import recon.modeler as modeler_module
from agents.factory import AGENTS
from branch_gym.cli_options import add_scan_options, scan_config
from branch_gym.evaluation.benchmark import benchmark
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig

_TILE_COLUMNS = 4


def trace(seed: int, policy: str, scan: ScanConfig) -> list[dict]:
    """Run the scan and keep what each modeling iteration saw and chose.

    Returns:
        One dict per iteration: ``report`` (the IterationReport), ``prior_px`` ((K, 2) projected
        model pixels or None) and ``T_world_camera`` ((4, 4) pose of its frame).
    """
    kept: list[dict] = []
    original = modeler_module.Modeler._iterate

    def instrumented(self, frames, timings):
        prior = self._prior(frames[-1])
        report = original(self, frames, timings)
        kept.append({
            "report": report,
            "prior_px": None if prior is None else prior.pixels.copy(),
            "T_world_camera": frames[-1].T_world_camera.copy(),
        })  # fmt: skip
        return report

    modeler_module.Modeler._iterate = instrumented
    try:
        run_trial(seed, policy, scan, AGENTS)
    finally:
        modeler_module.Modeler._iterate = original
    return kept


def draw(entry: dict) -> np.ndarray:
    """(H, W, 3) uint8 BGR tile of one iteration."""
    report = entry["report"]
    curves = report.mask_curves
    tile = cv2.cvtColor(curves.mask.astype(np.uint8) * 90, cv2.COLOR_GRAY2BGR)
    skeleton = curves.skeleton.pixels_uv
    tile[skeleton[:, 1], skeleton[:, 0]] = (255, 255, 255)
    for uv in curves.skeleton.bridge_uv.astype(int):
        cv2.circle(tile, tuple(uv), 3, (0, 255, 0), 1)
    if entry["prior_px"] is not None:
        for uv in entry["prior_px"].astype(int):
            cv2.circle(tile, tuple(uv), 2, (255, 0, 0), -1)
    for secondary in curves.secondaries:
        for uv in secondary.samples_px.astype(int):
            cv2.circle(tile, tuple(uv), 1, (0, 200, 0), -1)
    if curves.primary is not None:
        for uv in curves.primary.curve(np.linspace(0.0, 1.0, 40)).astype(int):
            cv2.circle(tile, tuple(uv), 1, (0, 0, 255), -1)
    z = entry["T_world_camera"][2, 3]
    text = f"{report.index} {report.outcome.value} z {z:.3f}"
    cv2.putText(tile, text, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 255, 255), 1)
    cv2.putText(tile, report.reason[:48], (3, tile.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX,
                0.3, (255, 255, 0), 1)  # fmt: skip
    return tile


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, required=True, help="tree seed")
    parser.add_argument("--policy", default="none", help="policy spec (eval.py --policies)")
    add_scan_options(
        parser,
        ("world", "tree", "segmenter", "modeler"),
        defaults={"world": "orchard", "tree": "paper", "segmenter": "learned"},
        modeler_example="over the defaults, e.g. primary_max_turn_deg=null",
    )
    parser.add_argument(
        "--benchmark", default=None, help="scan as this benchmark's first stratum does (orchard-v1)"
    )
    parser.add_argument("--first", type=int, default=1, help="first iteration drawn")
    parser.add_argument("--last", type=int, default=None, help="last iteration drawn")
    parser.add_argument("--out", type=Path, default=None, help="PNG of the tiles")
    args = parser.parse_args()
    scan = scan_config(args)
    if args.benchmark:
        bench = benchmark(args.benchmark)
        scan = bench.scan_config(bench.strata[0])
    entries = trace(args.seed, args.policy, scan)
    last = args.last or len(entries)
    chosen = [e for e in entries if args.first <= e["report"].index <= last]
    for entry in chosen:
        report, position = entry["report"], entry["T_world_camera"][:3, 3]
        print(
            f"{report.index:4d} {report.outcome.value:12s} camera x {position[0]:+.3f} "
            f"z {position[2]:.3f}  {report.reason}"
        )
    if args.out and chosen:
        tiles = [draw(entry) for entry in chosen]
        tiles += [np.zeros_like(tiles[0])] * (-len(tiles) % _TILE_COLUMNS)
        rows = [
            np.concatenate(tiles[i : i + _TILE_COLUMNS], axis=1)
            for i in range(0, len(tiles), _TILE_COLUMNS)
        ]
        cv2.imwrite(str(args.out), np.concatenate(rows, axis=0))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
