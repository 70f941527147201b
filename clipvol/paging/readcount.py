"""Bytes read from storage, counted at the read site.

Why a counter of its own: what a view costs is the bytes that come off the disk or the network,
not the bricks it draws (a blosc chunk of an empty-ish brick is a few hundred bytes, a noisy one
its whole size) nor the bytes a loader decodes. So every loader increments one
:class:`ReadCounter` right where it reads - the zarr loader after a chunk file's ``read``, the
numpy loader after slicing its (memory-mapped) source, a remote byte source after a response -
and the clip-texture, the render actions and the benchmarks report differences of its totals.

The counter is shared by every thread that reads through the loader (one small lock; a chunk read
is a system call or a network round trip, so the lock is noise beside it).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

__all__ = ["ReadCounter", "ReadTotals", "bytes_read_of"]


@dataclass(frozen=True, slots=True)
class ReadTotals:
    """A snapshot of a :class:`ReadCounter`: ``bytes`` read in ``reads`` read calls."""

    bytes: int = 0
    reads: int = 0

    def __sub__(self, other: "ReadTotals") -> "ReadTotals":
        return ReadTotals(self.bytes - other.bytes, self.reads - other.reads)


class ReadCounter:
    """Thread-safe running totals of bytes read from storage and of read calls."""

    __slots__ = ("_lock", "_bytes", "_reads")

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._bytes = 0
        self._reads = 0

    def add(self, nbytes: int) -> None:
        """Count one read of ``nbytes`` bytes."""
        with self._lock:
            self._bytes += int(nbytes)
            self._reads += 1

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
