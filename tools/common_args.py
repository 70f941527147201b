"""The flags several commands share, each declared once with one meaning: ``--memory-budget``,
``--threads``, ``--workers``, ``--scheduler``, ``--timeout``, ``--no-wait``, ``--brick``, ``--size``,
``--store``, ``--c``, ``--t``, the camera's ``--view``, ``--up``, ``--camera``, ``--no-labels``,
``--tolerance``, ``--frames``, ``--path``, ``--quiet``, ``--overwrite``, ``--unit``, and the groups
``--unverified``, ``--allow-partial``, the remote options and the cut flags.

Each flag is one line of :data:`FLAGS` (its name, type, default and help); a command picks the
flags it offers with :func:`add_common_arguments` and may change only how a value is stored
(:data:`OVERRIDABLE`), never its type, default, help or choices, so ``--timeout`` reads the same in
``clipvol render --help`` and ``clipvol view --help``. Threads are ``--threads`` everywhere;
``--workers`` is worker processes (sort-last on Dask) and ``--scheduler`` where they run. Where
commands truly differ in what a flag does when it is not given (``--timeout``: 300 s for a whole
``render``, 60 s per ``view --converged`` frame), its default is None, its help says each, and
:func:`fill_unset` (called by the ``clipvol`` parser once it has parsed) puts the command's value
in place. A renamed flag keeps its old spelling working (:func:`add_old_spelling`: hidden, a note on
stderr). The groups that live in their own module (:mod:`clipvol.tools.remote_args`,
:mod:`clipvol.tools.partial`, :mod:`clipvol.tools.cut_args`) are added by name through the same
call, so a command's argument set reads as one list.

Shared values are checked here, once: :func:`check_common_values`, which ``clipvol``'s ``main``
calls for every command before it runs, refuses a bad value with the same one-line error naming the
flag (``clipvol CMD: error: --threads: ...``, exit status 2): ``--threads`` an integer in 1..256 (the
clip-texture's :data:`~clipvol.paging.cliptexture.MAX_LOADER_THREADS`), ``--timeout`` finite seconds
in (0, a week], ``--memory-budget`` a size :func:`clipvol.units.parse_bytes` reads, above zero,
``--brick`` an integer >= 1; ``--size`` (WxH, 1..16384 pixels a side) is checked by its argparse type.
The parsed values are what the commands always received (``--memory-budget`` stays the text typed;
the clip-texture parses it).

Nothing here imports numpy: the choices come from :mod:`clipvol.choices`, so building a parser
stays light (``clipvol CMD --help``).
"""

from __future__ import annotations

import argparse
import math
import sys
from types import MappingProxyType
from typing import Any, Callable, Iterable, Mapping, NamedTuple

from clipvol.choices import CAMERA_PATHS, VIEWS
from clipvol.tools.value_checks import CHECKS, MAX_THREADS

__all__ = ["Common", "FLAGS", "GROUPS", "CHECKS", "add_common_arguments", "add_old_spelling", "check_common_values",
           "add_ignored", "fill_unset", "parse_size", "parse_xyz"]

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


def parse_xyz(text: str) -> tuple[float, float, float]:
    """``x,y,z``: three finite numbers (a point or a direction in the store's world frame)."""
    try:
        v = tuple(float(t) for t in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected three numbers x,y,z, got {text!r}")
    return v  # type: ignore[return-value]


class Common(NamedTuple):
    """One shared flag: its name, the keyword arguments of ``add_argument`` (type, default, help, ...)
    and ``unset``: per command, the value it takes when the flag is not given and its default is
    None (the help says each; :func:`fill_unset` puts it in place before the command runs).
    A named tuple, not a dataclass, so that building a parser does not import ``inspect``."""

    flag: str
    kw: Mapping[str, Any] = MappingProxyType({})
    unset: Mapping[str, Any] = MappingProxyType({})


#: one line per shared flag; the key is a command's handle for it in add_common_arguments
FLAGS: dict[str, Common] = {
    "store": Common("--store", dict(default=None, help="where a NIfTI/DICOM/HDF5/MRC input is bricked "
                                                        "(default ./NAME.zarr; reused when it exists)")),
    "brick": Common("--brick", dict(type=int, default=None,
                                    help="brick edge in voxels (default 64): of the store brick builds (even, "
                                         "8..256), or the bricks a .npy or procedural source is read in"),
                    unset={"brick": 64}),
    "size": Common("--size", dict(type=parse_size, default=None,
                                  help="image size WxH (default: 512x512 for render and serve, 192x192 for report, "
                                       "960x640 for view's window and 256x256 offscreen, the plane's cut through the "
                                       "volume for slice)"),
                   unset={"render": (512, 512), "serve": (512, 512), "report": (192, 192)}),
    "memory_budget": Common("--memory-budget", dict(default="256MB",
                                                    help="clip-texture (main memory) budget")),
    "threads": Common("--threads", dict(type=int, default=None,
                                        help=f"threads that load bricks (build them, for brick and summarize), "
                                             f"1..{MAX_THREADS} (default: the number of cores)")),
    "workers": Common("--workers", dict(type=int, default=None, metavar="N",
                                        help="N Dask worker processes: render draws N spatially disjoint brick "
                                             "groups in them and composites them (sort-last), view --offscreen each "
                                             "frame so (PNG frames); brick --scheduler processes builds in them; "
                                             "needs clipvol[dask]")),
    "scheduler": Common("--scheduler", dict(default=None, metavar="S",
                                            help="where the Dask work runs: processes (--workers of them), threads "
                                                 "(brick: --threads of them in one process) or tcp://HOST:PORT of a "
                                                 "dask.distributed scheduler (render and view with --workers: default "
                                                 "processes; brick: default the local thread pool, no Dask); needs "
                                                 "clipvol[dask]"),
                        unset={"render": "processes", "view": "processes"}),
    "no_wait": Common("--no-wait", dict(action="store_true",
                                        help="do not wait for the view's bricks: draw what is resident (after one "
                                             "pass, coarser where bricks are missing)")),
    "timeout": Common("--timeout", dict(type=float, default=None,
                                        help="seconds to wait for the bricks (default: 300 for a whole render or "
                                             "slice and for each frame of serve, 60 for each frame of view "
                                             "--converged, 120 for each converged frame of report)"),
                      unset={"render": 300.0, "slice": 300.0, "serve": 300.0, "view": 60.0, "report": 120.0}),
    "c": Common("--c", dict(type=int, default=None,
                            help="the channel of a channel set or an image with a c axis (default 0)")),
    "t": Common("--t", dict(type=int, default=None,
                            help="the time step of a time series or an image with a t axis (default 0)")),
    "camera": Common("--camera", dict(default=None, metavar="FILE.json",
                                      help="start from a camera saved by the viewer's C key (overrides --view, and "
                                           "for render --eye/--target/--up/--fov/--ortho)")),
    "view": Common("--view", dict(choices=VIEWS, default=None, type=str.lower,
                                  help="the side the eye is on: anterior, posterior, left, right, superior, inferior "
                                       "for a store with a patient frame (head up; front/back/side/top mean "
                                       "anterior/posterior/left/superior there), front/back/side/top along the "
                                       "array's z/-z/x/y otherwise; iso from anterior-right-superior (render's "
                                       "default; view: the window's start or --path turntable's first frame)"),
                   unset={"render": "iso"}),
    "up": Common("--up", dict(type=parse_xyz, default=None, metavar="X,Y,Z",
                              help="the image's up direction x,y,z in the store's world frame (default: superior for "
                                   "a patient frame, -y otherwise, so image rows follow +y; slice's oblique plane: "
                                   "anterior for an axial one)")),
    "no_labels": Common("--no-labels", dict(action="store_true",
                                            help="do not write the anatomical R/L, A/P, S/I letters at the image edges "
                                                 "(stores with a patient frame)")),
    "tolerance": Common("--tolerance", dict(default=None,
                                            help="point stores: the largest splat, a fraction of the screen (0.05), "
                                                 "'5%%' or '12px' (default: 0.01 for render, 0.05 for the viewer to "
                                                 "start with, where [ and ] change it)"),
                        unset={"render": "0.01", "view": "0.05"}),
    "frames": Common("--frames", dict(type=int, default=None,
                                      help="frames along the camera path (default 36; 4 for demo --quick)"),
                     unset={"view": 36}),
    "path": Common("--path", dict(choices=CAMERA_PATHS, default="orbit",
                                  help="camera path (default orbit; turntable: one upright turn, head-up for "
                                       "patient-frame stores)")),
    "quiet": Common("--quiet", dict(action="store_true", help="no progress bar or summary")),
    "overwrite": Common("--overwrite", dict(action="store_true",
                                            help="replace what this command writes when it is already there, once the "
                                                 "new one is complete: a clipvol store or an empty folder, a file of "
                                                 "the same kind (export), the summary tables (summarize), a store of "
                                                 "another size (demo); never the input or a folder holding it")),
    "unit": Common("--unit", dict(default=None,
                                  help="unit recorded in the store: of the voxel spacing (brick; default the input's, "
                                       "e.g. millimeter for NIfTI/DICOM, else micrometer) or of the point coordinates "
                                       "(brick-points; default none)"),
                   unset={"brick-points": ""}),
}


def fill_unset(args) -> None:
    """Put each shared flag's per-command value (:attr:`Common.unset`) in place where it was not given.

    The ``clipvol`` parser calls this once it has parsed a command line (``_Parser.parse_known_args``
    in :mod:`clipvol.tools.cli`), so every parsed namespace holds the command's value: the flag has
    one default (None) and one help, which names what each command does without it."""
    command = getattr(args, "command", None)
    for f in FLAGS.values():
        dest = f.kw.get("dest", f.flag.lstrip("-").replace("-", "_"))
        if command in f.unset and hasattr(args, dest) and getattr(args, dest) is None:
            setattr(args, dest, f.unset[command])


class _OldSpelling(argparse.Action):
    """A flag's old spelling: the same value as the new one (``dest``), with a note on stderr."""

    def __init__(self, option_strings, dest, new: str = "", why: str = "", **kw):
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kw)
        self.new, self.why = new, why

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: note: {option_string} is an old spelling of {self.new}{self.why}; it does the same",
              file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_old_spelling(group, old: str, new: str, why: str = "", **kw) -> None:
    """Keep ``old`` working as ``new`` (hidden from the help, a note on stderr when used), for the
    command lines of scripts written before the flag was renamed. ``kw``: ``type``, ``nargs``... of
    ``new``'s value (``dest`` defaults to ``new``'s)."""
    kw.setdefault("dest", new.lstrip("-").replace("-", "_"))
    group.add_argument(old, action=_OldSpelling, new=new, why=why, **kw)


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


class _Ignored(argparse.Action):
    """A flag a command accepts for old command lines and ignores, with a note on stderr saying why."""

    def __init__(self, option_strings, dest, why: str = "", **kw):
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kw)
        self.why = why

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: note: {option_string} is ignored: {self.why}", file=sys.stderr)


def add_ignored(group, flag: str, why: str, **kw) -> None:
    """Accept ``flag`` (hidden from the help) and ignore it with a note saying ``why``, where old
    command lines pass it (``brick-points --workers``: the build is single-threaded)."""
    group.add_argument(flag, action=_Ignored, why=why, dest="_ignored_" + flag.lstrip("-").replace("-", "_"), **kw)


#: what a command may change of a shared flag: how it is stored and shown, never its meaning
#: (type, default, help and choices are the flag's own, the same in every command)
OVERRIDABLE = frozenset({"dest", "metavar"})


def add_common_arguments(group, names: Iterable[str], **overrides: dict[str, Any]) -> None:
    """Add the shared flags ``names`` (keys of :data:`FLAGS` or :data:`GROUPS`) to ``group``, in order.

    ``overrides``: per flag, the ``add_argument`` keywords of :data:`OVERRIDABLE` this command
    changes (``export``'s ``--store`` is stored as ``brick_store``). A group (``remote``, ``cut``)
    takes the parser it is given and creates its own argument group there."""
    for name in names:
        if name in GROUPS:
            if name in overrides:
                raise KeyError(f"common_args: the group {name!r} takes no overrides")
            GROUPS[name](group)
            continue
        if name not in FLAGS:
            raise KeyError(f"common_args: no shared flag {name!r}; add a line to FLAGS")
        f = FLAGS[name]
        changed = set(overrides.get(name, {})) - OVERRIDABLE
        if changed:
            raise KeyError(f"common_args: {f.flag} keeps its {', '.join(sorted(changed))} (one meaning in every command)")
        kw = {**f.kw, **overrides.get(name, {})}
        action = group.add_argument(f.flag, **kw)
        group.set_defaults(**{_MARK + action.dest: True})  # check_common_values checks this command's value
    unknown = set(overrides) - set(names)
    if unknown:
        raise KeyError(f"common_args: overrides for flags not added: {sorted(unknown)}")
