"""Validate a clipvol store: its manifest; every chunk's checksum, its statistics and its filter.

The store's manifest (:mod:`clipvol.bricking.manifest`) must verify: a store without one (written
before manifests) or with one that does not match the checksum in its root metadata is
*unverified*, and the check fails whatever the bricks say (``clipvol repair`` writes a manifest
once every brick checks out). Every level's statistics arrays must match the manifest (a deleted,
replaced or swapped statistics chunk fails the check, naming the array).

Bricks are read through the zarr loader's own validated path (the blosc header is checked before
decoding, never read past its end; zarr v3 ``crc32c`` checksums; decoded bounds against the
store's statistics; a missing chunk must be empty by its statistics). A level ``L >= 1`` brick is
then compared exactly (NaN-aware) with :func:`clipvol.bricking.pyramid.downsample` of its level
``L - 1`` children, and its statistics (mean, std, NaN/Inf counts, histogram) are recomputed.

By default a seeded random sample of bricks per level is checked; ``--all`` checks every brick
with a progress bar. Each bad brick is printed as ``level L brick (z, y, x): what is wrong`` and a
summary names them all; the exit status is 1 when any brick is bad, the store is unverified, its
statistics differ from its manifest, or it is incomplete. A server that refuses access (HTTP
401/403) or cannot be reached is an error of its own (exit 2), never reported as bad bricks.
``clipvol repair STORE --source INPUT`` rebuilds exactly the bricks named here.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a store written by `clipvol brick`")
    parser.add_argument("--samples", type=int, default=8, help="bricks checked per level (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the brick sample (default 0)")
    parser.add_argument("--all", action="store_true", help="check every brick of every level (progress bar on stderr)")
    from clipvol.tools.common_args import add_common_arguments

    add_common_arguments(parser, ("quiet", "remote"))


def _close(x: float, y: float) -> bool:
    import math

    if math.isnan(x) or math.isnan(y):
        return math.isnan(x) and math.isnan(y)
    return math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12)


def _valid(loader, L: int, idx):
    """The brick's valid voxels (no edge padding), read through the loader's validated path."""
    start, stop = loader.pyramid.brick_voxel_box(L, idx)
    return loader.read_brick(L, idx)[tuple(slice(0, b - a) for a, b in zip(start, stop))]


def level_statistics(loader, L: int) -> dict:
    """Level ``L``'s statistics arrays, or ``{}`` when there are none or they do not match the
    store's manifest (``run`` reports that once per level; a brick is then checked without them)."""
    from clipvol.errors import StoreFormatError

    try:
        return loader.brick_statistics(L) or {}
    except StoreFormatError:
        return {}


def check_brick(loader, stats, L: int, idx) -> list[str]:
    """Problems found with brick ``(L, idx)`` of an opened :class:`~clipvol.loaders.zarr_store.ZarrLoader`
    (empty when it is sound). ``stats`` is a :class:`~clipvol.bricking.stats.StatsComputer`."""
    import numpy as np

    from clipvol.bricking.pyramid import downsample
    from clipvol.errors import ClipvolError, RemoteStoreError

    pyr = loader.pyramid
    try:
        block = _valid(loader, L, idx)
    except RemoteStoreError:
        raise  # the server's answer (permission denied, unreachable), not the brick's content
    except ClipvolError as e:
        return [str(e).split(": ", 1)[-1]]
    except Exception as e:  # anything a damaged chunk can make a codec raise
        return [f"cannot read or decode ({type(e).__name__}: {e})"]
    problems = []
    if L >= 1:
        start, stop = pyr.brick_voxel_box(L, idx)
        fine = pyr.levels[L - 1].shape
        lo = [2 * a for a in start]
        hi = [min(2 * b, n) for b, n in zip(stop, fine)]
        region = np.empty(tuple(h - l for l, h in zip(lo, hi)), dtype=pyr.dtype)
        try:
            for child in pyr.children(L, idx):
                cs, ce = pyr.brick_voxel_box(L - 1, child)
                region[tuple(slice(a - o, b - o) for a, b, o in zip(cs, ce, lo))] = _valid(loader, L - 1, child)
        except RemoteStoreError:
            raise
        except Exception:
            pass  # a bad child is reported as itself; this brick's filter cannot be checked until it is repaired
        else:
            expect = downsample(region, pyr.filter)
            same = block == expect
            if block.dtype.kind == "f":
                same |= np.isnan(block) & np.isnan(expect)
            if not same.all():
                problems.append(f"differs from the {pyr.filter} filter of level {L - 1} in {int(np.count_nonzero(~same))} voxels")
    sg = level_statistics(loader, L)
    st = stats.compute(block)
    for name in ("min", "max", "mean", "std"):
        if name in sg and not _close(float(sg[name][idx]), float(getattr(st, name))):
            problems.append(f"stored {name} {float(sg[name][idx])!r}, expected {float(getattr(st, name))!r}")
    for name in ("nan_count", "inf_count"):
        if name in sg and int(sg[name][idx]) != getattr(st, name):
            problems.append(f"stored {name} {int(sg[name][idx])}, expected {getattr(st, name)}")
    if "histogram" in sg:
        hist = np.asarray(sg["histogram"][idx])
        if not np.array_equal(hist, st.histogram):
            problems.append(f"stored histogram differs from the data in {int(np.count_nonzero(hist != st.histogram))} bins")
    return problems


def bad_bricks(loader, meta, keys, progress: bool = False, report=None) -> tuple[dict, int, int]:
    """Check ``keys`` (``(level, idx)``); return ``({(L, idx): [problems]}, checked, not_yet_written)``.

    Bricks not marked done (an interrupted build has not written them yet) are skipped, not failed.
    ``report(L, idx, problem)`` is called for each problem as it is found.
    """
    import sys

    from tqdm import tqdm

    from clipvol.bricking.stats import StatsComputer

    stats = StatsComputer(loader.pyramid.dtype, loader.pyramid.value_range, meta.histogram_bins)
    bad: dict = {}
    checked = pending = 0
    keys = list(keys)
    for L, idx in tqdm(keys, unit="brick", desc="checking", file=sys.stderr, disable=not progress, dynamic_ncols=True):
        done = level_statistics(loader, L).get("done")
        if done is not None and not bool(done[idx]):
            pending += 1
            continue
        checked += 1
        problems = check_brick(loader, stats, L, idx)
        if problems:
            bad[(L, idx)] = problems
            if report is not None:
                for p in problems:
                    report(L, idx, p)
    return bad, checked, pending


def open_checked(path, **remote):
    """``(meta, loader)`` for a store, incomplete ones included. ``remote``: options of a remote
    store (time-outs, in-flight). Whether the store is verified is the loader's ``verified`` and
    ``trust``, for the caller to report once (the loader's own warning is silenced here)."""
    import warnings

    from clipvol.bricking.store import open_store_meta
    from clipvol.loaders.zarr_store import UnverifiedStoreWarning, ZarrLoader
    from clipvol.paging.bytesource import is_remote_url

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnverifiedStoreWarning)
        if is_remote_url(str(path)):  # a store behind a URL: the same checks through the remote loader
            from clipvol.loaders.zarr_remote import RemoteZarrLoader, remote_store_meta

            remote.pop("cache", None)
            meta, _ = remote_store_meta(str(path), **remote)
            return meta, RemoteZarrLoader(str(path), allow_incomplete=True, **remote)
        loader = ZarrLoader(path, allow_incomplete=True)  # first: metadata that differs from the manifest says so
        return open_store_meta(path), loader


def run(args: argparse.Namespace) -> int:
    from clipvol.tools.kind_cli import kind_command

    return kind_command(args.store, "check")(args)  # the data kind's invariants (volume_check for a volume)


def volume_check(args: argparse.Namespace) -> int:
    """``clipvol check`` of a volume store or image set (the volume kind's hook, :mod:`clipvol.tools.volume_cli`)."""
    from pathlib import Path

    from clipvol.errors import ParameterError

    if args.samples < 1:
        raise ParameterError(f"--samples: expected an integer >= 1, got {args.samples}")
    from clipvol.paging.bytesource import is_remote_url
    from clipvol.tools.remote_args import remote_kwargs

    path = args.store if is_remote_url(args.store) else Path(args.store)
    members = set_members(path, **remote_kwargs(args))
    if members is not None:  # the root of a 4-D clipvol brick: every (c) or (t) checked, the worst status
        rc = 0
        for label, opened in members:
            rc = max(rc, _check_one(args, f"{path} ({label})", *opened()))
        return rc
    return _check_one(args, path, *open_checked(path, **remote_kwargs(args)))


def set_members(path, **remote):
    """``[(label, open), ...]`` for the members of the image set rooted at ``path`` (``open()``
    gives the member's ``(meta, loader)``, a 3-D view of the set's arrays), or None for a store."""
    import warnings
    from pathlib import Path

    from clipvol.bricking.channels import image_set, member_path, set_version
    from clipvol.bricking.store import open_store_meta
    from clipvol.loaders.zarr_store import UnverifiedStoreWarning, ZarrLoader
    from clipvol.paging.bytesource import is_remote_url

    if is_remote_url(str(path)):
        from clipvol.loaders.zarr_remote import RemoteZarrLoader, remote_set

        found = remote_set(str(path), **{k: v for k, v in remote.items() if k != "cache"})
        if found is None:
            return None
        axis, n, meta_of = found

        def open_remote(k):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UnverifiedStoreWarning)
                ld = RemoteZarrLoader(str(path), allow_incomplete=True, **{axis: k},
                                      **{a: v for a, v in remote.items() if a != "cache"})
            return meta_of(k), ld

        return [(f"{axis} = {k}", lambda k=k: open_remote(k)) for k in range(n)]
    found = image_set(path) if Path(path).is_dir() else None
    if found is None:
        return None
    axis, n = found
    if set_version(path) == 1:  # an older set: one store per member
        return [(f"{axis} = {k}", lambda k=k: open_checked(Path(path) / axis / str(k))) for k in range(n)]

    def open_member(k):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnverifiedStoreWarning)
            return open_store_meta(member_path(path, axis, k)), ZarrLoader(path, allow_incomplete=True, **{axis: k})

    return [(f"{axis} = {k}", lambda k=k: open_member(k)) for k in range(n)]


def _check_one(args: argparse.Namespace, path, meta, loader) -> int:
    """``clipvol check`` of one store (or one member of a set): exit status 0 or 1."""
    import sys

    import numpy as np

    from clipvol.errors import StoreFormatError

    pyr = loader.pyramid
    rng = np.random.default_rng(args.seed)
    keys = []
    for L in range(pyr.num_levels):
        g = pyr.grid(L)
        n = pyr.num_bricks(L)
        if args.all:
            flats = range(n)
        else:
            flats = sorted(int(p) for p in rng.choice(n, size=min(args.samples, n), replace=False))
        keys += [(L, tuple(int(v) for v in np.unravel_index(f, g))) for f in flats]

    def report(L, idx, problem):
        print(f"clipvol check: {path}: level {L} brick {idx}: {problem}", file=sys.stderr)

    level_bad = []
    for L in range(pyr.num_levels):
        try:
            loader.brick_statistics(L)
        except StoreFormatError as e:
            level_bad.append(L)
            print(f"clipvol check: {path}: level {L}: {str(e).split(': ', 1)[-1]}", file=sys.stderr)
    bad, checked, pending = bad_bricks(loader, meta, keys, progress=args.all and not args.quiet, report=report)
    if bad:
        names = ", ".join(f"level {L} brick {idx}" for L, idx in sorted(bad))
        print(f"clipvol check: {path}: {len(bad)} of {checked} bricks checked are bad: {names}; "
              f"`clipvol repair {path} --source INPUT` rebuilds them", file=sys.stderr)
    if not meta.complete:
        print(f"clipvol check: {path}: incomplete store (an interrupted build; {pending} of the bricks looked at not "
              "written yet); re-run the same clipvol brick command", file=sys.stderr)
        return 1
    if not loader.verified:
        print(f"clipvol check: {path}: {loader.trust}", file=sys.stderr)
    if bad or level_bad or not loader.verified:
        return 1
    what = "every brick" if args.all else f"{checked} bricks"
    print(f"{path}: ok ({pyr.num_levels} levels, {what} checked: manifest, checksums, statistics and filter match)")
    return 0
