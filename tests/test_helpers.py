"""The shared helpers: atomic JSON files, config utilities, field validation, stage timers."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from branch_gym.config_utils import flatten_dict, is_number
from branch_gym.files import write_json_atomic
from branch_gym.sim import validation as sim_validation
from recon import validation as recon_validation
from recon.timing import stage_timer


def test_write_json_atomic_writes_strict_json_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "out.json"
    write_json_atomic(path, {"b": 1, "a": [1.5, None]})
    assert path.read_text() == '{"b": 1, "a": [1.5, null]}'
    write_json_atomic(path, {"b": 1, "a": 2}, indent=2, sort_keys=True)
    assert path.read_text() == '{\n  "a": 2,\n  "b": 1\n}\n'
    assert sorted(p.name for p in path.parent.iterdir()) == ["out.json"]
    assert path.stat().st_mode & 0o777 == 0o644


def test_write_json_atomic_refuses_nan_and_keeps_the_old_file(tmp_path: Path) -> None:
    path = tmp_path / "out.json"
    write_json_atomic(path, {"x": 1})
    with pytest.raises(ValueError):
        write_json_atomic(path, {"x": math.nan})
    assert json.loads(path.read_text()) == {"x": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_is_number_takes_reals_but_not_bools() -> None:
    assert all(is_number(v) for v in (1, 2.5, np.float32(1.0), np.int64(3), math.inf))
    assert not any(is_number(v) for v in (True, "1", None, np.zeros(1)))


def test_flatten_dict_joins_nested_keys_with_dots() -> None:
    nested = {"a": 1, "ppo": {"gamma": 0.99, "net": {"width": 64}}, "b": [1]}
    assert flatten_dict(nested) == {"a": 1, "ppo.gamma": 0.99, "ppo.net.width": 64, "b": [1]}


@dataclass(frozen=True)
class _Example:
    rate: float = 1.0
    margin: float = 0.0
    count: int = 3


@pytest.mark.parametrize("module", [sim_validation, recon_validation])
def test_validation_helpers_name_the_class_the_field_and_the_value(module: object) -> None:
    module.require_positive(_Example(), "rate", "count")
    module.require_non_negative(_Example(), "margin")
    module.require_finite(_Example(rate=-1.0), "rate")
    with pytest.raises(ValueError, match=r"_Example\.rate must be positive and finite, got 0\.0"):
        module.require_positive(_Example(rate=0.0), "rate")
    with pytest.raises(ValueError, match=r"_Example\.rate must be positive and finite, got inf"):
        module.require_positive(_Example(rate=math.inf), "rate")
    module.require_positive(_Example(rate=math.inf), "rate", finite=False)
    with pytest.raises(ValueError, match=r"_Example\.margin must be finite and >= 0, got -1"):
        module.require_non_negative(_Example(margin=-1.0), "margin")
    with pytest.raises(ValueError, match=r"_Example\.margin must be >= 0, got nan"):
        module.require_non_negative(_Example(margin=math.nan), "margin", finite=False)
    with pytest.raises(ValueError, match=r"_Example\.rate must be .*finite"):
        module.require_finite(_Example(rate=math.nan), "rate")


def test_the_simulators_validators_are_recons() -> None:
    """One implementation: ``branch_gym.sim.validation`` only names ``recon.validation``'s."""
    for name in sim_validation.__all__:
        assert getattr(sim_validation, name) is getattr(recon_validation, name)
    assert is_number is recon_validation.is_number


def test_sim_validation_rejects_non_numbers_and_checks_int_bounds() -> None:
    with pytest.raises(ValueError, match=r"_Example\.rate must be positive and finite, got True"):
        sim_validation.require_positive(_Example(rate=True), "rate")
    sim_validation.require_int(_Example(), "count", minimum=1, maximum=3)
    with pytest.raises(ValueError, match=r"_Example\.count must be an int in \[0, 2\], got 3"):
        sim_validation.require_int(_Example(), "count", minimum=0, maximum=2)
    with pytest.raises(ValueError, match=r"_Example\.rate must be an int >= 1, got 1\.0"):
        sim_validation.require_int(_Example(), "rate", minimum=1)


def test_stage_timer_adds_milliseconds_also_when_the_block_raises() -> None:
    timings: dict[str, float] = {"a_ms": 5.0}
    with stage_timer(timings, "a_ms"):
        pass
    with pytest.raises(RuntimeError), stage_timer(timings, "b_ms"):
        raise RuntimeError("stage failed")
    assert timings["a_ms"] >= 5.0
    assert list(timings) == ["a_ms", "b_ms"]
    assert timings["b_ms"] >= 0.0
