"""Validate a clipvol store: metadata, the filter on a sample of bricks per level, their statistics.

For each level a seeded random sample of bricks is read; a level ``L >= 1`` brick is compared
exactly (NaN-aware) with :func:`clipvol.bricking.pyramid.downsample` of the level ``L - 1`` voxels it
summarises, and every sampled brick's statistics are recomputed and compared. A failure prints
``level L brick (z, y, x): what is wrong`` and exits with status 1.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a store written by `clipvol brick` (a directory or a URL)")
    parser.add_argument("--samples", type=int, default=8, help="bricks checked per level (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the brick sample (default 0)")


def _same(a, b) -> bool:
    import numpy as np

    if a.shape != b.shape:
        return False
    if a.dtype.kind == "f":
        return bool(np.array_equal(a, b, equal_nan=True))
    return bool(np.array_equal(a, b))


def _close(x: float, y: float) -> bool:
    import math

    if math.isnan(x) or math.isnan(y):
        return math.isnan(x) and math.isnan(y)
    return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12)


def check_brick(group, pyr, stats, L: int, idx) -> list[str]:
    """Problems found with brick ``(L, idx)`` (empty when it is sound)."""
    import numpy as np

    from clipvol.bricking.pyramid import downsample
    from clipvol.bricking.store import STATS_GROUP

    problems = []
    start, stop = pyr.brick_voxel_box(L, idx)
    sl = tuple(slice(a, b) for a, b in zip(start, stop))
    try:
        block = group[str(L)][sl]
    except Exception as e:  # a corrupt chunk: zarr / numcodecs raise various kinds
        return [f"cannot read or decode ({type(e).__name__}: {e})"]
    if L >= 1:
        prev = pyr.levels[L - 1].shape
        csl = tuple(slice(2 * a, min(2 * b, n)) for a, b, n in zip(start, stop, prev))
        try:
            src = group[str(L - 1)][csl]
        except Exception as e:
            return [f"cannot read its level {L - 1} voxels ({type(e).__name__}: {e})"]
        expect = downsample(src, pyr.filter)
        if not _same(block, expect):
            if block.shape != expect.shape:
                problems.append(f"shape {block.shape} differs from the {pyr.filter} filter of level {L - 1}: {expect.shape}")
            else:
                same = block == expect
                if block.dtype.kind == "f":
                    same |= np.isnan(block) & np.isnan(expect)
                diff = int(np.count_nonzero(~same))
                problems.append(f"differs from the {pyr.filter} filter of level {L - 1} in {diff} voxels")
    sg = group[f"{STATS_GROUP}/{L}"]
    st = stats.compute(block)
    for name in ("min", "max", "mean", "std"):
        have = float(sg[name][idx])
        want = float(getattr(st, name))
        if not _close(have, want):
            problems.append(f"stored {name} {have!r}, expected {want!r}")
    for name in ("nan_count", "inf_count"):
        have = int(sg[name][idx])
        if have != getattr(st, name):
            problems.append(f"stored {name} {have}, expected {getattr(st, name)}")
    hist = np.asarray(sg["histogram"][idx])
    if not np.array_equal(hist, st.histogram):
        problems.append(f"stored histogram differs from the data in {int(np.count_nonzero(hist != st.histogram))} bins")
    if not bool(sg["done"][idx]):
        problems.append("not marked done")
    return problems


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    import numpy as np
    import zarr

    from clipvol.bricking.stats import StatsComputer
    from clipvol.bricking.store import open_store_meta
    from clipvol.errors import ParameterError

    if args.samples < 1:
        raise ParameterError(f"--samples: expected an integer >= 1, got {args.samples}")
    from clipvol.paging.bytesource import is_remote_url

    if is_remote_url(args.store):  # a URL: our metadata check, then zarr-python over fsspec reads the bricks
        from clipvol.loaders.zarr_remote import remote_store_meta

        path = args.store
        meta, _ = remote_store_meta(args.store)
        group = zarr.open_group(args.store, mode="r")
    else:
        path = Path(args.store)
        meta = open_store_meta(path)
        group = zarr.open_group(str(path), mode="r")
    pyr = meta.pyramid
    for L, lv in enumerate(pyr.levels):
        try:
            arr = group[str(L)]
        except KeyError:
            print(f"clipvol check: {path}: level {L}: array missing", file=sys.stderr)
            return 1
        if tuple(arr.shape) != lv.shape or tuple(arr.chunks) != pyr.brick_shape or arr.dtype != pyr.dtype:
            print(f"clipvol check: {path}: level {L}: expected shape {lv.shape}, chunks {pyr.brick_shape}, dtype {pyr.dtype}; "
                  f"got {tuple(arr.shape)}, {tuple(arr.chunks)}, {arr.dtype}", file=sys.stderr)
            return 1
    stats = StatsComputer(pyr.dtype, pyr.value_range, meta.histogram_bins)
    rng = np.random.default_rng(args.seed)
    failures = checked = 0
    for L in range(pyr.num_levels):
        g = pyr.grid(L)
        n = pyr.num_bricks(L)
        picks = rng.choice(n, size=min(args.samples, n), replace=False)
        for flat in sorted(int(p) for p in picks):
            idx = tuple(int(v) for v in np.unravel_index(flat, g))
            checked += 1
            for problem in check_brick(group, pyr, stats, L, idx):
                failures += 1
                print(f"clipvol check: {path}: level {L} brick {idx}: {problem}", file=sys.stderr)
    if not meta.complete:
        print(f"clipvol check: {path}: incomplete store (an interrupted build); re-run the same clipvol brick command", file=sys.stderr)
        return 1
    if failures:
        return 1
    print(f"{path}: ok ({pyr.num_levels} levels, {checked} bricks checked: filter and statistics match)")
    return 0
