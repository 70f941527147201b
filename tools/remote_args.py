"""Command-line options shared by every command that reads a store: where remote chunks are cached,
how many requests stay in flight, how long a remote server may take, and whether a store without a
verified manifest may be drawn. Used by ``render``, ``view``, ``report``, ``info``, ``check``."""

from __future__ import annotations

import argparse
import sys


def add_remote_arguments(parser: argparse.ArgumentParser) -> None:
    from clipvol.choices import DEFAULT_CONNECT_TIMEOUT, DEFAULT_READ_TIMEOUT  # no numpy for --help

    g = parser.add_argument_group("remote stores (s3://, https://, gs://, any fsspec URL)")
    g.add_argument("--cache", metavar="DIR", default=None,
                   help="keep verified chunks of a remote store in DIR (reused by later runs; failures are never kept)")
    g.add_argument("--in-flight", type=int, default=None, metavar="N",
                   help="requests kept in flight to a remote store (default: sized from the measured "
                        "latency and bandwidth, 16 to 64)")
    g.add_argument("--connect-timeout", type=float, default=None, metavar="S",
                   help=f"seconds to connect to a remote store (default {DEFAULT_CONNECT_TIMEOUT:g})")
    g.add_argument("--read-timeout", type=float, default=None, metavar="S",
                   help=f"seconds without a byte before a remote request counts as stalled (default "
                        f"{DEFAULT_READ_TIMEOUT:g}); a stalled key is given up on within max(30 s, connect + read)")


def add_trust_arguments(parser: argparse.ArgumentParser) -> None:
    """``--unverified``: for the commands that draw a store (``render``, ``slice``, ``view``, ``report``)."""
    parser.add_argument("--unverified", action="store_true",
                        help="draw a clipvol store whose manifest is missing or does not verify (a store written "
                             "before manifests, or damaged); without it such a store is refused")


def remote_kwargs(args: argparse.Namespace) -> dict:
    """Loader keyword arguments for ``args.source`` (or ``args.store``): the remote options when it is
    a URL; an error naming the option when one is given for a local source."""
    from clipvol.errors import ParameterError
    from clipvol.paging.bytesource import check_timeout, is_remote_url

    check_wait(args)
    source = str(getattr(args, "source", None) or getattr(args, "store", ""))
    cache, in_flight = getattr(args, "cache", None), getattr(args, "in_flight", None)
    timeouts = {"--connect-timeout": getattr(args, "connect_timeout", None),
                "--read-timeout": getattr(args, "read_timeout", None)}
    if not is_remote_url(source):
        for name, value in (("--cache", cache), ("--in-flight", in_flight), *timeouts.items()):
            if value is not None:
                raise ParameterError(f"{name}: only for a remote store (s3://, https://, ...), got the local source {source!r}")
        return {}
    kw: dict = {}
    if cache is not None:
        kw["cache"] = cache
    if in_flight is not None:
        if in_flight < 1:
            raise ParameterError(f"--in-flight: expected an integer >= 1, got {in_flight}")
        kw["max_in_flight"] = in_flight
    for name, value in timeouts.items():
        if value is not None:
            kw[name[2:].replace("-", "_")] = check_timeout(value, name)
    return kw


def check_wait(args: argparse.Namespace) -> None:
    """Refuse a ``--timeout`` (seconds to wait for a frame's bricks) outside (0, a week]: ``-1``,
    ``0``, ``nan`` or ``inf`` would never wait or never end. ``clipvol``'s ``main`` checks it for
    every command first (:func:`clipvol.tools.common_args.check_common_values`); a command run
    another way reaches the same check here, through :func:`remote_kwargs`."""
    from clipvol.tools.value_checks import CHECKS

    t = getattr(args, "timeout", None)
    if t is not None:
        CHECKS["timeout"](t)


def check_trust(loader, args: argparse.Namespace, command: str) -> None:
    """Refuse to draw an unverified clipvol store unless ``--unverified`` was given.

    A clipvol store whose manifest is missing or does not verify raises
    :class:`~clipvol.errors.UnverifiedStoreError` saying why and what to do (the loader has
    already noted it on stderr); with ``--unverified`` it is drawn, the note standing as the
    warning. A foreign OME-Zarr image (no manifest by nature) is drawn after one note. Loaders
    that are not zarr stores (numpy, procedural, plug-ins) carry no ``verified`` flag and pass.
    """
    from clipvol.errors import UnverifiedStoreError

    if getattr(loader, "verified", True):
        return
    source = str(getattr(args, "source", None) or getattr(args, "store", ""))
    trust = getattr(loader, "trust", "") or "unverified"
    if not getattr(loader, "is_clipvol_store", False):
        print(f"clipvol {command}: note: {source}: {trust}", file=sys.stderr)
        return
    if getattr(args, "unverified", False):
        return
    raise UnverifiedStoreError(f"{source}: {trust}; refused: pass --unverified to draw it anyway")
