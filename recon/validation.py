"""Field checks for the ``__post_init__`` of the config dataclasses (recon's and branch_gym's).

Each helper checks the named fields of one object and raises a ``ValueError`` that names the
field as ``ClassName.field``, the requirement and the value::

    require_positive(self, "inlier_threshold_px", "sample_spacing_px")
    require_non_negative(self, "border_px", finite=False)
    require_int(self, "height_bins", minimum=1)

Numbers are real numbers other than bools (:func:`is_number`), numpy scalars included. The one
implementation: ``branch_gym`` uses it too (``branch_gym.sim.validation`` names it for the
simulator's modules); ``recon`` imports nothing of ``branch_gym``.

>>> from dataclasses import dataclass
>>> @dataclass
... class Example:
...     rate: float
>>> require_positive(Example(0.0), "rate")
Traceback (most recent call last):
    ...
ValueError: Example.rate must be positive and finite, got 0.0
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable

__all__ = [
    "is_number",
    "require_finite",
    "require_int",
    "require_non_negative",
    "require_positive",
]


def is_number(value: object) -> bool:
    """A real number: int, float or numpy scalar, but not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


_Test = Callable[[object], bool]
# (requirement in words, test) by (kind, finite); every test also needs a real number.
_CHECKS: dict[tuple[str, bool], tuple[str, _Test]] = {
    ("positive", True): ("positive and finite", lambda v: math.isfinite(v) and v > 0),
    ("positive", False): ("positive", lambda v: v > 0),
    ("non_negative", True): ("finite and >= 0", lambda v: math.isfinite(v) and v >= 0),
    ("non_negative", False): (">= 0", lambda v: v >= 0),
    ("finite", True): ("a finite number", math.isfinite),
}


def _require(obj: object, names: tuple[str, ...], ok: _Test, what: str) -> None:
    """Raise for the first of ``names`` whose value fails ``ok``, naming ``Class.name``."""
    for name in names:
        value = getattr(obj, name)
        if not ok(value):
            raise ValueError(f"{type(obj).__name__}.{name} must be {what}, got {value!r}")


def _check(obj: object, names: tuple[str, ...], kind: str, finite: bool) -> None:
    """:func:`_require` with the test of ``(kind, finite)`` on real numbers."""
    what, test = _CHECKS[kind, finite]
    _require(obj, names, lambda v: is_number(v) and test(v), what)


def require_positive(obj: object, *names: str, finite: bool = True) -> None:
    """Each named field is a number > 0 (and finite unless ``finite=False``: inf passes).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _check(obj, names, "positive", finite)


def require_non_negative(obj: object, *names: str, finite: bool = True) -> None:
    """Each named field is a number >= 0 (and finite unless ``finite=False``: inf passes).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _check(obj, names, "non_negative", finite)


def require_finite(obj: object, *names: str) -> None:
    """Each named field is a finite number (not NaN or infinite).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _check(obj, names, "finite", True)


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
