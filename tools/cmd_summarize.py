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
    from clipvol.tools.common_args import add_common_arguments, add_old_spelling

    add_common_arguments(parser, ("threads", "overwrite", "quiet"))
    add_old_spelling(parser, "--workers", "--threads", " (--workers is worker processes in render and view)", type=int)


def run(args: argparse.Namespace) -> int:
    import time

    from clipvol.bricking.summary import build_summary, summary_bytes
    from clipvol.units import format_bytes

    t0 = time.perf_counter()
    from clipvol.bricking.channels import image_set, member_path, set_version

    found = image_set(args.store)
    if found is not None and set_version(args.store) == 2:  # a 4-D brick: the tables of every c or t
        axis, n = found
        groups = [member_path(args.store, axis, k) for k in range(n)]
        for k, g in enumerate(groups):
            build_summary(g, workers=args.threads, progress=not args.quiet, overwrite=args.overwrite,
                          data=(args.store, (k,)))
    else:
        groups = [args.store]
        build_summary(args.store, workers=args.threads, progress=not args.quiet, overwrite=args.overwrite)
    if not args.quiet:
        total = sum(summary_bytes(g) or 0 for g in groups)
        print(f"{args.store}: summary tables {format_bytes(total)} in {time.perf_counter() - t0:.1f} s")
    return 0
