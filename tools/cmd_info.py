"""Describe a store: levels, shapes, bricks, bytes on disk, compression, value range, NaN/Inf counts.

Works on a store written by ``clipvol brick`` and on any OME-Zarr image (what ``render`` and
``view`` open): for the latter it reports what the metadata and the files say (levels stored
and derived, chunks, bytes) and no statistics, which only ``clipvol brick`` writes.

The compression ratio is the bytes of the voxels the written chunks hold - an edge chunk counts
only its voxels inside the level, not its padding - over the bytes of those chunk files.

For a store built from a file that records its geometry (NIfTI, DICOM, MRC, ...) it also prints
the origin, the voxel-to-world affine and which anatomical direction (R/L, A/P, S/I) each array
axis points to.

The first line says whether the store is *verified*: its manifest (:mod:`clipvol.bricking.manifest`)
matches the checksum in its root metadata, or why not (no manifest: a store written before
manifests, run ``clipvol repair``; a mismatch; a foreign OME-Zarr image, which has none).

Exits 1 (after the description) when a clipvol store is incomplete (an interrupted build is not a
store), when its statistics do not match its manifest (deleted, replaced or swapped), or when
bricks that hold data by the manifest (or, for an unverified store, by the statistics) have no
chunk file (lost data, not empty bricks).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

_META_FILES = {"zarr.json", ".zarray", ".zattrs", ".zgroup", ".zmetadata"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE", help="a store written by `clipvol brick`, or any OME-Zarr image "
                        "(a directory or a URL: s3://, https://, ...)")
    from clipvol.tools.remote_args import add_remote_arguments

    add_remote_arguments(parser)


def chunk_files(array_dir: Path) -> list[tuple[Path, tuple[int, ...] | None]]:
    """The chunk files of one zarr array directory and their chunk index (None if unparsable)."""
    out = []
    for root, _dirs, files in os.walk(array_dir):
        for f in files:
            if f in _META_FILES or f.endswith(".tmp"):
                continue
            p = Path(root) / f
            rel = p.relative_to(array_dir).as_posix()
            if rel.startswith("c/"):
                rel = rel[2:]
            parts = re.split(r"[./]", rel)
            idx = tuple(int(s) for s in parts) if parts and all(s.isdigit() for s in parts) else None
            out.append((p, idx))
    return out


def level_bytes(array_dir: Path, shape, chunks, itemsize: int) -> tuple[int, int, int]:
    """``(chunk files, bytes on disk, bytes of the voxels they hold)`` of one level."""
    n = disk = raw = 0
    full = itemsize
    for c in chunks:
        full *= int(c)
    for p, idx in chunk_files(array_dir):
        n += 1
        disk += p.stat().st_size
        if idx is None or len(idx) < 3:
            raw += full
            continue
        v = itemsize
        for i, c, s in zip(idx[-3:], chunks[-3:], shape[-3:]):
            v *= max(0, min(int(c), int(s) - int(i) * int(c)))
        raw += v
    return n, disk, raw


def _lost(path: Path, level: int, present: set, manifest=None) -> int:
    """Bricks that hold data - by the verified ``manifest`` (a chunk was written), else by their
    statistics (not min = max = 0 without NaN/Inf) - but whose chunk file is missing: lost data,
    which a reader must not show as empty."""
    import numpy as np
    import zarr

    from clipvol.bricking.store import STATS_GROUP

    if manifest is not None:
        written = manifest.sizes(level) > 0
        return sum(1 for idx in zip(*np.nonzero(written)) if tuple(int(i) for i in idx) not in present)

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


def _clipvol_attrs(path: Path) -> dict:
    """The ``clipvol`` attributes of the store's ``zarr.json`` (empty when unreadable)."""
    import json

    try:
        cv = json.loads((path / "zarr.json").read_text()).get("attributes", {}).get("clipvol")
    except (OSError, ValueError, AttributeError):
        return {}
    return cv if isinstance(cv, dict) else {}


def _checksummed(path: Path, level: int) -> bool:
    """True when level ``level``'s codec chain ends with zarr v3's ``crc32c``."""
    import json

    try:
        codecs = json.loads((path / str(level) / "zarr.json").read_text()).get("codecs") or []
    except (OSError, ValueError):
        return False
    return bool(codecs) and (codecs[-1] if isinstance(codecs[-1], str) else codecs[-1].get("name")) == "crc32c"


def _stats_problems(loader, levels: int) -> list[str]:
    """Per level, what is wrong with the statistics arrays against the verified manifest."""
    from clipvol.errors import StoreFormatError

    out = []
    for L in range(levels):
        try:
            loader.brick_statistics(L)
        except StoreFormatError as e:
            out.append(f"level {L}: {str(e).split(': ', 1)[-1]}")
    return out


def trust_line(loader) -> str:
    """The first line's verdict: verified by the manifest, or unverified and why."""
    if loader is None:
        return "(incomplete: a build in progress or interrupted; no manifest yet)"
    return f"({getattr(loader, 'trust', '') or 'unverified'})"


def _stats_line(loader, pyr) -> str | None:
    from clipvol.errors import StoreFormatError

    fn = getattr(loader, "brick_statistics", None)
    try:
        st = fn(0) if fn is not None else None
    except StoreFormatError:
        return None
    if not st:
        return None
    nan = int(st["nan_count"].sum()) if "nan_count" in st else 0
    inf = int(st["inf_count"].sum()) if "inf_count" in st else 0
    total = int(pyr.shape[0]) * int(pyr.shape[1]) * int(pyr.shape[2])
    return (f"non-finite {nan:,} NaN and {inf:,} Inf of {total:,} voxels (level 0)"
            + (f"; {100 * (nan + inf) / total:.2f} % drawn transparent" if nan + inf else ""))


def _print_geometry(meta) -> None:
    """Origin, affine and axis directions (only for stores that record them)."""
    if meta.frame is None and not any(meta.origin):
        return
    if meta.frame is None:
        print(f"origin     {', '.join(f'{v:g}' for v in meta.origin[::-1])} {meta.unit} (x, y, z; world position of voxel 0)")
        return
    # voxel 0 in the world frame the store names (the affine's translation), x, y, z as RAS+ reads them
    x, y, z = (float(v) for v in meta.frame.matrix[:3, 3])
    world_name = "patient RAS+" if meta.frame.frame == "RAS" else "world"
    print(f"origin     {x:g}, {y:g}, {z:g} {meta.unit} (x, y, z in the {world_name} frame; world position of voxel 0)")
    print(f"translation {', '.join(f'{v:g}' for v in meta.origin)} {meta.unit} (z, y, x along the array axes: OME's level-0 translation)")
    from clipvol.scene.orientation import axis_codes

    codes = axis_codes(meta.frame.affine, meta.frame.frame)
    world = "patient RAS+" if meta.frame.frame == "RAS" else "world"
    print(f"frame      {world}; array axes point to x {codes[0]}, y {codes[1]}, z {codes[2]} "
          f"(orientation {''.join(codes)}{', oblique' if meta.frame.oblique else ''})")
    for k, row in enumerate(meta.frame.affine[:3]):
        head = "affine    " if k == 0 else "          "
        print(f"{head} [{'  '.join(f'{v:10.4g}' for v in row)}]")


def _labels_line(path) -> str:
    """``labels     organs, vessels (...)``: the store's OME-Zarr label images (``clipvol brick --labels``),
    or "" when it has none; a newcomer learns here what ``--label-overlay NAME`` takes."""
    from clipvol.bricking.labels import label_names

    try:
        names = label_names(path)
    except (OSError, ValueError, TypeError):
        return ""
    if not names:
        return ""
    return f"labels     {', '.join(names)} (draw with render/view --label-overlay NAME; hide ids with --hide-labels)"


def run(args: argparse.Namespace) -> int:
    from clipvol.errors import InputNotFoundError
    from clipvol.paging.bytesource import is_remote_url

    from clipvol.tools.remote_args import remote_kwargs

    remote_kwargs(args)  # remote options on a local store are refused, naming the option
    if is_remote_url(args.store):  # a store behind a URL: see clipvol.tools.remote_info
        from clipvol.tools.remote_info import run_remote_info

        return run_remote_info(args)
    path = Path(args.store)
    if not path.exists():
        raise InputNotFoundError(f"{path}: no such store")
    from clipvol.tools.kind_cli import kind_command

    return kind_command(path, "info")(args)  # the data kind's summary (volume_info for a volume)


def volume_info(args: argparse.Namespace) -> int:
    """``clipvol info`` of a local volume store (the volume kind's hook, :mod:`clipvol.tools.volume_cli`)."""
    from clipvol.bricking.store import open_store_meta
    from clipvol.errors import StoreIncompleteError
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.units import format_bytes

    path = Path(args.store)
    from clipvol.bricking.channels import image_set

    found = image_set(path)
    if found is not None:  # the root of a 4-D brick: one image with a c or t axis (or, before, one store per member)
        from clipvol.tools.set_info import run_set_info

        return run_set_info(args, path, *found)
    import warnings

    from clipvol.loaders.zarr_store import UnverifiedStoreWarning

    meta = loader = None
    attrs_say_clipvol = False
    try:
        with warnings.catch_warnings():  # said once, in the first line
            warnings.simplefilter("ignore", UnverifiedStoreWarning)
            loader = ZarrLoader(path)
        attrs_say_clipvol = loader.is_clipvol_store
    except StoreIncompleteError:
        attrs_say_clipvol = True
    if attrs_say_clipvol:
        meta = open_store_meta(path)
        pyr = meta.pyramid
        dirs = [path / str(L) for L in range(pyr.num_levels)]
        stored = pyr.num_levels
    else:
        pyr = loader.pyramid
        stored = loader.stored_levels
        dirs = _ome_dataset_dirs(path)[:stored]
    it = pyr.dtype.itemsize
    print(f"store      {path} {trust_line(loader)}")
    stats_bad = _stats_problems(loader, pyr.num_levels) if meta is not None and loader is not None else []
    if meta is not None:
        if not stats_bad and _has_stats(path):
            print("kind       clipvol store (with per-brick statistics)")
        else:
            print(f"kind       clipvol store (statistics {'do not match the manifest' if stats_bad else 'missing'})")
        print(f"complete   {'yes' if meta.complete else 'no (interrupted build: re-run the same clipvol brick command)'}")
        crc = [_checksummed(path, L) for L in range(pyr.num_levels)]
        if all(crc):
            print("checksum   crc32c on every chunk")
        else:
            from clipvol.loaders.zarr_integrity import no_checksum_reason

            print(f"checksum   none: {no_checksum_reason(crc, _clipvol_attrs(path))}")
    else:
        print(f"kind       OME-Zarr image (not written by clipvol brick: no statistics; {stored} of "
              f"{pyr.num_levels} levels stored, the rest derived on the fly)")
    print(f"dtype      {pyr.dtype}")
    print(f"brick      {'x'.join(map(str, pyr.brick_shape))}" + ("" if meta is not None else " (the level-0 chunks)"))
    print(f"filter     {pyr.filter}")
    if meta is not None:
        print(f"codec      {meta.codec}")
        print(f"spacing    {', '.join(f'{s:g}' for s in pyr.spacing[::-1])} {meta.unit} (x, y, z, as brick --spacing takes it)")
    else:
        print(f"spacing    {', '.join(f'{s:g}' for s in pyr.spacing[::-1])} (x, y, z)")
    print(f"value range {pyr.value_range[0]:g} .. {pyr.value_range[1]:g}")
    labels = _labels_line(path)
    if labels:
        print(labels)
    if loader is not None:
        line = _stats_line(loader, pyr)
        if line:
            print(line)
    if meta is not None:
        _print_geometry(meta)
    print(f"{'level':>5} {'shape (z, y, x)':>22} {'grid':>14} {'bricks':>8} {'written':>9} {'on disk':>10} {'raw':>10} {'ratio':>6}")
    tot_disk = tot_raw = 0
    lost: dict[int, int] = {}
    for L, lv in enumerate(pyr.levels):
        grid = "x".join(map(str, pyr.grid(L)))
        shape = "x".join(map(str, lv.shape))
        if L >= stored:
            print(f"{L:>5} {shape:>22} {grid:>14} {pyr.num_bricks(L):>8} {'derived':>9} {'-':>10} {'-':>10} {'-':>6}")
            continue
        n, disk, raw = level_bytes(dirs[L], lv.shape, pyr.brick_shape, it)
        if meta is not None:
            lost[L] = _lost(path, L, {idx[-3:] for _, idx in chunk_files(dirs[L]) if idx and len(idx) >= 3},
                            loader.manifest if loader is not None else None)
        tot_disk += disk
        tot_raw += raw
        ratio = f"{raw / disk:.2f}" if disk else "-"
        print(f"{L:>5} {shape:>22} {grid:>14} {pyr.num_bricks(L):>8} {n:>9} {format_bytes(disk):>10} {format_bytes(raw):>10} {ratio:>6}")
    from clipvol.bricking.summary import summary_bytes

    sb = summary_bytes(path)
    if meta is None:
        pass  # summary tables belong to clipvol stores (`clipvol brick` an OME-Zarr to get them)
    elif sb is None:
        print(f"summary    none (image-based level of detail needs them: clipvol summarize {path})")
    else:
        share = f", {100.0 * sb / tot_disk:.1f} % of the bricks on disk" if tot_disk else ""
        print(f"summary    tables {format_bytes(sb)}{share}")
    from clipvol.bricking.spread import spread_on_disk

    sp = spread_on_disk(path)
    if sp is not None:
        share = f", {100.0 * sp[1] / tot_disk:.1f} % of the bricks on disk" if tot_disk else ""
        print(f"spread     levels {', '.join(map(str, sp[0]))} (the std of the level-0 voxels beneath each coarse "
              f"voxel: --classify distribution), {format_bytes(sp[1])}{share}")
    elif meta is not None and pyr.num_levels > 1 and pyr.filter == "mean":
        print("spread     none (coarse levels are classified by their mean; clipvol brick writes the spread)")
    vox = pyr.shape[0] * pyr.shape[1] * pyr.shape[2] * it
    print(f"total      {format_bytes(tot_disk)} on disk for {format_bytes(vox)} of level 0; "
          f"compression ratio {tot_raw / tot_disk:.2f} (voxels in written chunks, no padding, over their files)"
          if tot_disk else f"total      nothing written (every brick is empty) for {format_bytes(vox)} of level 0")
    for problem in stats_bad:
        print(f"clipvol info: {path}: {problem}", file=sys.stderr)
    bad = {L: k for L, k in lost.items() if k}
    by = "manifest" if loader is not None and loader.manifest is not None else "statistics"
    for L, k in bad.items():
        print(f"clipvol info: {path}: level {L}: {k} bricks hold data by the {by} but have no chunk file "
              "(lost data; `clipvol check --all` names them, `clipvol repair` rebuilds them)", file=sys.stderr)
    if meta is not None and not meta.complete:  # the counts above describe a partial store: not a success
        print(f"clipvol info: {path}: incomplete store (an interrupted build); re-run the same clipvol brick command",
              file=sys.stderr)
        return 1
    return 1 if bad or stats_bad else 0


def _has_stats(path: Path) -> bool:
    from clipvol.bricking.store import STATS_GROUP

    return (path / STATS_GROUP / "0" / "min").is_dir()


def _ome_dataset_dirs(path: Path) -> list[Path]:
    """The array directories of an OME-Zarr image's ``multiscales[0].datasets``, in order."""
    import json

    if (path / "zarr.json").is_file():
        attrs = json.loads((path / "zarr.json").read_text()).get("attributes") or {}
    else:
        attrs = json.loads((path / ".zattrs").read_text()) if (path / ".zattrs").is_file() else {}
    ome = attrs.get("ome") if isinstance(attrs.get("ome"), dict) else attrs
    return [path / d["path"] for d in ome["multiscales"][0]["datasets"]]
