"""Why does a rotating scan lose a side branch that a straight scan keeps? A study for issue 34.

On the orchard table from pixels, most branches a rotating policy misses are ones the scan
without rotation finds (``research/miss_overlap.py``). This script runs one trial of ``eval.py``'s
scan (orchard world, the learned segmenter or ``--segmenter gt``, LK) and prints, at every trust
update of the modeler (``SecondaryBranches.update_trust``, the authors' +1 / -1 check; a branch
below ``ModelerConfig.secondary_trust_min`` is deleted), each model side branch lying within
``--radius-mm`` of ground-truth side branch ``--branch``: its trust before the update, the share
of its observed points on the frame's mask (with the learned masks' tolerance), the same share for
the ground-truth centerline, how far the model lies from the truth (median, mm and px) and the
camera's yaw about the vertical. A branch whose model lies on the truth while the truth is off
the mask was deleted because the mask did not show it from that view.

    python research/trust_deletions.py --seed 31 --policy privileged --branch 0   # ~20 s
    python research/trust_deletions.py --seed 9 --policy periodic:22.5:2.5 --branch 1

The trace wraps ``SecondaryBranches.update_trust`` for the run (it reads, it changes nothing).
"""

from __future__ import annotations

import argparse

import numpy as np

from agents.factory import AGENTS
from branch_gym.cli_options import add_scan_options
from branch_gym.evaluation.episodes import run_trial
from branch_gym.scan import ScanConfig
from branch_gym.sim.world import World, WorldConfig
from recon.camera import project_points
from recon.frame import Frame
from recon.model3d import secondary
from recon.model3d.secondary import SecondaryBranches


def truth_centerline(seed: int, branch: int) -> np.ndarray:
    """(N, 3) centerline of ground-truth side branch ``branch`` of tree ``seed``, world frame."""
    world = World(WorldConfig.preset("orchard"))
    try:
        world.reset(seed)
        return world.tree.secondaries[branch].points
    finally:
        world.close()


def median_distance(points: np.ndarray, reference: np.ndarray) -> float:
    """Median over ``points`` (N, D) of the distance to the nearest of ``reference`` (M, D)."""
    gaps = np.linalg.norm(points[:, None] - reference[None], axis=2).min(axis=1)
    return float(np.median(gaps))


def trace(seed: int, policy: str, branch: int, radius_m: float, segmenter: str) -> None:
    """Run the trial with the trust updates traced (module docstring)."""
    truth = truth_centerline(seed, branch)
    original = SecondaryBranches.update_trust
    updates = 0

    def traced(self: SecondaryBranches, frame: Frame) -> None:
        nonlocal updates
        updates += 1
        tolerance = self.config.secondary_trust_tolerance_px or 0.0
        margin = self.config.image_margin_px
        rotation = frame.T_world_camera[:3, :3]
        yaw_deg = np.degrees(np.arctan2(rotation[0, 2], rotation[1, 2]))
        for candidate in self._branches:
            if candidate.model is None:
                continue
            observed = candidate.model.points[candidate.n_extension :]
            if median_distance(observed.mean(axis=0, keepdims=True), truth) > radius_m:
                continue
            on_mask, visible = secondary._mask_fraction(observed, frame, margin, tolerance)
            truth_on_mask, _ = secondary._mask_fraction(truth, frame, margin, tolerance)
            model_px, _ = project_points(observed, frame.T_world_camera, frame.intrinsics)
            truth_px, _ = project_points(truth, frame.T_world_camera, frame.intrinsics)
            print(
                f"update {updates:3d}  branch {id(candidate) % 10000:4d}"
                f"  trust {candidate.trust:2d}"
                f"  on the mask: model {on_mask:.2f} ({visible} points in view), truth "
                f"{truth_on_mask:.2f}  model to truth {1000 * median_distance(observed, truth):.1f}"
                f" mm, {median_distance(model_px, truth_px):.1f} px  camera z "
                f"{frame.T_world_camera[2, 3]:.3f} m, yaw {yaw_deg:6.1f} deg"
            )
        original(self, frame)

    scan = ScanConfig(world=WorldConfig.preset("orchard")).replace(
        segmenter=segmenter, tracker="lk"
    )
    SecondaryBranches.update_trust = traced
    try:
        result = run_trial(seed, policy, scan, AGENTS)
    finally:
        SecondaryBranches.update_trust = original
    row = result.branches[branch]
    print(
        f"trial done: {policy} on tree {seed}: branch {branch} matched {row['matched']}, miss "
        f"{row['miss'] or '-'}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, required=True, help="tree seed (eval.py's)")
    parser.add_argument("--policy", required=True, help="policy spec, e.g. privileged")
    parser.add_argument("--branch", type=int, required=True, help="ground-truth side branch")
    parser.add_argument("--radius-mm", type=float, default=15.0)
    add_scan_options(parser, ("segmenter",), defaults={"segmenter": "learned"})
    args = parser.parse_args()
    trace(args.seed, args.policy, args.branch, args.radius_mm / 1000.0, args.segmenter)


if __name__ == "__main__":
    main()
