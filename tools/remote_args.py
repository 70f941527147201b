"""Command-line options shared by every command that reads a store: where remote chunks are cached
and how many requests stay in flight. Used by ``render``, ``view``, ``report``, ``info``, ``check``."""

from __future__ import annotations

import argparse


def add_remote_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("remote stores (s3://, https://, gs://, any fsspec URL)")
    g.add_argument("--cache", metavar="DIR", default=None,
                   help="keep fetched chunks of a remote store in DIR (reused by later runs)")
    g.add_argument("--in-flight", type=int, default=None, metavar="N",
                   help="requests kept in flight to a remote store (default 16)")


def remote_kwargs(args: argparse.Namespace) -> dict:
    """Loader keyword arguments for ``args.source`` (or ``args.store``): the remote options when it is
    a URL; an error naming the option when one is given for a local source."""
    from clipvol.errors import ParameterError
    from clipvol.paging.bytesource import is_remote_url

    source = str(getattr(args, "source", None) or getattr(args, "store", ""))
    cache, in_flight = getattr(args, "cache", None), getattr(args, "in_flight", None)
    if not is_remote_url(source):
        for name, value in (("--cache", cache), ("--in-flight", in_flight)):
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
    return kw
