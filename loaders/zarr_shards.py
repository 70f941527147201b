"""Reading inner chunks of a sharded zarr v3 array (``sharding_indexed``) by byte range.

Why not zarr-python's reader: it sends one request per inner chunk plus index reads, outside this
loader's retries, time-outs, byte counting and checks. Here, where a level's inner chunk is the
brick (:class:`~clipvol.loaders.zarr_meta.ArrayMeta` ``shard``), a brick's bytes are found in two
steps:

1. the shard's index, read once per shard (a suffix or prefix range of the shard object; a
   shard whose decoded bricks fit in one run is read whole instead, index and data in one round
   trip, as zarr-python reads a shard it needs all of), verified (its crc32c, every entry inside the shard: :func:`~clipvol.loaders.zarr_shard_index.parse_index`)
   and kept in a small bounded cache of indices;
2. the brick's inner chunk, read as one byte range - together with its neighbours in the shard's
   byte layout: the shard's chunks are cut into runs of at most ``shard_run_bytes``
   (:func:`~clipvol.loaders.zarr_shard_index.plan_runs`), the first brick of a run asked for
   fetches the whole run in one request, and the loader threads' next reads of the run's other
   bricks are served from memory (:class:`~clipvol.loaders.zarr_shard_cache.ShardWindows`). A
   clip-texture loads nearest bricks first, and a run is a compact block of neighbours, so those
   reads follow within moments; ``shard_run_bytes=0`` reads one inner chunk per request.

The inner chunk's bytes then take the ordinary fast path of :mod:`clipvol.loaders.zarr_chunks`:
its own crc32c (and the manifest's crc32c for the brick, where there is one) is verified before
decoding, as for an unsharded chunk. Bytes are counted once, where they are read (index and run
reads), never again when a brick is served from a run in memory.

Local shards are opened the safe way of every store file (:mod:`clipvol.bricking.store_files`) and
read with ``os.pread``; a remote loader overrides :meth:`ShardReader._shard_index_raw`,
:meth:`ShardReader._shard_range` and :meth:`ShardReader._shard_object` with (ranged) requests
through its byte source.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from clipvol.bricking.pyramid import Int3
from clipvol.bricking.store_files import chunk_cap, open_checked
from clipvol.errors import BrickIntegrityError, InputFormatError
from clipvol.paging.loader import BrickKey

from .zarr_crc import _CRC32C_RESIDUE
from .zarr_meta import ArrayMeta
from .zarr_shard_cache import ShardWindows, SingleFlight
from .zarr_shard_index import ShardError, ShardIndex, ShardLayout, parse_index, plan_runs

__all__ = ["ShardReader", "SHARD_RUN_BYTES", "SHARD_WINDOW_BYTES", "SHARD_MAX_GAP", "SHARD_INDEXES"]

#: most bytes one request reads from a shard (a run of neighbouring inner chunks): large enough to
#: hide a 20-50 ms round trip behind the bytes of several bricks, small enough that a run of bricks
#: the view does not need costs little
SHARD_RUN_BYTES = 8 * 2**20
#: most bytes of fetched runs held in memory until their bricks are read
SHARD_WINDOW_BYTES = 64 * 2**20
#: the largest gap between two inner chunks read in one request (bytes read and thrown away)
SHARD_MAX_GAP = 64 * 2**10
#: shard indices kept (each 16 bytes per inner chunk, plus the runs)
SHARD_INDEXES = 1024
#: shards of more inner chunks than this ignore the read plan (matching it would cost more per read
#: than it saves); their runs are read as planned without it
MAX_PLANNED_CHUNKS = 4096


def _contiguous(ix: ShardIndex, members: np.ndarray, pos: int) -> np.ndarray:
    """Of ``members`` (inner chunks of one run), those whose bytes join ``pos``'s without a gap of
    more than :data:`SHARD_MAX_GAP`: one ranged read that skips the unplanned chunks around them."""
    order = members[np.argsort(ix.offsets[members], kind="stable")]
    ends = ix.offsets[order] + ix.sizes[order]
    cut = np.flatnonzero(ix.offsets[order][1:] - np.maximum.accumulate(ends)[:-1] > SHARD_MAX_GAP) + 1
    for group in np.split(order, cut):
        if pos in group:
            return group
    return np.array([pos])


class _AbsentShard(Exception):
    """The shard object does not exist (every brick in it is the fill value); never cached."""


class ShardReader:
    """The sharded read path of the zarr loader: ``_shard_chunk``, the read plan, and the raw reads."""

    #: see :data:`SHARD_RUN_BYTES` (a loader keyword, ``shard_run_bytes``)
    shard_run_bytes: int = SHARD_RUN_BYTES

    def _prepare_shards(self) -> None:
        """Per loader: the index cache and the run windows (bounded; shared by the loader threads)."""
        self._shard_indices = SingleFlight(SHARD_INDEXES)
        self._shard_windows = ShardWindows(max(SHARD_WINDOW_BYTES, 2 * self.shard_run_bytes))
        self._plans: dict[int, np.ndarray | None] = {}  # per level: sorted codes of the planned bricks
        self._inner_grids: dict[ShardLayout, np.ndarray] = {}

    def plan_reads(self, level: int, indices: np.ndarray | None) -> None:
        """The bricks of ``level`` about to be read (:class:`~clipvol.paging.loader.HasReadPlan`;
        ``None``: no plan). Where a plan is given, a read takes from a shard only the planned
        neighbours of the brick it reads (and reads a shard whole only when all its bricks are
        planned): a slab or a frustum-clipped window does not pull in the rest of each shard it
        touches. A no-op for unsharded levels."""
        if not (0 <= level < len(self._arrays)) or self._arrays[level].shard is None:
            return
        if indices is None:
            self._plans[level] = None
            return
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        _, gy, gx = self._grids[level]
        self._plans[level] = np.unique((idx[:, 0] * gy + idx[:, 1]) * gx + idx[:, 2])

    def _planned(self, level: int, sidx: tuple[int, ...], lay: ShardLayout) -> np.ndarray | None:
        """Per inner chunk of shard ``sidx`` (index order): whether its brick is planned; None: no plan."""
        plan = self._plans.get(level)
        if plan is None or lay.count > MAX_PLANNED_CHUNKS:
            return None
        cidx = self._inner_grid(lay) + np.asarray(sidx) * np.asarray(lay.per)
        lead = len(self._chunk_lead)
        b = cidx[:, lead:]
        grid = np.asarray(self._grids[level])
        ok = np.all(b < grid, axis=1) & np.all(cidx[:, :lead] == np.asarray(self._chunk_lead, dtype=np.int64), axis=1)
        code = (b[:, 0] * grid[1] + b[:, 1]) * grid[2] + b[:, 2]
        pos = np.searchsorted(plan, code)
        return ok & (pos < len(plan)) & (plan[np.minimum(pos, len(plan) - 1)] == code)

    def _inner_grid(self, lay: ShardLayout) -> np.ndarray:
        """``(count, ndim)`` positions of a shard's inner chunks in index (C) order, per layout (kept)."""
        grid = self._inner_grids.get(lay)
        if grid is None:
            grid = self._inner_grids[lay] = np.stack(np.unravel_index(np.arange(lay.count), lay.per), axis=1)
        return grid

    def _shard_chunk(self, am: ArrayMeta, level: int, index: Int3) -> Any:
        """The stored bytes of brick ``index``'s inner chunk at ``level`` (a sharded level), or None
        when it (or its whole shard) is absent. A shard that is truncated, whose index fails its
        checksum or points outside the shard, raises :class:`BrickIntegrityError` naming the shard
        and the brick; transient ``OSError`` propagate (the clip-texture retries them)."""
        lay: ShardLayout = am.shard
        sidx, pos = lay.locate(self._chunk_lead + tuple(index))
        try:
            try:
                ix: ShardIndex = self._shard_indices.get((level, sidx), lambda: self._load_index(am, level, sidx))
            except _AbsentShard:
                return None
            size = int(ix.sizes[pos])
            if size < 0:
                return None
            off = int(ix.offsets[pos])
            sizes = self._sizes[level]
            if sizes is not None and int(sizes[tuple(index)]) != size:
                raise ShardError(f"its index gives {size} bytes for this brick, the store's manifest "
                                 f"{int(sizes[tuple(index)])}")
            run = int(ix.run_of[pos])
            members = np.flatnonzero(ix.run_of == run)
            planned = self._planned(level, sidx, lay)
            if planned is not None:  # only the planned neighbours, contiguous with this chunk
                members = _contiguous(ix, members[planned[members] | (members == pos)], pos)
            start = int(ix.offsets[members].min())
            stop = int((ix.offsets[members] + ix.sizes[members]).max())
            if len(members) == 1:  # a run of one chunk: nothing to keep
                return self._shard_range(level, sidx, off, off + size)
            return self._shard_windows.chunk(
                (level, sidx, run, start, stop), pos, off, size,
                members=lambda: set(members.tolist()),
                fetch_run=lambda: (start, self._shard_range(level, sidx, start, stop)),
                fetch_one=lambda: self._shard_range(level, sidx, off, off + size))
        except ShardError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, tuple(index))}: shard "
                                      f"{self._shard_name(level, sidx)}: {e}") from None

    def _load_index(self, am: ArrayMeta, level: int, sidx: tuple[int, ...]) -> ShardIndex:
        """The shard's verified index and runs. A shard whose decoded bricks fit in one run is read
        whole in one request (index and data in one round trip, not two), its runs held as windows."""
        lay: ShardLayout = am.shard
        whole = None
        planned = self._planned(level, sidx, lay)
        if 0 < lay.count * am.nbytes <= self.shard_run_bytes and (planned is None or self._all_planned(level, sidx, lay, planned)):
            whole = self._shard_object(level, sidx, chunk_cap(am.nbytes) * lay.count + lay.index_nbytes)
            if whole is None:
                raise _AbsentShard
            n, size = lay.index_nbytes, len(whole)
            if size < n:
                raise ShardError(f"the shard is truncated: {size} bytes cannot hold its {n}-byte index")
            raw, bounds = (whole[size - n:], (0, size - n)) if lay.at_end else (whole[:n], (n, size))
        else:
            got = self._shard_index_raw(level, sidx, lay)
            if got is None:
                raise _AbsentShard
            raw, bounds = got
        offsets, sizes = parse_index(raw, lay, self._crc32c, _CRC32C_RESIDUE, chunk_cap(am.nbytes), bounds)
        ix = plan_runs(offsets, sizes, self.shard_run_bytes, SHARD_MAX_GAP)
        if whole is not None:
            view = memoryview(whole)
            for r, (start, stop) in enumerate(ix.runs):
                self._shard_windows.put((level, sidx, r, start, stop), start, view[start:stop],
                                        set(np.flatnonzero(ix.run_of == r).tolist()))
        return ix

    def _all_planned(self, level: int, sidx: tuple[int, ...], lay: ShardLayout, planned: np.ndarray) -> bool:
        """Whether every brick of shard ``sidx`` inside the level's grid is planned."""
        cidx = self._inner_grid(lay) + np.asarray(sidx) * np.asarray(lay.per)
        inside = np.all(cidx[:, len(self._chunk_lead):] < np.asarray(self._grids[level]), axis=1)
        return bool(np.all(planned[inside]))

    def _shard_name(self, level: int, sidx: tuple[int, ...]) -> str:
        am = self._arrays[level]
        root = self.path.resolve()
        rel = am.path.relative_to(root) if am.path.is_relative_to(root) else am.path
        return f"{rel.as_posix()}/{am.shard_key(sidx)}"

    # -- the raw reads (a remote loader overrides them) --------------------------------------------------
    def _open_shard(self, level: int, sidx: tuple[int, ...]) -> tuple[int, int] | None:
        """``(fd, size)`` of shard ``sidx``'s file, opened as what it claims (a regular file inside
        the store, at most the size its shape allows), or None when absent."""
        am = self._arrays[level]
        path = str(am.path / am.shard_key(sidx))
        try:
            return open_checked(path, self._root_real, self._dirs_ok,
                                chunk_cap(am.nbytes) * am.shard.count + am.shard.index_nbytes)
        except InputFormatError as e:
            raise ShardError(str(e).split(": ", 1)[-1]) from None

    def _shard_index_raw(self, level: int, sidx: tuple[int, ...], lay: ShardLayout) -> tuple[Any, tuple[int, int]] | None:
        """``(encoded index, (lo, hi) of the shard's data bytes)``, or None when the shard is absent."""
        opened = self._open_shard(level, sidx)
        if opened is None:
            return None
        fd, size = opened
        n = lay.index_nbytes
        try:
            if size < n:
                raise ShardError(f"the shard is truncated: {size} bytes cannot hold its {n}-byte index")
            raw = os.pread(fd, n, size - n if lay.at_end else 0)
        finally:
            os.close(fd)
        self.read_counter.add(len(raw))
        return raw, ((0, size - n) if lay.at_end else (n, size))

    def _shard_object(self, level: int, sidx: tuple[int, ...], cap: int) -> bytes | None:
        """All bytes of shard ``sidx`` (at most ``cap``), or None when it is absent."""
        opened = self._open_shard(level, sidx)
        if opened is None:
            return None
        fd, size = opened
        try:
            data = os.pread(fd, size, 0)
        finally:
            os.close(fd)
        self.read_counter.add(len(data))
        return data

    def _shard_range(self, level: int, sidx: tuple[int, ...], start: int, stop: int) -> bytes:
        """Bytes ``[start, stop)`` of shard ``sidx``; a shard that ends (or vanished) before ``stop``
        is a :class:`ShardError`."""
        opened = self._open_shard(level, sidx)
        if opened is None:
            raise ShardError("the shard vanished after its index was read")
        fd, _ = opened
        try:
            data = os.pread(fd, stop - start, start)
        finally:
            os.close(fd)
        self.read_counter.add(len(data))
        if len(data) != stop - start:
            raise ShardError(f"the shard is truncated: bytes {start}-{stop} read {len(data)}")
        return data
