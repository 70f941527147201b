"""Zarr v3 ``sharding_indexed``: the layout of a shard, its index, and the byte runs read at once.

Why its own module: a sharded array stores many inner chunks in one object (a *shard*) and an
index of where each lies, so reading one inner chunk needs the index first and then one byte range.
This module holds the pure part of that - parsing the codec's configuration, verifying and decoding
an index, and cutting a shard into the runs of neighbouring inner chunks that one request fetches
(:func:`plan_runs`) - without any I/O, so it can be tested alone; the reading itself is
:mod:`clipvol.loaders.zarr_shards`.

The index (zarr v3 spec, "sharding_indexed"): per inner chunk, in C order of its position in the
shard, a pair of little-endian uint64 ``(offset, nbytes)``; ``(2**64-1, 2**64-1)`` is an absent
chunk (fill value). It sits at the end of the shard object (``index_location: "end"``, the default)
or at its start, and is encoded with its own codecs: ``bytes`` (little endian), usually followed by
``crc32c``. Other index codecs are left to zarr-python (the loader falls back to it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from clipvol.errors import InputFormatError

__all__ = ["ShardLayout", "ShardIndex", "ShardError", "sharding_layout", "parse_index", "plan_runs", "ABSENT"]

#: offset and size of an absent inner chunk in a shard's index
ABSENT = 2**64 - 1
#: the most inner chunks per shard the fast path reads (an index of 16 MiB); more go to zarr-python
MAX_INNER_CHUNKS = 2**20


class ShardError(ValueError):
    """A shard (or its index) that is not what a shard must be: truncated, or failing its checksum,
    or pointing outside itself. The loader turns it into a BrickIntegrityError naming shard and brick."""


@dataclass(frozen=True, slots=True)
class ShardLayout:
    """How inner chunks sit in a shard: ``shard`` (shard shape, voxels per axis, all axes), ``per``
    (inner chunks per shard per axis), where the index is and whether it carries a crc32c."""

    shard: tuple[int, ...]
    per: tuple[int, ...]
    at_end: bool = True
    index_crc: bool = True

    @property
    def count(self) -> int:
        """Inner chunks per shard."""
        return math.prod(self.per)

    @property
    def index_nbytes(self) -> int:
        """Bytes of the encoded index: 16 per inner chunk, plus 4 for its crc32c."""
        return 16 * self.count + (4 if self.index_crc else 0)

    def locate(self, cidx: tuple[int, ...]) -> tuple[tuple[int, ...], int]:
        """``(shard index, inner chunk's position in the index)`` of the inner chunk at grid index ``cidx``."""
        sidx = tuple(c // p for c, p in zip(cidx, self.per))
        pos = 0
        for c, p in zip(cidx, self.per):
            pos = pos * p + c % p
        return sidx, pos


def sharding_layout(codec: dict, shard_shape: tuple[int, ...], where: str) -> tuple[ShardLayout, tuple[int, ...], list] | None:
    """``(layout, inner chunk shape, inner codecs)`` of a ``sharding_indexed`` codec entry, or None
    when its index codecs are not ``bytes`` (little endian) [+ ``crc32c``] (zarr-python reads those).
    Malformed configuration (an inner shape that does not divide the shard) is an InputFormatError."""
    conf = codec.get("configuration") or {}
    inner = conf.get("chunk_shape")
    if not (isinstance(inner, list) and len(inner) == len(shard_shape)
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in inner)):
        raise InputFormatError(f"{where}: sharding_indexed: expected an inner chunk_shape of {len(shard_shape)} "
                               f"positive integers, got {inner!r:.80}")
    if any(s % c for s, c in zip(shard_shape, inner)):
        raise InputFormatError(f"{where}: sharding_indexed: the inner chunk shape {inner} does not divide the shard "
                               f"shape {list(shard_shape)}")
    loc = conf.get("index_location", "end")
    if loc not in ("end", "start"):
        raise InputFormatError(f"{where}: sharding_indexed: expected index_location 'end' or 'start', got {loc!r:.40}")
    idx = [c if isinstance(c, dict) else {"name": c} for c in conf.get("index_codecs") or []]
    names = [c.get("name") for c in idx]
    if names not in (["bytes"], ["bytes", "crc32c"]) or \
            (idx[0].get("configuration") or {}).get("endian", "little") != "little":
        return None
    codecs = conf.get("codecs")
    if not isinstance(codecs, list):
        raise InputFormatError(f"{where}: sharding_indexed: expected a list of inner codecs, got {codecs!r:.80}")
    layout = ShardLayout(tuple(shard_shape), tuple(s // c for s, c in zip(shard_shape, inner)), loc == "end",
                         names[-1] == "crc32c")
    if layout.count > MAX_INNER_CHUNKS:  # an index of more than 16 MiB: not read here
        return None
    return layout, tuple(inner), codecs


@dataclass(frozen=True, slots=True)
class ShardIndex:
    """A verified index: per inner chunk its ``offsets`` and ``sizes`` (int64, -1 where absent),
    and the byte ``runs`` ``(start, stop)`` one request reads, ``run_of`` each chunk's run (-1: absent)."""

    offsets: np.ndarray
    sizes: np.ndarray
    runs: tuple[tuple[int, int], ...]
    run_of: np.ndarray

    @property
    def nbytes(self) -> int:
        return self.offsets.nbytes * 3


def parse_index(raw: Any, layout: ShardLayout, crc32c: Callable[[Any], int], residue: int, chunk_cap: int,
                data_bounds: tuple[int, int] | None) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets, sizes)`` (int64, -1 where absent) of an encoded index, verified: its length, its
    crc32c (``crc32c(raw) == residue`` for an intact message followed by its own checksum), each
    entry either absent in both halves or a range of at most ``chunk_cap`` bytes inside
    ``data_bounds`` ``(lo, hi)`` of the shard object (None: not known, a remote object whose size
    was not asked; a range past its end then reads short, which the reader refuses). Raises
    :class:`ShardError` saying what is wrong."""
    n = layout.count
    if len(raw) != layout.index_nbytes:
        raise ShardError(f"the shard is truncated: its index needs {layout.index_nbytes} bytes, got {len(raw)}")
    if layout.index_crc and crc32c(raw) != residue:
        raise ShardError("its index fails its crc32c checksum (the shard is truncated or corrupt)")
    pairs = np.frombuffer(bytes(raw[: 16 * n]), dtype="<u8").reshape(n, 2)
    off, nb = pairs[:, 0], pairs[:, 1]
    absent = (off == ABSENT) & (nb == ABSENT)
    if np.any((off == ABSENT) != (nb == ABSENT)):
        raise ShardError("its index has an entry with only one half marked absent (corrupt index)")
    present = ~absent
    if np.any(nb[present] > chunk_cap):
        raise ShardError(f"its index gives an inner chunk of {int(nb[present].max())} bytes, more than the "
                         f"{chunk_cap} one may hold (corrupt index)")
    limit = 2**62 if data_bounds is None else data_bounds[1]
    lo = 0 if data_bounds is None else data_bounds[0]
    if np.any(off[present] > limit) or np.any(off[present] < lo) or np.any(off[present] + nb[present] > limit):
        where = "past the end of the shard's data" if data_bounds is not None else "beyond any plausible shard"
        raise ShardError(f"its index points {where} (the shard is truncated or its index corrupt)")
    offsets = np.where(absent, -1, off.astype(np.int64))
    sizes = np.where(absent, -1, nb.astype(np.int64))
    return offsets, sizes


def plan_runs(offsets: np.ndarray, sizes: np.ndarray, cap: int, max_gap: int) -> ShardIndex:
    """Cut a shard's present inner chunks, in the order of their bytes, into runs of at most ``cap``
    bytes (a chunk larger than ``cap`` is a run of its own) that skip no more than ``max_gap`` bytes
    between neighbours: each run is one ranged read.

    Why a fixed partition rather than "the chunk asked for and what follows it": every inner chunk
    belongs to exactly one run, so the bytes of a shard are read at most once whichever of its
    bricks the loader threads ask for first, and two threads asking for bricks of one run wait for
    one request instead of sending two that overlap. zarr-python writes a shard's chunks back to
    back in Morton order, so a run is a compact block of neighbouring bricks - the ones a
    clip-texture, which loads nearest first, asks for next.
    """
    order = [int(i) for i in np.argsort(offsets, kind="stable") if sizes[i] >= 0]
    run_of = np.full(offsets.shape, -1, dtype=np.int64)
    runs: list[tuple[int, int]] = []
    start = stop = -1
    for i in order:
        o, s = int(offsets[i]), int(sizes[i])
        if runs and o - stop <= max_gap and max(stop, o + s) - start <= cap:
            stop = max(stop, o + s)
            runs[-1] = (start, stop)
        else:
            start, stop = o, o + s
            runs.append((start, stop))
        run_of[i] = len(runs) - 1
    return ShardIndex(offsets, sizes, tuple(runs), run_of)
