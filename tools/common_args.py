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

Shared values are checked here, once: :func:`check_common_values`, which ``clipvol``'s ``main``
calls for every command before it runs, refuses a bad value with the same one-line error naming the
flag (``clipvol CMD: error: --threads: ...``, exit status 2): ``--threads`` an integer in 1..256 (the
clip-texture's :data:`~clipvol.paging.cliptexture.MAX_LOADER_THREADS`), ``--timeout`` finite seconds
in (0, a week], ``--memory-budget`` a size :func:`clipvol.units.parse_bytes` reads, above zero,
``--brick`` an integer >= 1; ``--size`` (WxH, 1..16384 pixels a side) is checked by its argparse type.
The parsed values are what the commands always received (``--memory-budget`` stays the text typed;
the clip-texture parses it).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

from clipvol.tools.value_checks import CHECKS, MAX_THREADS

__all__ = ["Common", "FLAGS", "GROUPS", "CHECKS", "add_common_arguments", "check_common_values", "parse_size"]

#: the largest image side ``--size`` accepts
MAX_SIDE = 16384

#: a hidden namespace attribute, per shared flag a command took from FLAGS (e.g. ``_common_threads``)
_MARK = "_common_"


def check_common_values(args) -> None:
    """Refuse a shared flag's bad value with one line naming the flag (:class:`ParameterError`, exit 2).

    :func:`clipvol.tools.cli.main` calls this for every command before it runs, so ``render``,
    ``view``, ``slice``, ``report`` and ``export`` refuse the same values with the same words, before
    any store is opened or any output is touched."""
    for dest, check in CHECKS.items():
        value = getattr(args, dest, None)
        if value is not None and getattr(args, _MARK + dest, False):  # `clipvol brick --brick` is its own
            check(value)


def parse_size(text: str) -> tuple[int, int]:
    """``--size``: ``WxH`` pixels, each side in 1..16384."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 512x384, got {text!r}") from None
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise argparse.ArgumentTypeError(f"expected 1..{MAX_SIDE} pixels per side, got {text!r}")
    return w, h


@dataclass(frozen=True)
class Common:
    """One shared flag: its name and the keyword arguments of ``add_argument`` (type, default, help, ...)."""

    flag: str
    kw: dict[str, Any] = field(default_factory=dict)


#: one line per shared flag; the key is a command's handle for it in add_common_arguments
FLAGS: dict[str, Common] = {
    "store": Common("--store", dict(default=None, help="where a NIfTI/DICOM/HDF5/MRC input is bricked "
                                                        "(default ./NAME.zarr; reused when it exists)")),
    "brick": Common("--brick", dict(type=int, default=None,
                                    help="brick edge for .npy and procedural sources (default 64)")),
    "size": Common("--size", dict(type=parse_size, default=None, help="image size WxH")),
    "memory_budget": Common("--memory-budget", dict(default="256MB",
                                                    help="clip-texture (main memory) budget")),
    "threads": Common("--threads", dict(type=int, default=None,
                                        help=f"loader threads, 1..{MAX_THREADS} (default: cores)")),
    "no_wait": Common("--no-wait", dict(action="store_true",
                                        help="do not wait for the view's bricks (draw what is resident)")),
    "timeout": Common("--timeout", dict(type=float, default=300.0,
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
        action = group.add_argument(f.flag, **kw)
        group.set_defaults(**{_MARK + action.dest: True})  # check_common_values checks this command's value
    unknown = set(overrides) - set(names)
    if unknown:
        raise KeyError(f"common_args: overrides for flags not added: {sorted(unknown)}")
