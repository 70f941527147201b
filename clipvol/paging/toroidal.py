"""Window math of the clip-texture: budgets, per-level windows, toroidal slots, load costs.

Pure numpy, no threads, no I/O, so the paging rules can be tested and reasoned about alone; the
threaded :class:`clipvol.paging.cliptexture.ClipTexture` only applies them.

Allocation rule (``allocate``)
------------------------------
``slots = memory_budget // brick_nbytes`` brick slots exist in all. Levels are considered from
the coarsest (a single brick) towards the finest; a level is **held whole** while all of its bricks
fit *and* enough slots remain for a window of ``W = 2`` bricks per axis at every finer level. The
first level that does not fit, and every finer one, is **windowed** with one common window size
``W`` (bricks per axis; an axis shorter than ``W`` is held whole): the largest ``W >= 2`` such that
``whole bricks + sum over windowed levels of prod(min(W, grid))`` slots fit. Because ``W`` is the
same at every windowed level and each level's bricks cover twice the extent of the finer level's,
the windows nest like a clipmap. If even ``W = 2`` does not fit, :class:`ParameterError` names
``memory_budget`` and the minimum budget needed. The slot pool therefore never exceeds the budget.

Window placement (``level_window``)
-----------------------------------
At level ``L`` the centre ``c`` (world ``(x, y, z)``) has the continuous brick coordinate
``p = (c / spacing + 0.5) / (brick_shape * 2**L)`` per axis (brick ``b`` covers ``[b, b+1)``, the
same as :meth:`Pyramid.world_to_brick`). A window of ``w = min(W, grid)`` bricks starts at
``floor(p - w / 2 + 0.5)``, clamped to ``[0, grid - w]``: for odd ``w`` it is centred on the brick
holding the centre, for even ``w`` it leans to the side the centre is nearer, and it always holds
the centre's brick.

Toroidal mapping (``slot_of``)
------------------------------
Brick ``b`` of a level lives in slot ``b mod w`` per axis, flattened row-major over ``w``: any
``w`` consecutive bricks per axis map to distinct slots, so when the window moves, each brick that
enters takes exactly the slot of a brick that left (the 4-D toroidal mapping of OpenGL Volumizer, Bhaniramka & Demange 2002), and the
bricks that stay never move.

Load cost (``brick_costs``)
---------------------------
``cost = || gap(p, node_box) / extent_L ||_2``: the Euclidean distance from the point of interest
to the brick's node box (0 inside it), measured per axis in units of that level's brick extent
(``brick_shape * 2**L * spacing``). A coarse brick is thus "as near" as the fine brick at the same
relative position, and the queue breaks ties coarse before fine. The point of interest is the
centre moved by the predicted motion (:func:`predicted_offset`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..bricking.pyramid import Int3, Pyramid
from ..errors import ParameterError
from ..units import format_bytes

__all__ = [
    "minimum_budget",
    "Allocation",
    "allocate",
    "window_shape",
    "level_window",
    "slot_of",
    "window_bricks",
    "in_box",
    "window_diff",
    "brick_costs",
    "predicted_offset",
    "region_window",
]


def _prod(shape: Sequence[int]) -> int:
    return int(math.prod(int(s) for s in shape))


def window_shape(grid: Int3, window: int) -> Int3:
    """Bricks per axis of a window of ``window`` bricks on a level whose grid is ``grid``."""
    return tuple(min(int(window), int(g)) for g in grid)  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class Allocation:
    """How a memory budget is split into brick slots (see the module docstring).

    Attributes
    ----------
    budget : int
        The memory budget in bytes.
    brick_nbytes : int
        Bytes of one brick slot.
    window : int
        The largest window ``W`` (bricks per axis) the budget allows at the windowed levels.
    whole_levels : tuple of int
        Levels held whole, coarsest first.
    capacity : tuple of int
        Slots reserved per level (index = level): the whole grid or ``prod(min(W, grid))``.
    """

    budget: int
    brick_nbytes: int
    window: int
    whole_levels: tuple[int, ...]
    capacity: tuple[int, ...]

    def __post_init__(self) -> None:
        if self.window < 2:
            raise ParameterError(f"Allocation.window: expected >= 2, got {self.window}")
        if sum(self.capacity) * self.brick_nbytes > self.budget:
            raise ParameterError(
                f"Allocation: {sum(self.capacity)} slots of {self.brick_nbytes} bytes exceed the budget {self.budget}"
            )

    @property
    def slots(self) -> int:
        """Slots allocated over all levels."""
        return sum(self.capacity)

    @property
    def nbytes(self) -> int:
        """Bytes of the whole slot pool (never more than ``budget``)."""
        return self.slots * self.brick_nbytes


def minimum_budget(pyramid) -> int:
    """The smallest memory budget (bytes) :func:`allocate` accepts: a window of 2 bricks per axis
    (fewer where a level's grid is smaller) at every level."""
    return sum(_prod(window_shape(pyramid.grid(L), 2)) for L in range(pyramid.num_levels)) * pyramid.brick_nbytes


def _smaller_brick_hint(pyramid, budget: int) -> str:
    """``"; a store bricked at 32 would fit (needs 16 MB)"``: the largest cubic brick edge (a power of
    two from 8 to 256, below the current one) whose pyramid's minimum budget fits ``budget``, or ""."""
    cur = min(pyramid.brick_shape)
    for b in (256, 128, 64, 32, 16, 8):
        if b >= cur:
            continue
        try:
            alt = Pyramid.build(pyramid.shape, (b, b, b), pyramid.spacing, pyramid.filter, pyramid.dtype,
                                pyramid.value_range, pyramid.fill_value)
        except (ParameterError, ValueError):
            continue
        need = minimum_budget(alt)
        if need <= budget:
            return (f"; a store bricked at {b} ({alt.num_levels} levels) would fit, needing {format_bytes(need)} "
                    f"(`clipvol brick --brick {b}`)")
    return "; no brick size from 8 up fits it either"


def allocate(pyramid: Pyramid, memory_budget: int) -> Allocation:
    """Split ``memory_budget`` bytes into whole levels and windowed levels (module docstring).

    Raises
    ------
    ParameterError
        If not even a window of 2 bricks per axis fits at every level; names ``memory_budget``
        and the minimum needed.
    """
    budget = int(memory_budget)
    nb = pyramid.brick_nbytes
    slots = budget // nb
    n = pyramid.num_levels
    grids = [pyramid.grid(L) for L in range(n)]
    need2 = [_prod(window_shape(g, 2)) for g in grids]
    minimum = minimum_budget(pyramid)
    if slots * nb < minimum:
        raise ParameterError(
            f"memory_budget: expected at least {minimum} bytes ({format_bytes(minimum)}: a window of 2 bricks "
            f"per axis at each of {n} levels of {nb}-byte bricks), got {budget} ({format_bytes(budget)})"
            + _smaller_brick_hint(pyramid, budget)
        )
    whole: list[int] = []
    used = 0
    for L in range(n - 1, -1, -1):
        full = _prod(grids[L])
        if used + full + sum(need2[:L]) <= slots:
            whole.append(L)
            used += full
        else:
            break
    windowed = range(0, n - len(whole))

    def need(w: int) -> int:
        return used + sum(_prod(window_shape(grids[L], w)) for L in windowed)

    w = 2
    if len(windowed):
        w_cap = max(max(grids[L]) for L in windowed)
        lo, hi = 2, max(2, w_cap)  # need() is monotone in w: largest w with need(w) <= slots
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if need(mid) <= slots:
                lo = mid
            else:
                hi = mid - 1
        w = lo
    capacity = tuple(
        _prod(grids[L]) if L in whole else _prod(window_shape(grids[L], w)) for L in range(n)
    )
    return Allocation(budget, nb, w, tuple(whole), capacity)


def level_window(pyramid: Pyramid, level: int, center_xyz, shape: Int3) -> tuple[Int3, Int3]:
    """``(start, stop)`` brick indices ``(z, y, x)`` of a window of ``shape`` bricks around ``center_xyz``."""
    grid = pyramid.grid(level)
    if any(not (1 <= int(w) <= g) for w, g in zip(shape, grid)):
        raise ParameterError(f"window shape: expected 1..{grid} per axis at level {level}, got {tuple(shape)}")
    f = 2.0**level
    start, stop = [], []
    # plain floats: this runs for every level on every move, where numpy's per-call cost dominates
    for c, sp, b, w, g in zip(reversed([float(v) for v in center_xyz]), pyramid.spacing, pyramid.brick_shape, shape, grid):
        p = (c / sp + 0.5) / (b * f)  # continuous brick coordinate; brick i covers [i, i + 1)
        s = math.floor(p - w / 2.0 + 0.5) if math.isfinite(p) else 0
        s = min(max(s, 0), g - w)
        start.append(int(s))
        stop.append(int(s + w))
    return tuple(start), tuple(stop)  # type: ignore[return-value]


def slot_of(indices: np.ndarray, shape: Int3) -> np.ndarray:
    """Toroidal slot of each brick: ``b mod shape`` per axis, flattened row-major. ``(n, 3) -> (n,)``."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    w = np.asarray(shape, dtype=np.int64)
    m = idx % w
    return (m[:, 0] * w[1] + m[:, 1]) * w[2] + m[:, 2]


def window_bricks(start: Int3, stop: Int3) -> np.ndarray:
    """All brick indices ``(n, 3)`` (``z, y, x``) of the box ``[start, stop)``, row-major order."""
    axes = [np.arange(a, b, dtype=np.int64) for a, b in zip(start, stop)]
    if any(len(a) == 0 for a in axes):
        return np.zeros((0, 3), dtype=np.int64)
    zz, yy, xx = np.meshgrid(*axes, indexing="ij")
    return np.stack([zz.ravel(), yy.ravel(), xx.ravel()], axis=1)


def in_box(indices: np.ndarray, start: Int3, stop: Int3) -> np.ndarray:
    """``(n,)`` bool: which bricks of ``indices`` ``(n, 3)`` lie in ``[start, stop)``."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    return np.all((idx >= np.asarray(start)) & (idx < np.asarray(stop)), axis=1)


def window_diff(old: tuple[Int3, Int3], new: tuple[Int3, Int3]) -> tuple[np.ndarray, np.ndarray]:
    """Bricks that ``(entered, left)`` when a window moves from box ``old`` to box ``new``."""
    nb = window_bricks(*new)
    ob = window_bricks(*old)
    return nb[~in_box(nb, *old)], ob[~in_box(ob, *new)]


def brick_costs(pyramid: Pyramid, level: int, indices: np.ndarray, point_xyz) -> np.ndarray:
    """Load cost of bricks ``indices`` ``(n, 3)`` of ``level`` for a point of interest (module docstring)."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    lo, hi = pyramid.node_box(level, idx)
    p = np.asarray(point_xyz, dtype=np.float64).reshape(1, 3)
    gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
    ext = np.array(pyramid.brick_shape[::-1], dtype=np.float64) * 2.0**level * np.array(pyramid.spacing[::-1])
    return np.sqrt(np.sum((gap / ext) ** 2, axis=1))


def predicted_offset(history: Sequence[np.ndarray], lookahead: float = 1.0) -> np.ndarray:
    """Predicted displacement ``(x, y, z)`` of the centre: ``lookahead`` times its mean move.

    ``history`` holds the recent centres, oldest first; the mean displacement per move over it is
    the velocity (in moves, not seconds, so the rule is deterministic). Fewer than two centres
    predict no motion.
    """
    if len(history) < 2:
        return np.zeros(3)
    h = np.asarray(history, dtype=np.float64)
    v = (h[-1] - h[0]) / (len(h) - 1)
    return lookahead * v


def region_window(grid: Int3, cube: Int3, capacity: int, lo: Int3, hi: Int3, center_brick: Int3) -> tuple[Int3, Int3]:
    """``(start, stop)`` of a window that holds the region box ``[lo, hi)`` in ``capacity`` slots.

    The window takes the cube's shape where the region fits inside it (a stable shape while the
    region moves: moves re-use slots instead of re-assigning them) and grows along the axes where the
    region is longer (a slab: wide in the plane, thin across it), paying for it on the axes where
    the cube has room to spare, then - if still too large - on the longest axes. A window smaller
    than the region is centred on ``center_brick`` inside the region; one larger holds it whole.
    """
    g = np.asarray(grid, dtype=np.int64)
    ext = np.maximum(np.asarray(hi, dtype=np.int64) - np.asarray(lo, dtype=np.int64), 1)
    shape = np.minimum(np.maximum(ext, np.asarray(cube, dtype=np.int64)), g)
    cap = max(int(capacity), 1)
    while int(np.prod(shape)) > cap:
        slack = shape - ext
        k = int(np.argmax(slack)) if slack.max() > 0 else int(np.argmax(shape))
        if shape[k] <= 1:
            break
        shape[k] -= 1
    lo_a, hi_a = np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)
    c = np.asarray(center_brick, dtype=np.int64)
    start = np.where(shape >= ext,
                     np.clip(lo_a - (shape - ext) // 2, np.maximum(hi_a - shape, 0), np.minimum(lo_a, g - shape)),
                     np.clip(c - shape // 2, lo_a, hi_a - shape))
    start = np.clip(start, 0, g - shape)
    return tuple(int(v) for v in start), tuple(int(v) for v in start + shape)  # type: ignore[return-value]
