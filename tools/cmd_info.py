"""Describe a clipvol store: levels, shapes, bricks, bytes on disk, compression, value range, geometry.

For a store built from a file that records its geometry (NIfTI, DICOM, MRC, ...) it also prints
the origin, the voxel-to-world affine and which anatomical direction (R/L, A/P, S/I) each array
axis points to.

Exits 1 (after the description) when the store is incomplete (an interrupted build is not a store)
or when bricks whose statistics say they hold data have no chunk file (lost data, not empty bricks).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a store written by `clipvol brick`")


def _dir_bytes(path) -> tuple[int, int, set]:
    """(files, bytes, brick indices) of the chunk files under ``path/c``."""
    import os

    n = size = 0
    present = set()
    for root, _dirs, files in os.walk(path / "c"):
        for f in files:
            n += 1
            size += os.path.getsize(os.path.join(root, f))
            rel = os.path.relpath(os.path.join(root, f), path / "c").split(os.sep)
            if len(rel) == 3 and all(p.isdigit() for p in rel):
                present.add(tuple(int(p) for p in rel))
    return n, size, present


def _lost(path, level: int, present: set) -> int:
    """Bricks whose statistics say they hold data (not min = max = 0 without NaN/Inf) but whose
    chunk file is missing: lost data, which a reader must not show as empty."""
    import numpy as np
    import zarr

    from clipvol.bricking.store import STATS_GROUP

    try:
        sg = zarr.open_group(str(path / STATS_GROUP / str(level)), mode="r")
        mn, mx = np.asarray(sg["min"][...]), np.asarray(sg["max"][...])
        done = np.asarray(sg["done"][...]) if "done" in sg else np.ones(mn.shape, bool)
        odd = np.zeros(mn.shape, bool)
        for name in ("nan_count", "inf_count"):
            if name in sg:
                odd |= np.asarray(sg[name][...]) > 0
    except Exception:  # no statistics: nothing to compare with
        return 0
    holds = done & ((mn != 0) | (mx != 0) | odd)
    return sum(1 for idx in zip(*np.nonzero(holds)) if tuple(int(i) for i in idx) not in present)


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
    crc = _checksummed(path, pyr.num_levels)
    print(f"checksum   {'crc32c on every chunk' if crc else 'none (unverified store, written before checksums)'}")
    print(f"dtype      {pyr.dtype}")
    print(f"brick      {'x'.join(map(str, pyr.brick_shape))}")
    print(f"filter     {pyr.filter}")
    print(f"codec      {meta.codec}")
    print(f"spacing    {', '.join(f'{s:g}' for s in pyr.spacing)} {meta.unit} (z, y, x)")
    print(f"value range {pyr.value_range[0]:g} .. {pyr.value_range[1]:g}")
    _print_geometry(meta)
    print(f"{'level':>5} {'shape (z, y, x)':>22} {'grid':>14} {'bricks':>8} {'non-empty':>9} {'on disk':>10} {'raw':>10} {'ratio':>6}")
    tot_disk = tot_raw = 0
    lost = {}
    for L, lv in enumerate(pyr.levels):
        n, disk, present = _dir_bytes(path / str(L))
        lost[L] = _lost(path, L, present)
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
    import sys

    bad = {L: k for L, k in lost.items() if k}
    for L, k in bad.items():
        print(f"clipvol info: {path}: level {L}: {k} bricks hold data by their statistics but have no chunk file "
              "(lost data; `clipvol check --all` names them, `clipvol repair` rebuilds them)", file=sys.stderr)
    if not meta.complete:  # the counts above describe a partial store: not a success
        print(f"clipvol info: {path}: incomplete store (an interrupted build); re-run the same clipvol brick command",
              file=sys.stderr)
        return 1
    return 1 if bad else 0


def _checksummed(path, levels: int) -> bool:
    """True when every level's codec chain ends with zarr v3's ``crc32c``."""
    import json

    for L in range(levels):
        try:
            codecs = json.loads((path / str(L) / "zarr.json").read_text()).get("codecs") or []
        except (OSError, ValueError):
            return False
        if not codecs or (codecs[-1] if isinstance(codecs[-1], str) else codecs[-1].get("name")) != "crc32c":
            return False
    return True
