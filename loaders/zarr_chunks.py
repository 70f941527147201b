"""Reading a zarr store's chunks: the fast path of the zarr loader.

Why not just ``arr[...]``: zarr-python 3.1 spends ~0.3-0.9 ms of fixed overhead per indexing call
and funnels every thread through one event loop, so chunk-aligned reads from several loader
threads reach only a few percent of memcpy speed. Because a brick *is* one chunk, this reads the
chunk's file itself (``<array>/c/<bz>/<by>/<bx>`` for zarr v3's default key encoding) and decodes
it with numcodecs, which releases the GIL, in the calling loader thread. The codec chains
``bytes`` (+ ``blosc`` | ``zstd`` | ``gzip`` | nothing) (+ ``crc32c``) of zarr v3 and the plain
compressors of zarr v2 take this fast path; anything else (sharding, transpose, filters) falls
back to zarr indexing (:meth:`ChunkReader._read_zarr`), which gives the same values, only slower.
A sharded array (``sharding_indexed``) whose inner chunk is the brick and whose inner codecs are
one of those chains takes the fast path too: its inner chunks are read by byte range, with their
neighbours, by :mod:`clipvol.loaders.zarr_shards`.

Every raw chunk fetch goes through one method, :meth:`ChunkReader._chunk_bytes`, so a loader for
remote storage overrides only that (local files take :meth:`ChunkReader._chunk_into_buffer`, the
same bytes read into a per-thread buffer, unless a subclass overrides ``_chunk_bytes``). Every
file is opened as what it claims to be (:mod:`clipvol.bricking.store_files`): a regular file
inside the store, never a FIFO, device or link out, its size capped before it is read. The bytes
are verified (:mod:`clipvol.loaders.zarr_integrity`) before they are decoded. Bricks are returned
in native byte order (a big-endian store gives native arrays).

A mixin of :class:`~clipvol.loaders.zarr_store.ZarrLoader`, not an object it holds: the hot path
(:meth:`ChunkReader.read_brick_into`) reads per-level tables straight off the loader, and a remote
loader overrides single methods of it.
"""

from __future__ import annotations

import os
import threading
from typing import Any

import numpy as np

from clipvol.bricking.pyramid import Int3, pad_to_brick
from clipvol.bricking.store_files import chunk_cap, open_checked, read_capped
from clipvol.errors import BrickIntegrityError, InputFormatError
from clipvol.paging.loader import BrickKey

from .zarr_crc import crc32c_implementation
from .zarr_integrity import _UNREAD, _ChecksumError, _IdentityError
from .zarr_meta import ArrayMeta

__all__ = ["ChunkReader"]


def _blosc_sizes(data: bytes) -> tuple[int, int]:
    """``(nbytes, cbytes)`` from a blosc frame's 16-byte header (little-endian uint32s at 4 and 12)."""
    if len(data) < 16:
        raise ValueError(f"blosc frame of {len(data)} bytes is shorter than its 16-byte header")
    return int.from_bytes(data[4:8], "little"), int.from_bytes(data[12:16], "little")


class ChunkReader:
    """``read_brick`` / ``read_brick_into`` of the loader contract for stored levels, and the raw
    chunk fetch under them."""

    def _prepare_hot_path(self) -> None:
        """Per level, what :meth:`read_brick_into` needs without building anything per call: the
        chunk key's root as a string, the separator, the grid, whether edge bricks are whole, and
        whether the level can be decoded straight into a slot."""
        pyr = self._pyramid
        self._roots = [am.chunk_root(self._chunk_lead) for am in self._arrays]
        self._seps = [am.separator for am in self._arrays]
        self._grids = [pyr.grid(L) for L in range(pyr.num_levels)]
        self._full_last = [tuple(n % b == 0 for n, b in zip(pyr.levels[L].shape, pyr.brick_shape))
                           for L in range(pyr.num_levels)]
        self._direct = [L < self._stored and am.fast and not self._lead and am.chunks == pyr.brick_shape
                        and am.dtype == pyr.dtype and (am.decoder is None or am.blosc)
                        for L, am in enumerate(self._arrays)]
        self._crc32c = crc32c_implementation()[1]
        # per level: each chunk's exact size from the manifest, else one cap from the chunk shape
        self._sizes = [self._manifest.sizes(L) if self._manifest is not None and L < self._stored else None
                       for L in range(len(self._arrays))]
        self._caps = [chunk_cap(am.nbytes) for am in self._arrays]
        self._tls = threading.local()  # per loader thread: the read buffer of _chunk_into_buffer
        # a subclass that fetches chunks elsewhere (remote stores) overrides _chunk_bytes: use it
        local = type(self)._chunk_bytes is ChunkReader._chunk_bytes and hasattr(os, "readv")
        self._fetch = self._chunk_into_buffer if local else self._chunk_bytes
        self._prepare_shards()  # sharded levels: ShardReader (zarr_shards)

    def read_brick(self, level: int, index: Int3) -> np.ndarray:
        """Brick ``index`` ``(bz, by, bx)`` of ``level``: brick shape, native dtype, edge-replicated.

        Raises :class:`~clipvol.errors.BrickIntegrityError` when the chunk fails its checksum, when
        its decoded bounds disagree with the store's statistics, or when it is missing although the
        statistics say it holds data: wrong data is never returned as if right.
        """
        index = self._pyramid.check_key(level, index)
        if level >= self._stored:
            return self._derived_brick(level, index)
        am = self._arrays[level]
        start, stop = self._pyramid.brick_voxel_box(level, index)
        valid = tuple(e - s for s, e in zip(start, stop))
        if am.fast:
            buf = np.empty(am.nbytes, dtype=np.uint8)
            got = self._load_chunk(am, level, index, buf)
            if not got:
                self._check_absent(level, index)
                return np.full(self._pyramid.brick_shape, am.fill_value, dtype=self._pyramid.dtype)
            block = buf.view(am.dtype).reshape(am.chunks)
            if self._lead:
                block = block[self._within]
        else:
            got = 1
            block = self._read_zarr(level, start, stop)
        if block.shape != valid:
            block = block[tuple(slice(0, v) for v in valid)]
        if block.dtype != self._pyramid.dtype:
            block = block.astype(self._pyramid.dtype)
        self._check_loaded(level, index, block, got)
        return pad_to_brick(block, self._pyramid.brick_shape)

    def read_brick_into(self, level: int, index: Int3, out: np.ndarray) -> None:
        """Write brick ``index`` of ``level`` into ``out`` (brick shape and dtype, C-contiguous).

        The clip-texture hands its slot here: an interior brick of a blosc (or uncompressed) level
        is decoded straight into it, saving a copy of every brick; anything else goes through
        :meth:`read_brick` and one copy. Same contract and errors as :meth:`read_brick`; on an
        error ``out`` holds garbage (the caller marks the brick failed, it never shows it).
        """
        direct = self._direct
        if 0 <= level < len(direct) and direct[level] and out.shape == self._pyramid.brick_shape \
                and out.dtype == self._pyramid.dtype and out.flags.c_contiguous:
            grid = self._grids[level]
            bz, by, bx = index
            # interior bricks only (the hot path: no key object, no pathlib, one bounds test)
            if 0 <= bz < grid[0] - 1 or (bz == grid[0] - 1 and self._full_last[level][0]):
                if 0 <= by < grid[1] - 1 or (by == grid[1] - 1 and self._full_last[level][1]):
                    if 0 <= bx < grid[2] - 1 or (bx == grid[2] - 1 and self._full_last[level][2]):
                        am = self._arrays[level]
                        st = self._brick_stats(level, index) if self.verify_checksums or self.check_plausibility \
                            else None  # looked up once for both checks
                        got = self._load_chunk(am, level, index, out.reshape(-1).view(np.uint8), st)
                        if not got:
                            self._check_absent(level, index)
                            out.fill(am.fill_value)  # missing chunk the statistics call empty
                            return
                        self._check_loaded(level, index, out, got, st)
                        return
        out[...] = self.read_brick(level, index)

    # -- the raw fetch (the one method a remote store overrides) --------------------------------------
    def _open_chunk(self, level: int, index: Int3) -> tuple[int, int] | None:
        """``(fd, size)``: a read-only descriptor of brick ``index``'s chunk file at ``level`` (the
        path from precomputed per-level parts: no pathlib, no key object) and its size, or None
        when it is absent.

        The file must be what it claims (:mod:`clipvol.bricking.store_files`): opened without
        blocking and without following a link out of the store, its folder resolved inside the
        store (once per folder), a regular file, exactly the size the manifest records (or at
        most the cap for the chunk shape). Anything else is a :class:`BrickIntegrityError`
        naming the file; no byte of it is read.
        """
        bz, by, bx = index
        sep = self._seps[level]
        path = f"{self._roots[level]}{bz}{sep}{by}{sep}{bx}"
        sizes = self._sizes[level]
        try:
            opened = open_checked(path, self._root_real, self._dirs_ok, self._caps[level],
                                  None if sizes is None else int(sizes[bz, by, bx]) or None)
        except InputFormatError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file "
                                      f"{self._chunk_name(level, index)}: {str(e).split(': ', 1)[-1]}") from None
        return opened

    def _chunk_bytes(self, level: int, index: Int3) -> bytes | None:
        """The stored bytes of brick ``index``'s chunk at ``level``, or ``None`` when it is absent.

        Every raw chunk read of this loader goes through here, so a loader for another storage
        (object store, HTTP) overrides only this; decoding, checksum and plausibility stay above.
        Other ``OSError``\\ s propagate (transient: the clip-texture retries them).
        """
        opened = self._open_chunk(level, index)
        if opened is None:
            return None
        fd, size = opened
        try:  # one fstat and (for a regular file) one read: no buffered-reader object per chunk
            return read_capped(fd, size, max(size, self._caps[level]) if self._sizes[level] is None else size,
                               self._chunk_name(level, index))
        except InputFormatError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file {e}") from None
        finally:
            os.close(fd)

    def _chunk_into_buffer(self, level: int, index: Int3) -> memoryview | bytes | None:
        """:meth:`_chunk_bytes` of a local file, read into this thread's reused buffer: a memoryview
        valid until the same thread's next read through this loader (``_load_chunk`` is done with
        it by then), or None when the chunk is absent.

        Why: a fresh ``bytes`` per ~1 MB chunk costs an allocation and, whenever the allocator has
        handed the memory back to the kernel, a page fault per 4 KiB on the next read; one buffer
        per thread stays mapped and in the CPU cache, so the read is cheaper and the checksum and
        the decode that follow read the bytes from cache. It holds the largest chunk read so far,
        per loader thread. A short read, or a file whose size changed since ``fstat``, is read
        again whole by :meth:`_chunk_bytes`.
        """
        opened = self._open_chunk(level, index)
        if opened is None:
            return None
        fd, size = opened
        try:
            buf = getattr(self._tls, "buf", None)
            if buf is None or len(buf) <= size:  # one byte spare: a file that grew reads long
                buf = self._tls.buf = bytearray(size + 1 + (size >> 4))
            n = os.readv(fd, [buf])
        finally:
            os.close(fd)
        if n != size:
            return self._chunk_bytes(level, index)
        return memoryview(buf)[:n]

    def _load_chunk(self, am: ArrayMeta, level: int, index: Int3, out: np.ndarray, st: Any = _UNREAD) -> int:
        """Fetch, verify and decode one chunk into ``out`` (uint8, the chunk's bytes). ``st``: the
        brick's :meth:`_brick_stats` when the caller has looked them up already.

        Returns 0 when the chunk is absent, 2 when its checksum is intact *and* equals the one the
        statistics recorded for this brick (the bytes are exactly those written here), else 1
        (:meth:`~clipvol.loaders.zarr_integrity.IntegrityChecks._verify_chunk` decides).
        """
        if am.shard is None:
            data = self._fetch(level, index)
            if data is None:
                return 0
            self.read_counter.add(len(data))
        else:  # an inner chunk of a shard (counted where its index and run were read)
            data = self._shard_chunk(am, level, index)
            if data is None:
                return 0
        nbytes = out.size
        try:
            if am.checksum:
                body, loaded = self._verify_chunk(data, level, index, st)
            else:
                body, loaded = data, 1
            if am.decoder is None:
                if len(body) != nbytes:
                    raise ValueError(f"expected {nbytes} bytes, got {len(body)}")
                out[:] = np.frombuffer(body, dtype=np.uint8)
            elif am.blosc:
                # the header says the sizes: check them, then decode straight into `out`
                n, cbytes = _blosc_sizes(body)
                if n != nbytes or cbytes != len(body):
                    raise ValueError(f"blosc header: {n} bytes in {cbytes}, expected {nbytes} bytes in {len(body)}")
                am.decoder.decode(body, out=out)
            else:
                dec = np.frombuffer(am.decoder.decode(body), dtype=np.uint8)
                if dec.size != nbytes:
                    raise ValueError(f"decoded {dec.size} bytes, expected {nbytes}")
                out[:] = dec
        except _IdentityError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file "
                                      f"{self._chunk_name(level, index)}: {e}") from None
        except _ChecksumError as e:
            raise BrickIntegrityError(f"{self._where}: {BrickKey(level, index)}: chunk file "
                                      f"{self._chunk_name(level, index)} is truncated or corrupt ({e})") from None
        except Exception as e:  # numcodecs raises RuntimeError/ValueError/TypeError for bad data
            raise self._corrupt(level, index, e) from None
        return loaded

    def _chunk_name(self, level: int, index: Int3) -> str:
        am = self._arrays[level]
        if am.shard is not None:  # the shard file and where in it
            sidx, _ = am.shard.locate(self._chunk_lead + tuple(index))
            inner = tuple(c % p for c, p in zip(self._chunk_lead + tuple(index), am.shard.per))
            return f"{self._shard_name(level, sidx)} (shard), inner chunk {inner}"
        root = self.path.resolve()
        rel = am.path.relative_to(root) if am.path.is_relative_to(root) else am.path.relative_to(self.path) \
            if am.path.is_relative_to(self.path) else am.path
        key = am.key_prefix + "".join(f"{v}{am.separator}" for v in self._chunk_lead) + am.separator.join(str(i) for i in index)
        return f"{rel}/{key}"

    def _corrupt(self, level: int, index: Int3, e: BaseException) -> InputFormatError:
        return BrickIntegrityError(
            f"{self._where}: {BrickKey(level, index)}: chunk file {self._chunk_name(level, index)} is truncated or "
            f"corrupt ({type(e).__name__}: {e})"
        )

    def _read_zarr(self, level: int, start, stop) -> np.ndarray:
        """Codec chains off the fast path, through zarr-python (which verifies a crc32c itself). Anything
        zarr raises for metadata or data it cannot use becomes an :class:`InputFormatError`."""
        try:
            arr = self._zarr_arrays.get(level)
            if arr is None:
                import zarr

                with self._lock:
                    arr = self._zarr_arrays.get(level)
                    if arr is None:
                        arr = zarr.open_array(str(self._arrays[level].path), mode="r")
                        self._zarr_arrays[level] = arr
            sl = self._select + tuple(slice(a, b) for a, b in zip(start, stop))
            return np.asarray(arr[sl])
        except (OSError, MemoryError):
            raise
        except Exception as e:
            raise InputFormatError(f"{self._where} level {level}: zarr cannot read the array ({type(e).__name__}: "
                                   f"{str(e)[:200]})") from None
