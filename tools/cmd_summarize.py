"""Build the summary tables of image-based level of detail for an existing store.

Per brick a 256-level value histogram and the parent-child correspondence table (Wang, Garcia &
Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality Metric for Large Volume
Visualization", IEEE TVCG 13(1), 2007), stored in the store under ``clipvol_summary/`` (see
``docs/format.md``). Streamed, parallel, resumable per level; ``clipvol brick`` builds them for new
stores already.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a complete store written by `clipvol brick`")
    parser.add_argument("--workers", type=int, default=None, help="threads (default: number of cores)")
    parser.add_argument("--overwrite", action="store_true", help="rebuild tables that are already there")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary line")


def run(args: argparse.Namespace) -> int:
    import time

    from clipvol.bricking.summary import build_summary, summary_bytes
    from clipvol.errors import ParameterError
    from clipvol.units import format_bytes

    if args.workers is not None and args.workers < 1:
        raise ParameterError(f"--workers: expected an integer >= 1, got {args.workers}")
    t0 = time.perf_counter()
    from clipvol.bricking.channels import image_set, member_path, set_version

    found = image_set(args.store)
    if found is not None and set_version(args.store) == 2:  # a 4-D brick: the tables of every c or t
        axis, n = found
        groups = [member_path(args.store, axis, k) for k in range(n)]
        for k, g in enumerate(groups):
            build_summary(g, workers=args.workers, progress=not args.quiet, overwrite=args.overwrite,
                          data=(args.store, (k,)))
    else:
        groups = [args.store]
        build_summary(args.store, workers=args.workers, progress=not args.quiet, overwrite=args.overwrite)
    if not args.quiet:
        total = sum(summary_bytes(g) or 0 for g in groups)
        print(f"{args.store}: summary tables {format_bytes(total)} in {time.perf_counter() - t0:.1f} s")
    return 0
