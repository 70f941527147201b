"""The clip-texture: per-level toroidal brick windows in main memory, filled by loader threads.

After ``vzParameterClipTexture`` (Bhaniramka & Demange 2002, section 4.1) and the clipmap. A memory budget becomes
a pool of brick slots allocated once (:func:`clipvol.paging.toroidal.allocate`); coarse levels that fit
are held whole, finer ones keep a window of ``W`` bricks per axis around the centre of interest,
brick ``b`` living in slot ``b mod W``. Moving the centre evicts the bricks that left a window,
gives their slots to the bricks that entered, and re-sorts one load queue by distance (coarse
before fine at equal distance, biased towards where the centre is going). Loader threads pop the
queue front, call the loader, validate, copy into the slot and set its state to ``RESIDENT``.

A render action may narrow what is read with a region of interest (:meth:`ClipTexture.set_region`,
:mod:`clipvol.paging.region`): per level, the bricks it will draw - a slice's slab - around which
the windows are fitted inside the same slots and of which alone the bricks are queued.

The paging stage's threads live here (bricking has its own worker pool, and the loader conformance
suite its own test threads); the load order and retry timing are :mod:`clipvol.paging.queue`. One
lock guards all bookkeeping; loader calls run
outside it, and the copy into the slot happens under it after checking the slot's generation, so
a reader never sees a partly written brick and a late result for an evicted brick is dropped.
A loader that also offers ``read_brick_into(level, index, out)`` is handed the slot itself (no
copy); the slot is then marked busy until that write ends, and a brick that takes the slot over
meanwhile waits for it. See ``docs/cliptexture.md`` for the brick lifecycle and the failure
semantics.

Why one module of this size: the slot pool, the windows' relayout, the hand-off from the load
queue, the loader threads, the region and the cut's outside set all work on one slot table under
one lock, and every rule about who may write a slot when (busy, parked, generation) has to be read
beside the others. The parts without that state live apart: :mod:`.toroidal`, :mod:`.queue`,
:mod:`.region`, :mod:`.slab`, :mod:`.cells`.
"""

from __future__ import annotations

import operator
import os
import threading
import time
import warnings
import weakref
from collections import deque
from dataclasses import dataclass
from enum import IntEnum
from typing import Callable, Iterable

import numpy as np

from ..bricking.pyramid import Int3
from ..bricking.spread import spread_dtype
from ..errors import InputFormatError, LoaderError, ParameterError
from ..units import parse_bytes
from .cells import cell_edges, cell_ranges
from .loader import BrickKey, HasBrickRanges, HasReadPlan, Loader, check_brick
from .queue import LoadQueue
from .readcount import ReadCounter, bytes_read_of
from .region import Region
from .toroidal import (
    Allocation,
    allocate,
    brick_costs,
    in_box,
    level_window,
    predicted_offset,
    region_window,
    slot_of,
    window_bricks,
    window_shape,
)

__all__ = ["BrickState", "ClipTexture", "ClipTextureStats"]

#: centres kept for the motion prediction, and how many moves ahead it looks
HISTORY = 4
LOOKAHEAD = 1.0
#: sliding window (seconds) of the throughput figures, and loads kept for the latency percentiles
RATE_WINDOW_S = 5.0
LATENCY_SAMPLES = 2048
#: longest sleep of an idle loader thread before it checks that its clip-texture still exists
IDLE_POLL_S = 1.0
#: distinct bricks whose reads are kept apart between two take_reads() calls (a caller that never
#: takes them - no render action - must not grow the table without bound); reads of further bricks
#: are summed under the key None, which no frame draws (they count as prefetch)
MAX_READ_KEYS = 1 << 17
#: bytes between the writes that pre-fault the slot pool (the smallest page size of the platforms we run on)
_PAGE = 4096


#: subtracted from a prioritised brick's cost: it sorts before every distance (see ClipTexture.prioritize)
_URGENT = 1e18

class BrickState(IntEnum):
    """Lifecycle of a brick of the clip-texture (see ``docs/cliptexture.md``).

    ``ABSENT`` (outside every window, not yet placed, or in a window but outside the region of
    interest of :meth:`ClipTexture.set_region`) -> ``QUEUED`` (in a window, waiting in the
    load queue) -> ``LOADING`` (a loader thread is reading it) -> ``RESIDENT`` (its slot holds the
    loader's data) or, after the retries, ``FAILED``. Leaving the window makes any state ``ABSENT``.
    """

    ABSENT = 0
    QUEUED = 1
    LOADING = 2
    RESIDENT = 3
    FAILED = 4


# plain ints for the per-move numpy bookkeeping (enum attribute access is slow on hot paths)
_ABSENT, _QUEUED, _LOADING, _RESIDENT, _FAILED = (int(s) for s in BrickState)


@dataclass(frozen=True, slots=True)
class ClipTextureStats:
    """A snapshot of the clip-texture's memory, queue and loader throughput.

    Rates are over the last ``RATE_WINDOW_S`` seconds (or since creation if shorter); latencies
    (seconds, loader call plus validation, for the last ``LATENCY_SAMPLES`` loads) are ``nan``
    before the first load.
    """

    memory_budget: int
    pool_bytes: int
    window: int
    whole_levels: tuple[int, ...]
    resident_bricks: tuple[int, ...]
    resident_bytes_per_level: tuple[int, ...]
    resident_bytes: int
    queued: int
    loading: int
    loads_total: int
    bytes_loaded: int
    loads_per_s: float
    mb_per_s: float
    latency_p50: float
    latency_p95: float
    latency_p99: float
    retries: int
    dropped: int
    failures: int
    #: bricks the loader's bounds showed to be empty: filled without a read, not counted as loads
    empty_skipped: int = 0
    #: bytes the loader has read from storage (its ``read_counter``; None: the loader does not count)
    bytes_read: int | None = None


#: most loader threads: more only add stacks and lock contention (each thread's loads are I/O or a
#: decode; a remote store's latency is covered by a few dozen), and 100000 would exhaust the process
MAX_LOADER_THREADS = 256


def _count(value, name: str, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an int in ``[minimum, maximum]`` (numpy integers welcome, bools and floats refused)."""
    want = f"an integer >= {minimum}" if maximum is None else f"an integer in {minimum}..{maximum}"
    if isinstance(value, bool):
        raise ParameterError(f"{name}: expected {want}, got {value!r}")
    try:
        n = operator.index(value)
    except TypeError:
        raise ParameterError(f"{name}: expected {want}, got {value!r}") from None
    if n < minimum or (maximum is not None and n > maximum):
        raise ParameterError(f"{name}: expected {want}, got {value!r}")
    return n


def _key_rows(keys) -> np.ndarray:
    """``(m, 4)`` int64 ``(level, z, y, x)`` rows of ``keys``: such an array, or ``(level, index)``
    pairs / :class:`BrickKey` s (one Python step per key, for callers that hold a few)."""
    if isinstance(keys, np.ndarray):
        return np.asarray(keys, dtype=np.int64).reshape(-1, 4)
    rows = [(k.level, *k.index) if isinstance(k, BrickKey) else (int(k[0]), *(int(i) for i in k[1])) for k in keys]
    return np.asarray(rows, dtype=np.int64).reshape(-1, 4)


class _Countdown:
    """Bricks a ``wait_for`` call still waits for (compared by identity)."""

    __slots__ = ("n",)

    def __init__(self, n: int) -> None:
        self.n = n


class _Level:
    """Slot bookkeeping of one level: its pool and, per slot, brick, state, generation, attempts."""

    __slots__ = ("level", "grid", "whole", "shape", "start", "stop", "pool", "key", "state", "gen", "attempts", "not_before",
                 "busy", "empty", "cell_lo", "cell_hi", "spread", "urgent")

    def __init__(self, level: int, grid: Int3, whole: bool, capacity: int, brick_shape: Int3, dtype: np.dtype,
                 prefault: bool = True, cells: Int3 | None = None):
        self.level = level
        self.grid = grid
        self.whole = whole
        self.shape: Int3 = (0, 0, 0)
        self.start: Int3 = (0, 0, 0)
        self.stop: Int3 = (0, 0, 0)
        # allocated once. np.empty leaves its pages unmapped, so the first write of every page would
        # fault (the kernel maps and zeroes it, hundreds of MB on a first fill) inside the loader
        # threads, where it cost more than the decode; ``prefault`` writes one byte per page here
        # instead, once, so a first fill runs at the speed of every later one
        self.pool = np.empty((capacity, *brick_shape), dtype=dtype)
        if prefault and self.pool.nbytes:
            self.pool.reshape(-1).view(np.uint8)[::_PAGE] = 0
        self.key = np.full((capacity, 3), -1, dtype=np.int64)
        self.state = np.zeros(capacity, dtype=np.int8)
        self.gen = np.zeros(capacity, dtype=np.int64)
        self.attempts = np.zeros(capacity, dtype=np.int32)
        self.not_before = np.zeros(capacity, dtype=np.float64)
        # a thread is writing into the slot outside the lock (``read_brick_into``): the slot's next
        # brick waits ("parked") until that write is over, even if the write is for an evicted brick
        self.busy = np.zeros(capacity, dtype=bool)
        # the loader's bounds say the slot's brick holds only the fill value: filled, never read
        # (decided once per brick when it enters the window, in one vectorised bounds call)
        self.empty = np.zeros(capacity, dtype=bool)
        # per slot, its brick's cells' value ranges (clipvol.paging.cells), written with the brick
        shape = (capacity, *cells) if cells is not None else (0,)
        self.cell_lo = np.full(shape, np.inf, dtype=np.float32)
        self.cell_hi = np.full(shape, -np.inf, dtype=np.float32)
        # per slot, its brick's spread (clipvol.bricking.spread) where the loader has one for the level
        self.spread: np.ndarray | None = None
        # per slot, the generation of the brick whose prioritised entry waits in the load queue (-1:
        # none): ClipTexture.prioritize pushes a brick once, not once per frame that asks for it
        self.urgent = np.full(capacity, -1, dtype=np.int64)


class ClipTexture:
    """Per-level toroidal windows of bricks in main memory, paged in by loader threads.

    Parameters
    ----------
    loader : Loader
        The data source (:class:`clipvol.paging.loader.Loader`); called from several threads at once.
    memory_budget : int or str
        Bytes for the brick slot pool (``"256MB"``, ``"1GiB"``, ...); never exceeded.
    threads : int, optional
        Loader threads; default the loader's ``preferred_threads`` if it has one (a remote
        store asks for as many as it keeps requests in flight), else ``os.cpu_count()``.
    center : (x, y, z), optional
        Initial centre of interest in world units; default the volume's centre.
    retries : int
        How many times a failing ``read_brick`` is retried before the brick is ``FAILED``.
    retry_backoff : float
        Seconds before the first retry, doubling with each further one. A waiting retry does not
        hold a thread: the brick waits in a timed queue while threads serve other bricks.
    on_error : callable, optional
        ``on_error(key: BrickKey, exc)`` called (from a loader thread) when a brick fails for good.
    predictive : bool
        Bias the queue towards the direction the centre has been moving.
    cells_on_load : bool
        Take each loaded brick's per-cell value ranges in the loader thread
        (:func:`clipvol.paging.cells.cell_ranges`, for the renderer's empty-space skipping; about
        0.1 ms per MB of brick). Off by default: beside the other threads' decoding it made a fill
        1.3-1.4x as long (``docs/cliptexture.md``), and paging should keep up with decoding; the GPU
        cache then computes them once per brick when it uploads it.
    prefault : bool
        Touch every page of the slot pool at construction (the pool is then resident from the
        start), so the first fill does not pay a page fault per 4 KiB inside the loader threads.
        ``False`` maps pages only as bricks are written (a budget far above what a session visits
        then costs no memory).
    region : Region, optional
        Page only these bricks from the start (:meth:`set_region`); ``Region.empty(levels)`` reads
        nothing until a render action sets its own region - a slice viewer then never fills cubes
        it does not draw. Default: cube windows around ``center``.

    Notes
    -----
    ``get_brick`` returns a read-only view into the slot pool, valid until the caller's next
    :meth:`set_center` / :meth:`set_roaming_window` (which may give the slot to another brick).
    """

    def __init__(
        self,
        loader: Loader,
        memory_budget: int | str = "256MB",
        threads: int | None = None,
        *,
        center=None,
        retries: int = 2,
        retry_backoff: float = 0.05,
        on_error: Callable[[BrickKey, BaseException], None] | None = None,
        predictive: bool = True,
        prefault: bool = True,
        region: Region | None = None,
        cells_on_load: bool = False,
        outside: Callable[[int, np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.loader = loader
        self.pyramid = loader.pyramid
        self.memory_budget: int = parse_bytes(memory_budget, "memory_budget")
        if threads is None:  # an I/O-bound loader (a remote store) may ask for more threads than cores
            threads = min(int(getattr(loader, "preferred_threads", None) or os.cpu_count() or 1), MAX_LOADER_THREADS)
        nthreads = _count(threads, "threads", 1, MAX_LOADER_THREADS)
        retries = _count(retries, "retries", 0)
        try:
            backoff = float(retry_backoff)
        except (TypeError, ValueError):
            backoff = float("nan")
        if not (0.0 <= backoff < float("inf")):
            raise ParameterError(f"retry_backoff: expected finite seconds >= 0, got {retry_backoff!r}")
        if on_error is not None and not callable(on_error):
            raise ParameterError(f"on_error: expected a callable(key, exc) or None, got {on_error!r}")
        self.retries = retries
        self.retry_backoff = backoff
        self.on_error = on_error
        self.predictive = bool(predictive)
        #: levels whose bricks carry their spread (the loader's ``spread_levels``; consistent coarse levels)
        self.spread_levels: tuple[int, ...] = tuple(getattr(loader, "spread_levels", ()) or ())
        self.allocation: Allocation = allocate(self.pyramid, self.memory_budget)
        if self.spread_levels:  # the spread pools share the budget: the bricks' pools give them room
            sp = spread_dtype(self.pyramid.dtype).itemsize
            per = int(np.prod(self.pyramid.brick_shape)) * sp
            extra = sum(self.allocation.capacity[L] for L in self.spread_levels) * per
            try:
                self.allocation = allocate(self.pyramid, self.memory_budget - extra)
            except ParameterError:  # too tight to take it off: split the budget by bytes per voxel
                it = self.pyramid.dtype.itemsize
                try:
                    self.allocation = allocate(self.pyramid, self.memory_budget * it // (it + sp))
                except ParameterError:
                    # a budget that holds the bricks but not their spread beside them: the coarse levels
                    # classify their means, as a store without the spread does (a budget that worked
                    # before the spread existed still works)
                    self.spread_levels = ()
        self.whole_levels: tuple[int, ...] = self.allocation.whole_levels
        pyr = self.pyramid
        #: cells of each brick whose value ranges the loader threads compute (None: an odd brick extent)
        self.cell_edges = cell_edges(pyr.brick_shape) if cells_on_load else None
        cells = None if self.cell_edges is None else tuple(b // e for b, e in zip(pyr.brick_shape, self.cell_edges))
        self._levels = [
            _Level(L, pyr.grid(L), L in self.whole_levels, self.allocation.capacity[L], pyr.brick_shape, pyr.dtype,
                   bool(prefault), cells)
            for L in range(pyr.num_levels)
        ]
        for L in self.spread_levels:
            lv = self._levels[L]
            lv.spread = np.zeros((len(lv.state), *pyr.brick_shape), dtype=spread_dtype(pyr.dtype))
        self._window = self.allocation.window
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._queue = LoadQueue(backoff)  # heap by cost, delayed retries, parked jobs
        # the queued bricks per level, told each time the queue is re-sorted (HasReadPlan)
        self._plan_reads = loader.plan_reads if isinstance(loader, HasReadPlan) else None
        into = getattr(loader, "read_brick_into", None)
        self._read_into: Callable[[int, Int3, np.ndarray], None] | None = into if callable(into) else None
        # empty bricks (bounds [fill, fill], see HasBrickRanges) are filled here, never read
        self._ranges = loader.brick_ranges if isinstance(loader, HasBrickRanges) else None
        self._ranges_failed: set[int] = set()  # levels whose bounds call failed: not asked again
        # bricks outside the cut (crop box, clip planes: see set_outside) are filled here, never read
        self._outside = outside
        self._fill_brick = np.full(pyr.brick_shape, pyr.fill_value, dtype=pyr.dtype)
        self._fill_brick.setflags(write=False)
        self._fill_cells = None if cells is None else cell_ranges(self._fill_brick, self.cell_edges)
        self._skipped_empty = 0
        self._closing = False
        #: seconds ``with`` waits for the loader threads on leaving (a command bounded by a
        #: deadline sets what is left of it: a thread stuck in a read is a daemon and is left behind)
        self.close_timeout: float | None = 5.0
        self._pending = 0  # bricks QUEUED or LOADING (recounted on every move, decremented per outcome)
        self._watched: dict[tuple[int, Int3], list[_Countdown]] = {}  # brick -> wait_for calls waiting on it
        self.failures: dict[BrickKey, BaseException] = {}
        self.residency_version = 0
        #: counts the re-sorts of the load queue (a move, a new region or cut): the order
        #: :meth:`prioritize` set is gone after one
        self.queue_version = 0
        self._loads_total = 0
        self._bytes_total = 0
        #: bytes read from storage per brick since the last take_reads(), charged by the loader thread
        #: that read them (the loader's read_counter, per thread); None: the loader does not count
        self._reads_by_key: dict[tuple[int, Int3], int] | None = (
            {} if isinstance(getattr(self.loader, "read_counter", None), ReadCounter) else None)
        self._retries = 0
        self._dropped = 0
        self._events: deque[tuple[float, int]] = deque()  # (done time, bytes) in the rate window
        self._latency: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self._t0 = time.perf_counter()
        lo, hi = pyr.volume_box()
        if center is None and region is not None:
            center = region.center
        c = (lo + hi) / 2.0 if center is None else self._check_center(center)
        self._history: deque[np.ndarray] = deque([c], maxlen=HISTORY)
        self._region: Region | None = None  # None: cube windows, every brick of a window queued
        if region is not None:
            self._check_region(region)
            self._region = region
        with self._cv:
            self._apply(c, self._window)
        # the threads hold only a weak reference between loads, so a clip-texture that is dropped
        # without close() is still collected, and its threads end within IDLE_POLL_S
        ref = weakref.ref(self)
        self._threads = [
            threading.Thread(target=_loader_thread, args=(ref,), name=f"clipvol-loader-{i}", daemon=True)
            for i in range(nthreads)
        ]
        for t in self._threads:
            t.start()

    # -- public queries -------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """The centre of interest ``(x, y, z)`` in world units (a copy)."""
        return self._history[-1].copy()

    @property
    def window_size(self) -> int:
        """The roaming window ``W`` (bricks per axis) of the windowed levels."""
        return self._window

    def window_shape(self, level: int) -> tuple[int, int, int]:
        """Bricks per axis ``(z, y, x)`` of ``level``'s window (its whole grid for a whole level)."""
        return self._lv(level).shape

    def window(self, level: int) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """``(start, stop)`` brick indices ``(z, y, x)`` of ``level``'s current window."""
        lv = self._lv(level)
        with self._lock:
            return lv.start, lv.stop

    def in_window_mask(self, level: int, indices: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: which bricks ``indices`` (``(n, 3)`` ``bz, by, bx``) lie in ``level``'s window."""
        lv = self._lv(level)
        with self._lock:
            return in_box(indices, lv.start, lv.stop)

    def resident_mask(self, level: int, indices: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: which bricks ``indices`` are resident (their data is in memory)."""
        lv = self._lv(level)
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        with self._lock:
            return self._resident_locked(lv, idx)

    @staticmethod
    def _resident_locked(lv: _Level, idx: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: resident among ``idx`` (``(n, 3)``); the caller holds the lock."""
        ok = in_box(idx, lv.start, lv.stop)
        s = slot_of(idx[ok], lv.shape)
        res = np.zeros(len(idx), dtype=bool)
        res[ok] = (lv.state[s] == _RESIDENT) & np.all(lv.key[s] == idx[ok], axis=1)
        return res

    def out_of_reach_mask(self, level: int, indices: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: bricks of ``level`` that the region (:meth:`set_region`) says no sample reaches
        (outside a slice's slab). All False with cube windows."""
        region = self._region
        if region is None:
            return np.zeros(len(np.asarray(indices).reshape(-1, 3)), dtype=bool)
        return region.out_of_reach(self.pyramid, self._lv(level).level, indices)

    def state(self, level: int, index) -> BrickState:
        """The :class:`BrickState` of brick ``index`` of ``level``."""
        idx = self.pyramid.check_key(level, index)
        lv = self._levels[level]
        with self._lock:
            s = self._slot_if_held(lv, idx)
            return BrickState.ABSENT if s is None else BrickState(int(lv.state[s]))

    def get_brick(self, level: int, index) -> np.ndarray | None:
        """A read-only view of the resident brick, or ``None`` if it is not resident.

        The view stays valid until the caller's next :meth:`set_center` / :meth:`set_roaming_window`.
        """
        return self._resident_view(level, index, "pool")

    def get_spread(self, level: int, index) -> np.ndarray | None:
        """A read-only view of the resident brick's spread (:mod:`clipvol.bricking.spread`), or
        ``None`` if the brick is not resident or its level carries none; valid as :meth:`get_brick`'s."""
        return self._resident_view(level, index, "spread")

    def _resident_view(self, level: int, index, pool: str) -> np.ndarray | None:
        """Read-only view of the slot of resident brick ``index`` in the level's array ``pool``
        (``"pool"``: the voxels, ``"spread"``: their spread), or None."""
        idx = self.pyramid.check_key(level, index)
        lv = self._levels[level]
        arr = getattr(lv, pool)
        if arr is None:
            return None
        with self._lock:
            s = self._slot_if_held(lv, idx)
            if s is None or lv.state[s] != _RESIDENT:
                return None
            view = arr[s].view()
        view.flags.writeable = False
        return view

    def get_bricks(self, level: int, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(resident mask (n,), copies (m, *brick_shape))`` of the resident bricks among ``indices``.

        One lock and one fancy-indexed copy for many bricks (the splat action gathers thousands
        of small point-node bricks per frame); the copies stay valid after the slots are reused.
        """
        lv = self._lv(level)
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        with self._lock:
            res = self._resident_locked(lv, idx)
            data = lv.pool[slot_of(idx[res], lv.shape)]
        return res, data

    def cell_ranges(self, level: int, indices) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(resident mask (n,), min (m, *cells), max (m, *cells))``: copies of the per-cell value
        ranges (:func:`clipvol.paging.cells.cell_ranges`, computed by the loader thread that loaded
        each brick) of the resident bricks among ``indices`` ``(n, 3)``, under one lock; None when
        the brick shape has no cells."""
        if self.cell_edges is None:
            return None
        lv = self._lv(level)
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        with self._lock:
            res = self._resident_locked(lv, idx)
            s = slot_of(idx[res], lv.shape)
            return res, lv.cell_lo[s], lv.cell_hi[s]

    def resident_bricks(self) -> list[tuple[int, tuple[int, int, int]]]:
        """Every resident brick as ``(level, (bz, by, bx))``, coarsest level first."""
        out = []
        with self._lock:
            for lv in reversed(self._levels):
                for k in lv.key[lv.state == BrickState.RESIDENT]:
                    out.append((lv.level, (int(k[0]), int(k[1]), int(k[2]))))
        return out

    def failure_snapshot(self) -> dict:
        """``{BrickKey: exception}`` of the bricks failed now, copied under the lock (loader
        threads add to :attr:`failures` while a frame reads it)."""
        with self._lock:
            return dict(self.failures)

    @property
    def stats(self) -> ClipTextureStats:
        """A :class:`ClipTextureStats` snapshot."""
        nb = self.pyramid.brick_nbytes
        now = time.perf_counter()
        with self._lock:
            res = tuple(int(np.count_nonzero(lv.state == BrickState.RESIDENT)) for lv in self._levels)
            queued = sum(int(np.count_nonzero(lv.state == BrickState.QUEUED)) for lv in self._levels)
            loading = sum(int(np.count_nonzero(lv.state == BrickState.LOADING)) for lv in self._levels)
            self._trim_events(now)
            n_ev = len(self._events)
            b_ev = sum(b for _, b in self._events)
            lat = np.array(self._latency, dtype=np.float64)
            loads, total, retries, dropped, fails = (
                self._loads_total, self._bytes_total, self._retries, self._dropped, len(self.failures)
            )
            skipped = self._skipped_empty
        span = max(min(RATE_WINDOW_S, now - self._t0), 1e-9)
        p = np.percentile(lat, [50, 95, 99]) if lat.size else np.full(3, np.nan)
        return ClipTextureStats(
            memory_budget=self.memory_budget,
            pool_bytes=self.allocation.nbytes,
            window=self._window,
            whole_levels=self.whole_levels,
            resident_bricks=res,
            resident_bytes_per_level=tuple(r * nb for r in res),
            resident_bytes=sum(res) * nb,
            queued=queued,
            loading=loading,
            loads_total=loads,
            bytes_loaded=total,
            loads_per_s=n_ev / span,
            mb_per_s=b_ev / span / 1e6,
            latency_p50=float(p[0]),
            latency_p95=float(p[1]),
            latency_p99=float(p[2]),
            retries=retries,
            dropped=dropped,
            failures=fails,
            empty_skipped=skipped,
            bytes_read=bytes_read_of(self.loader),
        )

    # -- control ---------------------------------------------------------------------------------
    def set_center(self, xyz) -> None:
        """Move the centre of interest to ``xyz`` (world ``(x, y, z)``): evict, re-queue, re-sort."""
        c = self._check_center(xyz)
        with self._cv:
            self._check_open()
            self._move_to(c)
            self._cv.notify_all()

    @property
    def region(self) -> Region | None:
        """The region of interest set by :meth:`set_region` (``None``: cube windows)."""
        return self._region

    @property
    def bytes_read(self) -> int | None:
        """Bytes the loader has read from storage so far (``None`` if it does not count them)."""
        return bytes_read_of(self.loader)

    def set_region(self, region: Region | None) -> None:
        """Page the bricks of ``region`` (per level, around its centre) instead of cube windows.

        A render action calls this each frame with what it will draw (a slice: a slab per level,
        :mod:`clipvol.paging.slab`); ``None`` restores cube windows around the current centre (a
        volume view). The centre moves to ``region.center`` (motion prediction included); each
        windowed level's window is fitted around the level's bricks inside its slots
        (:func:`~clipvol.paging.toroidal.region_window`: the memory budget holds), and only the
        region's bricks are queued, nearest the centre first. Bricks of a window outside the region
        are read only when a frame waits for them. Repeating the current region changes nothing.
        """
        if region is not None:
            self._check_region(region)
        with self._cv:
            self._check_open()
            if region is None and self._region is None:
                return
            if region is not None and region.same_as(self._region):
                return
            self._region = region
            if region is None:
                self._apply(self._history[-1], self._window)
            else:
                self._move_to(np.asarray(region.center, dtype=np.float64))
            self._cv.notify_all()

    def _check_region(self, region) -> None:
        if not isinstance(region, Region):
            raise ParameterError(f"region: expected a clipvol.paging.region.Region or None, "
                                 f"got {type(region).__name__}")
        if len(region.bricks) != self.pyramid.num_levels:
            raise ParameterError(f"region: expected bricks for {self.pyramid.num_levels} levels, "
                                 f"got {len(region.bricks)}")
        for L, b in enumerate(region.bricks):
            if b is not None and len(b) and np.any(b.max(axis=0) >= np.asarray(self.pyramid.grid(L))):
                raise ParameterError(f"region: brick indices of level {L} beyond its grid {self.pyramid.grid(L)}")

    def _move_to(self, c: np.ndarray) -> None:
        """Append ``c`` to the motion history (reset on a teleport) and place the windows; lock held."""
        prev = self._history[-1]
        if self._is_teleport(c - prev):
            self._history.clear()
        self._history.append(c)
        self._apply(c, self._window)

    def set_roaming_window(self, size: int) -> None:
        """Set ``W``, the bricks per axis of the windowed levels' windows.

        ``size`` is limited to the budget's largest window (:attr:`allocation`.window), as the
        physical memory window of Volumizer is limited by the memory allowed.
        """
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 2:
            raise ParameterError(f"roaming window size: expected an integer >= 2 (bricks per axis), got {size!r}")
        w = min(int(size), self.allocation.window)
        with self._cv:
            self._check_open()
            self._window = w
            self._apply(self._history[-1], w)
            self._cv.notify_all()

    def set_outside(self, outside: Callable[[int, np.ndarray], np.ndarray] | None) -> int:
        """Bricks never to read: ``outside(level, keys (n, 3))`` -> ``(n,)`` bool, or None for none.

        A renderer that draws only a cut of the volume (a crop box, clip planes: see
        :class:`clipvol.scene.geometry.Shape`) culls the bricks outside it; this keeps the
        clip-texture from reading them too. They are filled with the fill value like empty bricks
        (never drawn: the selection culls them). A new cut re-queues the bricks it brings back in;
        returns how many (a GPU cache holding their fill must then be emptied).
        """
        if outside is not None and not callable(outside):
            raise ParameterError(f"outside: expected a callable(level, keys) or None, got {outside!r}")
        with self._cv:
            self._check_open()
            self._outside = outside
            requeued = 0
            for lv in self._levels:
                held = np.nonzero(lv.key[:, 0] >= 0)[0]
                if not len(held):
                    continue
                now_empty = self._empty_mask(lv.level, lv.key[held])
                back = held[lv.empty[held] & ~now_empty]  # filled for the old cut, inside the new one
                lv.gen[back] += 1  # a late fill for the old cut is dropped
                lv.attempts[back] = 0
                lv.not_before[back] = 0.0
                lv.empty[back] = False
                # read again; one a region of interest leaves unqueued (ABSENT) stays so, now unfilled
                lv.state[back[lv.state[back] != _ABSENT]] = _QUEUED
                requeued += len(back)
                waiting = held[(lv.state[held] == _QUEUED) & now_empty]  # not read yet, now outside
                lv.empty[waiting] = True
            self._pending = sum(
                int(np.count_nonzero((lv.state >= _QUEUED) & (lv.state <= _LOADING))) for lv in self._levels
            )
            self.residency_version += 1
            self._rebuild_queue()
            self._cv.notify_all()
        return requeued

    def take_reads(self) -> dict[tuple[int, Int3] | None, int] | None:
        """Bytes read from storage per brick ``(level, index)`` by this clip-texture's loads since the
        previous call (or since it was made), and forget them; None when the loader does not count.
        Past :data:`MAX_READ_KEYS` distinct bricks, further bricks' reads are summed under ``None``.

        Why per brick and taken, not a difference of the loader's total: loader threads keep
        filling the windows around the centre while and after a frame draws, so the bytes read
        between two instants depend on timing. Charged per brick and taken once, every read is
        counted exactly once: the caller splits them into the bricks its frame drew and the rest
        (the prefetch), and the same work reports the same bytes."""
        with self._cv:
            if self._reads_by_key is None:
                return None
            out, self._reads_by_key = self._reads_by_key, {}
            return out

    def wait_until_idle(self, timeout: float | None = None) -> bool:
        """Block until no brick is queued or loading; ``False`` if ``timeout`` seconds passed first."""
        with self._cv:
            return self._cv.wait_for(lambda: self._closing or self._idle(), timeout) and self._idle()

    def wait_for(self, keys: Iterable, timeout: float | None = None) -> bool:
        """Block until each ``(level, index)`` in ``keys`` is resident, failed or out of its window.

        The bricks waited for are loaded first (:meth:`prioritize`): a frame waits for what it
        draws, and the rest of the windows fills by distance behind them.
        """
        ks = [(k.level, k.index) if isinstance(k, BrickKey) else (int(k[0]), tuple(int(i) for i in k[1])) for k in keys]
        for L, idx in ks:
            self.pyramid.check_key(L, idx)
        self.prioritize(ks)

        def unsettled(L: int, idx: Int3) -> bool:
            lv = self._levels[L]
            s = self._slot_if_held(lv, idx)
            return s is not None and _QUEUED <= lv.state[s] <= _LOADING

        def settled() -> bool:
            return self._pending == 0 or not any(unsettled(L, idx) for L, idx in ks)

        with self._cv:
            if settled():
                return True
            # loader threads wake this waiter only when its count of unsettled bricks reaches 0
            # (set_center wakes everyone anyway); the predicate below is the authority
            countdown = _Countdown(sum(unsettled(L, idx) for L, idx in ks))
            for k in ks:
                self._watched.setdefault(k, []).append(countdown)
            try:
                return self._cv.wait_for(lambda: self._closing or settled(), timeout) and settled()
            finally:
                for k in ks:
                    waiters = self._watched[k]
                    waiters.remove(countdown)
                    if not waiters:
                        del self._watched[k]

    def prioritize(self, keys: Iterable | np.ndarray) -> int:
        """Move the queued bricks among ``keys`` to the front of the load queue, nearest first;
        returns how many were moved.

        ``keys``: an ``(m, 4)`` int64 array of ``(level, z, y, x)`` rows (a selection's
        :meth:`~clipvol.scene.selection.Selection.missing_wanted_keys`, checked per level in numpy),
        or ``(level, index)`` pairs / :class:`BrickKey` s. Keys outside their level's window or of no
        level are skipped.

        The queue orders a window's bricks by distance from the centre of interest, which is right for
        prefetching but makes a frame that needs a few bricks of a large window (a point octree's
        sparse deep levels, a thin cut) wait behind many it does not draw. The moved bricks' old
        entries stay in the queue and are skipped when popped (lazy invalidation); retries keep
        their back-off. A brick already moved and not yet taken by a loader thread is not pushed
        again (a per-slot mark, cleared when its entry is popped or the queue is re-sorted): a frame
        loop that asks for the same missing bricks every frame grows the queue by nothing. A brick
        of a window that the current region (:meth:`set_region`) left unqueued is queued now: a
        frame reads what it draws even where the region did not foresee it.
        """
        rows = _key_rows(keys)
        moved = 0
        with self._cv:
            entries: list[tuple] = []
            for L in np.unique(rows[:, 0]).tolist():
                if not 0 <= L < len(self._levels):
                    continue
                lv = self._levels[L]
                idx = rows[rows[:, 0] == L, 1:]
                idx = idx[np.all((idx >= np.asarray(lv.start)) & (idx < np.asarray(lv.stop)), axis=1)]
                if not len(idx):
                    continue
                s = slot_of(idx, lv.shape)
                held = np.all(lv.key[s] == idx, axis=1)
                s = np.unique(s[held])  # (a key given twice is one brick)
                on = s[lv.state[s] == _ABSENT]  # in the window, outside the region: read on demand
                if len(on):
                    lv.state[on] = _QUEUED
                    lv.attempts[on] = 0
                    lv.not_before[on] = 0.0
                    self._pending += len(on)
                s = s[(lv.state[s] == _QUEUED) & (lv.not_before[s] <= 0.0) & (lv.urgent[s] != lv.gen[s])]
                if not len(s):
                    continue
                k = lv.key[s]
                gen = lv.gen[s]
                lv.urgent[s] = gen
                cost = brick_costs(self.pyramid, L, k, self._interest_point(L)) - _URGENT
                entries += [(c, -L, z, y, x, L, sl, g) for c, (z, y, x), sl, g in
                            zip(cost.tolist(), k.tolist(), s.tolist(), gen.tolist())]
            if entries:
                self._queue.push_many(entries)
                moved = len(entries)
                self._cv.notify_all()
        return moved

    def close(self, timeout: float | None = 5.0) -> bool:
        """Stop the loader threads and join them for up to ``timeout`` seconds in all.

        Returns ``True`` when every thread has ended. A thread stuck inside ``read_brick`` cannot be
        interrupted: after the timeout ``close`` warns and returns ``False``; the thread is a daemon
        (it never keeps the interpreter alive) and discards its result when the loader returns.
        """
        with self._cv:
            self._closing = True
            self._queue.clear()
            for lv in self._levels:  # no plan any more: the loader may serve other readers
                self._tell_plan(lv.level, None)
            self._cv.notify_all()
        deadline = None if timeout is None else time.monotonic() + timeout
        for t in self._threads:
            if t is threading.current_thread():
                continue
            t.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
        alive = [t.name for t in self._threads if t.is_alive() and t is not threading.current_thread()]
        if alive:
            warnings.warn(
                f"ClipTexture.close: {len(alive)} loader thread(s) still inside read_brick after {timeout} s "
                f"({', '.join(alive)}); they are daemons and will drop their result",
                RuntimeWarning,
                stacklevel=2,
            )
            return False
        return True

    def __enter__(self) -> "ClipTexture":
        return self

    def __exit__(self, *exc) -> None:
        self.close(self.close_timeout)

    def __repr__(self) -> str:
        return (
            f"ClipTexture({type(self.loader).__name__}, budget={self.memory_budget}, W={self._window}, "
            f"whole_levels={self.whole_levels}, threads={len(self._threads)})"
        )

    # -- internals (call with the lock held unless noted) ---------------------------------------
    def _lv(self, level: int) -> _Level:
        if isinstance(level, bool) or not (0 <= int(level) < len(self._levels)):
            raise ParameterError(f"level: expected 0..{len(self._levels) - 1}, got {level!r}")
        return self._levels[int(level)]

    def _check_open(self) -> None:
        if self._closing:
            raise ParameterError("ClipTexture: expected an open clip-texture, got one that was closed")

    @staticmethod
    def _check_center(xyz) -> np.ndarray:
        try:
            c = np.asarray(xyz, dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            raise ParameterError(f"center: expected three numbers (x, y, z), got {xyz!r}") from None
        if not np.all(np.isfinite(c)):
            raise ParameterError(f"center: expected finite (x, y, z), got {tuple(c)}")
        return c

    @staticmethod
    def _slot_if_held(lv: _Level, idx) -> int | None:
        if not all(a <= i < b for i, a, b in zip(idx, lv.start, lv.stop)):
            return None
        s = int(slot_of(np.asarray(idx), lv.shape)[0])
        return s if tuple(lv.key[s]) == tuple(idx) else None

    def _idle(self) -> bool:
        return self._pending == 0

    def _is_teleport(self, move: np.ndarray) -> bool:
        """A move longer than half the finest window's extent resets the motion history."""
        pyr = self.pyramid
        ext = np.array(pyr.brick_shape[::-1], dtype=np.float64) * np.array(pyr.spacing[::-1]) * self._window
        return bool(np.any(np.abs(move) > ext / 2.0))

    def _interest_point(self, level: int) -> np.ndarray:
        """The centre moved by the predicted motion, at most half a window of ``level`` away."""
        c = self._history[-1]
        if not self.predictive:
            return c
        off = predicted_offset(list(self._history), LOOKAHEAD)
        pyr = self.pyramid
        ext = np.array(pyr.brick_shape[::-1], dtype=np.float64) * 2.0**level * np.array(pyr.spacing[::-1])
        n = float(np.linalg.norm(off / ext))
        limit = self._window / 2.0
        if n > limit:
            off = off * (limit / n)
        return c + off

    def _apply(self, center: np.ndarray, window: int) -> None:
        """Place every level's window for ``center`` and ``window``; evict, move, queue; re-sort."""
        evicted = 0
        region = self._region
        for lv in self._levels:
            want = None if region is None else region.bricks[lv.level]
            if lv.whole:
                shape = lv.grid
                start, stop = level_window(self.pyramid, lv.level, center, shape)
            elif want is not None and len(want):
                start, stop = region_window(
                    lv.grid, window_shape(lv.grid, window), len(lv.state), tuple(want.min(axis=0)),
                    tuple(want.max(axis=0) + 1), self.pyramid.world_to_brick(lv.level, center))
                shape = tuple(b - a for a, b in zip(start, stop))
            else:
                shape = window_shape(lv.grid, window)
                start, stop = level_window(self.pyramid, lv.level, center, shape)
            if (start, stop, shape) != (lv.start, lv.stop, lv.shape):
                evicted += self._relayout(lv, start, stop, shape)
            self._queue_wanted(lv, want)
        if evicted:
            self.residency_version += 1
        self._pending = sum(
            int(np.count_nonzero((lv.state >= _QUEUED) & (lv.state <= _LOADING))) for lv in self._levels
        )
        self._rebuild_queue()

    def _relayout(self, lv: _Level, start: Int3, stop: Int3, shape: Int3) -> int:
        """Give ``lv`` the window ``[start, stop)`` of ``shape``; returns how many resident bricks left."""
        if shape == lv.shape:
            # a move (the common case): each entering brick takes the slot of one that left
            bricks = window_bricks(start, stop)
            enter = bricks[~in_box(bricks, lv.start, lv.stop)]
            s = slot_of(enter, shape)
            evicted = int(np.count_nonzero(lv.state[s] == _RESIDENT))
            lv.gen[s] += 1  # late results for the bricks that left are dropped
            lv.key[s] = enter
            lv.state[s] = _QUEUED
            lv.attempts[s] = 0
            lv.not_before[s] = 0.0
            lv.empty[s] = self._empty_mask(lv.level, enter)
            lv.start, lv.stop = start, stop
            return evicted
        # a new window shape (or the first placement): slots are re-assigned; bricks kept move along
        bricks = window_bricks(start, stop)
        new_slot = slot_of(bricks, shape)
        held = in_box(bricks, lv.start, lv.stop) if lv.shape != (0, 0, 0) else np.zeros(len(bricks), bool)
        old_slot = np.zeros(len(bricks), dtype=np.int64)
        if held.any():
            old_slot[held] = slot_of(bricks[held], lv.shape)
            held[held] = np.all(lv.key[old_slot[held]] == bricks[held], axis=1)
        old_state = np.where(held, lv.state[old_slot], _ABSENT)
        was_resident = int(np.count_nonzero(lv.state == _RESIDENT))
        in_place = held & (old_slot == new_slot)
        moved = held & ~in_place & ((old_state == _RESIDENT) | (old_state == _FAILED))
        moved &= ~lv.busy[new_slot]  # never copy into a slot a late writer is still filling: reload instead
        # bricks that change slot (only when the window shape changes) carry their data along
        data = lv.pool[old_slot[moved & (old_state == _RESIDENT)]].copy() if moved.any() else None
        if data is not None and self.cell_edges is not None:
            cells = (lv.cell_lo[old_slot[moved & (old_state == _RESIDENT)]].copy(),
                     lv.cell_hi[old_slot[moved & (old_state == _RESIDENT)]].copy())
        keep_attempts = lv.attempts[old_slot].copy()
        keep_nb = lv.not_before[old_slot].copy()
        keep_empty = lv.empty[old_slot].copy()
        # every slot not kept in place gets a new generation: late results for it are dropped
        kept_slots = np.zeros(len(lv.state), dtype=bool)
        kept_slots[new_slot[in_place]] = True
        lv.gen[~kept_slots] += 1
        lv.key[~kept_slots] = -1
        lv.state[~kept_slots] = _ABSENT
        lv.attempts[~kept_slots] = 0
        lv.not_before[~kept_slots] = 0.0
        lv.empty[~kept_slots] = False
        enter = ~in_place
        lv.key[new_slot[enter]] = bricks[enter]
        lv.state[new_slot[enter]] = _QUEUED
        fresh = enter & ~moved
        lv.empty[new_slot[fresh]] = self._empty_mask(lv.level, bricks[fresh])
        if moved.any():
            ms = new_slot[moved]
            lv.state[ms] = old_state[moved]
            lv.attempts[ms] = keep_attempts[moved]
            lv.not_before[ms] = keep_nb[moved]
            lv.empty[ms] = keep_empty[moved]
            if data is not None and len(data):
                lv.pool[new_slot[moved & (old_state == _RESIDENT)]] = data
                if self.cell_edges is not None:
                    lv.cell_lo[new_slot[moved & (old_state == _RESIDENT)]] = cells[0]
                    lv.cell_hi[new_slot[moved & (old_state == _RESIDENT)]] = cells[1]
        lv.start, lv.stop, lv.shape = start, stop, shape
        still = int(np.count_nonzero(lv.state == _RESIDENT))
        return was_resident - still

    def _queue_wanted(self, lv: _Level, want: np.ndarray | None) -> None:
        """Queue the window's bricks that ``want`` lists (``None``: all of them); unqueue the rest.

        A brick of the window outside the region keeps its slot, key and generation with state
        ``ABSENT`` (never read unless :meth:`prioritize` asks for it); a resident, loading or failed
        one keeps its state (holding it costs nothing: the slot is allocated either way).
        """
        held = lv.key[:, 0] >= 0
        if want is None:
            wanted = held
        else:
            g = np.asarray(lv.grid, dtype=np.int64)
            code = (lv.key[:, 0] * g[1] + lv.key[:, 1]) * g[2] + lv.key[:, 2]
            wcode = (want[:, 0] * g[1] + want[:, 1]) * g[2] + want[:, 2]
            wanted = held & np.isin(code, wcode)
        on = wanted & (lv.state == _ABSENT)
        if on.any():
            lv.state[on] = _QUEUED
            lv.attempts[on] = 0
            lv.not_before[on] = 0.0
        lv.state[~wanted & (lv.state == _QUEUED)] = _ABSENT

    def _tell_plan(self, level: int, keys: np.ndarray | None) -> None:
        """Tell a loader that reads several bricks per request (:class:`HasReadPlan`) which bricks
        of ``level`` are queued, so it fetches those together and not their unqueued neighbours. A
        loader whose hint fails is not told again (a hint never fails a load)."""
        plan = self._plan_reads
        if plan is None:
            return
        try:
            plan(level, keys)
        except Exception:
            self._plan_reads = None

    def _rebuild_queue(self) -> None:
        """Rebuild the load queue (sorted by cost, coarse first at ties) and the retry queue."""
        now = time.monotonic()
        entries: list[tuple] = []
        delayed: list[tuple] = []
        for lv in self._levels:
            q = np.nonzero(lv.state == _QUEUED)[0]
            self._tell_plan(lv.level, lv.key[q])
            if not len(q):
                continue
            due = lv.not_before[q] <= now
            for s in q[~due]:
                delayed.append((float(lv.not_before[s]), lv.level, int(s), int(lv.gen[s])))
            q = q[due]
            keys = lv.key[q]
            cost = brick_costs(self.pyramid, lv.level, keys, self._interest_point(lv.level))
            L = lv.level
            for c, k, s, g in zip(cost.tolist(), keys.tolist(), q.tolist(), lv.gen[q].tolist()):
                entries.append((c, -L, k[0], k[1], k[2], L, s, g))
        self._queue.rebuild(entries, delayed)
        for lv in self._levels:  # the prioritised entries are gone with the old heap
            lv.urgent.fill(-1)
        self.queue_version += 1

    def _valid(self, level: int, slot: int, gen: int, state: int) -> bool:
        lv = self._levels[level]
        return lv.gen[slot] == gen and lv.state[slot] == state

    def _promote_due(self, now: float) -> float | None:
        """Move due retries into the load queue; return seconds until the next one (or None)."""
        def cost(L: int, s: int) -> tuple:
            k = self._levels[L].key[s]
            c = float(brick_costs(self.pyramid, L, k[None], self._interest_point(L))[0])
            return (c, -L, int(k[0]), int(k[1]), int(k[2]))

        self._queue.promote(now, cost, lambda L, s, gen: self._valid(L, s, gen, _QUEUED))
        return self._queue.next_retry_in(now)

    def _pop_job(self) -> tuple[tuple[int, int, int, Int3, bool] | None, float | None]:
        """Pop the front of the queue (lazy invalidation): ``(job, None)``, or ``(None, seconds)``
        until the next retry is due (``None``: nothing scheduled). A job is ``(level, slot,
        generation, index, empty)``; ``empty``: fill the slot, read nothing."""
        wait = self._promote_due(time.monotonic()) if self._queue.has_delayed() else None
        if not self._closing:
            while (entry := self._queue.pop()) is not None:
                _, _, bz, by, bx, L, s, gen = entry
                lv = self._levels[L]
                if lv.busy[s] and self._valid(L, s, gen, _QUEUED):
                    self._queue.park(L, s, entry)  # back in the queue when the writer is done
                    continue
                if lv.urgent[s] == gen:  # this brick's prioritised entry leaves the queue (or this is
                    lv.urgent[s] = -1    # its plain one, popped first: the prioritised one is then stale)
                if self._valid(L, s, gen, _QUEUED):
                    if lv.not_before[s] > 0.0 and lv.not_before[s] > time.monotonic():
                        continue  # a stale prioritised entry of a brick now waiting out its retry back-off
                    lv.state[s] = _LOADING
                    empty = bool(lv.empty[s])
                    if self._read_into is not None and not empty:
                        lv.busy[s] = True
                    return (L, s, gen, (bz, by, bx), empty), None
        return None, wait

    def _load(self, job: tuple[int, int, int, Int3, bool]) -> bool:
        """Load one brick: read outside the lock, validate, copy and publish under the lock.

        Returns ``False`` when the clip-texture is closing (the thread then ends).
        """
        L, s, gen, idx, empty = job
        into = self._read_into is not None and not empty
        counter = self.loader.read_counter if self._reads_by_key is not None else None
        read0 = counter.thread_bytes() if counter is not None else 0
        t0 = time.perf_counter()
        err: BaseException | None = None
        brick = None
        spread = None
        try:
            if empty:
                brick = self._fill_brick  # copied into the slot below; the loader is not called
            elif into:
                self._read_into(L, idx, self._levels[L].pool[s])  # straight into the slot
            else:
                brick = check_brick(self.loader, L, idx, self.loader.read_brick(L, idx))
            if self._levels[L].spread is not None and not empty:
                spread = self.loader.read_spread(L, idx)
        except Exception as e:  # a loader's failure never kills the thread
            err = e
        latency = time.perf_counter() - t0
        cells = None
        if err is None and self.cell_edges is not None:  # here, outside the lock (numpy releases the GIL)
            data = self._levels[L].pool[s] if into else brick
            cells = self._fill_cells if empty else cell_ranges(data, self.cell_edges)
        report = None
        nread = counter.thread_bytes() - read0 if counter is not None else 0
        with self._cv:
            if nread:  # charged whatever became of the load: the bytes were read
                rk = self._reads_by_key
                key = (L, idx) if len(rk) < MAX_READ_KEYS or (L, idx) in rk else None  # None: "other bricks"
                rk[key] = rk.get(key, 0) + nread
            if into:
                self._levels[L].busy[s] = False
                if self._queue.unpark(L, s):
                    self._cv.notify_all()
            if self._closing:
                return False
            if not self._valid(L, s, gen, _LOADING):
                self._dropped += 1  # the brick left its window meanwhile: a late result
                return True
            lv = self._levels[L]
            wake = True
            if err is None:
                if brick is not None:
                    lv.pool[s] = brick  # under the lock, after the generation check
                if lv.spread is not None:
                    lv.spread[s] = 0 if spread is None else spread  # an empty brick has no spread
                if cells is not None:
                    lv.cell_lo[s], lv.cell_hi[s] = cells
                lv.state[s] = _RESIDENT
                self._pending -= 1
                if self.failures:
                    self.failures.pop(BrickKey(L, idx), None)
                self.residency_version += 1
                if brick is self._fill_brick:
                    self._skipped_empty += 1
                else:
                    nb = self.pyramid.brick_nbytes
                    self._loads_total += 1
                    self._bytes_total += nb
                    now = time.perf_counter()
                    self._events.append((now, nb))
                    self._trim_events(now)
                    self._latency.append(latency)
                # only waiters care about a load that leaves work queued: spare the wake-ups
                wake = self._pending == 0 or self._count_down(L, idx)
            elif isinstance(err, (LoaderError, InputFormatError)) or lv.attempts[s] >= self.retries:
                # a broken contract or corrupt data (checksum, statistics) reads the same bytes again: no retry
                lv.state[s] = _FAILED
                self._pending -= 1
                self._count_down(L, idx)
                key = BrickKey(L, idx)
                self.failures[key] = err
                report = (key, err)
            else:
                lv.attempts[s] += 1
                self._retries += 1
                lv.state[s] = _QUEUED
                nb_t = self._queue.retry_at(int(lv.attempts[s]), time.monotonic())
                lv.not_before[s] = nb_t
                self._queue.delay(nb_t, L, s, gen)
            if wake:
                self._cv.notify_all()
        if report is not None and self.on_error is not None:
            try:
                self.on_error(*report)
            except Exception as e:  # the callback's bug must not kill the loader thread
                warnings.warn(f"ClipTexture on_error callback raised {type(e).__name__}: {e}", RuntimeWarning)
        return True

    def _empty_mask(self, level: int, keys: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: which bricks ``keys`` are filled instead of read: outside the cut
        (:meth:`set_outside`), or shown by the loader's bounds to hold only the fill value.

        One vectorised call when bricks enter a window (not one per load in the loader threads,
        where its small numpy steps held the GIL against the other threads' reads). Bounds that are
        unknown - or a bounds call that fails - leave the brick to be read: its load reports any
        real failure. After a failed call the level's bounds are not asked again (this runs under
        the lock, and a remote store's bounds may need the network).
        """
        n = len(keys)
        cut = np.zeros(n, dtype=bool)
        if self._outside is not None and n:
            cut = np.asarray(self._outside(level, np.asarray(keys, dtype=np.int64).reshape(-1, 3)), dtype=bool)
        return cut | self._bounds_empty(level, keys)

    def _bounds_empty(self, level: int, keys: np.ndarray) -> np.ndarray:
        n = len(keys)
        if self._ranges is None or n == 0 or level in self._ranges_failed:
            return np.zeros(n, dtype=bool)
        try:
            r = self._ranges(level, np.asarray(keys, dtype=np.int64).reshape(-1, 3))
            if r is None:
                return np.zeros(n, dtype=bool)
            r = np.asarray(r, dtype=np.float64).reshape(n, 2)
        except Exception:  # a loader's bounds are an optimisation: never a reason to fail a move
            self._ranges_failed.add(level)
            return np.zeros(n, dtype=bool)
        fill = self.pyramid.fill_value
        return (r[:, 0] == fill) & (r[:, 1] == fill)

    def _count_down(self, level: int, idx: Int3) -> bool:
        """A watched brick settled: count down its waiters; ``True`` if one of them is due."""
        due = False
        for countdown in self._watched.get((level, idx), ()):
            countdown.n -= 1
            due |= countdown.n <= 0
        return due

    def _trim_events(self, now: float) -> None:
        while self._events and now - self._events[0][0] > RATE_WINDOW_S:
            self._events.popleft()


def _loader_thread(ref: "weakref.ref[ClipTexture]") -> None:
    """Body of a loader thread: pop a job under the lock, load it, repeat; sleep when idle.

    It keeps a strong reference to the clip-texture only while popping and loading, and ends when
    the clip-texture closes or has been garbage collected.
    """
    while True:
        ct = ref()
        if ct is None:
            return
        with ct._cv:
            job, wait = ct._pop_job()
            if job is None:
                if ct._closing:
                    return
                cv = ct._cv
                del ct  # sleep without keeping the clip-texture alive
                cv.wait(IDLE_POLL_S if wait is None else min(wait, IDLE_POLL_S))
                continue
        if not ct._load(job):
            return
        del ct
