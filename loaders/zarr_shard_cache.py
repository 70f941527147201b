"""Two small bounded caches of the sharded read path: verified shard indices, and the byte windows
(runs of neighbouring inner chunks) fetched in one request and served to the loader threads.

Why a cache and not a batch call: the clip-texture's loader threads each ask for one brick
(``read_brick_into``) in distance order; the bricks of one run are neighbours, so the other threads
ask for them within moments. The first thread to need a run fetches it whole; the others wait for
that one request (never send their own) and take their chunk's bytes from memory. No thread is
added: whoever asks first does the read, in its own thread.

Bounds: indices by count (each a few kB), windows by bytes (oldest dropped first). Each inner
chunk is served from a window once: a second read of that brick (a reload after eviction, or the
retry of a brick that failed its checksum) reads its bytes from storage again, so a retry never
sees the same possibly damaged bytes twice and a window leaves memory as soon as its bricks are in.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, Callable, Hashable

__all__ = ["SingleFlight", "ShardWindows"]

#: seconds a thread waits for another thread's read of the same key before reading it itself
#: (the reader's own time-outs end it long before; this only bounds the wait)
WAIT_S = 600.0


class SingleFlight:
    """A bounded LRU map whose misses are computed once: concurrent callers of :meth:`get` for one
    missing key wait for the first caller's ``make()`` instead of each calling their own."""

    def __init__(self, max_items: int) -> None:
        self.max_items = int(max_items)
        self._items: OrderedDict[Hashable, Any] = OrderedDict()
        self._pending: dict[Hashable, threading.Event] = {}
        self._lock = threading.Lock()

    def get(self, key: Hashable, make: Callable[[], Any]) -> Any:
        """The value of ``key``: cached, or made by ``make()`` (here or in the thread already making
        it). An exception of ``make`` propagates and nothing is kept; a waiter then makes its own."""
        for _ in range(2):  # a wait, then at most one make of our own
            with self._lock:
                if key in self._items:
                    self._items.move_to_end(key)
                    return self._items[key]
                ev = self._pending.get(key)
                if ev is None:
                    ev = self._pending[key] = threading.Event()
                    break
            ev.wait(WAIT_S)
        else:
            return make()  # the other thread failed (or took too long): read it ourselves, uncached
        try:
            value = make()
            with self._lock:
                self._items[key] = value
                while len(self._items) > self.max_items:
                    self._items.popitem(last=False)
            return value
        finally:
            with self._lock:
                self._pending.pop(key, None)
            ev.set()

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


class ShardWindows:
    """Fetched runs of a shard kept briefly, at most ``max_bytes`` together (oldest dropped first).

    :meth:`chunk` returns one inner chunk's bytes: from a window in memory, or by fetching the run
    that holds it (``fetch_run()``, done once however many threads ask for chunks of that run at
    once), or - for a chunk already served from its window, or when the run's read failed in
    another thread - by ``fetch_one()``, its own range."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        self._windows: OrderedDict[Hashable, list] = OrderedDict()  # key -> [start, bytes, chunks not yet served]
        self._held = 0
        self._pending: dict[Hashable, threading.Event] = {}  # runs being read, by the thread reading each
        self._lock = threading.Lock()
        #: inner chunks served from memory (their bytes were read with their run)
        self.served = 0

    def _take(self, key: Hashable, pos: int, off: int, size: int) -> memoryview | None:
        """Chunk ``pos``'s bytes from window ``key`` if it is held and the chunk not yet served; drops
        the window once all its chunks are. Called with the lock held."""
        w = self._windows.get(key)
        if w is None or pos not in w[2]:
            return None
        start, data, left = w
        left.discard(pos)
        if not left:
            del self._windows[key]
            self._held -= len(data)
        self.served += 1
        return memoryview(data)[off - start: off - start + size]

    def chunk(self, key: Hashable, pos: int, off: int, size: int, members: Callable[[], set],
              fetch_run: Callable[[], tuple[int, bytes]], fetch_one: Callable[[], bytes]) -> Any:
        """Bytes of inner chunk ``pos`` (``size`` bytes at ``off`` of the shard), which belongs to
        run ``key``; ``members()``: the positions of the run's chunks; ``fetch_run()`` returns
        ``(start, bytes)`` of the whole run, read from storage (and counted there)."""
        with self._lock:
            got = self._take(key, pos, off, size)
            if got is not None:
                return got
            if key in self._windows:  # this chunk was served from the window already: read it again
                ev = None
            else:
                ev = self._pending.get(key)
                mine = ev is None
                if mine:
                    ev = self._pending[key] = threading.Event()
        if ev is None:
            return fetch_one()
        if not mine:  # another thread is reading this run: wait for it, then take from memory
            ev.wait(WAIT_S)
            with self._lock:
                got = self._take(key, pos, off, size)
            return got if got is not None else fetch_one()
        try:
            start, data = fetch_run()
            with self._lock:
                self._insert(key, start, data, members())
                got = self._take(key, pos, off, size)
                self.served -= got is not None  # read here, with its run: not served from memory
        finally:
            with self._lock:
                self._pending.pop(key, None)
            ev.set()
        return got if got is not None else fetch_one()

    def put(self, key: Hashable, start: int, data: Any, members: set) -> None:
        """Hold ``data`` (bytes from ``start`` of the shard) as the window of run ``key``: a run read
        with something else (a whole shard read at once), not by :meth:`chunk`."""
        with self._lock:
            self._insert(key, start, data, members)

    def _insert(self, key: Hashable, start: int, data: Any, members: set) -> None:
        """Hold a window, dropping the oldest beyond ``max_bytes`` (never the one just held). Lock held."""
        old = self._windows.pop(key, None)
        if old is not None:
            self._held -= len(old[1])
        self._windows[key] = [start, data, set(members)]
        self._held += len(data)
        while self._held > self.max_bytes and len(self._windows) > 1:
            _, (_, gone, _) = self._windows.popitem(last=False)
            self._held -= len(gone)

    def clear(self) -> None:
        with self._lock:
            self._windows.clear()
            self._held = 0
