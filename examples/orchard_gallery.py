"""Orchard frames beside their instance labels, depth and ground-truth optical flow.

Usage::

    python examples/orchard_gallery.py --out docs/figures/orchard_frames.jpg [--seeds 0 1 2 ...] \
        [--variety docs/figures/orchard_variety.jpg --variety-seeds 0 1 ... 11]

Each row is one tree seed (the architecture cycles through paper, tall spindle and UFO): the
camera starts at the scan's home pose, climbs a few centimetres and sometimes turns about the
branch; the frame is shown with its labels, its depth and its ground-truth flow against the
frame 7.5 mm lower (the paper's pairing), coded with the Middlebury colour wheel normalised by
the frame's largest flow (``flow_vis``, as FlowNet2's ``flow2img``).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import cv2
import flow_vis
import numpy as np

from branch_gym.sim.scene.flow import ground_truth_flow
from branch_gym.sim.scene.labels import (
    FIRST_ROW_TREE_LABEL,
    GROUND_LABEL,
    POST_LABEL,
    PRIMARY_LABEL,
    SKY_LABEL,
    WIRE_LABEL,
)
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.world import World, WorldConfig

ARCHITECTURES = ("paper", "tall_spindle", "ufo")
PAIR_STEP_M = 0.0075  # the paper's frame pairing: 7.5 mm of camera travel
CLIMB_SPEED_MPS = 0.025
STEP_S = 1.0 / 60.0
# Label colours (RGB) for the picture.
COLOURS = {
    "sky": (170, 200, 235),
    "ground": (120, 90, 60),
    "post": (200, 60, 200),
    "wire": (0, 230, 230),
    "row": (60, 90, 200),
    "primary": (230, 40, 40),
    "secondary": (250, 160, 30),
    "details": (250, 240, 60),
    "other": (0, 0, 0),
}
MAX_TURN_DEG = 15.0  # the camera turns at most this much about its own vertical while climbing
MAX_DEPTH_M = 4.0  # depth picture: black at the camera, white at 4 m and beyond
VARIETY_COLUMNS = 4
JPEG_QUALITY = 90  # the pictures are documentation: JPEG keeps the repository small


def colour_labels(labels: np.ndarray, n_secondaries: int) -> np.ndarray:
    """(H, W, 3) uint8 picture of an instance-label image (see ``COLOURS``)."""
    out = np.zeros((*labels.shape, 3), np.uint8)
    out[labels == SKY_LABEL] = COLOURS["sky"]
    out[labels == GROUND_LABEL] = COLOURS["ground"]
    out[labels == POST_LABEL] = COLOURS["post"]
    out[labels == WIRE_LABEL] = COLOURS["wire"]
    out[labels >= FIRST_ROW_TREE_LABEL] = COLOURS["row"]
    out[(labels >= 2) & (labels < 2 + n_secondaries)] = COLOURS["secondary"]
    out[labels == 2 + n_secondaries] = COLOURS["details"]
    out[labels == PRIMARY_LABEL] = COLOURS["primary"]
    return out


def climb(world: World, distance_m: float, yaw_rate: float = 0.0) -> None:
    """Move the camera up by ``distance_m`` (and turn it at ``yaw_rate`` rad/s about its y)."""
    for _ in range(max(1, round(distance_m / (CLIMB_SPEED_MPS * STEP_S)))):
        world.apply_camera_twist(np.array([0.0, -CLIMB_SPEED_MPS, 0.0, 0.0, yaw_rate, 0.0]), STEP_S)


def gallery_row(seed: int, rgb_only: bool = False) -> np.ndarray:
    """RGB | labels | depth | flow for the tree of ``seed``: (240, 1280, 3) uint8 RGB (or the
    RGB frame alone)."""
    architecture = ARCHITECTURES[seed % len(ARCHITECTURES)]
    world = World(WorldConfig.preset("orchard", getattr(TreeConfig, architecture)()))
    try:
        world.reset(seed)
        rng = np.random.default_rng(seed)
        distance_m = rng.uniform(0.02, 0.3)
        turn_rad = np.radians(rng.uniform(-MAX_TURN_DEG, MAX_TURN_DEG))
        climb(world, distance_m, yaw_rate=turn_rad * CLIMB_SPEED_MPS / distance_m)
        T_before, before = world.T_world_camera, world.render()
        climb(world, PAIR_STEP_M)
        images, T_after = world.render(), world.T_world_camera
        if rgb_only:
            return images.rgb
        flow = ground_truth_flow(images.depth_m, T_after, T_before, world.config.camera)
        flow_picture = flow_vis.flow_to_color(np.nan_to_num(flow))
        depth = np.clip(np.nan_to_num(images.depth_m, posinf=MAX_DEPTH_M) / MAX_DEPTH_M, 0, 1)
        depth_picture = np.repeat((255 * depth).astype(np.uint8)[..., None], 3, axis=2)
        labels = colour_labels(images.labels, len(world.tree.secondaries))
        del before
        return np.hstack([images.rgb, labels, depth_picture, flow_picture])
    finally:
        world.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures/orchard_frames.jpg"))
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(6)))
    parser.add_argument("--variety", type=Path, help="also write a grid of RGB frames here")
    parser.add_argument("--variety-seeds", type=int, nargs="+", default=list(range(6, 18)))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    grid = np.vstack([gallery_row(seed) for seed in args.seeds])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), grid[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    print(f"wrote {args.out}")
    if args.variety:
        frames = [gallery_row(seed, rgb_only=True) for seed in args.variety_seeds]
        frames += [np.zeros_like(frames[0])] * (-len(frames) % VARIETY_COLUMNS)
        rows = [
            np.hstack(frames[i : i + VARIETY_COLUMNS])
            for i in range(0, len(frames), VARIETY_COLUMNS)
        ]
        cv2.imwrite(
            str(args.variety), np.vstack(rows)[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
        )
        print(f"wrote {args.variety}")


if __name__ == "__main__":
    main()
