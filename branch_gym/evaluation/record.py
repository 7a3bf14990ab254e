"""Record one simulated scan as a scan folder: ``python -m agents.commands record``.

The recorded folder replays with ``python -m recon.replay`` (``docs/replay.md``). The policy
specs are read by the factory the command hands in (:mod:`agents.commands`).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from branch_gym.cli_options import add_scan_options, scan_config
from branch_gym.evaluation.episodes import Recording, run_trial
from branch_gym.policy import PolicyFactory
from branch_gym.scan import ScanConfig
from branch_gym.scoring import ScanResult


def record_scan(
    seed: int,
    policy_spec: str = "none",
    scan_config: ScanConfig | None = None,
    out_dir: str | Path = "scan",
    image_format: str = "png",
    jpeg_quality: int = 95,
    overwrite: bool = False,
    *,
    factory: PolicyFactory,
) -> ScanResult:
    """Scan the tree of ``seed`` with a policy and record it as a scan folder.

    Args:
        seed: Tree seed (also the modeler's seed).
        policy_spec: Policy spec ("none", "periodic:22.5:1.5", "ppo:PATH", ...).
        scan_config: Scan settings (``end_height_m`` low for a short recording).
        out_dir: The scan folder to create (appears only when complete).
        image_format: "png" (lossless: exact replays) or "jpg" (small).
        jpeg_quality: JPEG quality 0-100.
        overwrite: Replace an existing ``out_dir``.
        factory: Reads the spec (``agents.factory.AGENTS``).

    Returns:
        The scan's :class:`branch_gym.scoring.ScanResult` (scored online).
    """
    record = Recording(Path(out_dir), image_format, jpeg_quality, overwrite)
    return run_trial(seed, policy_spec, scan_config or ScanConfig(), factory, record)


def main(argv: list[str] | None, factory: PolicyFactory) -> int:
    """``python -m agents.commands record --seed 0 --out DIR``: record one simulated scan."""
    parser = argparse.ArgumentParser(
        prog="python -m agents.commands record", description="Record a simulated scan."
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policy", default="none", help=f"policy spec: {factory.spec_forms}")
    add_scan_options(
        parser,
        ("end_height", "segmenter"),
        defaults={"end_height": ScanConfig.end_height_m, "segmenter": "gt"},
    )
    parser.add_argument("--image-format", choices=("png", "jpg"), default="png")
    parser.add_argument("--jpeg-quality", type=int, default=95)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    config = scan_config(args)
    result = record_scan(
        args.seed,
        args.policy,
        config,
        args.out,
        image_format=args.image_format,
        jpeg_quality=args.jpeg_quality,
        overwrite=args.overwrite,
        factory=factory,
    )
    size = sum(p.stat().st_size for p in args.out.rglob("*") if p.is_file())
    print(
        f"recorded {args.out} ({size / 1e6:.1f} MB): seed {args.seed}, {result.n_iterations} "
        f"iterations, {len(result.model.secondaries)} secondaries, scan time "
        f"{result.scan_time_s:.1f} s, PB residual {result.metrics.pb_residual_mean_m * 1e3:.2f} mm"
    )
    return 0
