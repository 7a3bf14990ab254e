"""The scan options of every command and research script, declared and read in one place.

=================  ===============================  ============================================
option             sets                             values
=================  ===============================  ============================================
``--world``        the world preset                 :data:`branch_gym.sim.world.WORLDS`
``--tree``         the tree distribution            :data:`branch_gym.env.config.TREE_PRESETS`
``--tracker``      ``ScanConfig.tracker``           ``lk`` | ``oracle``
``--segmenter``    ``ScanConfig.segmenter``         ``gt`` | ``noisy:LEVEL`` | ``learned[:PATH]``
``--speed``        ``ScanConfig.speed_mps``         m/s
``--end-height``   ``ScanConfig.end_height_m``      m
``--modeler``      ``ScanConfig.modeler`` fields    ``FIELD=VALUE ...`` (:mod:`recon.config`)
=================  ===============================  ============================================

:func:`add_scan_options` declares the ones a command takes (one argument group, the command's
own defaults); :func:`scan_config` turns the parsed options into a
:class:`~branch_gym.scan.ScanConfig`, and :func:`scan_changes` gives them as the config fields
of a command that keeps them by name (``TrainConfig``). ``recon.replay`` declares its own: it
reads recordings, not simulated scans (its ``--segmenter`` takes ``mask``), and ``recon`` does
not import ``branch_gym``.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from branch_gym.env.config import TREE_PRESETS, scan_with_tree
from branch_gym.scan import ScanConfig
from branch_gym.sim.world import WORLDS, WorldConfig
from recon.config import add_modeler_argument, modeler_overrides
from recon.tracking import TRACKERS

SCAN_OPTIONS = ("world", "tree", "tracker", "segmenter", "speed", "end_height", "modeler")
# The options that are ScanConfig fields of the same value: option dest -> field.
_SCAN_FIELDS = {
    "tracker": "tracker",
    "segmenter": "segmenter",
    "speed": "speed_mps",
    "end_height": "end_height_m",
}
# Each option but --modeler: (flag, help, argparse keywords).
_ARGUMENTS: dict[str, tuple[str, str, dict[str, Any]]] = {
    "world": (
        "--world",
        "clean: the paper's world; orchard: sky, row, trellis, camera model",
        {"choices": WORLDS},
    ),
    "tree": ("--tree", "tree distribution", {"choices": TREE_PRESETS}),
    "tracker": ("--tracker", "point tracker", {"choices": TRACKERS}),
    "segmenter": (
        "--segmenter",
        "segmenter spec: gt | noisy:mild|moderate|severe | learned[:PATH]",
        {},
    ),
    "speed": ("--speed", "camera speed (m/s)", {"type": float, "metavar": "MPS"}),
    "end_height": (
        "--end-height",
        "scan end height (m); lower for quick runs",
        {"type": float, "metavar": "M"},
    ),
}


def add_scan_options(
    parser: argparse.ArgumentParser,
    options: Sequence[str] = SCAN_OPTIONS,
    defaults: Mapping[str, Any] | None = None,
    modeler_example: str = "over the defaults, e.g. secondary_trust_tolerance_px=0",
) -> argparse._ArgumentGroup:
    """Declare the scan options ``options`` (names of :data:`SCAN_OPTIONS`) on ``parser``.

    Args:
        parser: The command's parser.
        options: The options the command takes, in help order.
        defaults: The command's default of an option (by name); an option without one is None
            when not given (the scan's, or the recipe's, value stays).
        modeler_example: What ``--modeler`` applies over, with an example, for its help.

    Returns:
        The "scan" argument group.

    Raises:
        ValueError: an unknown option name, or a default for an option not taken.
    """
    defaults = dict(defaults or {})
    unknown = sorted(set(options) - set(SCAN_OPTIONS)) + sorted(set(defaults) - set(options))
    if unknown:
        raise ValueError(f"unknown or untaken scan options {unknown}: expected {SCAN_OPTIONS}")
    group = parser.add_argument_group("scan", "the simulated scan")
    for name in options:
        if name == "modeler":
            add_modeler_argument(group, modeler_example)
            continue
        flag, help_text, keywords = _ARGUMENTS[name]
        default = defaults.get(name)
        if default is not None:
            help_text += f" (default {default})"
        group.add_argument(flag, default=default, help=help_text, **keywords)
    return group


def scan_changes(args: argparse.Namespace) -> dict[str, Any]:
    """The scan options given, as config fields: ``world`` and ``tree`` (preset names),
    ``tracker``, ``segmenter``, ``speed_mps``, ``end_height_m``; those not given are left out.

    >>> scan_changes(argparse.Namespace(tracker="oracle", speed=None, tree="paper"))
    {'tree': 'paper', 'tracker': 'oracle'}
    """
    changes = {name: getattr(args, name, None) for name in ("world", "tree")}
    changes |= {field: getattr(args, dest, None) for dest, field in _SCAN_FIELDS.items()}
    return {field: value for field, value in changes.items() if value is not None}


def scan_config(args: argparse.Namespace, base: ScanConfig | None = None) -> ScanConfig:
    """The scan of the parsed options: ``base`` (default ``ScanConfig()``) in the world preset
    given, with the tree given (a stretch preset also sets its heights), then the other fields
    given, then the ``--modeler`` settings over the modeler's.

    Raises:
        ValueError, TypeError: a bad value (named), e.g. an unknown or removed modeler field.
    """
    scan = base or ScanConfig()
    changes = scan_changes(args)
    if "world" in changes:
        scan = scan.replace(world=WorldConfig.preset(changes.pop("world")))
    if "tree" in changes:
        scan = scan_with_tree(scan, changes.pop("tree"))
    scan = scan.replace(**changes)
    if getattr(args, "modeler", None):
        scan = scan.replace(modeler=replace(scan.modeler, **modeler_overrides(args.modeler)))
    return scan
