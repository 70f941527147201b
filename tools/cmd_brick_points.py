"""Build a point octree store from scattered points (after Meredith & Ma 2001).

Reads .npy, .csv, .parquet, .ply or an unstructured mesh (through meshio) in chunks, builds an
octree with at most --max-points points per node out of core, and writes a zarr store that
`clipvol render`, `info` and `check` open. See docs/format.md ("Point stores").
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", metavar="INPUT", help=".npy, .csv, .parquet, .ply, a mesh (.vtu, .vtk, .xdmf, ...) "
                        "or clustered:N (procedural)")
    parser.add_argument("output", metavar="OUTPUT", help="point store directory to create (an interrupted build of the same input and parameters is resumed)")
    parser.add_argument("--max-points", type=int, default=64, help="N: most points per octree node, >= 8 (default 64)")
    parser.add_argument("--value", action="append", default=None, metavar="NAME",
                        help="value column / property / point-data array to keep (repeatable; default: all)")
    parser.add_argument("--xyz", default="x,y,z", help="coordinate column names for .csv/.parquet/.ply/structured .npy (default x,y,z)")
    parser.add_argument("--memory-points", type=int, default=1 << 21, help="most points the build holds in memory (default 2097152)")
    parser.add_argument("--representative", choices=("nearest", "mean"), default="nearest",
                        help="values of inner nodes' points: the nearest point's (Meredith & Ma) or the cell's mean")
    from clipvol.tools.common_args import add_common_arguments, add_ignored

    add_common_arguments(parser, ("unit", "overwrite", "quiet"))
    add_ignored(parser, "--workers", "the build is single-threaded", type=int)


def run(args: argparse.Namespace) -> int:
    import time

    from clipvol.bricking.point_sources import open_point_source
    from clipvol.bricking.point_store import build_point_store
    from clipvol.errors import ParameterError

    xyz = [c.strip() for c in args.xyz.split(",")]
    if len(xyz) != 3 or not all(xyz):
        raise ParameterError(f"--xyz: expected three column names x,y,z, got {args.xyz!r}")
    if args.memory_points < 1024:
        raise ParameterError(f"--memory-points: expected >= 1024, got {args.memory_points}")
    t0 = time.perf_counter()
    src = open_point_source(args.input, args.value, xyz)
    meta = build_point_store(src, args.output, max_points=args.max_points, overwrite=args.overwrite,
                             progress=not args.quiet, memory_points=args.memory_points, unit=args.unit,
                             representative=args.representative)
    if not args.quiet:
        dt = time.perf_counter() - t0
        print(f"{args.output}: {meta.num_points:,} points, {meta.num_nodes:,} nodes, depth {meta.depth}, "
              f"{meta.num_stored:,} stored with representatives, in {dt:.1f} s ({meta.num_points / max(dt, 1e-9):,.0f} points/s)")
    return 0
