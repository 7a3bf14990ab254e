"""Small helpers shared by the configuration modules (env, training, evaluation).

:func:`is_number` (:mod:`recon.validation`'s) is the one test of "a real number" the config
checks use;
:func:`flatten_dict` turns a nested config dict into dotted keys for "what changed" messages;
:func:`read_config_file` reads a recipe (``configs/*.json``) that a command takes with
``--config``: the fields of its config dataclass that differ from their defaults, and a
``description``; :func:`load_config` builds a command's config: the defaults, then the recipe,
then the options given (:func:`with_overrides`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import fields, is_dataclass, replace
from pathlib import Path
from typing import Any

from recon.validation import is_number

__all__ = [
    "DESCRIPTION_KEY",
    "check_keys",
    "flatten_dict",
    "is_number",
    "load_config",
    "read_config_file",
    "with_overrides",
]

# A recipe's words for people: what it makes and how it was chosen (not a config field).
DESCRIPTION_KEY = "description"


def flatten_dict(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict -> dotted keys: ``{"ppo": {"gamma": 0.9}}`` -> ``{"ppo.gamma": 0.9}``.

    Args:
        data: The nested dict (e.g. a config's ``asdict``); only dict values are descended into.
        prefix: Prepended to every key (used by the recursion).

    Returns:
        A new dict, in the order of a depth-first walk of ``data``.

    >>> flatten_dict({"a": 1, "ppo": {"gamma": 0.99, "net": {"width": 64}}})
    {'a': 1, 'ppo.gamma': 0.99, 'ppo.net.width': 64}
    """
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(flatten_dict(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def read_config_file(path: str | Path) -> dict[str, Any]:
    """The config fields of a recipe file (a JSON object), without its ``description``.

    Raises:
        FileNotFoundError: no such file (named).
        ValueError: not a JSON object (named).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"config file {path} is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"config file {path} must hold a JSON object")
    data.pop(DESCRIPTION_KEY, None)
    return data


def check_keys(cls: type, data: Mapping[str, Any]) -> None:
    """Raise unless every key of ``data`` is a field of the dataclass ``cls``.

    Raises:
        ValueError: the unknown keys, named with the class and its fields.
    """
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(
            f"unknown {cls.__name__} key(s) {unknown}: expected some of {sorted(names)}"
        )


def with_overrides(config: Any, overrides: Mapping[str, Any]) -> Any:
    """``config`` (a dataclass) with the values given: None leaves a field as it is, a dict
    goes into a nested config field the same way.

    >>> from branch_gym.training.config import TrainConfig
    >>> config = with_overrides(TrainConfig(), {"seed": 7, "n_envs": None, "ppo": {"gamma": 0.9}})
    >>> config.seed, config.n_envs == TrainConfig().n_envs, config.ppo.gamma
    (7, True, 0.9)

    Raises:
        ValueError, TypeError: a bad value or an unknown field (the dataclass's own checks).
    """
    changes = {}
    for name, value in overrides.items():
        if value is None:
            continue
        current = getattr(config, name, None)
        if isinstance(value, Mapping) and is_dataclass(current):
            value = with_overrides(current, value)
        changes[name] = value
    return replace(config, **changes)


def load_config(
    cls: type, path: str | Path | None, overrides: Mapping[str, Any] | None = None
) -> Any:
    """A command's config: ``cls``'s defaults, then a recipe file (its ``from_dict``) unless
    ``path`` is None, then the ``overrides`` given (:func:`with_overrides`: the options).

    Raises:
        FileNotFoundError: no such file (named).
        ValueError: a bad file or value (named).
    """
    config = cls() if path is None else cls.from_dict(read_config_file(path))
    return with_overrides(config, overrides or {})
