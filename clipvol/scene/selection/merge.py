"""Fewer, larger proxy boxes: complete sibling sets of one level drawn as one box over their parent.

Where all existing children of an octree node are drawn from the same level, one box over the node
samples exactly the same data as the children's boxes (the level's texture is addressed toroidally
and seamless across bricks), so a renderer may draw it in one go: fewer proxy boxes, no per-box ray
set-up, and early ray termination across what were brick faces. Pure numpy; the renderer passes
what it knows of texture memory as ``windows`` and ``may_cover``.
"""

from __future__ import annotations

import numpy as np

from .cut import DrawItem, DrawItems
from .order import depth_first

__all__ = ["merge_items", "KeptMerge", "CELL_LEVEL"]


def merge_items(items: list[DrawItem] | DrawItems, pyramid, windows, may_cover=None) -> DrawItems:
    """Replace each complete set of sibling items of one level by one item over their parent node.

    Where all existing children of an octree node are drawn from the same level, one box over the
    node samples exactly the same data as the children's boxes (the level's texture is addressed
    toroidally and seamless across bricks), so the renderer may draw it in one go: fewer proxy
    boxes, no per-box ray set-up, and early ray termination across what were brick faces. Applied
    bottom-up, a full-resolution frame collapses to a handful of boxes.

    The visibility order stays exact: siblings are consecutive in a depth-first back-to-front list,
    and their parent's convex box takes their place. A merge happens only if the node's extent in
    bricks fits the level's GPU window on every axis (``windows[level]``, ``(z, y, x)`` bricks, or
    ``None`` for no merging), so no two bricks of one item share a texture slot. Fallback items
    (an ancestor drawn over part of its box) are never merged.

    ``may_cover(level, node_level, nodes) -> (m,) bool``, optional: a sibling that was culled
    (frustum, transparency) and so is drawn by no item may still be covered by the merged box when
    this says so - the renderer answers True when the node's bricks of ``level`` are all in texture
    memory: the merged box then shows the real data there (outside the view, or transparent).
    ``nodes`` is ``(m, 3)`` int64 ``(z, y, x)`` of level ``node_level``: it is asked once per
    data level and node level for every culled sibling of the frame.
    A sibling that any item overlaps is never covered, so no region is drawn twice.

    Works on the items' arrays (:class:`DrawItems`, as :func:`select` gives them; a plain list is
    turned into one) and returns :class:`DrawItems` too: a consumer that reads arrays (the page
    table) never makes a ``DrawItem`` object (thousands of them cost a changed projected-size cut of
    the 512^3 head ~5 ms a frame); indexing or iterating makes them, as from a list.
    """
    if not len(items):
        return _empty()
    arr = DrawItems.from_items(items)
    full = _whole_nodes(arr, pyramid)
    out = _merge_levels(_Merging.of(arr, full), pyramid, windows, may_cover, arr.lo[~full], arr.hi[~full])
    return out.items()


def _empty() -> DrawItems:
    return DrawItems(np.zeros((0, 4), dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)))


def _whole_nodes(arr: DrawItems, pyramid) -> np.ndarray:
    """``(n,)`` bool: which items are whole node boxes (not fallback octants), vectorised per level."""
    levels, index = arr.rows[:, 0], arr.rows[:, 1:]
    full = arr.span == 1
    for L in np.unique(levels):
        sel = levels == L
        lo_n, hi_n = pyramid.node_box(int(L), index[sel])
        tol = 1e-9 * np.maximum(1.0, np.abs(hi_n - lo_n).max(axis=1, keepdims=True))
        same = np.all(np.abs(lo_n - arr.lo[sel]) <= tol, axis=1) & np.all(np.abs(hi_n - arr.hi[sel]) <= tol, axis=1)
        full[sel] &= same
    return full


class _Merging:
    """The merge's working list: per entry its data level, node (level, index; node level -1: a
    fallback item, never merged), first brick, span and box, in the list's order."""

    __slots__ = ("data_lv", "node_lv", "node_idx", "idx", "span", "lo", "hi")

    def __init__(self, data_lv, node_lv, node_idx, idx, span, lo, hi) -> None:
        self.data_lv, self.node_lv, self.node_idx, self.idx, self.span, self.lo, self.hi = \
            data_lv, node_lv, node_idx, idx, span, lo, hi

    @classmethod
    def of(cls, arr: DrawItems, full: np.ndarray) -> "_Merging":
        levels, index = arr.rows[:, 0], arr.rows[:, 1:]
        return cls(levels, np.where(full, levels, -1), index, index, arr.span, arr.lo, arr.hi)

    def take(self, keep) -> "_Merging":
        return _Merging(*(getattr(self, k)[keep] for k in self.__slots__))

    @staticmethod
    def join(parts: list) -> "_Merging":
        return _Merging(*(np.concatenate([getattr(p, k) for p in parts]) for k in _Merging.__slots__))

    def items(self) -> DrawItems:
        return DrawItems(np.concatenate([self.data_lv[:, None], self.idx], axis=1), self.lo, self.hi, self.span)


def _touched(pyramid, m: _Merging, first_level: int, stop: int | None = None) -> dict:
    """Per node level from ``first_level`` up to below ``stop`` (default: every level), the set
    (:func:`_flag_set`) of nodes that hold a drawn whole-node entry of ``m`` (its node and every
    ancestor: a flat int key per node, no tuple per brick and ancestor, thousands a frame). The
    merge asks it of the node levels it merges at only: a kept merge's lower passes, of a few
    changed cells, ask two levels, not every level's set of flags."""
    grids = [np.asarray(pyramid.grid(n), dtype=np.int64) for n in range(pyramid.num_levels)]
    parts: dict[int, list[np.ndarray]] = {}
    whole = m.node_lv >= 0
    for L in np.unique(m.data_lv[whole]).tolist():
        idx = m.idx[whole & (m.data_lv == L)]  # (a merged entry's first brick: its ancestors are the node's)
        for n in range(max(L, first_level), pyramid.num_levels if stop is None else stop):
            a = idx >> (n - L)
            g = grids[n]
            parts.setdefault(n, []).append((a[:, 0] * g[1] + a[:, 1]) * g[2] + a[:, 2])
    return {n: _flag_set(np.concatenate(v), int(np.prod(grids[n]))) for n, v in parts.items()}


def _merge_levels(m: _Merging, pyramid, windows, may_cover, fb_lo, fb_hi, first: int | None = None,
                  stop: int | None = None) -> _Merging:
    """The merge's passes over node levels ``first`` (default: the lowest whole entry's) up to
    ``stop`` (default: the top level; merged entries reach node level ``stop`` at most)."""
    top = pyramid.num_levels - 1 if stop is None else stop
    whole = m.node_lv >= 0
    n = (int(m.node_lv[whole].min()) if whole.any() else top) if first is None else first
    if n >= top:
        return m
    grids = [np.asarray(pyramid.grid(k), dtype=np.int64) for k in range(pyramid.num_levels)]
    touched = _touched(pyramid, m, n, top)

    def undrawn(level: int, node_level: int, nodes: np.ndarray) -> np.ndarray:
        """``(m,)`` bool: may each of ``nodes`` (level ``node_level``, no item of which is drawn
        from ``level``) be covered by a merged box? Not where an item lies in it."""
        g = grids[node_level]
        flat = (nodes[:, 0] * g[1] + nodes[:, 1]) * g[2] + nodes[:, 2]
        ok = ~_in_set(flat, touched.get(node_level))
        if len(fb_lo):  # a fallback octant overlapping the node (a loading frame), in chunks of ~4 M tests
            rows = np.nonzero(ok)[0]
            chunk = max(1, (1 << 22) // (3 * len(fb_lo)))
            for c in range(0, len(rows), chunk):
                r = rows[c:c + chunk]
                lo, hi = pyramid.node_box(node_level, nodes[r])
                tol = 1e-9 * np.maximum(1.0, np.abs(hi - lo).max(axis=1))[:, None, None]
                hit = np.all((fb_lo[None] < hi[:, None] - tol) & (fb_hi[None] > lo[:, None] + tol), axis=2)
                ok[r[hit.any(axis=1)]] = False
        if ok.any():
            ok[ok] = np.asarray(may_cover(level, node_level, nodes[ok]), dtype=bool)
        return ok

    # Level by level, bottom-up: at node level n, a run of consecutive whole items of one data level
    # under one parent is a sibling set (depth-first order keeps siblings consecutive); it merges into
    # one item over the parent where its missing siblings may be covered and the block fits the
    # level's GPU window. The merged item takes the run's place, so the order stays back to front,
    # and may merge again at level n + 1. Vectorised per level: a full-resolution cut of thousands of
    # bricks is a handful of numpy passes, not one stack walk per item.
    out_lo, out_hi, out_idx, out_span = m.lo.copy(), m.hi.copy(), m.idx.copy(), m.span.copy()
    data_lv, node_lv, node_idx = m.data_lv, m.node_lv.copy(), m.node_idx.copy()
    while n < top:
        cand = node_lv == n
        if not cand.any():
            n += 1
            continue
        parent = node_idx >> 1
        same = np.zeros(len(data_lv), dtype=bool)  # entry i continues the run of entry i - 1
        same[1:] = cand[1:] & cand[:-1] & (data_lv[1:] == data_lv[:-1]) & np.all(parent[1:] == parent[:-1], axis=1)
        start = np.nonzero(cand & ~same)[0]
        run = np.cumsum(cand & ~same) - 1  # run number of each candidate entry
        present = np.bincount(run[cand], minlength=len(start))
        grid_n = np.asarray(pyramid.grid(n), dtype=np.int64)
        p_run = parent[start]
        kids = np.prod(np.minimum(np.maximum(grid_n - 2 * p_run, 0), 2), axis=1)  # (np.clip costs more)
        L_run = data_lv[start]
        span = 2 ** (n + 1 - L_run)
        first = p_run * span[:, None]
        ok = np.zeros(len(start), dtype=bool)
        for L in np.unique(L_run):  # the merged block must fit the data level's GPU window
            win = windows[int(L)] if int(L) < len(windows) else None
            if win is None:
                continue
            r = L_run == L
            cnt = np.minimum(first[r] + span[r, None], np.asarray(pyramid.grid(int(L)), dtype=np.int64)) - first[r]
            ok[r] = np.all(cnt <= np.asarray(win, dtype=np.int64), axis=1)
        need = np.nonzero(ok & (present < kids))[0]  # missing siblings: each must be coverable
        if len(need) and may_cover is None:
            ok[need] = False
        elif len(need):
            ok[need] = _siblings_coverable(need, start, run, cand, node_idx, p_run, L_run, grid_n, n, undrawn)
        if not ok.any():
            n += 1
            continue
        ks = np.nonzero(ok)[0]
        s0 = start[ks]  # the merged item takes the place of its run's first entry
        out_lo[s0], out_hi[s0] = pyramid.node_box(n + 1, p_run[ks])
        out_idx[s0], out_span[s0] = first[ks], span[ks]
        node_lv[s0], node_idx[s0] = n + 1, p_run[ks]
        keep = np.ones(len(data_lv), dtype=bool)
        drop = np.zeros(len(data_lv) + 1, dtype=np.int64)  # the rest of each merged run goes
        np.add.at(drop, s0 + 1, 1)
        np.add.at(drop, s0 + present[ks], -1)
        keep &= np.cumsum(drop[:-1]) == 0
        data_lv, node_lv, node_idx = data_lv[keep], node_lv[keep], node_idx[keep]
        out_lo, out_hi, out_idx, out_span = out_lo[keep], out_hi[keep], out_idx[keep], out_span[keep]
        n += 1
    return _Merging(data_lv, node_lv, node_idx, out_idx, out_span, out_lo, out_hi)


#: most cells of a node level held as a flag per cell by :func:`_flag_set` (16 MB); above it, sorted keys
FLAG_SET_MAX_CELLS = 1 << 24


def _flag_set(keys: np.ndarray, cells: int) -> np.ndarray:
    """The set of flat cell ``keys`` of a level of ``cells`` cells: a bool flag per cell where the
    level is small enough (a scatter, O(n): sorting the keys of every ancestor of a 13 742-brick cut
    cost ~6 ms a frame), else the sorted unique keys. Asked with :func:`_in_set`."""
    if cells <= FLAG_SET_MAX_CELLS:
        flags = np.zeros(cells, dtype=bool)
        flags[keys] = True
        return flags
    return np.unique(keys)


def _in_set(keys: np.ndarray, held: np.ndarray | None) -> np.ndarray:
    """``(n,)`` bool: is each of ``keys`` in ``held`` (a :func:`_flag_set`; None: the empty set)?"""
    if held is None:
        return np.zeros(len(keys), dtype=bool)
    if held.dtype == bool:
        return held[keys]
    return np.isin(keys, held)


#: the eight child octants ``(z, y, x)`` of a node, in the order of their number ``4 z + 2 y + x``
OCTANTS = np.array([(z, y, x) for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=np.int64)


def _siblings_coverable(need, start, run, cand, node_idx, p_run, L_run, grid_n, n, undrawn) -> np.ndarray:
    """For the sibling runs ``need`` at node level ``n``: is every existing child of the run's
    parent that the run does not hold coverable (``undrawn``)? Asked for all runs at once: one
    question per culled sibling costs a 4 096-brick cut about 10 ms a frame."""
    held = np.zeros((len(start), 8), dtype=bool)  # (run, octant): the run holds that child
    members = np.nonzero(cand)[0]
    held[run[members], (node_idx[members] & 1) @ np.array([4, 2, 1])] = True
    kids = 2 * p_run[need][:, None, :] + OCTANTS[None]  # (k, 8, 3)
    missing = np.all(kids < grid_n, axis=2) & ~held[need]
    r, o = np.nonzero(missing)
    good = np.ones(len(need), dtype=bool)
    for L in np.unique(L_run[need[r]]).tolist():
        w = L_run[need[r]] == L
        ans = undrawn(int(L), n, kids[r[w], o[w]])
        good[np.unique(r[w][~ans])] = False
    return good


#: node level of :class:`KeptMerge`'s cells: a changed leaf re-merges the 4^3 level-0 bricks of its
#: level-2 node, and the merge above that level runs over the cells' merged entries
CELL_LEVEL = 2


class KeptMerge:
    """:func:`merge_items` of a cut kept between frames, merged again only where its leaves changed.

    A kept projected-size cut (:class:`~clipvol.scene.selection.kept_cut.KeptCut`) changes by a
    few leaves a frame; merging the whole cut again cost the 512^3 head's 13 742 bricks ~23 ms a
    frame. Below node level ``cell_level`` the merge never crosses a cell (a node of that level):
    a run of siblings lies in one parent, and whatever the merge asks about a missing sibling lies
    in that parent too. So the entries the lower passes leave in a cell depend on the cell's leaves
    alone: they are kept per cell, and a frame runs the lower passes over the cells whose leaves
    changed (and the leaves coarser than the cells) only, then the upper passes over all cells'
    entries - a cell's worth per merged block, not a brick's. The result is :func:`merge_items`'s
    for the same items, entry for entry (``tests/scene/test_kept_merge.py``).

    The items must be whole nodes in depth-first order (:func:`~clipvol.scene.selection.order.depth_first`,
    what a kept cut gives with ``ordered=False``); fallback items (a loading frame's) make every
    call a merge from nothing. ``may_cover`` may depend on the camera (the render action covers a
    culled node not in texture memory while it lies beside the view): a kept cell's entries hold
    only while it answers the cell's questions as before, so each call asks them again (one call
    over every question's kept box where ``may_cover`` tells its boxes, else one per level pair)
    and merges again the cells where an answer changed. New ``windows`` merge everything again; a
    caller whose ``may_cover`` changed otherwise (other textures) calls :meth:`reset`.

    What a changed frame costs besides the changed cells' merge is kept flat in the cut's size:
    the cut is compared with the last one only past the rows they share at the front and the back
    (:meth:`_diff`), the questions keep their boxes through a merge (only new questions' boxes are
    made), and where the cells merged again give the entries they had (every merging frame of the
    512^3 CT-like head's orbit: the answers that changed decide no merge) the kept entries stay the
    same object, so the upper passes' result is known to be theirs without a compare, and no sort
    of the entries is made (docs/benchmarks.md, "The rest of an orbit frame").
    """

    def __init__(self, pyramid, cell_level: int = CELL_LEVEL) -> None:
        self.pyramid = pyramid
        self.cell_level = max(0, min(int(cell_level), pyramid.num_levels - 1))
        g = np.asarray(pyramid.grid(self.cell_level), dtype=np.int64)
        self._cell_grid = g
        self._items: DrawItems | None = None
        self._items_cells: np.ndarray | None = None  # each of its rows' cell (:meth:`_cells`)
        self._kept: _Merging | None = None  # the lower passes' entries, in depth-first order
        self._kept_cell: np.ndarray | None = None  # each kept entry's cell (flat key; -1: coarser than a cell)
        self._windows = None
        #: the lower passes' questions to ``may_cover`` of the kept cells, and the upper passes' of
        #: the last call: ``(level, node_level, nodes, answers, cells, box)`` (cells None: upper;
        #: box: a one-element list holding the nodes' camera-free boxes ``(lo, hi)`` once made, or
        #: None: kept with the questions, so that a merge makes only its new questions' boxes)
        self._asked: list[tuple] = []
        #: the upper passes' input entries, their questions (as :attr:`_asked`'s) and their result:
        #: the same entries whose camera answers hold merge the same, and the same object is returned
        self._upper: tuple | None = None
        #: :meth:`answers_hold`'s camera-free boxes of :attr:`_asked`'s questions and their answers,
        #: joined once per list of questions: ``(asked, lo, hi, answers)``
        self._boxes: tuple | None = None
        self.remerged = 0  # items the lower passes ran over in the last call (benchmarks and tests)
        self.upper_kept = False  # the last call kept the upper passes' result (benchmarks and tests)

    @property
    def holding(self) -> bool:
        """Cells are kept from the last :meth:`merge` (the next merges only the changed ones)."""
        return self._kept is not None

    def reset(self) -> None:
        """Forget the kept cells: the next :meth:`merge` merges from nothing."""
        self._items = self._items_cells = self._kept = self._kept_cell = None
        self._asked = []
        self._upper = None
        self._boxes = None

    def _recording(self, may_cover, lower: bool):
        """``may_cover`` whose questions and answers are kept in :attr:`_asked` (with the cell of
        each node for the lower passes' questions, whose nodes lie below the cells' level)."""
        if may_cover is None:
            return None
        K, g = self.cell_level, self._cell_grid

        resident = getattr(may_cover, "resident", None) if _split(may_cover) else None

        def asked(level: int, node_level: int, nodes) -> np.ndarray:
            nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
            if resident is None:
                ans = np.asarray(may_cover(level, node_level, nodes), dtype=bool).reshape(len(nodes))
                ask = np.ones(len(nodes), dtype=bool)
            else:  # an answer from texture memory holds for every camera: only the others are kept
                ans = np.asarray(resident(level, node_level, nodes), dtype=bool).reshape(len(nodes))
                ask = ~ans
                if ask.any():
                    ans[ask] = np.asarray(may_cover.beside(level, node_level, nodes[ask]), dtype=bool).reshape(-1)
            cells = None
            if lower:
                a = nodes >> max(K - node_level, 0)
                cells = (a[:, 0] * g[1] + a[:, 1]) * g[2] + a[:, 2]
            self._asked.append((level, node_level, nodes[ask], ans[ask], None if cells is None else cells[ask],
                                [None]))
            return ans

        return asked

    def answers_hold(self, may_cover) -> bool:
        """Would ``may_cover`` answer every question of the last :meth:`merge` as it did (so the
        same items merge the same)? One call per question group; where ``may_cover`` tells the
        boxes its camera answers for (:func:`_boxed`), one call over every question's box.

        A still cut's orbit frame asks this and nothing else of the merge. Each group's call made
        its nodes' boxes again (``Pyramid.node_box``, the padding) before the camera's test: ~0.2-0.25 ms
        a group on the 512^3 CT-like head, whatever the group's size. The boxes do not depend on
        the camera, so they are made once per list of questions and kept; a frame is then one
        vectorised test over all of them and a compare."""
        if not any(len(q[2]) for q in self._asked):
            return True
        if _boxed(may_cover):  # one test over every question's kept box, one compare
            _, lo, hi, ans = self._joined_boxes(may_cover)
            return np.array_equal(np.asarray(may_cover.beside_boxes(lo, hi), dtype=bool).reshape(len(ans)), ans)
        now = self._answers_now(may_cover)
        return all(np.array_equal(a, q[3]) for a, q in zip(now, self._asked))

    def _joined_boxes(self, may_cover) -> tuple:
        """:attr:`_boxes` for the questions :attr:`_asked` holds (joined once per list of them),
        each group's boxes made where it has none yet (:meth:`_make_boxes`)."""
        held, asked = self._boxes, self._asked
        if held is None or held[0] is not asked:  # (a merge made a new list of questions)
            self._make_boxes(asked, may_cover)
            boxes = [q[5][0] for q in asked if len(q[2])]
            lo = np.concatenate([b[0] for b in boxes]) if boxes else np.zeros((0, 3))
            hi = np.concatenate([b[1] for b in boxes]) if boxes else np.zeros((0, 3))
            ans = np.concatenate([q[3] for q in asked]) if asked else np.zeros(0, dtype=bool)
            held = self._boxes = (asked, lo, hi, ans)
        return held

    @staticmethod
    def _make_boxes(asked: list, may_cover) -> None:
        """Make the camera-free boxes of the question groups of ``asked`` that have none (where
        ``may_cover`` tells them, :func:`_boxed`): a merge's new questions, a few."""
        if not _boxed(may_cover):
            return
        for q in asked:
            if q[5][0] is None and len(q[2]):
                q[5][0] = may_cover.boxes(q[0], q[1], q[2])

    def _answers_now(self, may_cover) -> list[np.ndarray]:
        """``may_cover``'s camera part's answers now to each question group of :attr:`_asked`, in
        its order (:meth:`answers_hold`): over the kept boxes in one call where ``may_cover`` tells
        its boxes (:func:`_boxed`; the boxes made once per list of questions), else group by group."""
        asked = self._asked
        if not _boxed(may_cover):
            ask = _camera_part(may_cover)
            return [np.asarray(ask(L, n, nodes), dtype=bool).reshape(len(nodes)) if len(nodes)
                    else np.zeros(0, dtype=bool) for L, n, nodes, *_ in asked]
        _, lo, hi, _ = self._joined_boxes(may_cover)
        flat = np.asarray(may_cover.beside_boxes(lo, hi), dtype=bool).reshape(len(lo)) if len(lo) \
            else np.zeros(0, dtype=bool)
        return np.split(flat, np.cumsum([len(q[2]) for q in asked])[:-1]) if asked else []

    def _cells(self, rows: np.ndarray) -> np.ndarray:
        """Flat key of each item's cell (-1 for an item at or above the cells' level)."""
        K, g = self.cell_level, self._cell_grid
        L = rows[:, 0]
        a = rows[:, 1:] >> np.maximum(K - L, 0)[:, None]
        return np.where(L < K, (a[:, 0] * g[1] + a[:, 1]) * g[2] + a[:, 2], -1)

    def _changed_cells(self, old: np.ndarray, new: np.ndarray) -> np.ndarray:
        """``(cells,)`` bool over the cells' level: a leaf of ``old`` or ``new`` (``(n, 4)`` rows)
        in the cell is not in the other (a flag scatter per level, no sort)."""
        pyr = self.pyramid
        dirty = np.zeros(int(np.prod(self._cell_grid)), dtype=bool)
        for a, b in ((old, new), (new, old)):
            for L in np.unique(a[:, 0]).tolist():
                if L >= self.cell_level:
                    continue
                g = np.asarray(pyr.grid(L), dtype=np.int64)
                ka, kb = a[a[:, 0] == L, 1:], b[b[:, 0] == L, 1:]
                held = _flag_set((kb[:, 0] * g[1] + kb[:, 1]) * g[2] + kb[:, 2], int(np.prod(g)))
                gone = ~_in_set((ka[:, 0] * g[1] + ka[:, 1]) * g[2] + ka[:, 2], held)
                if gone.any():
                    dirty[self._cells(a[a[:, 0] == L][gone])] = True
        return dirty

    def _diff(self, new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cells whose leaves differ between the last call's items and ``new`` (rows, both in
        depth-first order), and each of ``new``'s rows' cell (:meth:`_cells`).

        A changed cut keeps most of its rows where they were: past the rows the two have in common
        at the front and at the back, only the middles are compared (a row of one middle cannot be
        in the other's front or back: depth-first order is strict over a cut's nodes, which do not
        nest) and only the new middle's cells worked out; the common front's and back's cells are
        the last call's."""
        old, old_cells = self._items.rows, self._items_cells
        m = min(len(old), len(new))
        ne = np.any(old[:m] != new[:m], axis=1)
        front = int(np.argmax(ne)) if ne.any() else m
        k = m - front
        ne = np.any(old[len(old) - k:][::-1] != new[len(new) - k:][::-1], axis=1)
        back = int(np.argmax(ne)) if ne.any() else k
        a, b = old[front:len(old) - back], new[front:len(new) - back]
        dirty = self._changed_cells(a, b)
        cells = np.concatenate([old_cells[:front], self._cells(b), old_cells[len(old) - back:]])
        return dirty, cells

    def merge(self, items: DrawItems, windows, may_cover=None) -> DrawItems:
        """:func:`merge_items` of ``items`` (whole nodes, depth-first order) for ``windows`` and
        ``may_cover``, re-running the lower passes only in the cells whose leaves changed since
        the last call (:meth:`_diff`), asking the kept questions again over their kept boxes
        (:meth:`_answers_now`), and keeping the lower passes' entries (the same object, so the
        upper passes' result is known to be for them without a compare) where the changed cells
        merge to the entries they had: an orbit's usual changed frame."""
        arr = DrawItems.from_items(items)
        if not len(arr):
            self.reset()
            return _empty()
        pyr, K = self.pyramid, self.cell_level
        windows = tuple(None if w is None else tuple(int(v) for v in w) for w in windows)
        upper_now = None  # the camera's answers now to the upper passes' questions (None: ask them)
        if self._kept is None or self._windows != windows:
            cells = self._cells(arr.rows)
            redo = np.ones(len(arr), dtype=bool)
            keep = None
            self._asked = []
            self._upper = None  # (other windows: other upper merges)
        else:
            # (the same items object: no leaf changed, only answers can have)
            if arr is self._items:
                dirty, cells = np.zeros(int(np.prod(self._cell_grid)), dtype=bool), self._items_cells
            else:
                dirty, cells = self._diff(arr.rows)
            old = self._asked
            now = self._answers_now(may_cover) if may_cover is not None else None
            for q, a in zip(old, now if now is not None else [None] * len(old)):
                if q[4] is None or a is None:
                    continue
                r = ~dirty[q[4]]  # a kept cell whose answers changed: merged again
                if r.any():
                    dirty[q[4][r][a[r] != q[3][r]]] = True
            if now is not None:
                upper_now = [(q, a) for q, a in zip(old, now) if q[4] is None]
            self._asked = []
            for L, n, nodes, ans, where, box in old:  # the questions of the cells kept (with their boxes)
                if where is None:
                    continue
                k = ~dirty[where]
                if k.any():
                    b = box[0]
                    self._asked.append((L, n, nodes[k], ans[k], where[k], [None if b is None else (b[0][k], b[1][k])]))
            redo = (cells < 0) | dirty[np.maximum(cells, 0)]
            keep = (self._kept_cell >= 0) & ~dirty[np.maximum(self._kept_cell, 0)]
        self._boxes = None  # (the questions are made again below)
        self.remerged = int(redo.sum())
        part = DrawItems(arr.rows[redo], arr.lo[redo], arr.hi[redo], arr.span[redo])
        full = _whole_nodes(part, pyr)  # (a kept cell's leaves were checked when it was merged)
        if not full.all():  # a fallback item: merged from nothing, nothing kept
            self.reset()
            self.remerged = len(arr)
            return merge_items(arr, pyr, windows, may_cover)
        none = np.zeros((0, 3))
        merged = _merge_levels(_Merging.of(part, full), pyr, windows, self._recording(may_cover, True), none, none,
                               stop=K)
        merged_cells = None
        if keep is not None and _same_entries(self._kept.take(~keep), merged):
            merged, merged_cells = self._kept, self._kept_cell  # the cells merged again to what they had
        elif keep is not None and keep.any():  # the kept cells' entries and the new ones, in depth-first order
            merged = _Merging.join([self._kept.take(keep), merged])
            merged = merged.take(depth_first(merged.data_lv, merged.idx))
        self._make_boxes(self._asked, may_cover)  # (the new questions': the kept ones have theirs)
        self._asked = _grouped(self._asked)  # (one call per level pair when asked again)
        if merged_cells is None:  # each entry's cell: its first brick's (a lower pass never merges beyond a cell)
            merged_cells = self._cells(np.concatenate([merged.data_lv[:, None], merged.idx], axis=1))
        self._items, self._items_cells = arr, cells
        self._kept, self._kept_cell, self._windows = merged, merged_cells, windows
        # the upper passes: what they made of the same entries holds while the camera answers their
        # questions as before (a cell merged again to the entries it had: a flying camera's usual frame)
        up = self._upper
        if up is not None and _same_entries(up[0], merged) and (may_cover is None or self._upper_hold(
                up[1], may_cover, upper_now)):
            self.upper_kept = True
            self._asked = self._asked + up[1]  # (asked again by answers_hold with the lower ones)
            return up[2]
        self.upper_kept = False
        lower, self._asked = self._asked, []
        out = _merge_levels(merged, pyr, windows, self._recording(may_cover, False), none, none, first=K).items()
        self._make_boxes(self._asked, may_cover)
        self._upper = (merged, _grouped(self._asked), out)
        self._asked = lower + self._upper[1]
        return out

    @staticmethod
    def _upper_hold(asked: list, may_cover, now: list | None) -> bool:
        """Does the camera answer the upper passes' questions ``asked`` as before? ``now``: its
        ``(question, answer)`` pairs already asked (:meth:`_answers_now`), used where they are
        ``asked``'s questions, else they are asked here."""
        if now is not None and len(now) == len(asked) and all(q is g for (q, _), g in zip(now, asked)):
            return all(np.array_equal(a, q[3]) for q, a in now)
        ask = _camera_part(may_cover)
        return all(np.array_equal(np.asarray(ask(L, n, nodes), dtype=bool).reshape(len(nodes)), ans)
                   for L, n, nodes, ans, *_ in asked if len(nodes))


def _same_entries(a: _Merging, b: _Merging) -> bool:
    """Are two working lists the same entries in the same order (levels, nodes, bricks, boxes)?"""
    return a is b or (len(a.data_lv) == len(b.data_lv)
                      and all(np.array_equal(getattr(a, k), getattr(b, k)) for k in _Merging.__slots__))


def _grouped(asked: list) -> list:
    """:attr:`KeptMerge._asked` with the questions of one ``(level, node_level)`` in one entry."""
    groups: dict = {}
    for q in asked:
        groups.setdefault((q[0], q[1]), []).append(q)
    def joined(qs: list) -> tuple:
        L, n = qs[0][:2]
        cells = None if qs[0][4] is None else np.concatenate([q[4] for q in qs])
        boxes = [q[5][0] for q in qs if len(q[2])]
        box = None if any(b is None for b in boxes) else \
            (np.concatenate([b[0] for b in boxes]), np.concatenate([b[1] for b in boxes])) if boxes else None
        return (L, n, np.concatenate([q[2] for q in qs]), np.concatenate([q[3] for q in qs]), cells, [box])

    return [qs[0] if len(qs) == 1 else joined(qs) for qs in groups.values()]


def _split(may_cover) -> bool:
    """Does ``may_cover`` tell its two parts apart: ``resident`` (an answer that holds for every
    camera while the textures are the same) and ``beside`` (the camera's answer for the others)?"""
    return callable(getattr(may_cover, "resident", None)) and callable(getattr(may_cover, "beside", None))


def _boxed(may_cover) -> bool:
    """Is ``may_cover`` split (:func:`_split`) and its camera's part ``beside`` the answer of
    ``beside_boxes(lo, hi)`` (``(n,)`` bool, the camera's) for the camera-free boxes ``boxes(level,
    node_level, nodes) -> (lo, hi)``, as attributes (the render action's)?"""
    return _split(may_cover) and callable(getattr(may_cover, "boxes", None)) \
        and callable(getattr(may_cover, "beside_boxes", None))


def _camera_part(may_cover):
    """What to ask again of a kept question: the camera's part where ``may_cover`` is split (only
    questions its texture memory did not answer were kept), else ``may_cover`` itself."""
    return may_cover.beside if _split(may_cover) else may_cover
