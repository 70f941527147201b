"""Bytes read from storage, counted at the read site.

Why a counter of its own: what a view costs is the bytes that come off the disk or the network,
not the bricks it draws (a blosc chunk of an empty-ish brick is a few hundred bytes, a noisy one
its whole size) nor the bytes a loader decodes. So every loader increments one
:class:`ReadCounter` right where it reads - the zarr loader after a chunk file's ``read``, the
numpy loader after slicing its (memory-mapped) source, a remote byte source after a response -
and the clip-texture, the render actions and the benchmarks report differences of its totals.

The counter is shared by every thread that reads through the loader (one small lock; a chunk read
is a system call or a network round trip, so the lock is noise beside it). It also keeps a running
total per thread (:meth:`ReadCounter.thread_bytes`): a loader thread of the clip-texture takes the
difference around one brick's load, so each read is charged to the brick that caused it - the
frame's bricks apart from the prefetch's - however many threads read at once.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

__all__ = ["ReadCounter", "ReadTotals", "bytes_read_of", "split_reads"]


@dataclass(frozen=True, slots=True)
class ReadTotals:
    """A snapshot of a :class:`ReadCounter`: ``bytes`` read in ``reads`` read calls."""

    bytes: int = 0
    reads: int = 0

    def __sub__(self, other: "ReadTotals") -> "ReadTotals":
        return ReadTotals(self.bytes - other.bytes, self.reads - other.reads)


class ReadCounter:
    """Thread-safe running totals of bytes read from storage and of read calls."""

    __slots__ = ("_lock", "_bytes", "_reads", "_local")

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._bytes = 0
        self._reads = 0
        self._local = threading.local()

    def add(self, nbytes: int) -> None:
        """Count one read of ``nbytes`` bytes (in the totals and in the calling thread's own)."""
        n = int(nbytes)
        with self._lock:
            self._bytes += n
            self._reads += 1
        self._local.bytes = getattr(self._local, "bytes", 0) + n

    def thread_bytes(self) -> int:
        """Bytes counted so far by reads made in the calling thread (a difference of two calls is
        what the reads between them cost, whatever other threads read meanwhile)."""
        return getattr(self._local, "bytes", 0)

    @property
    def bytes(self) -> int:
        """Bytes read so far."""
        return self._bytes

    @property
    def reads(self) -> int:
        """Read calls so far."""
        return self._reads

    def snapshot(self) -> ReadTotals:
        """Both totals, read together."""
        with self._lock:
            return ReadTotals(self._bytes, self._reads)

    def __repr__(self) -> str:
        return f"ReadCounter(bytes={self._bytes}, reads={self._reads})"


def bytes_read_of(loader) -> int | None:
    """Bytes ``loader`` has read from storage (its ``read_counter``), or ``None`` for a loader that
    does not count (a custom loader need not: the figures are then absent, never guessed)."""
    counter = getattr(loader, "read_counter", None)
    return counter.bytes if isinstance(counter, ReadCounter) else None


def _row_codes(rows: np.ndarray) -> np.ndarray:
    """One int64 per ``(level, z, y, x)`` row."""
    return (rows[:, 0] << 48) | (rows[:, 1] << 32) | (rows[:, 2] << 16) | rows[:, 3]


def split_reads(reads: dict | None, keys) -> tuple[int, int] | tuple[None, None]:
    """``(frame, other)``: the bytes of ``reads`` (a clip-texture's :meth:`take_reads`, per brick
    ``(level, index)``, or None for reads summed past its table's size) charged to the bricks ``keys`` (``(n, 4)`` rows ``(level, z, y, x)``, the
    bricks a frame drew or wanted; repeats counted once) and to all the others (the prefetch);
    ``(None, None)`` when the loader does not count."""
    if reads is None:
        return None, None
    total = sum(reads.values())
    if not reads:
        return 0, 0
    # the few bricks read since the last frame against the cut's (thousands of) rows, in numpy:
    # one code per row (16 bits a field: levels and brick indices stay far below 2**16)
    read_keys = list(reads)
    read_rows = np.array([(L, *idx) for L, idx in read_keys], dtype=np.int64).reshape(-1, 4)
    rows = np.asarray(keys, dtype=np.int64).reshape(-1, 4)
    hit = np.isin(_row_codes(read_rows), _row_codes(rows))
    frame = int(sum(reads[k] for k, h in zip(read_keys, hit.tolist()) if h))
    return frame, total - frame
