"""The field checks of the config dataclasses, as the simulator's modules import them.

One implementation, :mod:`recon.validation` (``recon`` is the layer below: it imports nothing of
branch_gym); this module only names it for ``branch_gym``.
"""

from __future__ import annotations

from recon.validation import (
    require_finite,
    require_int,
    require_non_negative,
    require_positive,
)

__all__ = ["require_finite", "require_int", "require_non_negative", "require_positive"]
