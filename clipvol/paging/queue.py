"""The clip-texture's load queue: what to load next, and when a failed load may be tried again.

Three parts, one order:

* the **heap** of queued bricks, ordered by cost (distance from the centre of interest in brick
  units, biased along the motion), coarse levels first at equal cost - rebuilt whenever the centre
  moves, so it is always sorted for the current view;
* the **retries**, each waiting until its time (exponential backoff: ``backoff * 2**(attempt-1)``
  seconds after the failure), then entering the heap at its current cost;
* the **parked** jobs: a brick whose slot is still being written by a late reader of the brick it
  replaces waits here and re-enters the heap when the writer is done.

Entries are tuples ``(cost, -level, bz, by, bx, level, slot, generation)``; an entry is *valid* only
while its slot still has that generation and is queued, which the clip-texture checks when it pops
one (lazy invalidation: moving the window never searches the heap). Not thread-safe by itself: the
clip-texture calls it under its lock.
"""

from __future__ import annotations

import heapq
from typing import Callable, Iterator

__all__ = ["LoadQueue", "Entry"]

#: ``(cost, -level, bz, by, bx, level, slot, generation)``
Entry = tuple


class LoadQueue:
    """Heap of queued bricks, delayed retries and parked jobs (see the module docstring).

    Parameters
    ----------
    retry_backoff : float
        Seconds before the first retry, doubling with each further one.
    """

    def __init__(self, retry_backoff: float) -> None:
        self.retry_backoff = float(retry_backoff)
        self._heap: list[Entry] = []
        self._delayed: list[tuple[float, int, int, int]] = []  # (not_before, level, slot, gen)
        self._parked: dict[tuple[int, int], Entry] = {}  # (level, slot) -> entry waiting for a busy slot

    def __len__(self) -> int:
        return len(self._heap)

    def rebuild(self, entries: list[Entry], delayed: list[tuple[float, int, int, int]]) -> None:
        """Replace the heap by ``entries`` and the retries by ``delayed``; parked jobs are dropped
        (every queued brick is in ``entries`` again)."""
        entries.sort()
        self._heap = entries  # a sorted list is a heap
        self._parked.clear()
        heapq.heapify(delayed)
        self._delayed = delayed

    def clear(self) -> None:
        self._heap.clear()
        self._delayed.clear()
        self._parked.clear()

    def push(self, entry: Entry) -> None:
        heapq.heappush(self._heap, entry)

    def push_many(self, entries: list[Entry]) -> None:
        """Push ``entries``: one at a time while they are few beside the heap, else by one re-heapify."""
        if len(entries) * 8 < len(self._heap):
            for e in entries:
                heapq.heappush(self._heap, e)
        else:
            self._heap.extend(entries)
            heapq.heapify(self._heap)

    def pop(self) -> Entry | None:
        """The front entry (cheapest), or None when empty; the caller checks its validity."""
        return heapq.heappop(self._heap) if self._heap else None

    # -- retries -----------------------------------------------------------------------------
    def retry_at(self, attempts: int, now: float) -> float:
        """When a brick that failed ``attempts`` times may be tried again."""
        return now + self.retry_backoff * 2.0 ** (int(attempts) - 1)

    def delay(self, not_before: float, level: int, slot: int, gen: int) -> None:
        """Schedule a retry of ``(level, slot)`` (generation ``gen``) for ``not_before``."""
        heapq.heappush(self._delayed, (not_before, level, slot, gen))

    def due(self, now: float) -> Iterator[tuple[int, int, int]]:
        """Pop the retries whose time has come: ``(level, slot, gen)``."""
        while self._delayed and self._delayed[0][0] <= now:
            _, L, s, gen = heapq.heappop(self._delayed)
            yield L, s, gen

    def has_delayed(self) -> bool:
        """True while a retry waits (the loader threads skip the retry step otherwise)."""
        return bool(self._delayed)

    def next_retry_in(self, now: float) -> float | None:
        """Seconds until the next retry is due (None: none scheduled)."""
        return self._delayed[0][0] - now if self._delayed else None

    # -- parking -----------------------------------------------------------------------------
    def park(self, level: int, slot: int, entry: Entry) -> None:
        """Hold ``entry`` until :meth:`unpark` for its slot (the slot is being written)."""
        self._parked[(level, slot)] = entry

    def unpark(self, level: int, slot: int) -> bool:
        """Put the job parked on ``(level, slot)`` back in the heap; True if there was one."""
        entry = self._parked.pop((level, slot), None)
        if entry is None:
            return False
        heapq.heappush(self._heap, entry)
        return True

    def promote(self, now: float, cost: Callable[[int, int], float], valid: Callable[[int, int, int], bool]) -> None:
        """Move due retries into the heap at their current ``cost(level, slot)`` if still ``valid``."""
        for L, s, gen in self.due(now):
            if valid(L, s, gen):
                self.push(cost(L, s) + (L, s, gen))
