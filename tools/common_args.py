"""The flags every drawing command shares, declared once: ``--memory-budget``, ``--threads``,
``--timeout``, ``--no-wait``, ``--brick``, ``--size``, ``--store``, and the groups ``--unverified``,
``--allow-partial``, the remote options and the cut flags.

``clipvol render``, ``view``, ``slice``, ``report`` and ``export`` read stores with the same loader
and clip-texture options. Each flag is one line of :data:`FLAGS` (its name, type, default and help);
a command picks the flags it offers with :func:`add_common_arguments` and changes a default or a
help where its meaning really differs (``view --timeout`` waits per frame, 60 s; ``report --size``
is 192x192). The groups that already live in their own module (:mod:`clipvol.tools.remote_args`,
:mod:`clipvol.tools.partial`, :mod:`clipvol.tools.cut_args`) are added by name through the same call,
so a command's argument set reads as one list.

Shared values are checked here, once, while the command line is parsed, so every command refuses
the same bad value with the same one-line error naming the flag and exit status 2 (argparse's
``clipvol CMD: error: argument --threads: ...``): ``--threads`` an integer in 1..256 (the
clip-texture's :data:`~clipvol.paging.cliptexture.MAX_LOADER_THREADS`), ``--timeout`` finite seconds
in (0, a week], ``--memory-budget`` a size :func:`clipvol.units.parse_bytes` reads, ``--size`` WxH in
1..16384 pixels a side, ``--brick`` an integer >= 1. The parsed values are what the commands always
received (``--memory-budget`` stays the text typed; the clip-texture parses it).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

__all__ = ["Common", "FLAGS", "GROUPS", "add_common_arguments", "parse_threads", "parse_timeout",
           "parse_memory_budget", "parse_size", "parse_brick"]

#: most loader threads a command accepts; the clip-texture's own limit
#: (clipvol.paging.cliptexture.MAX_LOADER_THREADS, checked equal in tests/cli/test_common_args.py;
#: not imported here so that ``clipvol --help`` does not load numpy)
MAX_THREADS = 256
#: the longest ``--timeout`` accepted: a week (clipvol.tools.remote_args.MAX_WAIT); longer is a typo
MAX_WAIT = 7 * 86400.0
#: the largest image side ``--size`` accepts
MAX_SIDE = 16384


def parse_threads(text: str) -> int:
    """``--threads``: an integer in 1..256 (0 would never load; thousands only add stacks)."""
    try:
        n = int(text)
    except ValueError:
        n = None
    if n is None or not 1 <= n <= MAX_THREADS:
        raise argparse.ArgumentTypeError(f"expected an integer in 1..{MAX_THREADS}, got {text!r}")
    return n


def parse_timeout(text: str) -> float:
    """``--timeout``: seconds in (0, a week]; ``0``, ``-1``, ``nan`` or ``inf`` would never wait or never end."""
    try:
        t = float(text)
    except ValueError:
        t = math.nan
    if not (math.isfinite(t) and 0 < t <= MAX_WAIT):
        raise argparse.ArgumentTypeError(f"expected seconds in (0, {MAX_WAIT:g}], got {text!r}")
    return t


def parse_memory_budget(text: str) -> str:
    """``--memory-budget``: a size such as ``256MB`` or ``2GiB`` above zero, checked now and kept as
    typed (the clip-texture parses it again, with the same :func:`clipvol.units.parse_bytes`)."""
    from clipvol.errors import ParameterError
    from clipvol.units import parse_bytes

    try:
        n = parse_bytes(text, "--memory-budget")
    except ParameterError:
        n = 0
    if n <= 0:
        raise argparse.ArgumentTypeError(f"expected a size above zero like '512MB' or '2GiB', got {text!r}")
    return text


def parse_size(text: str) -> tuple[int, int]:
    """``--size``: ``WxH`` pixels, each side in 1..16384."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 512x384, got {text!r}") from None
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise argparse.ArgumentTypeError(f"expected 1..{MAX_SIDE} pixels per side, got {text!r}")
    return w, h


def parse_brick(text: str) -> int:
    """``--brick``: a brick edge in voxels, an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1 (voxels), got {text!r}")
    return n


@dataclass(frozen=True)
class Common:
    """One shared flag: its name and the keyword arguments of ``add_argument`` (type, default, help, ...)."""

    flag: str
    kw: dict[str, Any] = field(default_factory=dict)


#: one line per shared flag; the key is a command's handle for it in add_common_arguments
FLAGS: dict[str, Common] = {
    "store": Common("--store", dict(default=None, help="where a NIfTI/DICOM/HDF5/MRC input is bricked "
                                                        "(default ./NAME.zarr; reused when it exists)")),
    "brick": Common("--brick", dict(type=parse_brick, default=None,
                                    help="brick edge for .npy and procedural sources (default 64)")),
    "size": Common("--size", dict(type=parse_size, default=None, help="image size WxH")),
    "memory_budget": Common("--memory-budget", dict(type=parse_memory_budget, default="256MB",
                                                    help="clip-texture (main memory) budget")),
    "threads": Common("--threads", dict(type=parse_threads, default=None,
                                        help=f"loader threads, 1..{MAX_THREADS} (default: cores)")),
    "no_wait": Common("--no-wait", dict(action="store_true",
                                        help="do not wait for the view's bricks (draw what is resident)")),
    "timeout": Common("--timeout", dict(type=parse_timeout, default=300.0,
                                        help="seconds to wait for the view's bricks (default %(default)g)")),
}


def _remote(p) -> None:
    from clipvol.tools.remote_args import add_remote_arguments

    add_remote_arguments(p)


def _unverified(p) -> None:
    from clipvol.tools.remote_args import add_trust_arguments

    add_trust_arguments(p)


def _partial(p) -> None:
    from clipvol.tools.partial import add_partial_argument

    add_partial_argument(p)


def _cut(p) -> None:
    from clipvol.tools.cut_args import add_cut_arguments

    add_cut_arguments(p)


#: the shared groups kept in their own modules (with their parsing); added by name like a flag
GROUPS: dict[str, Callable[[Any], None]] = {
    "remote": _remote,
    "unverified": _unverified,
    "allow_partial": _partial,
    "cut": _cut,
}


def add_common_arguments(group, names: Iterable[str], **overrides: dict[str, Any]) -> None:
    """Add the shared flags ``names`` (keys of :data:`FLAGS` or :data:`GROUPS`) to ``group``, in order.

    ``overrides``: per flag, the ``add_argument`` keywords this command changes, e.g.
    ``timeout=dict(default=60.0, help=...)``; the type (and so the check) is never changed. A group
    (``remote``, ``cut``) takes the parser it is given and creates its own argument group there."""
    for name in names:
        if name in GROUPS:
            if name in overrides:
                raise KeyError(f"common_args: the group {name!r} takes no overrides")
            GROUPS[name](group)
            continue
        if name not in FLAGS:
            raise KeyError(f"common_args: no shared flag {name!r}; add a line to FLAGS")
        f = FLAGS[name]
        kw = {**f.kw, **overrides.get(name, {})}
        if "type" in overrides.get(name, {}) and overrides[name]["type"] is not f.kw.get("type"):
            raise KeyError(f"common_args: {f.flag} keeps its type (its check is shared)")
        group.add_argument(f.flag, **kw)
    unknown = set(overrides) - set(names)
    if unknown:
        raise KeyError(f"common_args: overrides for flags not added: {sorted(unknown)}")
