"""Thin owner of one pybullet physics client (the panda-gym split: it speaks numpy).

Everything that talks to pybullet goes through a :class:`Bullet` instance, so that several
simulations can live in one process (each with its own client id) and so that a scene can be
torn down completely between episodes (pybullet leaks memory otherwise).

pybullet's C code prints banners (``argv[0]=``, the EGL device list) on file descriptor 1 when
it connects or loads a plugin; :func:`stdout_to_log` routes them into this module's DEBUG log so
that library code keeps stdout clean for a CLI's output. (``import pybullet`` itself prints its
build time on stderr, not stdout.)
"""

from __future__ import annotations

import ctypes
import logging
import os
import pkgutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import pybullet
from pybullet_utils.bullet_client import BulletClient

from branch_gym.sim.validation import require_positive

logger = logging.getLogger(__name__)

_STDOUT_FD = 1


def _flush_c_stdout() -> None:
    """Flush the C library's stdout buffer (pybullet's printf output), where there is one."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to ask (e.g. Windows)
        pass


@contextmanager
def stdout_to_log() -> Iterator[None]:
    """Send what C code writes to file descriptor 1 during the block to the DEBUG log.

    Python's ``sys.stdout`` redirection does not reach C ``printf``: this swaps the descriptor
    itself (into a temporary file, read back and logged afterwards) and flushes the C buffer
    before putting stdout back. The descriptor is process-wide: another thread printing during
    the block is logged too. Without a usable descriptor 1 the block runs unchanged.
    """
    sys.stdout.flush()
    _flush_c_stdout()
    try:
        saved = os.dup(_STDOUT_FD)
    except OSError:
        yield
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), _STDOUT_FD)
        try:
            yield
        finally:
            _flush_c_stdout()
            os.dup2(saved, _STDOUT_FD)
            os.close(saved)
        sink.seek(0)
        text = sink.read().decode(errors="replace").strip()
    if text:
        logger.debug("pybullet stdout: %s", text)


@dataclass(frozen=True)
class BulletConfig:
    """How to connect.

    Attributes:
        gui: Open the pybullet GUI window (for people; needs a display).
        use_egl: Load the EGL renderer plugin (GPU machines). It must be loaded before any body is
            created, or it silently renders an empty scene (reference.md, "Gotchas").
        time_step_s: Physics / kinematic integration step in seconds.
    """

    gui: bool = False
    use_egl: bool = False
    time_step_s: float = 1.0 / 240.0

    def __post_init__(self) -> None:
        require_positive(self, "time_step_s")


class Bullet:
    """One pybullet client plus the few helpers the world needs.

    Attributes:
        p: The :class:`BulletClient`; call raw pybullet functions on it (client id is implicit).
        renderer: ``pybullet.ER_TINY_RENDERER`` or ``pybullet.ER_BULLET_HARDWARE_OPENGL`` (EGL).
    """

    def __init__(self, config: BulletConfig | None = None) -> None:
        self.config = config or BulletConfig()
        mode = pybullet.GUI if self.config.gui else pybullet.DIRECT
        with stdout_to_log():
            self.p = BulletClient(connection_mode=mode)
        self._egl_plugin: int | None = None
        self.renderer = pybullet.ER_TINY_RENDERER
        if self.config.use_egl:
            self._load_egl()
        self.reset()

    def _load_egl(self) -> None:
        egl = pkgutil.get_loader("eglRenderer")
        path = egl.get_filename() if egl is not None else None
        with stdout_to_log():
            plugin = self.p.loadPlugin(path, "_eglRendererPlugin") if path else -1
        if plugin < 0:
            raise RuntimeError("could not load the pybullet EGL renderer plugin (eglRenderer)")
        self._egl_plugin = plugin
        self.renderer = pybullet.ER_BULLET_HARDWARE_OPENGL
        logger.info("EGL renderer plugin loaded (id %d)", plugin)

    def reset(self) -> None:
        """Remove every body, constraint and cached shape: the leak-free way to rebuild a scene."""
        self.p.resetSimulation()
        self.p.setTimeStep(self.config.time_step_s)
        self.p.setGravity(0.0, 0.0, 0.0)
        if self.config.gui:
            self.p.configureDebugVisualizer(pybullet.COV_ENABLE_GUI, 0)

    def close(self) -> None:
        """Disconnect (idempotent)."""
        if self.p is None:
            return
        try:
            if self._egl_plugin is not None:
                self.p.unloadPlugin(self._egl_plugin)
            self.p.disconnect()
        except pybullet.error:  # already disconnected
            pass
        self.p = None

    def __enter__(self) -> Bullet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
