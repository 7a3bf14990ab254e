"""Files that readers see whole or not at all.

:func:`write_json_atomic` writes into a temporary file next to the target (``.NAME.XXXX.tmp``),
flushes it to disk and renames it into place: a reader, or a run killed mid-write, sees the old
file or the new one, never half of one.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["FILE_MODE", "PARTIAL_WRITE_GLOB", "write_json_atomic"]

FILE_MODE = 0o644
# What a killed write leaves behind (the temporary name of write_json_atomic).
PARTIAL_WRITE_GLOB = ".*.tmp"


def write_json_atomic(
    path: Path, data: Any, *, indent: int | None = None, sort_keys: bool = False
) -> None:
    """Write ``data`` as strict JSON to ``path`` atomically (temporary file, fsync, rename).

    Args:
        path: The target file; its folder is created if missing.
        data: Anything ``json.dumps`` takes; NaN and infinities are refused (strict JSON).
        indent: ``json.dumps`` indent; with one the text also ends in a newline (files for people).
        sort_keys: Sort the keys of every object.

    Raises:
        ValueError: ``data`` holds a non-finite float.
        TypeError: ``data`` is not JSON-serialisable.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, allow_nan=False, indent=indent, sort_keys=sort_keys)
    if indent is not None:
        text += "\n"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, FILE_MODE)  # mkstemp makes it private
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
