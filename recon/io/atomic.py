"""Output folders that appear complete or not at all: a sibling temp folder, renamed when done."""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

logger = logging.getLogger(__name__)


class OutputExistsError(FileExistsError):
    """The output folder exists and overwriting was not asked for."""


def check_output_dir(out_dir: str | Path, overwrite: bool) -> Path:
    """Fail early when ``out_dir`` exists (and is not to be overwritten) or is a file.

    Raises:
        OutputExistsError: ``out_dir`` exists and ``overwrite`` is False, or it is not a folder.
    """
    out = Path(out_dir)
    if out.exists() and (not overwrite or not out.is_dir()):
        what = "a file" if not out.is_dir() else "a folder"
        raise OutputExistsError(
            f"output {out} exists already ({what}); choose another path or pass overwrite"
        )
    return out


@contextmanager
def atomic_output_dir(out_dir: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder next to ``out_dir``; on success it is renamed to ``out_dir``.

    On an exception the temporary folder is deleted and ``out_dir`` is left as it was: readers
    never see a half-written output.

    Args:
        out_dir: The final folder.
        overwrite: Replace an existing ``out_dir`` (only after the new one is complete).

    Raises:
        OutputExistsError: ``out_dir`` exists and ``overwrite`` is False.
    """
    out = check_output_dir(out_dir, overwrite).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if out.exists():
        check_output_dir(out, overwrite)
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / out.name)
    try:
        os.replace(tmp, out)
    except OSError:
        if old is not None:  # put the previous output back
            os.replace(old / out.name, out)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    logger.debug("wrote %s", out)
