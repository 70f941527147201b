"""``clipvol brick``: stream a level-0 volume into a multiresolution clipvol store.

How it works, and why:

* **Two passes over the input, one over the pyramid.** The per-brick histograms need the global
  finite value range of level 0 before the first brick is summarised, so a first, parallel pass
  reads level 0 slab by slab and takes its finite min/max (cheap next to compression; for an
  ``.npy`` it is served from the page cache the second time). The range is stored in the store's
  attributes, so a resumed build does not repeat that pass. The second pass builds **every level
  in one streaming sweep** with a per-level accumulator: a level-0 slab (one brick-row in z,
  ``brick_z x Y x X``) is cut into bricks; each brick is summarised, compressed, written, and
  down-sampled into its place in the next level's slab buffer. When a level's buffer holds a full
  brick-row (two child slabs) it is processed the same way, recursively. Nothing is read back
  from the store, and peak memory is about two level-0 slabs plus one slab per coarser level
  (each a quarter of the one below), whatever the volume's depth.
* **Exact filter.** Every brick is down-sampled with :func:`clipvol.bricking.pyramid.downsample` on its own.
  Brick extents are even (the brick size must be even), so that is exactly the filter applied to
  the whole level; edge bricks are the last along their axis, where edge replication applies.
* **Parallel.** Bricks of a slab are independent tasks on a thread pool of ``workers`` threads:
  statistics (numpy), down-sampling (numpy) and compression (numcodecs blosc) release the GIL.
  The next level-0 slab is read by a separate thread while the current one is processed.
* **Direct chunk writes.** A brick is encoded with the same numcodecs codec zarr would use and
  written as the chunk file zarr expects (``<level>/c/<bz>/<by>/<bx>``; an edge brick is padded
  with the fill value to the full chunk, as zarr does). This is byte-identical to
  ``arr[brick] = block`` but avoids zarr-python's per-call overhead, which dominates for
  thousands of small chunks. Hence the output must be a local directory. Empty bricks (all bytes
  zero, the fill value) are not written.
* **Resumable.** ``attrs["clipvol"]["complete"]`` is ``false`` until the very last write. Each
  brick-row's statistics and then its ``done`` flags are written after its bricks, from the main
  thread. Re-running the same job on an incomplete store recomputes the (cheap, deterministic)
  down-sampling but skips the statistics, compression and writes of bricks already done, giving
  a store identical to an uninterrupted run.

Why one module of this size: the two passes, the resume state and the write loop share one build
state and its crash rules; the build lock is :mod:`.build_lock`, what ``--overwrite`` may replace
:mod:`.output_guard`, the options are :mod:`.build_options`, the pyramid's
arithmetic :mod:`.pyramid`, the statistics :mod:`.stats` and the manifest :mod:`.manifest`.
"""

from __future__ import annotations

import sys
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import (OPERATIONAL_ERRNOS, ClipvolError, InputFormatError, OutputExistsError,
                      OutputWriteError, ParameterError, SourceChangedError, describe_os_error)
from .build_lock import output_lock
from .build_options import BRICK_RANGE, CODECS, BuildOptions
from .output_guard import check_not_input, check_overwrite, exists_error, remove_output
from .pyramid import Pyramid, downsample
from .spread import SPREAD_GROUP, moments_down, spread_dtype, spread_of
from .source_types import Source
from .sources import check_source_unchanged, file_inodes, identity_changes, open_source, source_identity
from .stats import StatsComputer, finite_range
from .worldframe import WorldFrame
from .store import (
    HIST_BINS,
    STAT_ARRAYS,
    STATS_GROUP,
    StoreMeta,
    clipvol_metadata,
    ome_metadata,
    parse_metadata,
)

__all__ = ["brick_volume", "BuildOptions", "write_chunk", "CODECS", "BRICK_RANGE", "store_codecs", "chunk_encoder", "output_lock", "job_spec",
           "prepare_output", "mark_complete", "encode_brick", "plan_build"]




def write_chunk(path: Path, data: bytes) -> None:
    """Write one encoded brick to its chunk file ``path`` (``L/c/k/y/x`` under the store).

    The one place a local build writes a brick, so every brick's write is one call to watch or
    to fail (tests interrupt a build here, after a given brick, as a crash or a full disk would)."""
    with open(path, "wb") as f:
        f.write(data)


def store_codecs(codec: str, dtype: np.dtype, checksum: bool = True) -> list:
    """The zarr v3 ``compressors`` (bytes-to-bytes codecs) for ``--codec``: blosc or nothing, then
    zarr v3's ``crc32c`` codec, so that every reader of the store (ours, zarr-python, others)
    verifies each chunk's checksum before decoding it."""
    from zarr.codecs import BloscCodec, Crc32cCodec

    tail = [Crc32cCodec()] if checksum else []
    if codec == "none":
        return tail
    shuffle = "bitshuffle" if dtype.itemsize == 1 else "shuffle"
    if codec == "lz4":
        return [BloscCodec(cname="lz4", clevel=5, shuffle=shuffle, typesize=dtype.itemsize)] + tail
    if codec == "zstd":
        return [BloscCodec(cname="zstd", clevel=1, shuffle=shuffle, typesize=dtype.itemsize)] + tail
    raise ParameterError(f"codec: expected one of {', '.join(CODECS)}, got {codec!r}")


def chunk_encoder(codec: str, dtype: np.dtype, checksum: bool = True) -> Callable[[np.ndarray], bytes]:
    """Encode a full chunk (C order, native little-endian) to the bytes zarr stores for ``codec``,
    with the 4-byte little-endian CRC-32C of the encoded bytes appended (zarr v3 ``crc32c``)."""
    import numcodecs

    if codec == "none":
        enc = lambda a: np.ascontiguousarray(a, dtype=dtype.newbyteorder("<")).tobytes()  # noqa: E731
    else:
        shuffle = numcodecs.Blosc.BITSHUFFLE if dtype.itemsize == 1 else numcodecs.Blosc.SHUFFLE
        clevel = 5 if codec == "lz4" else 1
        comp = numcodecs.Blosc(cname=codec, clevel=clevel, shuffle=shuffle, blocksize=0)
        enc = lambda a: bytes(comp.encode(np.ascontiguousarray(a, dtype=dtype.newbyteorder("<"))))  # noqa: E731
    if not checksum:
        return enc
    import google_crc32c

    def with_crc(a: np.ndarray) -> bytes:
        data = enc(a)
        return data + google_crc32c.value(data).to_bytes(4, "little")

    return with_crc


def encode_brick(block: np.ndarray, brick_shape, encode: Callable[[np.ndarray], bytes]) -> bytes | None:
    """The chunk file's bytes for a brick's valid voxels ``block`` (an edge brick is padded with the
    fill value, as zarr does), or ``None`` for an empty brick (all fill bytes: not written).
    Shared by the local sweep and the Dask build, so both write the same bytes."""
    if not block.view(f"u{block.dtype.itemsize}").any():  # not all fill (0) bytes
        return None
    full = block
    if block.shape != tuple(brick_shape):
        full = np.zeros(brick_shape, dtype=block.dtype)
        full[: block.shape[0], : block.shape[1], : block.shape[2]] = block
    return encode(full)


def job_spec(src: Source, pyr_shape, brick, filter, codec, spacing, unit) -> dict[str, Any]:
    """The parameters that must match for a build to be resumed, the source's identity included
    (:func:`clipvol.bricking.sources.source_identity`: size, mtime, sampled-content hash, dtype, shape)."""
    return {
        "source_identity": source_identity(src),
        "source": f"{src.key or src.name} ({'x'.join(map(str, src.shape))} {src.dtype.name})",
        "shape": list(pyr_shape),
        "dtype": src.dtype.name,
        "brick_shape": list(brick),
        "filter": filter,
        "codec": codec,
        "spacing": list(spacing),
        "unit": unit,
    }


def _stored_job(cv: dict) -> dict[str, Any]:
    levels = cv.get("levels") or [[]]
    return {
        "source_identity": cv.get("source_identity"),
        "source": cv.get("source"),
        "shape": list(levels[0]),
        "dtype": cv.get("dtype"),
        "brick_shape": cv.get("brick_shape"),
        "filter": cv.get("filter"),
        "codec": cv.get("codec"),
        "spacing": cv.get("spacing"),
        "unit": cv.get("unit"),
    }


def _read_attrs(path: Path) -> dict | None:
    import json

    try:
        meta = json.loads((path / "zarr.json").read_text())
    except (OSError, ValueError):
        return None
    attrs = meta.get("attributes") if isinstance(meta, dict) else None
    return attrs if isinstance(attrs, dict) else None


def prepare_output(output: Path, job: dict, overwrite: bool) -> dict | None:
    """Clear or vet an existing output; return its attrs when it is a resumable build of ``job``.

    ``overwrite`` removes ``output`` itself (a symlink: the link, not its target) and nothing else,
    only here, before the first write of the build, and only after
    :func:`~clipvol.bricking.output_guard.check_overwrite` allowed it (a clipvol store or an empty
    folder that neither is, holds nor lies inside the input)."""
    if not output.exists() and not output.is_symlink():
        return None
    if overwrite:
        remove_output(output)
        return None
    attrs = _read_attrs(output) if output.is_dir() and not output.is_symlink() else None
    cv = (attrs or {}).get("clipvol")
    if not isinstance(cv, dict):
        raise exists_error(output, "store")
    if cv.get("complete"):
        raise exists_error(output, "store", what="exists (a complete clipvol store)")
    stored = _stored_job(cv)
    diff = [k for k in job if k != "source_identity" and stored.get(k) != job[k]]
    if not diff and stored.get("source_identity") != job["source_identity"]:
        changes = identity_changes(stored.get("source_identity"), job["source_identity"])
        raise SourceChangedError(
            f"{output}: the input changed since this interrupted build started ({'; '.join(changes)}); resuming would "
            "mix old and new data: pass --overwrite to start again"
        )
    if diff:
        k = diff[0]
        raise OutputExistsError(
            f"{output}: an interrupted build with different parameters ({k}: expected {job[k]!r} to resume, "
            f"got {stored.get(k)!r}); pass --overwrite to start again"
        )
    return attrs


def mark_complete(group) -> None:
    """Write the store's manifest (:mod:`clipvol.bricking.manifest`) and set
    ``attrs['clipvol']['complete']`` with the manifest's checksum: the very last write of any build path."""
    from .manifest import write_manifest

    attrs = dict(group.attrs)
    cv = dict(attrs["clipvol"])
    root = Path(group.store.root) / group.path if group.path else Path(group.store.root)
    pyramid = parse_metadata(attrs, str(root)).pyramid
    cv["manifest"] = write_manifest(root, [pyramid.grid(L) for L in range(pyramid.num_levels)])
    cv["complete"] = True
    group.attrs.update({"clipvol": cv})


def _scan_range(src: Source, pool: ThreadPoolExecutor, workers: int, chunk_bytes: int = 8 << 20) -> tuple[float, float]:
    """Finite (min, max) of level 0, in z-slabs of about ``chunk_bytes`` read in parallel.

    At most ``workers + 1`` slabs are in flight, so memory stays bounded by the thread count.
    """
    Z, Y, X = src.shape
    slab = max(1, chunk_bytes // max(1, Y * X * src.dtype.itemsize))
    lo, hi = np.inf, -np.inf
    futs: list[Future] = []

    def one(z0: int) -> tuple[float, float] | None:
        return finite_range(src.read((z0, 0, 0), (min(z0 + slab, Z), Y, X)))

    def drain(n: int) -> None:
        nonlocal lo, hi
        while len(futs) > n:
            r = futs.pop(0).result()
            if r is not None:
                lo, hi = min(lo, r[0]), max(hi, r[1])

    for z0 in range(0, Z, slab):
        futs.append(pool.submit(one, z0))
        drain(workers + 1)
    drain(0)
    if not np.isfinite(lo):
        return 0.0, 0.0  # no finite value at all: a degenerate but valid range
    return float(lo), float(hi)


class _Builder:
    """The streaming sweep over all levels (see the module docstring)."""

    def __init__(self, group, pyramid: Pyramid, output: Path, codec: str, pool: ThreadPoolExecutor, bar) -> None:
        self.pyr = pyramid
        self.B = pyramid.brick_shape
        self.out = output
        self.pool = pool
        self.bar = bar
        # a resumed build of a store written before checksums keeps that store's codec chain
        self.checksum = any(type(c).__name__ == "Crc32cCodec" for c in group["0"].metadata.codecs)
        self.encode = chunk_encoder(codec, pyramid.dtype, self.checksum)
        self.stats = StatsComputer(pyramid.dtype, pyramid.value_range)
        self.nlev = pyramid.num_levels
        self.stat_arrays = [{name: group[f"{STATS_GROUP}/{L}/{name}"] for name in STAT_ARRAYS
                             if name in group[f"{STATS_GROUP}/{L}"]} for L in range(self.nlev)]
        self.crc = [None] * self.nlev  # per level: the chunk crc32c of the bricks of the row being written
        self.done = [np.asarray(self.stat_arrays[L]["done"][...], dtype=bool) for L in range(self.nlev)]
        self.buffers: list[np.ndarray | None] = [None] * self.nlev
        # the spread beside levels >= 1 (clipvol.bricking.spread), when the store was created with it: the
        # level-0 moments of each level's slab travel with its values (float64, one pair per level)
        self.spread = has_spread_arrays(group, self.nlev)
        self.spread_dtype = spread_dtype(pyramid.dtype)
        self.encode_spread = chunk_encoder(codec, self.spread_dtype, self.checksum) if self.spread else None
        self.moments: list[tuple[np.ndarray, np.ndarray] | None] = [None] * self.nlev
        self._made_dirs: set[Path] = set()
        self._dir_lock = threading.Lock()
        self.bytes_written = 0
        self._bytes_lock = threading.Lock()

    # -- one brick (worker thread) ----------------------------------------------------------
    def _write(self, parts: tuple, data: bytes) -> None:
        """Write one chunk file ``out/<parts...>/<bx>`` (directories made once)."""
        d = self.out.joinpath(*parts[:-1])
        if d not in self._made_dirs:
            d.mkdir(parents=True, exist_ok=True)
            with self._dir_lock:
                self._made_dirs.add(d)
        write_chunk(d / parts[-1], data)
        with self._bytes_lock:
            self.bytes_written += len(data)

    def _brick(self, L: int, slab: np.ndarray, k: int, by: int, bx: int, write: bool):
        B = self.B
        ys, xs = slice(by * B[1], (by + 1) * B[1]), slice(bx * B[2], (bx + 1) * B[2])
        block = slab[:, ys, xs]
        mom = self.moments[L]
        m1 = m2 = None
        if mom is not None:
            m1, m2 = mom[0][:, ys, xs], mom[1][:, ys, xs]
        st = None
        if write:
            st = self.stats.compute(block)
            crc = -1  # no chunk written
            data = encode_brick(block, B, self.encode)
            if data is not None:
                if self.checksum:
                    crc = int.from_bytes(data[-4:], "little")
                self._write((str(L), "c", str(k), str(by), str(bx)), data)
            if self.spread and L >= 1:
                sp = encode_brick(spread_of(m1, m2, self.pyr.dtype), B, self.encode_spread)
                if sp is not None:
                    self._write((SPREAD_GROUP, str(L), "c", str(k), str(by), str(bx)), sp)
            st = (st, crc)
        if L + 1 < self.nlev:
            child = downsample(block, self.pyr.filter)
            buf = self.buffers[L + 1]
            z0 = (k % 2) * (B[0] // 2)
            y0, x0 = by * B[1] // 2, bx * B[2] // 2
            at = (slice(z0, z0 + child.shape[0]), slice(y0, y0 + child.shape[1]), slice(x0, x0 + child.shape[2]))
            buf[at] = child
            if self.spread:
                c1, c2 = moments_down(block, m1, m2)
                self.moments[L + 1][0][at], self.moments[L + 1][1][at] = c1, c2
        return st

    # -- one brick-row of a level (main thread) -----------------------------------------------
    def process(self, L: int, k: int, slab: np.ndarray) -> None:
        pyr, B = self.pyr, self.B
        gz, gy, gx = pyr.grid(L)
        if L + 1 < self.nlev and k % 2 == 0:
            Z1, Y1, X1 = pyr.levels[L + 1].shape
            j = k // 2
            self.buffers[L + 1] = np.empty((min(B[0], Z1 - j * B[0]), Y1, X1), dtype=pyr.dtype)
            if self.spread:
                shape = self.buffers[L + 1].shape
                self.moments[L + 1] = (np.empty(shape, dtype=np.float64), np.empty(shape, dtype=np.float64))
        write = not bool(self.done[L][k].all())
        futs = [self.pool.submit(self._brick, L, slab, k, by, bx, write) for by in range(gy) for bx in range(gx)]
        try:
            results = []
            for f in futs:
                results.append(f.result())
                if self.bar is not None:
                    self.bar.update(1)
        except BaseException:
            for f in futs:
                f.cancel()
            raise
        if write:
            self._write_stats(L, k, results, gy, gx)
        if L + 1 < self.nlev and (k % 2 == 1 or k == gz - 1):
            buf = self.buffers[L + 1]
            self.buffers[L + 1] = None
            self.moments[L] = None  # this slab's moments are folded into the next level's
            self.process(L + 1, k // 2, buf)

    def _write_stats(self, L: int, k: int, results, gy: int, gx: int) -> None:
        arrs = self.stat_arrays[L]
        shape = (gy, gx)
        crcs = [c for _, c in results]
        results = [r for r, _ in results]
        if "chunk_crc32c" in arrs:
            arrs["chunk_crc32c"][k] = np.array(crcs, dtype=np.int64).reshape(shape)
        for name in ("min", "max", "mean", "std"):
            arrs[name][k] = np.array([getattr(r, name) for r in results], dtype=np.float64).reshape(shape)
        for name in ("nan_count", "inf_count"):
            arrs[name][k] = np.array([getattr(r, name) for r in results], dtype=np.int64).reshape(shape)
        arrs["histogram"][k] = np.stack([r.histogram for r in results]).reshape(shape + (-1,))
        arrs["done"][k] = np.ones(shape, dtype=bool)  # last: the row is finished
        self.done[L][k] = True


def _create_store(output: Path, pyramid: Pyramid, codec: str, unit: str, source_desc: str, frame=None,
                  identity: dict | None = None):
    import zarr

    group = zarr.open_group(str(output), mode="w-", zarr_format=3)
    origin = frame.origin if frame is not None else (0.0, 0.0, 0.0)
    cv = clipvol_metadata(pyramid, unit=unit, codec=codec, complete=False, source=source_desc, frame=frame)
    if identity is not None:
        cv["source_identity"] = identity
    attrs = {"ome": ome_metadata(pyramid, name=output.stem or "image", unit=unit, origin=origin), "clipvol": cv}
    compressors = store_codecs(codec, pyramid.dtype)
    for L, lv in enumerate(pyramid.levels):
        group.create_array(
            str(L),
            shape=lv.shape,
            chunks=pyramid.brick_shape,
            dtype=pyramid.dtype,
            fill_value=0,
            compressors=compressors or None,
            dimension_names=["z", "y", "x"],
            config={"write_empty_chunks": False},
        )
        create_stats_arrays(group, pyramid.grid(L), L)
        if L >= 1 and with_spread(pyramid):
            create_spread_array(group, pyramid, L, codec)
    if with_spread(pyramid):
        cv["spread"] = spread_attrs(pyramid)
    group.attrs.update(attrs)  # written after the arrays: a store is only recognised once whole
    return group


def with_spread(pyramid: Pyramid) -> bool:
    """Does a build of ``pyramid`` write the spread beside its coarse levels? For the mean filter
    (the other filters' coarse voxels are no mean of a distribution) and more than one level."""
    return pyramid.filter == "mean" and pyramid.num_levels > 1


def spread_attrs(pyramid: Pyramid) -> dict:
    """The ``attrs["clipvol"]["spread"]`` block: where the spread arrays are and what they hold."""
    return {"group": SPREAD_GROUP, "levels": list(range(1, pyramid.num_levels)),
            "dtype": spread_dtype(pyramid.dtype).name, "statistic": "std",
            "of": "the level-0 voxels beneath each voxel (2**L per axis, edge-replicated like the mean)"}


def has_spread_arrays(group, nlev: int) -> bool:
    """Was the store created with the spread arrays (a resumed build of an older store has none)?"""
    return nlev > 1 and all(f"{SPREAD_GROUP}/{L}" in group for L in range(1, nlev))


def create_spread_array(group, pyramid: Pyramid, L: int, codec: str) -> None:
    """Create level ``L``'s spread array ``clipvol_spread/L``: the level's shape and chunks, the
    type of :func:`~clipvol.bricking.spread.spread_dtype`, the levels' codecs (checksummed)."""
    dt = spread_dtype(pyramid.dtype)
    group.create_array(f"{SPREAD_GROUP}/{L}", shape=pyramid.levels[L].shape, chunks=pyramid.brick_shape, dtype=dt,
                       fill_value=0, compressors=store_codecs(codec, dt) or None, dimension_names=["z", "y", "x"],
                       config={"write_empty_chunks": False})


def create_stats_arrays(group, g: tuple[int, int, int], L: int, names=STAT_ARRAYS) -> None:
    """Create the statistics arrays ``names`` of level ``L`` (grid ``g``) under ``clipvol_stats/L``
    (replacing any there: ``clipvol repair`` restores deleted or damaged ones with this)."""
    from zarr.codecs import Crc32cCodec, ZstdCodec

    stat_codecs = [ZstdCodec(level=0), Crc32cCodec()]  # the statistics the loads are checked against are checked too
    row = (1, g[1], g[2])
    sg = group.require_group(f"{STATS_GROUP}/{L}")
    specs = {name: ("float64", np.nan) for name in ("min", "max", "mean", "std")}
    specs.update({"nan_count": ("int64", 0), "inf_count": ("int64", 0), "histogram": ("int64", 0), "done": ("bool", False),
                  # each written chunk's own crc32c (-1: no chunk): a chunk that is intact but belongs to another
                  # brick, or to another build, is caught at no cost (its trailing crc is compared with this)
                  "chunk_crc32c": ("int64", -1)})
    for name in names:
        dtype, fill = specs[name]
        shape, chunks = (g + (HIST_BINS,), row + (HIST_BINS,)) if name == "histogram" else (g, row)
        sg.create_array(name, shape=shape, chunks=chunks, dtype=dtype, fill_value=fill, compressors=stat_codecs,
                        overwrite=True)


def plan_build(src: Source, source, output: Path, opts: BuildOptions) -> tuple:
    """What a build of ``src`` (opened from ``source``) into ``output`` writes, decided once for the
    local and the Dask build (:func:`clipvol.bricking.dask_build.brick_volume_dask`), so that both
    write the same store: ``(spacing, unit, frame, job, inodes)`` - the voxel size (the option, else
    the input's, else 1), the unit, the world frame (the input's with that spacing, moved to
    ``opts.origin``), the job spec a resumed build must match and the input files' inodes.

    Refuses, before anything is written, an input that records no voxel size when none is given, an
    output that is one of the inputs, and an ``--overwrite`` of anything clipvol did not write
    (:mod:`clipvol.bricking.output_guard`)."""
    if opts.spacing is None and getattr(src, "spacing_required", None):  # the input records no voxel size
        raise InputFormatError(src.spacing_required)
    sp = tuple(float(v) for v in (opts.spacing or src.spacing or (1.0, 1.0, 1.0)))
    unit = opts.unit or getattr(src, "unit", None) or "micrometer"
    frame = src.frame.with_spacing(sp) if getattr(src, "frame", None) is not None else None
    if opts.origin is not None:
        frame = (frame or WorldFrame.from_spacing(sp)).with_origin(opts.origin)
    job = job_spec(src, src.shape, opts.brick, opts.filter, opts.codec, sp, unit)
    inodes = file_inodes(src)
    inputs = [*src.files(), *([source] if isinstance(source, (str, Path)) else [])]
    check_not_input(output, inputs)
    if opts.overwrite:
        check_overwrite(output, inputs)
    return sp, unit, frame, job, inodes


def brick_volume(source, output, options: BuildOptions | None = None, **kwargs) -> StoreMeta:
    """Brick ``source`` into a multiresolution clipvol store at ``output`` (a local directory).

    Parameters
    ----------
    source : str, Path, numpy.ndarray or Source
        Level-0 input; see :func:`clipvol.bricking.sources.open_source` for the formats.
    output : str or Path
        The store directory to create (or resume).
    options : BuildOptions, optional
        How to build it (:class:`~clipvol.bricking.build_options.BuildOptions`: brick, filter,
        codec, spacing, unit, workers, overwrite, progress, raw_shape, raw_dtype, byte_order,
        summary, origin); :func:`clipvol.bricking.dask_build.brick_volume_dask` takes the same.
    **kwargs
        Any of those options as a keyword, over ``options`` (``brick=32, codec="zstd"``).

    Returns
    -------
    StoreMeta
        The validated metadata of the finished store.
    """
    opts = BuildOptions.from_kwargs(options, **kwargs)
    workers, progress, overwrite = opts.workers, opts.progress, opts.overwrite
    bshape, filter, codec = opts.brick, opts.filter, opts.codec
    output = Path(output)
    src = open_source(source, raw_shape=opts.raw_shape, raw_dtype=opts.raw_dtype, byte_order=opts.byte_order)
    try:
        sp, unit, frame, job, inodes = plan_build(src, source, output, opts)
        with write_errors(output), output_lock(output), \
                ThreadPoolExecutor(max_workers=workers, thread_name_prefix="clipvol-brick") as pool:
            attrs = prepare_output(output, job, overwrite)
            if attrs is None:
                vr = _scan_range(src, pool, workers)
                pyramid = Pyramid.build(src.shape, bshape, sp, filter, src.dtype, vr, 0.0)
                group = _create_store(output, pyramid, codec, unit, job["source"], frame, job["source_identity"])
            else:
                import zarr

                pyramid = parse_metadata(attrs, str(output)).pyramid
                group = zarr.open_group(str(output), mode="r+")
            _sweep(src, group, pyramid, output, codec, pool, progress)
            check_source_unchanged(src, job["source_identity"], inodes, output)
            mark_complete(group)  # the very last write
        if opts.summary:  # summary tables (image-based LOD): their own completion marker, resumable
            from .summary import build_summary

            with write_errors(output, "its summary tables"):
                build_summary(output, workers=workers, progress=progress)
        return parse_metadata(dict(group.attrs), str(output))
    finally:
        src.close()


class write_errors:
    """Context manager: an :class:`OSError` of the machine's state (disk full, read-only file
    system, permission denied: :data:`~clipvol.errors.OPERATIONAL_ERRNOS`) raised while writing
    ``output`` becomes one :class:`~clipvol.errors.OutputWriteError` naming the output and the file.
    A build stopped this way is never marked complete, so re-running it resumes."""

    def __init__(self, output, what: str = "the store") -> None:
        self.output, self.what = output, what

    def __enter__(self) -> "write_errors":
        return self

    def __exit__(self, kind, e, tb) -> bool:
        if isinstance(e, OSError) and not isinstance(e, ClipvolError) and e.errno in OPERATIONAL_ERRNOS:
            err = OutputWriteError(f"{self.output}: cannot write {self.what} ({describe_os_error(e)}); "
                                   "nothing is marked complete: fix this and re-run to resume")
            err.errno = e.errno
            raise err from e
        return False


def _sweep(src: Source, group, pyramid: Pyramid, output: Path, codec: str, pool: ThreadPoolExecutor, progress: bool) -> None:
    from tqdm import tqdm

    total = sum(pyramid.num_bricks(L) for L in range(pyramid.num_levels))
    bar = tqdm(total=total, unit="brick", desc="bricking", file=sys.stderr, disable=not progress, dynamic_ncols=True)
    try:
        builder = _Builder(group, pyramid, output, codec, pool, bar)
        Z, Y, X = pyramid.shape
        B = pyramid.brick_shape[0]
        gz = pyramid.grid(0)[0]
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="clipvol-read") as reader:
            def read(k: int) -> np.ndarray:
                return src.read((k * B, 0, 0), (min((k + 1) * B, Z), Y, X))

            nxt = reader.submit(read, 0)
            for k in range(gz):
                slab = nxt.result()
                if k + 1 < gz:
                    nxt = reader.submit(read, k + 1)
                builder.process(0, k, slab)
                del slab
    finally:
        bar.close()
