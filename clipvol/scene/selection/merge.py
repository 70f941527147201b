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
            touched.update((n, (int(a), int(b), int(c))) for a, b, c in unique_rows(idx >> (n - int(L))).tolist())
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

    # a sibling set can merge only once all its drawn members are on the stack, so no merge is tried
    # while the next item is a whole-node sibling of the one just pushed (7 of 8 tries for a full
    # cut; each costs a set of children and a walk down the stack)
    parents = index >> 1
    same_next = np.zeros(len(items), dtype=bool)
    same_next[:-1] = full[:-1] & full[1:] & (levels[:-1] == levels[1:]) & np.all(parents[:-1] == parents[1:], axis=1)
    stack: list[tuple[DrawItem, tuple[int, tuple[int, int, int]] | None]] = []
    for it, f, wait in zip(items, full, same_next):
        stack.append((it, (it.level, tuple(it.index)) if f else None))
        if wait:
            continue
        while _merge_top(stack, pyramid, windows, undrawn if may_cover is not None else None):
            pass
    return [it for it, _ in stack]


def _merge_top(stack, pyramid, windows, may_cover) -> bool:
    top, node = stack[-1]
    if node is None:
        return False
    n, nidx = node
    if n + 1 >= pyramid.num_levels:
        return False
    L = top.level
    win = windows[L] if L < len(windows) else None
    if win is None:
        return False
    parent = tuple(i // 2 for i in nidx)
    kids = set(pyramid.children(n + 1, parent))
    present: set = set()
    for it, nd in reversed(stack):  # the contiguous run of drawn siblings at the top
        if nd is None or nd[0] != n or it.level != L or nd[1] not in kids or nd[1] in present:
            break
        present.add(nd[1])
    missing = kids - present
    if missing and (may_cover is None or not all(may_cover(L, n, m) for m in missing)):
        return False
    span = 2 ** (n + 1 - L)
    first = tuple(p * span for p in parent)
    grid = pyramid.grid(L)
    counts = [min(f + span, g) - f for f, g in zip(first, grid)]
    if any(cnt > w for cnt, w in zip(counts, win)):
        return False
    lo, hi = pyramid.node_box(n + 1, parent)
    merged = DrawItem(L, first, tuple(float(v) for v in lo), tuple(float(v) for v in hi), span)
    del stack[len(stack) - len(present):]
    stack.append((merged, (n + 1, parent)))
    return True
