"""``clipvol info URL``: a clipvol store behind a URL, described from its metadata over the network.

Object sizes come from the server's listing where it has one (S3, GCS); over plain HTTP they are
unknown and printed as ``-``, never as zeros. The first line says whether the store verifies against
its manifest, fetched with the rest of the metadata: a manifest the server does not give (404) makes
the store unverified, and statistics it does not give (404) are reported as not matching the
manifest (exit 1), never read as empty bricks."""

from __future__ import annotations

import argparse
import sys


def run_remote_info(args: argparse.Namespace) -> int:
    from clipvol.loaders.zarr_remote import remote_store_meta
    from clipvol.tools.remote_args import remote_kwargs
    from clipvol.units import format_bytes

    kw = remote_kwargs(args)
    kw.pop("cache", None)
    import warnings

    from clipvol.loaders.zarr_remote import RemoteZarrLoader
    from clipvol.loaders.zarr_store import UnverifiedStoreWarning
    from clipvol.tools.cmd_info import _stats_problems, trust_line

    from clipvol.loaders.zarr_remote import remote_set

    if remote_set(args.store, **kw) is not None:  # the root of a 4-D clipvol brick: every member described
        from clipvol.tools.set_info import run_image_info

        return run_image_info(args, args.store)
    meta, level_files = remote_store_meta(args.store, **kw)
    pyr = meta.pyramid
    it = pyr.dtype.itemsize
    with warnings.catch_warnings():  # said once, in the first line
        warnings.simplefilter("ignore", UnverifiedStoreWarning)
        loader = RemoteZarrLoader(args.store, allow_incomplete=True, **kw)
    try:
        stats_bad = _stats_problems(loader, pyr.num_levels)
    finally:
        loader.close()
    print(f"store      {args.store} {trust_line(loader if meta.complete else None)}")
    print("kind       clipvol store (" + ("statistics do not match the manifest or are missing)" if stats_bad
                                         else "with per-brick statistics)"))
    print(f"complete   {'yes' if meta.complete else 'no (interrupted build: re-run the same clipvol brick command)'}")
    print(f"dtype      {pyr.dtype}")
    print(f"brick      {'x'.join(map(str, pyr.brick_shape))}")
    print(f"filter     {pyr.filter}")
    print(f"codec      {meta.codec}")
    print(f"spacing    {', '.join(f'{s:g}' for s in pyr.spacing)} {meta.unit} (z, y, x)")
    print(f"value range {pyr.value_range[0]:g} .. {pyr.value_range[1]:g}")
    print(f"{'level':>5} {'shape (z, y, x)':>22} {'grid':>14} {'bricks':>8} {'written':>9} {'stored':>10} {'raw':>10} {'ratio':>6}")
    tot_disk = tot_raw = 0
    unlisted = False
    for L, lv in enumerate(pyr.levels):
        grid = "x".join(map(str, pyr.grid(L)))
        shape = "x".join(map(str, lv.shape))
        listed = level_files(L)
        if listed is None:  # a server that cannot list (plain HTTP): sizes unknown, not zero
            unlisted = True
            print(f"{L:>5} {shape:>22} {grid:>14} {pyr.num_bricks(L):>8} {'-':>9} {'-':>10} {'-':>10} {'-':>6}")
            continue
        n, disk = listed
        raw = n * int(pyr.brick_nbytes)
        tot_disk += disk
        tot_raw += raw
        ratio = f"{raw / disk:.2f}" if disk else "-"
        print(f"{L:>5} {shape:>22} {grid:>14} {pyr.num_bricks(L):>8} {n:>9} {format_bytes(disk):>10} {format_bytes(raw):>10} {ratio:>6}")
    vox = pyr.shape[0] * pyr.shape[1] * pyr.shape[2] * it
    if unlisted:
        print(f"total      bytes stored unknown (the server cannot list objects) for {format_bytes(vox)} of level 0")
    elif tot_disk:
        print(f"total      {format_bytes(tot_disk)} stored for {format_bytes(vox)} of level 0; "
              f"compression ratio {tot_raw / tot_disk:.2f} over written bricks (padded to full bricks)")
    else:
        print(f"total      nothing written (every brick is empty) for {format_bytes(vox)} of level 0")
    for problem in stats_bad:
        print(f"clipvol info: {args.store}: {problem}", file=sys.stderr)
    if not meta.complete:
        print(f"clipvol info: {args.store}: incomplete store (an interrupted build); re-run the same clipvol brick "
              "command", file=sys.stderr)
        return 1
    return 1 if stats_bad else 0
