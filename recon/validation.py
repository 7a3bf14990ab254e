"""Field checks for the ``__post_init__`` of recon's config dataclasses.

Each helper checks the named fields of one object and raises a ``ValueError`` that names the
field as ``ClassName.field``, the requirement and the value::

    require_positive(self, "inlier_threshold_px", "sample_spacing_px")
    require_non_negative(self, "border_px", finite=False)

(``recon`` imports nothing of branch_gym, which has its own: ``branch_gym/sim/validation.py``.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

__all__ = ["require_finite", "require_non_negative", "require_positive"]

_Test = Callable[[float], bool]
# (requirement in words, test) by (kind, finite).
_CHECKS: dict[tuple[str, bool], tuple[str, _Test]] = {
    ("positive", True): ("positive and finite", lambda v: math.isfinite(v) and v > 0),
    ("positive", False): ("positive", lambda v: v > 0),
    ("non_negative", True): ("finite and >= 0", lambda v: math.isfinite(v) and v >= 0),
    ("non_negative", False): (">= 0", lambda v: v >= 0),
    ("finite", True): ("finite", math.isfinite),
}


def _check(obj: object, names: Iterable[str], kind: str, finite: bool) -> None:
    """Raise for the first of ``names`` that fails the test, naming ``Class.name``."""
    what, test = _CHECKS[kind, finite]
    bad = next((name for name in names if not test(getattr(obj, name))), None)
    if bad is not None:
        value = getattr(obj, bad)
        raise ValueError(f"{type(obj).__name__}.{bad} must be {what}, got {value!r}")


def require_positive(obj: object, *names: str, finite: bool = True) -> None:
    """Each named field is > 0 (and finite unless ``finite=False``, which lets inf through).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _check(obj, names, "positive", finite)


def require_non_negative(obj: object, *names: str, finite: bool = True) -> None:
    """Each named field is >= 0 (and finite unless ``finite=False``, which lets inf through).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _check(obj, names, "non_negative", finite)


def require_finite(obj: object, *names: str) -> None:
    """Each named field is finite (not NaN or infinite).

    Raises:
        ValueError: The first field that is not, named as ``ClassName.field``.
    """
    _check(obj, names, "finite", True)
