"""Small helpers shared by the configuration modules (env, training, evaluation).

:func:`is_number` is the one test of "a real number" the config checks use;
:func:`flatten_dict` turns a nested config dict into dotted keys for "what changed" messages.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from typing import Any

__all__ = ["flatten_dict", "is_number"]


def is_number(value: object) -> bool:
    """A real number: int, float or numpy scalar, but not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def flatten_dict(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict -> dotted keys: ``{"ppo": {"gamma": 0.9}}`` -> ``{"ppo.gamma": 0.9}``.

    Args:
        data: The nested dict (e.g. a config's ``asdict``); only dict values are descended into.
        prefix: Prepended to every key (used by the recursion).

    Returns:
        A new dict, in the order of a depth-first walk of ``data``.
    """
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(flatten_dict(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat
