"""Rebuild the bad bricks of a clipvol store, and their ancestors, from the original input.

Every brick is checked as ``clipvol check --all`` does (checksum, statistics, filter). Each bad
level-0 brick is re-read from ``--source``; each bad coarser brick, and every ancestor of a bad
brick, is recomputed with the store's filter from its (by then sound) children, exactly as
``clipvol brick`` computes it. Chunks and statistics are rewritten in place (a chunk through a
temporary file and an atomic rename); nothing else is touched. The input must be the one the store
was built from (its recorded identity: size, modification time, sampled-content hash, dtype,
shape); the repaired bricks are checked again before the command reports success.

The store's manifest (:mod:`clipvol.bricking.manifest`) is the reference: a level whose statistics
arrays were deleted, replaced or swapped has them recomputed from its bricks, which the manifest
verifies chunk by chunk. After any change the manifest is written again and recorded in the root
metadata. A store without a manifest (written before manifests) gets one once every brick checks
out against its statistics; one without statistics either cannot be vouched for and is refused
(rebuild it with ``clipvol brick``).

Metadata first: when the manifest verifies and pins the arrays' metadata and the multiscale
transforms, every ``zarr.json`` that differs from it (an edited byte order, codec chain, fill value,
shape, chunk grid, a shortened multiscale list) is put back from the manifest
(:func:`clipvol.bricking.manifest.restore_metadata`) before anything is opened; chunks that another
build left there then fail their checks and are rebuilt from ``--source``. A manifest written
before metadata pins is written again once every brick checks out, pinning the metadata as it is.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a store written by `clipvol brick`")
    parser.add_argument("--source", required=True, metavar="INPUT", help="the input the store was built from")
    from clipvol.tools.common_args import add_common_arguments

    add_common_arguments(parser, ("quiet",))


def _ancestors(bad, num_levels: int) -> dict[int, set]:
    todo: dict[int, set] = {L: set() for L in range(num_levels)}
    for L, idx in bad:
        while L < num_levels:
            todo[L].add(tuple(idx))
            idx = tuple(i // 2 for i in idx)
            L += 1
    return todo


def rebuild_brick(loader, src, L: int, idx):
    """The valid voxels of brick ``(L, idx)``: from the input at level 0, else the filter over its children."""
    import numpy as np

    from clipvol.bricking.pyramid import downsample

    pyr = loader.pyramid
    start, stop = pyr.brick_voxel_box(L, idx)
    if L == 0:
        return src.read(start, stop)
    fine = pyr.levels[L - 1].shape
    lo = [2 * a for a in start]
    hi = [min(2 * b, n) for b, n in zip(stop, fine)]
    region = np.empty(tuple(h - l for l, h in zip(lo, hi)), dtype=pyr.dtype)
    for child in pyr.children(L, idx):
        cs, ce = pyr.brick_voxel_box(L - 1, child)
        region[tuple(slice(a - o, b - o) for a, b, o in zip(cs, ce, lo))] = \
            loader.read_brick(L - 1, child)[tuple(slice(0, b - a) for a, b in zip(cs, ce))]
    return downsample(region, pyr.filter)


def restore_statistics(loader, group, L: int, stats) -> int:
    """Recompute every statistics array of level ``L`` from its bricks, each verified against the
    manifest (size and crc32c of its chunk), and write them; returns the bricks read."""
    import numpy as np

    from clipvol.bricking.pipeline import create_stats_arrays
    from clipvol.bricking.store import STATS_GROUP

    pyr = loader.pyramid
    grid = pyr.grid(L)
    table = loader.manifest.tables[L]
    cols = {n: np.empty(grid, np.float64) for n in ("min", "max", "mean", "std")}
    cols.update({n: np.zeros(grid, np.int64) for n in ("nan_count", "inf_count")})
    hist = np.zeros(grid + (stats.bins,), np.int64)
    for idx in np.ndindex(*grid):
        start, stop = pyr.brick_voxel_box(L, idx)
        st = stats.compute(loader.read_brick(L, idx)[tuple(slice(0, b - a) for a, b in zip(start, stop))])
        for n in cols:
            cols[n][idx] = getattr(st, n)
        hist[idx] = st.histogram
    create_stats_arrays(group, grid, L)
    sg = group[f"{STATS_GROUP}/{L}"]
    for n, a in cols.items():
        sg[n][...] = a
    sg["histogram"][...] = hist
    sg["done"][...] = np.ones(grid, bool)
    sg["chunk_crc32c"][...] = np.asarray(table["crc32c"])
    return int(np.prod(grid))


def record_manifest(path, group, pyr) -> None:
    """Write the manifest of the store at ``path`` and record its checksum in the root metadata."""
    from clipvol.bricking.manifest import ManifestError, write_manifest
    from clipvol.errors import StoreFormatError

    try:
        entry = write_manifest(path, [pyr.grid(L) for L in range(pyr.num_levels)])
    except ManifestError as e:
        raise StoreFormatError(f"{path}: cannot vouch for this store ({e}); rebuild it with clipvol brick") from None
    cv = dict(group.attrs["clipvol"])
    cv["manifest"] = entry
    group.attrs.update({"clipvol": cv})


def run(args: argparse.Namespace) -> int:
    import os
    import sys
    from pathlib import Path

    import numpy as np
    import zarr

    from clipvol.bricking.build_lock import output_lock
    from clipvol.bricking.pipeline import chunk_encoder
    from clipvol.bricking.sources import identity_changes, open_source, source_identity
    from clipvol.bricking.stats import StatsComputer
    from clipvol.bricking.store import STATS_GROUP
    from clipvol.errors import SourceChangedError, StoreIncompleteError
    from clipvol.tools.cmd_check import bad_bricks, open_checked

    from clipvol.bricking.manifest import ManifestError, restore_metadata

    path = Path(args.store)
    from clipvol.bricking.channels import image_set, set_version
    from clipvol.errors import ParameterError

    if path.is_dir() and image_set(path) is not None and set_version(path) == 2:
        raise ParameterError(f"{path}: the root of a 4-D clipvol brick (one image with a {image_set(path)[0]} axis): "
                             "repair works on a 3-D store; `clipvol check` names the bad member and brick, and "
                             f"`clipvol brick INPUT {path} --overwrite` rebuilds the image")
    with output_lock(path):
        try:
            put_back = restore_metadata(path)
        except (ManifestError, OSError, ValueError):
            put_back = []  # no verified manifest: nothing vouches for any metadata (opening says why)
        if put_back:
            print(f"{path}: restored from the manifest: {'; '.join(put_back)}", file=sys.stderr)
        meta, loader = open_checked(path)
        if not meta.complete:
            raise StoreIncompleteError(f"{path}: incomplete store (an interrupted build): re-run the same clipvol brick "
                                       "command to finish it instead")
        pyr = loader.pyramid
        src = open_source(args.source)
        try:
            group = zarr.open_group(str(path), mode="r+")
            recorded = group.attrs["clipvol"].get("source_identity")
            ident = source_identity(src)
            if recorded is not None:
                changes = identity_changes(recorded, ident)
            else:
                print(f"note: {path} records no source identity; checking shape and dtype only", file=sys.stderr)
                changes = [c for c in identity_changes({"shape": list(pyr.shape), "dtype": pyr.dtype.name}, ident)
                           if c.startswith(("shape", "dtype"))]
            if changes:
                raise SourceChangedError(f"{args.source}: not the input {path} was built from ({'; '.join(changes)})")
            stats = StatsComputer(pyr.dtype, pyr.value_range, meta.histogram_bins)
            restored = []
            if loader.manifest is not None:  # statistics that differ from the manifest: recomputed from verified bricks
                from clipvol.errors import StoreFormatError

                for L in range(pyr.num_levels):
                    try:
                        loader.brick_statistics(L)
                    except StoreFormatError:
                        restore_statistics(loader, group, L, stats)
                        restored.append(L)
                loader.refresh_statistics()
            keys = [(L, idx) for L in range(pyr.num_levels) for idx in np.ndindex(*pyr.grid(L))]
            bad, checked, _ = bad_bricks(loader, meta, keys, progress=not args.quiet)
            if not bad:
                done = [f"restored the metadata of {'; '.join(put_back)} from the manifest"] if put_back else []
                if restored:
                    done.append(f"recomputed the statistics of level{'s' if len(restored) > 1 else ''} "
                                f"{', '.join(map(str, restored))} from its verified bricks")
                if restored or not loader.verified or not loader.metadata_pinned:
                    record_manifest(path, group, pyr)
                    done.append("wrote the manifest")
                    meta, loader = open_checked(path)
                    again, _, _ = bad_bricks(loader, meta, keys)
                    if again or not loader.verified:
                        print(f"clipvol repair: {path}: still bad after writing the manifest ({loader.trust})",
                              file=sys.stderr)
                        return 1
                print(f"{path}: {'; '.join(done) if done else 'nothing to repair'} ({checked} bricks checked)")
                return 0
            todo = _ancestors(bad, pyr.num_levels)
            B = pyr.brick_shape
            n = 0
            for L in range(pyr.num_levels):
                if not todo[L]:
                    continue
                am = loader._arrays[L]
                encode = chunk_encoder(meta.codec, pyr.dtype, am.checksum)
                sg = group[f"{STATS_GROUP}/{L}"]
                for idx in sorted(todo[L]):
                    block = rebuild_brick(loader, src, L, idx)
                    chunk = path / str(L) / "c" / str(idx[0]) / str(idx[1]) / str(idx[2])
                    crc = -1
                    if block.view(f"u{block.dtype.itemsize}").any():
                        full = np.zeros(B, dtype=pyr.dtype)  # an edge brick is padded with the fill value, as zarr does
                        full[tuple(slice(0, s) for s in block.shape)] = block
                        chunk.parent.mkdir(parents=True, exist_ok=True)
                        tmp = chunk.with_name(chunk.name + ".repair")
                        data = encode(full)
                        tmp.write_bytes(data)
                        os.replace(tmp, chunk)
                        if am.checksum:
                            crc = int.from_bytes(data[-4:], "little")
                    else:
                        chunk.unlink(missing_ok=True)  # empty bricks are not written
                    if "chunk_crc32c" in sg:
                        sg["chunk_crc32c"][idx] = crc
                    st = stats.compute(block)
                    for name in ("min", "max", "mean", "std", "nan_count", "inf_count"):
                        sg[name][idx] = getattr(st, name)
                    sg["histogram"][idx] = st.histogram
                    sg["done"][idx] = True
                    n += 1
                loader.refresh_statistics()
            repaired = [(L, idx) for L in todo for idx in todo[L]]
            again, _, _ = bad_bricks(loader, meta, repaired)
            if not again:  # the manifest pins what was just rebuilt; checked once more through it
                record_manifest(path, group, pyr)
                meta, loader = open_checked(path)
                again, _, _ = bad_bricks(loader, meta, repaired)
        finally:
            src.close()
    for (L, idx), problems in sorted(again.items()):
        print(f"clipvol repair: {path}: level {L} brick {idx} still bad: {'; '.join(problems)}", file=sys.stderr)
    names = ", ".join(f"level {L} brick {idx}" for L, idx in sorted(bad))
    put = f"restored the metadata of {'; '.join(put_back)} from the manifest; " if put_back else ""
    print(f"{path}: {put}rebuilt {n} bricks ({len(bad)} bad: {names}; the rest their ancestors)")
    return 1 if again else 0
