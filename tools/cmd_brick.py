"""Brick a volume into a multiresolution clipvol store (OME-Zarr 0.5, zarr v3).

Streamed (memory bounded by a few brick slabs), parallel across cores, and resumable: re-running
the same command on an interrupted build finishes it. See ``docs/format.md`` for the store.
"""

from __future__ import annotations

import argparse
import sys

from clipvol.errors import ParameterError


def _triple(text: str, name: str, kind=float, order: str = "z,y,x") -> tuple:
    parts = [p for p in text.replace("x", ",").split(",") if p.strip()]
    try:
        vals = tuple(kind(p) for p in parts)
    except ValueError:
        raise ParameterError(f"--{name}: expected three comma-separated values {order}, got {text!r}") from None
    if len(vals) != 3:
        raise ParameterError(f"--{name}: expected three comma-separated values {order}, got {text!r}")
    return vals


def _xyz(text: str, name: str) -> tuple:
    """A per-axis world quantity typed x,y,z (as every coordinate of the CLI), as the store's z,y,x."""
    return _triple(text, name, order="x,y,z")[::-1]


def _threads(args) -> int | None:
    """What the build's ``workers`` is: the threads (``--threads``; the local pool, or Dask's
    ``threads`` scheduler), or with ``--scheduler processes`` the worker processes (``--workers``).

    ``--workers N`` without ``--scheduler processes`` is how threads were asked for before
    ``--threads``: it still means N threads, with a note naming ``--threads``."""
    if args.scheduler == "processes":
        if args.threads is not None:
            raise ParameterError("--threads: with --scheduler processes each worker process runs one thread; "
                                 "expected --workers N for the number of processes")
        return args.workers
    if args.workers is None:
        return args.threads
    if args.threads is not None:
        raise ParameterError(f"--workers: expected --threads alone (threads) or --workers with --scheduler processes, "
                             f"got --threads {args.threads} and --workers {args.workers}")
    print(f"clipvol brick: note: --workers {args.workers} is worker processes with --scheduler processes; "
          f"without it, it is taken as --threads {args.workers}, as before", file=sys.stderr)
    return args.workers


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", metavar="INPUT", help=".npy, raw file (with --shape/--dtype), TIFF stack directory or glob, "
                        "multi-page TIFF, zarr array / OME-Zarr image, NIfTI .nii/.nii.gz, DICOM series folder, "
                        "HDF5 FILE.h5:/dataset, MRC .mrc/.map, or procedural:NAME?size=N")
    parser.add_argument("output", metavar="OUTPUT", help="store directory to create (or resume)")
    from clipvol.tools.common_args import add_common_arguments

    add_common_arguments(parser, ("brick",))
    parser.set_defaults(_common_brick=False)  # the build checks its own, stricter: even, 8..256
    parser.add_argument("--filter", default="mean", help="down-sampling filter: mean | subsample | max | mode (label volumes) (default mean)")
    parser.add_argument("--codec", default="lz4", help="lz4 | zstd | none (default lz4: blosc lz4 + shuffle)")
    parser.add_argument("--spacing", metavar="X,Y,Z",
                        help="level-0 voxel size x,y,z, as every coordinate of the CLI (default: the input's, else 1,1,1)")
    parser.add_argument("--origin", default=None, metavar="X,Y,Z",
                        help="world position x,y,z of voxel 0 (OME translation; default: the input's, else 0,0,0): "
                             "co-registered volumes drawn as overlays (render --overlay) are placed by it")
    add_common_arguments(parser, ("unit",))
    parser.add_argument("--shape", help="raw input: shape Z,Y,X")
    parser.add_argument("--dtype", help="raw input: numpy dtype, e.g. uint16")
    parser.add_argument("--byte-order", default="little", help="raw input: little | big (default little)")
    add_common_arguments(parser, ("threads", "workers", "scheduler", "overwrite", "quiet"))
    parser.add_argument("--labels", action="append", default=[], metavar="FILE[:NAME]",
                        help="a label volume (integer ids, the image's shape) to brick into OUTPUT/labels/NAME with "
                             "the mode filter (OME-Zarr labels; NAME defaults to the file's stem); repeatable")
    parser.add_argument("--axes", default=None, choices=("czyx", "tzyx"),
                        help="a 4-D input's axes: czyx (channels, the default) or tzyx (time steps, .npy only); "
                             "OUTPUT is one OME-Zarr 0.5 image with a c or t axis (4-D arrays, chunk 1 along it) that "
                             "info, check, render --c/--t, view, clipvol.open and other OME-Zarr readers open")
    parser.add_argument("--no-summary", action="store_true",
                        help="skip the summary tables of image-based level of detail (add them later with `clipvol summarize`)")


def run(args: argparse.Namespace) -> int:
    import time

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.units import format_bytes

    spacing = _xyz(args.spacing, "spacing") if args.spacing else None
    shape = _triple(args.shape, "shape", int) if args.shape else None
    labels = _label_specs(args.labels, args.output)  # all refused before any work
    t0 = time.perf_counter()
    build = brick_volume
    from functools import partial

    from clipvol.bricking.channels import brick_set, channel_count

    axis = (args.axes or "czyx")[0]
    if channel_count(args.input) is not None:  # a 4-D input: one image with a c or t axis
        if args.scheduler or args.labels:
            raise ParameterError(f"INPUT: a 4-D ({axis}, z, y, x) input is bricked with local threads and without --labels")
        build = partial(brick_set, axis=axis)
    elif args.axes is not None:
        raise ParameterError(f"--axes: expected a 4-D input for --axes {args.axes}, got {args.input} (not 4-D)")
    extra = {}
    if args.origin is not None:
        extra["origin"] = _xyz(args.origin, "origin")
    threads = _threads(args)
    if args.scheduler:
        from clipvol.bricking.dask_build import brick_volume_dask

        build = partial(brick_volume_dask, scheduler=args.scheduler)
    meta = build(
        args.input, args.output, brick=args.brick, filter=args.filter, codec=args.codec, spacing=spacing,
        unit=args.unit, workers=threads, overwrite=args.overwrite, progress=not args.quiet,
        raw_shape=shape, raw_dtype=args.dtype, byte_order=args.byte_order, summary=not args.no_summary, **extra,
    )
    channels = len(meta) if isinstance(meta, list) else 0
    meta = meta[0] if channels else meta
    for path, name in labels:
        from clipvol.bricking.labels import brick_labels

        # never overwrite here: --overwrite cleared OUTPUT (its labels with it) before the build started
        brick_labels(args.output, path, name, codec=args.codec, workers=threads, overwrite=False,
                     progress=not args.quiet)
        if not args.quiet:
            print(f"{args.output}: labels {name!r} from {path} in {args.output}/labels/{name}")
    if not args.quiet:
        pyr = meta.pyramid
        nbytes = int(pyr.dtype.itemsize) * pyr.shape[0] * pyr.shape[1] * pyr.shape[2]
        dt = time.perf_counter() - t0
        nbytes *= max(channels, 1)
        print(f"{args.output}: {pyr.num_levels} levels, level 0 {pyr.shape} {pyr.dtype}"
              + (f" x {channels} {'channels' if axis == 'c' else 'time steps'} (one 4-D image, axes {axis}, z, y, x)"
                 if channels else "")
              + f", {format_bytes(nbytes)} in {dt:.1f} s ({format_bytes(nbytes / max(dt, 1e-9))}/s)")
    return 0


def _label_specs(specs, output) -> list[tuple[str, str]]:
    """``--labels FILE[:NAME]`` as ``(file, name)`` pairs, every name checked to be one plain folder
    name and every file to exist, before the image is built (a bad name found after the build
    would leave a store without the labels asked for)."""
    from pathlib import Path

    from clipvol.bricking.labels import check_label_name
    from clipvol.errors import InputNotFoundError

    out, seen = [], set()
    for spec in specs:
        path, _, name = spec.partition(":") if not Path(spec).exists() else (spec, "", "")
        name = name if _ else (Path(path).stem.split(".")[0] or "labels")
        try:
            check_label_name(name)
        except ParameterError as e:
            raise ParameterError(f"--labels {spec}: {e}") from None
        if not Path(path).exists():
            raise InputNotFoundError(f"--labels {spec}: {path}: no such file")
        if name in seen:
            raise ParameterError(f"--labels {spec}: expected one label volume per name, got {name!r} twice")
        seen.add(name)
        out.append((path, name))
    return out
