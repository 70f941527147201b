"""Describe a clipvol store: levels, shapes, bricks, bytes on disk, compression, value range, geometry.

For a store built from a file that records its geometry (NIfTI, DICOM, MRC, ...) it also prints
the origin, the voxel-to-world affine and which anatomical direction (R/L, A/P, S/I) each array
axis points to.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a store written by `clipvol brick`")


def _dir_bytes(path) -> tuple[int, int]:
    """(files, bytes) of the chunk files under ``path/c``."""
    import os

    n = size = 0
    for root, _dirs, files in os.walk(path / "c"):
        for f in files:
            n += 1
            size += os.path.getsize(os.path.join(root, f))
    return n, size


def _print_geometry(meta) -> None:
    """Origin, affine and axis directions (only for stores that record them)."""
    if meta.frame is None and not any(meta.origin):
        return
    print(f"origin     {', '.join(f'{v:g}' for v in meta.origin)} {meta.unit} (z, y, x; world position of voxel 0)")
    if meta.frame is None:
        return
    from clipvol.scene.orientation import axis_codes

    codes = axis_codes(meta.frame.affine, meta.frame.frame)
    world = "patient RAS+" if meta.frame.frame == "RAS" else "world"
    print(f"frame      {world}; array axes point to x {codes[0]}, y {codes[1]}, z {codes[2]} "
          f"(orientation {''.join(codes)}{', oblique' if meta.frame.oblique else ''})")
    for k, row in enumerate(meta.frame.affine[:3]):
        head = "affine    " if k == 0 else "          "
        print(f"{head} [{'  '.join(f'{v:10.4g}' for v in row)}]")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from clipvol.bricking.store import open_store_meta
    from clipvol.units import format_bytes

    path = Path(args.store)
    meta = open_store_meta(path)
    pyr = meta.pyramid
    it = pyr.dtype.itemsize
    print(f"store      {path}")
    print(f"complete   {'yes' if meta.complete else 'no (interrupted build: re-run the same clipvol brick command)'}")
    print(f"dtype      {pyr.dtype}")
    print(f"brick      {'x'.join(map(str, pyr.brick_shape))}")
    print(f"filter     {pyr.filter}")
    print(f"codec      {meta.codec}")
    print(f"spacing    {', '.join(f'{s:g}' for s in pyr.spacing)} {meta.unit} (z, y, x)")
    print(f"value range {pyr.value_range[0]:g} .. {pyr.value_range[1]:g}")
    _print_geometry(meta)
    print(f"{'level':>5} {'shape (z, y, x)':>22} {'grid':>14} {'bricks':>8} {'non-empty':>9} {'on disk':>10} {'raw':>10} {'ratio':>6}")
    tot_disk = tot_raw = 0
    for L, lv in enumerate(pyr.levels):
        n, disk = _dir_bytes(path / str(L))
        raw = n * int(pyr.brick_nbytes)
        tot_disk += disk
        tot_raw += raw
        ratio = f"{raw / disk:.2f}" if disk else "-"
        grid = "x".join(map(str, pyr.grid(L)))
        shape = "x".join(map(str, lv.shape))
        print(f"{L:>5} {shape:>22} {grid:>14} {pyr.num_bricks(L):>8} {n:>9} {format_bytes(disk):>10} {format_bytes(raw):>10} {ratio:>6}")
    vox = pyr.shape[0] * pyr.shape[1] * pyr.shape[2] * it
    print(f"total      {format_bytes(tot_disk)} on disk for {format_bytes(vox)} of level 0; "
          f"compression ratio {tot_raw / tot_disk:.2f} over written bricks" if tot_disk else
          f"total      nothing written (every brick is empty) for {format_bytes(vox)} of level 0")
    return 0
