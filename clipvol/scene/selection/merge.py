"""Fewer, larger proxy boxes: complete sibling sets of one level drawn as one box over their parent.

Where all existing children of an octree node are drawn from the same level, one box over the node
samples exactly the same data as the children's boxes (the level's texture is addressed toroidally
and seamless across bricks), so a renderer may draw it in one go: fewer proxy boxes, no per-box ray
set-up, and early ray termination across what were brick faces. Pure numpy; the renderer passes
what it knows of texture memory as ``windows`` and ``may_cover``.
"""

from __future__ import annotations

import numpy as np

from ...rows import unique_rows
from .cut import DrawItem

__all__ = ["merge_items"]


def merge_items(items: list[DrawItem], pyramid, windows, may_cover=None) -> list[DrawItem]:
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

    ``may_cover(level, node_level, node_index) -> bool``, optional: a sibling that was culled
    (frustum, transparency) and so is drawn by no item may still be covered by the merged box when
    this says so - the renderer answers True when the node's bricks of ``level`` are all in texture
    memory: the merged box then shows the real data there (outside the view, or transparent).
    A sibling that any item overlaps is never covered, so no region is drawn twice.
    """
    if not items:
        return []
    boxes_lo = np.array([it.lo for it in items], dtype=np.float64)
    boxes_hi = np.array([it.hi for it in items], dtype=np.float64)
    # which items are whole node boxes (not fallback octants), vectorised per level
    levels = np.array([it.level for it in items])
    index = np.array([it.index for it in items], dtype=np.int64)
    full = np.array([it.span == 1 for it in items])
    for L in np.unique(levels):
        sel = levels == L
        lo_n, hi_n = pyramid.node_box(int(L), index[sel])
        tol = 1e-9 * np.maximum(1.0, np.abs(hi_n - lo_n).max(axis=1, keepdims=True))
        same = np.all(np.abs(lo_n - boxes_lo[sel]) <= tol, axis=1) & np.all(np.abs(hi_n - boxes_hi[sel]) <= tol, axis=1)
        full[sel] &= same
    # nodes holding a drawn item (every ancestor of each whole-node item), and fallback boxes
    touched: set[tuple[int, tuple[int, int, int]]] = set()
    for L in np.unique(levels[full]):
        idx = index[full & (levels == L)]
        for n in range(int(L), pyramid.num_levels):
            touched.update((n, tuple(r)) for r in unique_rows(idx >> (n - int(L))).tolist())
    fb_lo, fb_hi = boxes_lo[~full], boxes_hi[~full]

    def undrawn(level: int, node_level: int, node_index) -> bool:
        if (node_level, tuple(node_index)) in touched:
            return False
        if len(fb_lo):
            lo, hi = pyramid.node_box(node_level, node_index)
            tol = 1e-9 * max(1.0, float(np.abs(hi - lo).max()))
            if np.all((fb_lo < hi - tol) & (fb_hi > lo + tol), axis=1).any():
                return False
        return bool(may_cover(level, node_level, node_index))

    # Level by level, bottom-up: at node level n, a run of consecutive whole items of one data level
    # under one parent is a sibling set (depth-first order keeps siblings consecutive); it merges into
    # one item over the parent where its missing siblings may be covered and the block fits the
    # level's GPU window. The merged item takes the run's place, so the order stays back to front,
    # and may merge again at level n + 1. Vectorised per level: a full-resolution cut of thousands of
    # bricks is a handful of numpy passes, not one stack walk per item.
    out = list(items)
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
        same = np.zeros(len(out), dtype=bool)  # entry i continues the run of entry i - 1
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
        for k in np.nonzero(ok & (present < kids))[0]:  # missing siblings: each must be coverable
            if may_cover is None:
                ok[k] = False
                continue
            members = {tuple(v) for v in node_idx[start[k]:start[k] + present[k]].tolist()}
            pk = tuple(int(v) for v in p_run[k])
            ok[k] = all(undrawn(int(L_run[k]), n, m) for m in pyramid.children(n + 1, pk) if m not in members)
        if not ok.any():
            n += 1
            continue
        lo, hi = pyramid.node_box(n + 1, p_run[ok])
        keep = np.ones(len(out), dtype=bool)
        for j, k in enumerate(np.nonzero(ok)[0]):
            s0 = int(start[k])
            out[s0] = DrawItem(int(L_run[k]), tuple(int(v) for v in first[k]), tuple(float(v) for v in lo[j]),
                               tuple(float(v) for v in hi[j]), int(span[k]))
            keep[s0 + 1:s0 + int(present[k])] = False
            node_lv[s0] = n + 1
            node_idx[s0] = p_run[k]
        out = [it for it, kp in zip(out, keep) if kp]
        data_lv, node_lv, node_idx = data_lv[keep], node_lv[keep], node_idx[keep]
        n += 1
    return out
