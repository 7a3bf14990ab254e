"""``render()`` of :class:`branch_gym.env.BranchScanEnv`: video frames and the pybullet GUI.

* ``rgb_array``: the camera's current view with the latest mask, its fitted 2D curves and the
  projected 3D model overlaid (:func:`camera_frame`), e.g. for ``gymnasium.wrappers.RecordVideo``.
* ``human``: the pybullet GUI window (``BulletConfig(gui=True)``), its viewpoint following the
  camera (:func:`follow_in_gui`). It needs a display: :func:`require_display` refuses early on a
  headless Linux machine, where pybullet would otherwise fail inside its C code.
"""

from __future__ import annotations

import os
import sys

import numpy as np

from branch_gym.env.observation import Drawing
from branch_gym.scan import ScanSession
from branch_gym.sim.world import World
from recon.modeler import IterationReport
from recon.overlay import compose_frame

# pybullet GUI viewpoint (our choice): 0.9 m away, yawed 45 deg, 20 deg above the camera.
GUI_DISTANCE_M = 0.9
GUI_YAW_DEG = 45.0
GUI_PITCH_DEG = -20.0


def require_display() -> None:
    """Raise when ``render_mode="human"`` cannot open a window.

    Raises:
        RuntimeError: on Linux without ``DISPLAY`` or ``WAYLAND_DISPLAY``.
    """
    headless = not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if sys.platform.startswith("linux") and headless:
        raise RuntimeError(
            "render_mode='human' opens the pybullet GUI and needs a display (DISPLAY is not set); "
            "use render_mode='rgb_array' (e.g. with gymnasium.wrappers.RecordVideo) instead"
        )


def follow_in_gui(world: World) -> None:
    """Point the pybullet GUI's viewpoint at the camera."""
    camera = world.T_world_camera[:3, 3]
    world.bullet.p.resetDebugVisualizerCamera(
        GUI_DISTANCE_M, GUI_YAW_DEG, GUI_PITCH_DEG, camera.tolist()
    )


def camera_frame(
    session: ScanSession, report: IterationReport | None, drawing: Drawing
) -> np.ndarray:
    """(H, W, 3) uint8: a fresh render of the camera's view with the pipeline's state overlaid.

    Args:
        session: The scan (its world renders the view; its model and angle are annotated).
        report: The latest modeling iteration (mask and 2D curves), or None before the first.
        drawing: The latest observation drawing (projected model, candidates).
    """
    curves = None if report is None else report.mask_curves
    outcome = "-" if report is None else report.outcome.value
    text = (
        f"angle {session.angle_deg:+.1f} deg  {outcome}",
        f"model secondaries {len(session.model.secondaries)}",
    )
    return compose_frame(
        session.world.render().rgb,
        None if curves is None else curves.mask,
        None if curves is None else curves.primary,
        drawing.candidates,
        drawing.model,
        text,
    )
