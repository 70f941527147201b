"""Serve an interactive view of stores to web browsers: open the printed URL (with its token).

``clipvol serve data.zarr`` renders offscreen and streams frames to a page (orbit, zoom, view
presets, transfer function and window, composite / MIP / iso, slices, probe and ruler, crop box and
clip plane, the HUD). It binds 127.0.0.1 and prints a URL with a random token that every request
needs; to look at data on a cluster node, tunnel the port: ``ssh -L 8642:localhost:8642 node``,
run ``clipvol serve data.zarr --port 8642`` there and open the printed URL locally. Needs
``pip install 'clipvol[serve]'``. Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import sys

from clipvol.errors import ParameterError
from clipvol.tools.common_args import add_common_arguments, add_old_spelling


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="clipvol stores / OME-Zarr directories or URLs (s3://, https://, ...), procedural:NAME?size=N, "
                        ".npy files, or NIfTI / DICOM / HDF5 / MRC inputs (bricked first, into ./NAME.zarr or --store)")
    add_common_arguments(p, ("store", "brick"))
    n = p.add_argument_group("network")
    n.add_argument("--host", default="127.0.0.1",
                   help="interface to listen on (default 127.0.0.1: this machine only; reach it through an SSH tunnel)")
    n.add_argument("--port", type=int, default=8642, help="port (default 8642; 0: any free port)")
    n.add_argument("--token", default=None,
                   help="the token every request must carry (default: a random one, printed in the URL)")
    n.add_argument("--no-token", action="store_true", help="no token (only with a loopback --host)")
    n.add_argument("--max-views", type=int, default=8, help="most browser views open at once (default 8)")
    n.add_argument("--message-rate", type=float, default=120.0, metavar="N",
                   help="most messages a second one view may send before it is disconnected (default 120)")
    add_old_spelling(n, "--rate", "--message-rate", " (--rate is view --play's time steps per second)", type=float)
    v = p.add_argument_group("frames")
    add_common_arguments(v, ("size",))
    v.add_argument("--format", choices=("jpeg", "webp", "png"), default="jpeg",
                   help="encoding of the frames drawn while the camera moves (default jpeg); the converged frame is PNG")
    v.add_argument("--target-fps", type=float, default=10.0,
                   help="frame rate held while the camera moves, by drawing smaller and coarser (default 10)")
    add_common_arguments(v, ("memory_budget", "threads", "timeout"))
    from clipvol.tools.render_args import add_render_arguments

    add_render_arguments(v, ("texture_budget",))
    add_common_arguments(p, ("remote", "unverified"))


def run(args) -> int:
    import secrets
    from pathlib import Path

    from clipvol.app.autobrick import bricked_source
    from clipvol.app.serve import run_server
    from clipvol.app.serve.server import check_exposure
    from clipvol.app.session import open_loader
    from clipvol.tools.remote_args import check_trust, remote_kwargs

    if args.no_token and args.token is not None:
        raise ParameterError("--no-token: expected either --token or --no-token, got both")
    token = None if args.no_token else (args.token if args.token is not None else secrets.token_urlsafe(24))
    check_exposure(args.host, token)
    if not 0 <= args.port <= 65535:
        raise ParameterError(f"--port: expected 0..65535, got {args.port}")
    if args.max_views < 1:
        raise ParameterError(f"--max-views: expected at least 1, got {args.max_views}")
    if not args.message_rate > 0:
        raise ParameterError(f"--message-rate: expected a number > 0, got {args.message_rate}")
    if not 0.5 <= args.target_fps <= 120:
        raise ParameterError(f"--target-fps: expected 0.5..120, got {args.target_fps}")
    if args.store is not None and len(args.sources) > 1:
        raise ParameterError("--store: expected one SOURCE with --store (each input of several is bricked into ./NAME.zarr)")
    from clipvol.app.serve.server import _aiohttp

    _aiohttp()  # no aiohttp: the extra's name before any bricking
    kwargs = {} if args.brick is None else {"brick": args.brick}
    loaders, names = [], []
    for text in args.sources:
        source = bricked_source(text, args.store, log=lambda line: print(line, file=sys.stderr))
        args.source = source
        loader = open_loader(source, **kwargs, **remote_kwargs(args))
        check_trust(loader, args, "serve")
        loaders.append(loader)
        names.append(Path(text).name if "://" not in text and not text.startswith("procedural:") else text)

    def announce(url: str) -> None:
        print(f"clipvol serve: {len(loaders)} store(s); open {url}", flush=True)
        print("clipvol serve: Ctrl-C stops it", file=sys.stderr, flush=True)

    run_server(loaders, names, host=args.host, port=args.port, token=token, size=args.size,
               memory_budget=args.memory_budget, texture_budget=args.texture_budget, threads=args.threads,
               timeout=args.timeout, moving_format=args.format, target_s=1.0 / args.target_fps,
               max_views=args.max_views, rate=args.message_rate, announce=announce)
    return 0
