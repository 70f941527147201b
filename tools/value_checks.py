"""The checks of the values every drawing command shares (``--threads``, ``--timeout``,
``--memory-budget``, ``--brick``): one line naming the flag each.

A leaf of the CLI: :mod:`clipvol.tools.common_args` (the flags' table, which runs them for every
command) and :mod:`clipvol.tools.remote_args` (which checks ``--timeout`` for a command run without
``clipvol``'s ``main``) both import it, so neither imports the other for them.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from clipvol.errors import ParameterError

__all__ = ["MAX_THREADS", "MAX_WAIT", "CHECKS"]

#: most loader threads a command accepts; the clip-texture's own limit
#: (clipvol.paging.cliptexture.MAX_LOADER_THREADS, checked equal in tests/cli/test_common_args.py;
#: not imported here so that ``clipvol --help`` does not load numpy)
MAX_THREADS = 256
#: the longest ``--timeout`` (seconds to wait for a frame's bricks) accepted: a week; longer is a typo
MAX_WAIT = 7 * 86400.0


def _threads(value) -> None:
    if not (isinstance(value, int) and 1 <= value <= MAX_THREADS):
        raise ParameterError(f"--threads: expected an integer in 1..{MAX_THREADS}, got {value!r}")


def _timeout(value) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and 0 < value <= MAX_WAIT):
        raise ParameterError(f"--timeout: expected seconds in (0, {MAX_WAIT:g}], got {value!r}")


def _memory_budget(value) -> None:
    from clipvol.units import parse_bytes

    try:
        n = parse_bytes(value, "--memory-budget")
    except ParameterError:
        n = 0
    if n <= 0:
        raise ParameterError(f"--memory-budget: expected a size above zero like '512MB' or '2GiB', got {value!r}")


def _brick(value) -> None:
    if not (isinstance(value, int) and value >= 1):
        raise ParameterError(f"--brick: expected a brick edge >= 1 (voxels), got {value!r}")


#: the shared values checked by :func:`clipvol.tools.common_args.check_common_values`: parsed attribute -> check (None: not given)
CHECKS: dict[str, Callable[[Any], None]] = {
    "threads": _threads,
    "timeout": _timeout,
    "memory_budget": _memory_budget,
    "brick": _brick,
}
