"""Field checks for the ``__post_init__`` of branch_gym's config dataclasses (sim and above).

Each helper checks the named fields of one object and raises a ``ValueError`` that names the
field as ``ClassName.field``, the requirement and the value::

    require_positive(self, "control_time_step_s", "max_joint_speed_radps")
    require_non_negative(self, "damping_max", "collision_margin_m")

Numbers are real numbers other than bools (:func:`branch_gym.config_utils.is_number`), numpy
scalars included. ``recon`` has its own (``recon/validation.py``): it imports nothing of ours.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable

from branch_gym.config_utils import is_number

__all__ = ["require_finite", "require_int", "require_non_negative", "require_positive"]


def _require(obj: object, names: tuple[str, ...], ok: Callable[[object], bool], what: str) -> None:
    """Raise for the first of ``names`` whose value fails ``ok``, naming ``Class.name``."""
    for name in names:
        value = getattr(obj, name)
        if not ok(value):
            raise ValueError(f"{type(obj).__name__}.{name} must be {what}, got {value!r}")


def require_positive(obj: object, *names: str, finite: bool = True) -> None:
    """Each named field is a number > 0 (and finite unless ``finite=False``).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    if finite:
        _require(
            obj, names, lambda v: is_number(v) and math.isfinite(v) and v > 0, "positive and finite"
        )
    else:
        _require(obj, names, lambda v: is_number(v) and v > 0, "positive")


def require_non_negative(obj: object, *names: str, finite: bool = True) -> None:
    """Each named field is a number >= 0 (and finite unless ``finite=False``).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    if finite:
        _require(
            obj, names, lambda v: is_number(v) and math.isfinite(v) and v >= 0, "finite and >= 0"
        )
    else:
        _require(obj, names, lambda v: is_number(v) and v >= 0, ">= 0")


def require_finite(obj: object, *names: str) -> None:
    """Each named field is a finite number.

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _require(obj, names, lambda v: is_number(v) and math.isfinite(v), "a finite number")


def require_int(obj: object, *names: str, minimum: int, maximum: int | None = None) -> None:
    """Each named field is an int (not a bool) in ``[minimum, maximum]`` (no upper bound if None).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    bound = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"

    def ok(value: object) -> bool:
        integral = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        return integral and minimum <= value and (maximum is None or value <= maximum)

    _require(obj, names, ok, f"an int {bound}")
