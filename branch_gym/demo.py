"""``make demo``: the orchard benchmark from pixels and the clean table, on a few trees.

Two evaluations through the evaluation library (:func:`run_evaluation`, the code behind
``eval.py``), each printed as a table and written with its figures:

- ``orchard/``, the headline: the orchard world (sky, row, trellis, camera model) seen from
  pixels (the shipped learned segmenter, Lucas-Kanade tracking on the rendered bark) with no
  rotation, the paper's controller (periodic 22.5 deg / 1.5), the authors' controller (FTL
  22.5 deg / 1), the privileged bound (it reads the ground truth) and the shipped orchard student
  ``ppo_ctg_orchard`` at 25 s a branch (its card: ``agents/models/ppo_ctg_orchard.md``; the
  60-tree table: ``docs/results/orchard.md``);
- ``clean/``: the paper's clean world (ground-truth masks, LK) with no rotation, the paper's
  controller, the privileged bound and the shipped clean-world student ``ppo_dagger_v2``, next to
  the paper's Table I (``docs/results/paper_table.md``).

It also writes a video of the orchard student scanning the first orchard tree and a
camera/scene snapshot of that tree. A few trees give a noisy table: the pages above hold the
60-tree ones. Re-running resumes.

Usage: ``python -m agents.commands demo [--trees N] [--clean-trees N] [--out DIR] [--workers K]``
(installed: ``branch-gym-demo``).
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from gymnasium.wrappers import RecordVideo
from tqdm import tqdm

from branch_gym.env import BranchScanEnv
from branch_gym.evaluation.config import EvalConfig
from branch_gym.evaluation.episodes import run_episode
from branch_gym.evaluation.pipeline import EvalOutcome, run_evaluation
from branch_gym.evaluation.report import format_comparison, format_table
from branch_gym.evaluation.runner import ConfigMismatchError
from branch_gym.policy import PolicyFactory
from branch_gym.scan import ScanConfig
from branch_gym.sim.world import World, WorldConfig

# The shipped orchard student at the price it is shipped for (agents/models/ppo_ctg_orchard.md).
ORCHARD_STUDENT = "ppo:ppo_ctg_orchard@25"
ORCHARD_POLICIES = (
    "none",
    "periodic:22.5:1.5",  # the paper's controller
    "ftl:22.5:1",  # the authors' controller
    "privileged",  # the bound: reads the ground truth
    ORCHARD_STUDENT,
)
# The orchard from pixels: the shipped learned segmenter (docs/orchard_segmenter.md), LK.
ORCHARD_SCAN = ScanConfig(world=WorldConfig.preset("orchard"), segmenter="learned")
CLEAN_POLICIES = ("none", "periodic:22.5:1.5", "privileged", "ppo:ppo_dagger_v2@100")
# Trees per table: the whole demo took 149 CPU-seconds (2026-12-07, --workers 1; an orchard scan
# from pixels ~2.5x a clean one), so under 2 minutes on 2 idle cores.
DEMO_ORCHARD_TREES = 3
DEMO_CLEAN_TREES = 2


def _video(out: Path, seed: int, policy: str, scan: ScanConfig, factory: PolicyFactory) -> Path:
    """An MP4 of one scan played by ``policy``: the camera image with the pipeline overlaid."""
    env = BranchScanEnv(render_mode="rgb_array", scan=scan, **factory.env_kwargs(policy))
    agent = factory.make(policy, env)
    folder = out / "video"
    recorder = RecordVideo(
        env, str(folder), episode_trigger=lambda _: True, name_prefix=f"scan_tree{seed}",
        disable_logger=True,
    )  # fmt: skip
    try:
        run_episode(agent, recorder, seed, policy, options=factory.reset_options(policy))
    finally:
        recorder.close()
    return next(folder.glob(f"scan_tree{seed}*.mp4"))


def _snapshot(out: Path, seed: int, world_config: WorldConfig) -> Path:
    """Camera image and third-person view of a tree at its home pose."""
    world = World(world_config)
    try:
        world.reset(seed)
        camera = world.render().rgb
        scene = world.snapshot(480, 360)
    finally:
        world.close()
    pad = np.zeros((max(scene.shape[0], camera.shape[0]), camera.shape[1], 3), np.uint8)
    pad[: camera.shape[0]] = camera
    scene_pad = np.zeros((pad.shape[0], *scene.shape[1:]), np.uint8)
    scene_pad[: scene.shape[0]] = scene
    path = out / "snapshot.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate([pad, scene_pad], axis=1)[..., ::-1])
    return path


def _evaluate(title: str, config: EvalConfig, out: Path) -> EvalOutcome:
    """Run (or resume) one table with a progress bar; exits on trials of another config."""
    print(f"\n{title}: {config.trees} trees x {len(config.policies)} policies {config.policies}")
    try:
        with tqdm(total=len(config.keys), unit="scan") as bar:
            return run_evaluation(
                config,
                out,
                on_start=lambda total, done: bar.update(done),
                on_done=lambda key: bar.update(1),
            )
    except ConfigMismatchError as exc:  # trials of an older pipeline or model in out
        sys.exit(f"error: {exc}")


def build_parser() -> argparse.ArgumentParser:
    """The demo's command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--trees", type=int, default=DEMO_ORCHARD_TREES, help="orchard trees")
    parser.add_argument("--clean-trees", type=int, default=DEMO_CLEAN_TREES)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("results/demo"))
    return parser


def main(
    argv: list[str] | None,
    factory: PolicyFactory,
    paper_column: Callable[[str], dict | None],
) -> int:
    """Run the demo; returns the exit status (``agents.commands.demo``: ``make demo``,
    ``branch-gym-demo``, which hand in the policies and the paper's columns)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    orchard = EvalConfig(
        ORCHARD_POLICIES,
        args.trees,
        workers=args.workers,
        scan=ORCHARD_SCAN,
        policy_factory=factory,
    )
    clean = EvalConfig(
        CLEAN_POLICIES, args.clean_trees, workers=args.workers, policy_factory=factory
    )
    orchard_outcome = _evaluate("Orchard from pixels", orchard, args.out / "orchard")
    print(format_table(orchard_outcome.summary))
    clean_outcome = _evaluate("Clean world, next to the paper", clean, args.out / "clean")
    print(format_comparison(clean_outcome.summary, paper_column))
    print(
        f"\nOn {orchard.trees} and {clean.trees} trees one branch moves a column by many points; "
        "the 60-tree tables: docs/results/orchard.md, docs/results/paper_table.md"
    )
    snapshot = _snapshot(args.out / "orchard", orchard.seed, ORCHARD_SCAN.world)
    print(f"\nRecording {ORCHARD_STUDENT} scanning orchard tree {orchard.seed} ...")
    video = _video(args.out / "orchard", orchard.seed, ORCHARD_STUDENT, ORCHARD_SCAN, factory)
    files = [*orchard_outcome.files, *clean_outcome.files, snapshot, video]
    print("\nwrote:", *[str(p) for p in files], sep="\n  ")
    return 0
