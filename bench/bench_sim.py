"""Simulator costs on one core: rendering a 320x240 frame and resetting the world.

Figures (medians, milliseconds):

* ``render_frame_ms``: one RGB + depth + segmentation frame (``World.render``) at camera heights
  along a straight-up scan (0.275 -> 0.75 m) of a few paper-default trees, background included.
* ``render_frame_bare_ms``: the same scan with only the primary branch (no secondaries, no
  clutter) and the background disabled: the renderer's floor.
* ``reset_ms``: ``World.reset`` with a new tree each time (tree drawing, meshes, textures, robot
  and home-pose IK).
* ``render_frame_orchard_ms``, ``reset_orchard_ms``: the same on the orchard world (sky, row,
  trellis, camera model; issue 31: <= 2x ``render_frame_ms`` of the same run, <= 300 ms), and
  their ratio ``render_orchard_over_clean``. The clean, orchard and fast orchard scans are taken
  in turn, seed by seed (:func:`render_frames_in_turn_ms`).
* ``render_frame_orchard_fast_ms``: the same frames in the world ``"orchard_fast"`` (the
  orchard's pixel-changing speed-ups on, ``OrchardConfig.fast``), and
  ``render_orchard_fast_over_clean`` (issue 60: <= 2).

Only the timed call is measured: the camera motion between frames is not.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from branch_gym.sim.robot.home import SCAN_END_HEIGHT_M
from branch_gym.sim.scene.background import BackgroundConfig
from branch_gym.sim.scene.tree_scene import SceneConfig
from branch_gym.sim.tree.config import TreeConfig
from branch_gym.sim.tree.generator import generate_tree
from branch_gym.sim.tree.ground_truth import TreeGT
from branch_gym.sim.world import World, WorldConfig

RENDER_SEEDS = (0, 1, 2)  # paper-default trees scanned for the render figures
RESET_SEEDS = tuple(range(100, 140))  # 40 new trees for the reset figure (>= 30 asked)
# Frames every 1 cm of climb: ~48 frames per tree; the camera moves at 0.1 m/s for 0.1 s (the
# arm's joint-speed limit is far away) and no frame is rendered in between.
CLIMB_SPEED_MPS = 0.1
CLIMB_STEP_S = 0.1
WARMUP_SEEDS = (98, 99)  # first builds pay lazy imports and allocator growth: not timed
S_TO_MS = 1e3


def _up_twist(speed_mps: float) -> np.ndarray:
    """(6,) camera-frame twist straight up (image up is camera -y in the level scan pose)."""
    return np.array([0.0, -speed_mps, 0.0, 0.0, 0.0, 0.0])


def _scan_render_ms(world: World) -> list[float]:
    """Milliseconds of each ``world.render()`` along a straight-up scan from the home pose."""
    times = []
    while world.T_world_camera[2, 3] <= SCAN_END_HEIGHT_M:
        start = time.perf_counter()
        world.render()
        times.append((time.perf_counter() - start) * S_TO_MS)
        if not world.apply_camera_twist(_up_twist(CLIMB_SPEED_MPS), CLIMB_STEP_S).ok:
            break
    return times


def _bare_tree(seed: int) -> TreeGT:
    """A paper-default primary branch drawn from ``seed``, alone (no secondaries, no clutter)."""
    config = TreeConfig()
    full = generate_tree(config, np.random.default_rng(seed), seed=seed)
    return TreeGT(primary=full.primary, seed=seed)


def render_frame_ms(
    seeds: tuple[int, ...] = RENDER_SEEDS, bare: bool = False, world_name: str = "clean"
) -> float:
    """Median render time per frame over straight-up scans of the trees of ``seeds``.

    Args:
        seeds: Tree seeds (paper-default distribution).
        bare: Render the primary branch alone, without background.
        world_name: One of ``WORLDS`` (``WorldConfig.preset``).

    Returns:
        Median milliseconds per ``World.render`` call.
    """
    config = WorldConfig.preset(world_name)
    if bare:
        config = WorldConfig(scene=SceneConfig(background=BackgroundConfig(enabled=False)))
    return _render_in_turn({world_name: config}, seeds, bare)[world_name]


def render_frames_in_turn_ms(
    world_names: tuple[str, ...], seeds: tuple[int, ...] = RENDER_SEEDS
) -> dict[str, float]:
    """:func:`render_frame_ms` of several worlds, their scans taken in turn, seed by seed.

    Their ratios then share the machine's moment: timed a minute apart on a loaded machine, the
    same code's orchard-over-clean ratio read 1.63 and 2.13 (measured).
    """
    return _render_in_turn({name: WorldConfig.preset(name) for name in world_names}, seeds)


def _render_in_turn(
    configs: dict[str, WorldConfig], seeds: tuple[int, ...], bare: bool = False
) -> dict[str, float]:
    """Median ms per ``World.render`` of each world over the scans of ``seeds``, in turn."""
    worlds = {name: World(config) for name, config in configs.items()}
    try:
        times: dict[str, list[float]] = {name: [] for name in worlds}
        for seed in seeds:
            for name, world in worlds.items():
                world.reset(seed, tree=_bare_tree(seed) if bare else None)
                world.render()  # warm-up: first frame of a scene
                times[name] += _scan_render_ms(world)
        return {name: float(np.median(values)) for name, values in times.items()}
    finally:
        for world in worlds.values():
            world.close()


def reset_ms(seeds: tuple[int, ...] = RESET_SEEDS, world_name: str = "clean") -> float:
    """Median ``World.reset`` time in milliseconds, a new tree per reset."""
    world = World(WorldConfig.preset(world_name))
    try:
        for seed in WARMUP_SEEDS:
            world.reset(seed)
        times = []
        for seed in seeds:
            start = time.perf_counter()
            world.reset(seed)
            times.append((time.perf_counter() - start) * S_TO_MS)
        return float(np.median(times))
    finally:
        world.close()


def run() -> dict[str, float]:
    """Simulator benchmark figures (module docstring), medians in milliseconds, one core."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core, as the targets (OpenCV ignores OMP_NUM_THREADS)
    try:
        frames = render_frames_in_turn_ms(("clean", "orchard", "orchard_fast"))
        return {
            "render_frame_ms": frames["clean"],
            "render_frame_bare_ms": render_frame_ms(bare=True),
            "reset_ms": reset_ms(),
            "render_frame_orchard_ms": frames["orchard"],
            "reset_orchard_ms": reset_ms(world_name="orchard"),
            "render_frame_orchard_fast_ms": frames["orchard_fast"],
        }
    finally:
        cv2.setNumThreads(threads)
