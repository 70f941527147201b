"""What a selection produces: draw items in visibility order, the ideal cut, counts (pure data).

A selection policy's output is a cut of the brick octree plus per-node data, never GL: the render
actions (volume, slice, splat) turn it into draws, the frame loop into loads and uploads.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ...rows import rows_in

__all__ = ["DrawItem", "DrawItems", "BrickKeys", "Selection", "Residency"]


class Residency(Protocol):
    """What the selection asks of a clip-texture (or of a GPU-cache-aware wrapper around one)."""

    def in_window_mask(self, level: int, indices: np.ndarray) -> np.ndarray: ...

    def resident_mask(self, level: int, indices: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, slots=True)
class DrawItem:
    """One box to draw: sample brick ``(level, index)`` over the world box ``[lo, hi]`` (``(x, y, z)``).

    The box is the brick's node box, or a sub-box of it where finer bricks are not available (the
    brick is then an ancestor of the region's ideal brick).
    """

    level: int
    index: tuple[int, int, int]
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    #: bricks per axis this item covers from ``index`` (a power of two; > 1 only after
    #: :func:`~clipvol.scene.selection.merge.merge_items`), clipped to the level's grid
    span: int = 1


class _RowList(Sequence):
    """A list held as an ``(n, 4)`` int64 array ``rows`` (plus whatever a subclass keeps beside
    it), whose Python elements are made by :meth:`_make` only when one is asked for. Indexing,
    iterating and comparing behave as the plain list it stands for."""

    __slots__ = ("rows", "_list")

    def __init__(self, rows) -> None:
        self.rows = np.asarray(rows, dtype=np.int64).reshape(-1, 4)
        self._list: list | None = None

    def _make(self) -> list:
        raise NotImplementedError

    def _elements(self) -> list:
        if self._list is None:
            self._list = self._make()
        return self._list

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i):
        return self._elements()[i]

    def __iter__(self):
        return iter(self._elements())

    def __eq__(self, other) -> bool:
        if isinstance(other, (list, tuple, _RowList)):
            return list(self) == list(other)
        return NotImplemented

    def __repr__(self) -> str:
        return f"{type(self).__name__}({len(self)} rows)"


class DrawItems(_RowList):
    """A list of :class:`DrawItem` held as arrays, made into objects only when an element is asked for.

    Why: a full-resolution cut holds thousands of items, and the frame itself needs only their
    arrays - the merge, the neighbour set, the convergence test read ``rows``/``lo``/``hi`` - and
    then draws a handful of merged boxes. Building a ``DrawItem`` (and its three tuples) per brick
    cost 5-8 ms of a 4 096-brick frame, and their garbage collection as much again.
    """

    __slots__ = ("lo", "hi", "span")

    def __init__(self, rows, lo, hi, span=None) -> None:
        #: ``rows``: ``(n, 4)`` int64 ``(level, z, y, x)``; ``lo``/``hi``: ``(n, 3)`` float64 world
        #: ``(x, y, z)``; ``span``: ``(n,)`` int64 (all 1 unless merged)
        super().__init__(rows)
        self.lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
        self.hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        self.span = np.ones(len(self.rows), dtype=np.int64) if span is None else np.asarray(span, dtype=np.int64)

    @classmethod
    def from_items(cls, items) -> "DrawItems":
        """The arrays of a sequence of :class:`DrawItem` (itself if it is one already)."""
        if isinstance(items, DrawItems):
            return items
        items = list(items)
        out = cls([(it.level, *it.index) for it in items], [it.lo for it in items], [it.hi for it in items],
                  [it.span for it in items])
        out._list = items
        return out

    def _make(self) -> list[DrawItem]:
        return [DrawItem(r[0], (r[1], r[2], r[3]), (a[0], a[1], a[2]), (b[0], b[1], b[2]), s)
                for r, a, b, s in zip(self.rows.tolist(), self.lo.tolist(), self.hi.tolist(), self.span.tolist())]


class BrickKeys(_RowList):
    """A list of brick keys ``(level, (z, y, x))`` held as one ``(n, 4)`` int64 array, made into
    tuples only when an element is asked for (the frame itself reads the array: see
    :class:`DrawItems`)."""

    __slots__ = ()

    @classmethod
    def from_keys(cls, keys) -> "BrickKeys":
        """The array of a sequence of ``(level, (z, y, x))`` keys (itself if it is one already)."""
        if isinstance(keys, BrickKeys):
            return keys
        keys = list(keys)
        out = cls([(L, *idx) for L, idx in keys])
        out._list = keys
        return out

    def _make(self) -> list[tuple[int, tuple[int, int, int]]]:
        return [(r[0], (r[1], r[2], r[3])) for r in self.rows.tolist()]


@dataclass
class Selection:
    """The result of :func:`~clipvol.scene.selection.select`.

    Attributes
    ----------
    items : DrawItems
        What to draw, in exact back-to-front order for the camera: a list of :class:`DrawItem`
        held as arrays (a plain list given here is taken as one).
    wanted : BrickKeys
        The ideal cut ignoring residency (inside the window), coarse levels first, then nearest
        first: the load priority and the target of ``wait``; a list of ``(level, index)`` held as
        one array (a plain list given here is taken as one).
    counts : dict or Mapping
        (A kept cut's is a read-only :class:`~clipvol.scene.selection.kept_cut.KeptCounts`, its
        culled counts completed when first read.) ``visited``, ``culled_frustum``, ``culled_shape``, ``culled_transparent``,
        ``culled_policy`` (nodes a policy's own test left out), ``refined``, ``outside_window``
        (boxes drawn from the parent because the child is outside the window), ``fallback`` (items
        drawn from an ancestor because the ideal brick is not resident), ``missing`` (regions not
        drawn: nothing resident), ``texels`` (of the items' bricks), ``level`` (roaming / fixed:
        the level chosen, else -1).
    policy : str
        The policy that chose the cut.
    node_data : dict
        Per-node data a policy attaches to the cut, keyed by ``(level, index)`` (e.g. importance,
        blend ratios); empty for the built-in volume policies.
    frustum_culled : tuple of numpy.ndarray or None
        ``(lo, hi)``, ``(m, 3)`` world boxes the camera's frustum culled while the cut was made,
        kept where the policy's cut depends on the camera only through the frustum
        (``policy.camera_free()``); None otherwise. With them,
        :func:`~clipvol.scene.selection.coherence.cut_holds` tells whether the same cut is the
        cut of another camera.
    ordered : bool
        True: ``items`` in back-to-front order and ``wanted`` in load order for the camera that
        made the cut. False (a cut kept by a frame loop and updated,
        :class:`~clipvol.scene.selection.kept_cut.KeptCut`): both in depth-first order, every
        item a whole node drawn from its own brick; whoever draws the items one by one orders
        them (:func:`~clipvol.scene.selection.coherence.node_order`).
    """

    items: DrawItems
    wanted: BrickKeys
    counts: dict = field(default_factory=dict)
    policy: str = ""
    node_data: dict = field(default_factory=dict)
    frustum_culled: tuple | None = None
    ordered: bool = True

    def __post_init__(self) -> None:
        # one form whoever builds it: the frame's set tests read the arrays, callers the elements
        self.items = DrawItems.from_items(self.items)
        self.wanted = BrickKeys.from_keys(self.wanted)

    def item_keys(self) -> np.ndarray:
        """``(n, 4)`` int64 ``(level, z, y, x)`` of each item, in order: what the frame's set tests
        (convergence, neighbours, merge) work on, without a Python tuple per brick."""
        return self.items.rows

    def wanted_keys(self) -> np.ndarray:
        """``(m, 4)`` int64 ``(level, z, y, x)`` of :attr:`wanted`, in order."""
        return self.wanted.rows

    def is_converged(self) -> bool:
        """Every wanted brick is drawn at its own level."""
        return bool(rows_in(self.wanted_keys(), self.item_keys()).all())

    def missing_wanted_keys(self) -> np.ndarray:
        """``(m, 4)`` int64 ``(level, z, y, x)`` of the wanted bricks not drawn at their own level,
        in load-priority order: what a frame loop asks the clip-texture for, without a Python tuple
        per brick (:meth:`~clipvol.paging.cliptexture.ClipTexture.prioritize` takes the array)."""
        w = self.wanted_keys()
        return w[~rows_in(w, self.item_keys())]

    def missing_wanted(self) -> list[tuple[int, tuple[int, int, int]]]:
        """Wanted bricks not drawn at their own level, in load-priority order."""
        return [(L, (z, y, x)) for L, z, y, x in self.missing_wanted_keys().tolist()]

