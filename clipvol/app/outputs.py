"""The files a one-shot command writes: checked before any work, written whole or not at all.

Why a module of its own: ``clipvol render``, ``slice`` and ``tf`` each promise an output that is
either complete or absent, and each refuses a path it cannot write before it opens a store or
starts a thread (a render that ran a minute and then found the folder missing wasted the minute).
The checks name the flag; what may never be written over (an input) is
:func:`clipvol.bricking.output_guard.check_not_input`'s rule.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterable

from ..errors import ParameterError

__all__ = ["check_output_file", "check_outputs", "write_atomic"]


def check_output_file(path, suffix: str, flag: str) -> None:
    """Fail before any work when ``path`` cannot be written: wrong suffix, or a missing folder.

    Raises
    ------
    ParameterError
        Naming ``flag``: ``--out: expected a .png file name, got 'a.jpg'``.
    """
    p = Path(path)
    if suffix and not p.name.lower().endswith(suffix):
        raise ParameterError(f"{flag}: expected a {suffix} file name, got {str(path)!r}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ParameterError(f"{flag}: {str(path)!r}: the folder {str(parent)!r} does not exist")


def check_outputs(outputs: Iterable[tuple[str, object]], inputs: Iterable) -> None:
    """Refuse every ``(flag, path)`` of ``outputs`` (None: not asked) that is one of ``inputs`` or
    lies inside one (``slice u.npy --npy u.npy`` wrote the slice over its input)."""
    from ..bricking.output_guard import check_not_input

    inputs = list(inputs)
    for flag, out in outputs:
        if out is not None:
            check_not_input(out, inputs, flag)


def write_atomic(path, write: Callable[[str], object]) -> None:
    """``write(tmp)`` to ``PATH.partial``, then rename it to ``path``: a reader never sees half a
    file, and an error leaves no ``.partial`` behind."""
    tmp = f"{path}.partial"
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
