"""The scan options every command declares through branch_gym.cli_options."""

from __future__ import annotations

import argparse
from dataclasses import replace

import pytest

from branch_gym.cli_options import add_scan_options, scan_changes, scan_config
from branch_gym.env.config import scan_with_tree
from branch_gym.scan import ScanConfig
from branch_gym.sim.world import WorldConfig


def _parse(argv: list[str], **kwargs) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_scan_options(parser, **kwargs)
    return parser.parse_args(argv)


def test_the_options_given_make_the_scan_the_commands_built_by_hand() -> None:
    args = _parse(
        ["--world", "orchard", "--tree", "ufo", "--tracker", "oracle", "--speed", "0.03"],
        defaults={"world": "clean", "tree": "paper"},
    )
    by_hand = scan_with_tree(ScanConfig(world=WorldConfig.preset("orchard")), "ufo").replace(
        tracker="oracle", speed_mps=0.03
    )
    assert scan_config(args) == by_hand


def test_defaults_apply_and_options_not_given_keep_the_scan() -> None:
    args = _parse([], defaults={"world": "clean", "tree": "paper"})
    assert (args.world, args.tree, args.tracker, args.segmenter) == ("clean", "paper", None, None)
    assert scan_config(args) == ScanConfig(world=WorldConfig.preset("clean"))
    base = ScanConfig(tracker="oracle", end_height_m=0.4)
    assert scan_config(_parse([], options=("tracker", "end_height")), base) == base


def test_an_end_height_given_wins_over_a_stretch_tree() -> None:
    stretch = scan_config(_parse(["--tree", "tall_spindle_leader"]))
    assert stretch.end_height_m > ScanConfig().end_height_m  # the preset sets its stretch
    args = _parse(["--tree", "tall_spindle_leader", "--end-height", "1.2"])
    assert scan_config(args) == stretch.replace(end_height_m=1.2)


def test_modeler_settings_go_over_the_modeler_and_bad_ones_are_refused() -> None:
    args = _parse(["--modeler", "secondary_trust_tolerance_px=0"])
    scan = scan_config(args)
    assert scan.modeler == replace(ScanConfig().modeler, secondary_trust_tolerance_px=0)
    with pytest.raises(ValueError, match="no_such_field"):
        scan_config(_parse(["--modeler", "no_such_field=1"]))


def test_a_command_takes_only_the_options_it_declares() -> None:
    args = _parse(["--tracker", "lk"], options=("tracker", "segmenter"))
    assert scan_changes(args) == {"tracker": "lk"}
    with pytest.raises(SystemExit):
        _parse(["--world", "orchard"], options=("tracker",))
    with pytest.raises(SystemExit):  # argparse names the bad choice
        _parse(["--tracker", "sift"])
    with pytest.raises(ValueError, match="colour"):
        _parse([], options=("tracker", "colour"))
    with pytest.raises(ValueError, match="world"):
        _parse([], options=("tracker",), defaults={"world": "clean"})
