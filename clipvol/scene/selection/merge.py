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

__all__ = ["merge_items"]


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
        return DrawItems(np.zeros((0, 4), dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    arr = DrawItems.from_items(items)
    boxes_lo, boxes_hi = arr.lo, arr.hi
    levels, index = arr.rows[:, 0], arr.rows[:, 1:]
    # which items are whole node boxes (not fallback octants), vectorised per level
    full = arr.span == 1
    for L in np.unique(levels):
        sel = levels == L
        lo_n, hi_n = pyramid.node_box(int(L), index[sel])
        tol = 1e-9 * np.maximum(1.0, np.abs(hi_n - lo_n).max(axis=1, keepdims=True))
        same = np.all(np.abs(lo_n - boxes_lo[sel]) <= tol, axis=1) & np.all(np.abs(hi_n - boxes_hi[sel]) <= tol, axis=1)
        full[sel] &= same
    # nodes holding a drawn item (every ancestor of each whole-node item), and fallback boxes
    # (per node level, a set of flat int keys: no tuple per brick and ancestor, thousands a frame)
    grids = [np.asarray(pyramid.grid(n), dtype=np.int64) for n in range(pyramid.num_levels)]
    parts: dict[int, list[np.ndarray]] = {}
    for L in np.unique(levels[full]).tolist():
        idx = index[full & (levels == L)]
        for n in range(L, pyramid.num_levels):
            a = idx >> (n - L)
            g = grids[n]
            parts.setdefault(n, []).append((a[:, 0] * g[1] + a[:, 1]) * g[2] + a[:, 2])
    touched = {n: _flag_set(np.concatenate(v), int(np.prod(grids[n]))) for n, v in parts.items()}
    fb_lo, fb_hi = boxes_lo[~full], boxes_hi[~full]

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
    out_lo, out_hi, out_idx, out_span = boxes_lo.copy(), boxes_hi.copy(), index.copy(), arr.span.copy()
    data_lv = levels.copy()
    node_lv = np.where(full, levels, -1)  # -1: a fallback item, never merged
    node_idx = index.copy()
    top = pyramid.num_levels - 1
    n = int(node_lv[full].min()) if full.any() else top
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
        kids = np.prod(np.clip(grid_n - 2 * p_run, 0, 2), axis=1)
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
    return DrawItems(np.concatenate([data_lv[:, None], out_idx], axis=1), out_lo, out_hi, out_span)


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
