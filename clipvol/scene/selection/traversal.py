"""Which bricks a frame draws, at which level, and in which order: one traversal, many policies.

After ``vzClipRenderAction`` (Bhaniramka & Demange 2002, section 4.2) and LaMar, Hamann & Joy (1999,
sections 3-4). :func:`select` runs five stages over the brick octree (:class:`Octree`); only the
*refine decision* of stage 1 belongs to the selection policy (:mod:`.policies`), everything else is
shared by every policy:

1. **Cut.** From the root, cull nodes outside the camera frustum, wholly outside the
   :class:`~clipvol.scene.geometry.Shape`, or rejected by the policy's own ``keep`` test (a
   cutting plane keeps only the nodes it crosses). The policy decides which nodes to refine:
   level by level (:meth:`Traversal.descend`) with a vectorised ``refine`` predicate, or greedily
   (:meth:`Traversal.greedy`) from a priority queue under a texel budget. Children are only
   entered inside the clip-texture's window (``in_window_mask``); a child outside it is covered by
   its parent's data. Leaves that the transfer function makes fully transparent are dropped; a
   transparent node that must be refined is still refined (a coarse brick's range does not bound
   its children's: a mean can hide a thin bright feature). The leaves are the ideal cut,
   :attr:`Selection.wanted`.
2. **Residency.** Each leaf is drawn with its own brick if resident, else with its nearest resident
   ancestor's brick over the leaf's box; if no ancestor is resident, the region is not drawn.
3. **Merge.** Sibling boxes all drawn from the same ancestor brick become one box.
4. **Order.** Exact back-to-front order (:mod:`.order`).
5. **Report.** Counts of what was culled, refined, drawn from an ancestor or missing.
"""

from __future__ import annotations

import heapq
from typing import Callable

import numpy as np

from ...errors import ParameterError
from ...rows import unique_rows
from ..camera import Camera
from ..params import RenderParams
from .cut import BrickKeys, DrawItems, Residency, Selection
from .octree import Octree
from .order import depth_first, load_order, order_nodes
from .policies import policy_for

__all__ = ["Traversal", "select"]

_EMPTY3 = np.zeros((0, 3))


class Traversal:
    """The state of one :func:`select` call, and the primitives a policy's ``cut`` is made of.

    Attributes a policy may read: ``tree`` (:class:`Octree`), ``camera``, ``params``
    (:class:`~clipvol.scene.params.RenderParams`), ``counts``.
    """

    def __init__(self, tree: Octree, camera: Camera, params: RenderParams, policy, residency, transparent) -> None:
        self.tree, self.camera, self.params, self.policy = tree, camera, params, policy
        self.residency, self.shape, self.transparent = residency, params.shape, transparent
        self.counts = dict(visited=0, culled_frustum=0, culled_shape=0, culled_transparent=0, culled_policy=0,
                           refined=0, outside_window=0, fallback=0, missing=0, texels=0, level=-1)
        # records: data node (level, idx) drawn over region node (level, idx)
        self.rec: list[tuple[int, np.ndarray, int, np.ndarray]] = []
        self._keep = getattr(policy, "keep", None)
        # boxes (lo, hi) the frustum culled, kept only when a policy asks (set it to a list): a cut
        # replayed for a turned camera is valid only while none of them enters the new frustum
        self.frustum_culled: list[tuple[np.ndarray, np.ndarray]] | None = None

    # -- the shared tests ----------------------------------------------------------------------
    def _in_frustum(self, lo: np.ndarray, hi: np.ndarray, level: int | None = None) -> np.ndarray:
        keep = self.camera.boxes_in_frustum(lo, hi)
        if self.frustum_culled is not None and not keep.all():
            out = np.nonzero(~keep)[0]
            empty = getattr(self.policy, "subtree_empty", None)
            if empty is not None and level is not None and level <= self.tree.top:
                # a node that draws nothing at any level (itself and every descendant transparent)
                # cannot leave a hole when it comes into view, so it does not forbid a replay
                out = out[~np.asarray(empty(self, level, lo[out], hi[out]), dtype=bool)]
            if len(out):
                self.frustum_culled.append((lo[out], hi[out]))
        return keep

    def _keep_mask(self, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        keep = self._in_frustum(lo, hi)
        if self.shape is not None and not self.shape.is_everything:
            keep &= ~self.shape.boxes_outside(lo, hi)
        if self._keep is not None:
            keep &= np.asarray(self._keep(self, level, lo, hi), dtype=bool)
        return keep

    def cull(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Drop nodes outside the frustum, the shape or the policy's ``keep``; returns kept ``(idx, lo, hi)``."""
        lo, hi = self.tree.boxes(level, idx)
        self.counts["visited"] += len(idx)
        keep = self._in_frustum(lo, hi, level)
        self.counts["culled_frustum"] += int((~keep).sum())
        if self.shape is not None and not self.shape.is_everything:
            out = self.shape.boxes_outside(lo, hi) & keep
            self.counts["culled_shape"] += int(out.sum())
            keep &= ~out
        if self._keep is not None and keep.any():
            out = ~np.asarray(self._keep(self, level, lo, hi), dtype=bool) & keep
            self.counts["culled_policy"] += int(out.sum())
            keep &= ~out
        return idx[keep], lo[keep], hi[keep]

    def opaque(self, level: int, idx: np.ndarray) -> np.ndarray:
        """Mask of nodes not fully transparent under the transfer function (counts the others)."""
        if self.transparent is None or len(idx) == 0 or level > self.tree.top:
            return np.ones(len(idx), dtype=bool)
        t = np.asarray(self.transparent(level, idx), dtype=bool).reshape(len(idx))
        self.counts["culled_transparent"] += int(t.sum())
        return ~t

    def in_window(self, level: int, idx: np.ndarray) -> np.ndarray:
        if self.residency is None or len(idx) == 0 or level > self.tree.top:
            return np.ones(len(idx), dtype=bool)
        return np.asarray(self.residency.in_window_mask(level, idx), dtype=bool).reshape(len(idx))

    def resident(self, level: int, idx: np.ndarray) -> np.ndarray:
        if self.residency is None or len(idx) == 0:
            return np.ones(len(idx), dtype=bool)
        return np.asarray(self.residency.resident_mask(level, idx), dtype=bool).reshape(len(idx))

    def projected_voxel(self, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Pixels one voxel of ``level`` covers at each box's nearest depth."""
        return self.camera.projected_size(lo, hi, self.tree.voxel(level))

    def _refine(self, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The policy's refine mask of real nodes (level 0 is never refined)."""
        if level == 0:
            return np.zeros(len(lo), dtype=bool)
        return np.asarray(self.policy.refine(self, level, lo, hi), dtype=bool).reshape(len(lo))

    # -- building the cut ----------------------------------------------------------------------
    def leaves(self, level: int, idx: np.ndarray) -> None:
        """Record nodes ``idx`` of ``level`` as leaves of the cut (transparent ones are dropped)."""
        idx = idx[self.opaque(level, idx)]
        if len(idx):
            self.rec.append((level, idx, level, idx))

    def leaves_of(self, nodes) -> None:
        """Record ``(level, index)`` nodes, in any order, as leaves of the cut (per level at once)."""
        by_level: dict[int, list] = {}
        for lv, b in nodes:
            by_level.setdefault(lv, []).append(b)
        for lv, rows in by_level.items():
            self.leaves(lv, np.array(rows, dtype=np.int64))

    def refine_one(self, level: int, index, fits):
        """Expand node ``index`` of ``level`` and cull its children, if ``fits(children, n_out)``
        says the cut may grow by them (``n_out``: its children outside the window, recorded as drawn
        from it); else undo the records and counts this made and return None. The budgeted greedy
        refinements (texel budget here, block budget in the image policy) grow the cut this way,
        one node at a time. Returns ``(children, lo, hi, n_out)``."""
        rec0, counts0 = len(self.rec), dict(self.counts)
        c = self.expand(level, np.array([index], dtype=np.int64))
        c, clo, chi = self.cull(level - 1, c) if len(c) else (c, _EMPTY3, _EMPTY3)
        n_out = sum(len(r[1]) for r in self.rec[rec0:])
        if not fits(len(c), n_out):
            del self.rec[rec0:]
            self.counts.clear()
            self.counts.update(counts0)
            return None
        self.counts["refined"] += 1
        return c, clo, chi, n_out

    def expand(self, level: int, idx: np.ndarray) -> np.ndarray:
        """Children of ``idx`` in the clip-texture's window; children outside the window (but in
        the frustum and shape) become records drawn from their parent."""
        c, parent = self.tree.children(level, idx)
        if level > self.tree.top:  # virtual parents have no data to fall back on
            return c
        win = self.in_window(level - 1, c)
        if not win.all():
            cout, pout = c[~win], parent[~win]
            lo, hi = self.tree.boxes(level - 1, cout)
            keep = self._keep_mask(level - 1, lo, hi)
            rows, pr = cout[keep], pout[keep]
            if len(rows):
                upr, inv = np.unique(pr, return_inverse=True)
                ok = self.opaque(level, idx[upr])[inv.reshape(-1)]
                self.counts["outside_window"] += int(ok.sum())
                if ok.any():
                    self.rec.append((level, idx[pr][ok], level - 1, rows[ok]))
        return c[win]

    def root_level(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """Descend the virtual levels above the top; returns the culled top-level ``(level, idx, lo, hi)``."""
        tree = self.tree
        level, idx = tree.root, np.zeros((1, 3), dtype=np.int64)
        while level > tree.top and len(idx):
            idx, _, _ = self.cull(level, idx)
            idx = self.expand(level, idx)
            level -= 1
        idx, lo, hi = self.cull(level, idx)
        return level, idx, lo, hi

    def descend(self) -> None:
        """Level-by-level traversal: refine where the policy's ``refine`` says so, else make a leaf."""
        level, idx, lo, hi = self.root_level()
        while len(idx):
            refine = self._refine(level, lo, hi)
            self.counts["refined"] += int(refine.sum())
            self.leaves(level, idx[~refine])
            if not refine.any() or level == 0:
                break
            idx = self.expand(level, idx[refine])
            level -= 1
            idx, lo, hi = self.cull(level, idx)

    def greedy(self, budget: int, cost: Callable[[int, int], int] | None = None) -> None:
        """Refine the node of highest priority first while the budget holds.

        Priority is the policy's ``priority(t, level, lo, hi)`` (default: projected voxel size);
        only nodes its ``refine`` accepts are candidates. ``cost(n_nodes, texels_per_brick)``
        prices a cut (default: its texels); refining stops at the first refinement that would
        exceed ``budget``. The cut stays a valid octree cut at every step.
        """
        tree = self.tree
        cost = cost or (lambda n, texels: n * texels)
        prio = getattr(self.policy, "priority", None)
        level, idx, lo, hi = self.root_level()
        nodes: dict[tuple, bool] = {}
        heap: list = []
        counter = 0

        def push(lv: int, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
            nonlocal counter
            ref = self._refine(lv, lo, hi)
            size = prio(self, lv, lo, hi) if prio is not None else self.projected_voxel(lv, lo, hi)
            for r, s, f in zip(rows, np.asarray(size, dtype=np.float64), ref):
                key = (lv, tuple(int(v) for v in r))
                nodes[key] = True
                if f:
                    heapq.heappush(heap, (-float(min(s, 1e300)), counter, key))
                    counter += 1

        push(level, idx, lo, hi)
        drawn_from_parent = 0  # records of children outside the window, drawn from their parent
        while heap:
            _, _, key = heap[0]
            lv, b = key
            got = self.refine_one(lv, b, lambda n_c, n_out: cost(len(nodes) - 1 + n_c + drawn_from_parent + n_out,
                                                                    tree.texels) <= budget)
            if got is None:
                break
            heapq.heappop(heap)
            c, clo, chi, n_out = got
            drawn_from_parent += n_out
            del nodes[key]
            push(lv - 1, c, clo, chi)
        self.leaves_of(nodes)


# ----------------------------------------------------------------------------------------------
def _resolve(t: Traversal, data_lv, data_idx):
    """Replace non-resident data bricks by their nearest resident ancestor (-1: none)."""
    src_lv, src_idx = data_lv.copy(), data_idx.copy()
    done = np.zeros(len(src_lv), dtype=bool)
    for lv in range(int(src_lv.min()) if len(src_lv) else 0, t.tree.top + 1):
        rows = np.nonzero(~done & (src_lv == lv))[0]
        if not len(rows):
            continue
        # ask once per distinct brick (a wrapper may reserve GPU slots on each positive answer)
        uniq, inv = unique_rows(src_idx[rows], return_inverse=True)
        res = t.resident(lv, uniq)[inv.reshape(-1)]
        done[rows[res]] = True
        up = rows[~res]
        src_lv[up] += 1
        src_idx[up] //= 2
    src_lv[~done] = -1
    return src_lv, src_idx


def _merge_fallback(tree: Octree, src_lv, src_idx, reg_lv, reg_idx):
    """Merge complete sibling groups drawn from one ancestor into their parent's box."""
    if not len(src_lv):
        return src_lv, src_idx, reg_lv, reg_idx
    for lv in range(int(reg_lv.min()), tree.top):
        sel = np.nonzero((reg_lv == lv) & (src_lv > lv))[0]
        if len(sel) < 2:
            continue
        parent = reg_idx[sel] // 2
        key = np.concatenate([parent, src_lv[sel, None], src_idx[sel]], axis=1)
        uniq, inv, cnt = unique_rows(key, return_inverse=True, return_counts=True)
        inv = inv.reshape(-1)
        full = cnt == tree.n_children(lv + 1, uniq[:, :3])
        if not full.any():
            continue
        drop = sel[full[inv]]
        keep = np.ones(len(src_lv), dtype=bool)
        keep[drop] = False
        new = uniq[full]
        src_lv = np.concatenate([src_lv[keep], new[:, 3]])
        src_idx = np.concatenate([src_idx[keep], new[:, 4:]])
        reg_lv = np.concatenate([reg_lv[keep], np.full(len(new), lv + 1)])
        reg_idx = np.concatenate([reg_idx[keep], new[:, :3]])
    return src_lv, src_idx, reg_lv, reg_idx


def select(pyramid, camera: Camera, params: RenderParams | None = None, *, residency: Residency | None = None,
           transparent: Callable[[int, np.ndarray], np.ndarray] | None = None, policy=None,
           ordered: bool = True) -> Selection:
    """Choose the bricks to draw for ``camera`` and their back-to-front order.

    Parameters
    ----------
    pyramid : Pyramid
        The data's pyramid (``loader.pyramid``).
    camera : Camera
        The view.
    params : RenderParams, optional
        Policy and its parameters, texel budget, shape (defaults: projected size, 1 px).
    residency : object, optional
        Has ``in_window_mask(level, idx)`` and ``resident_mask(level, idx)`` (``idx`` ``(n, 3)``
        ``(bz, by, bx)``), e.g. a ``ClipTexture``; None treats every brick as resident.
    transparent : callable, optional
        ``transparent(level, idx) -> (n,) bool``, True for bricks the transfer function makes
        fully transparent; they are neither requested nor drawn.
    policy : object, optional
        A policy instance to use instead of the one ``params.policy`` names (for policies that
        carry state between frames, such as a visibility estimate).
    ordered : bool
        False: where every item is a whole node drawn from its own brick, leave the items in
        depth-first order (:func:`~clipvol.scene.selection.order.depth_first`) instead of
        computing the visibility order - a single pass walks a page table and needs none, and a
        path that draws box by box orders the few merged boxes instead
        (:func:`~clipvol.scene.selection.coherence.node_order`). The selection's ``ordered``
        says which order it holds.

    Returns
    -------
    Selection
        Items in back-to-front order, the ideal cut (``wanted``) and counts.
    """
    if params is None:
        params = RenderParams()
    if not isinstance(params, RenderParams):
        raise ParameterError(f"params: expected a RenderParams, got {type(params).__name__}")
    params.check_for(pyramid)
    tree = Octree(pyramid)
    policy = policy if policy is not None else policy_for(params)
    t = Traversal(tree, camera, params, policy, residency, transparent)
    free = bool(getattr(policy, "camera_free", lambda: False)())
    if free:  # keep what the frustum culled: the cut may then be drawn again for a turned camera
        t.frustum_culled = []
    policy.cut(t)
    culled = None
    if free:
        boxes = t.frustum_culled
        culled = (np.concatenate([b[0] for b in boxes]) if boxes else _EMPTY3,
                  np.concatenate([b[1] for b in boxes]) if boxes else _EMPTY3)

    if t.rec:
        data_lv = np.concatenate([np.full(len(r[1]), r[0], dtype=np.int64) for r in t.rec])
        data_idx = np.concatenate([r[1] for r in t.rec]).astype(np.int64)
        reg_lv = np.concatenate([np.full(len(r[3]), r[2], dtype=np.int64) for r in t.rec])
        reg_idx = np.concatenate([r[3] for r in t.rec]).astype(np.int64)
    else:
        data_lv = reg_lv = np.zeros(0, dtype=np.int64)
        data_idx = reg_idx = np.zeros((0, 3), dtype=np.int64)

    # the ideal cut: unique data bricks, coarse first, then nearest first
    if len(data_lv):
        u = unique_rows(np.concatenate([data_lv[:, None], data_idx], axis=1))
        wo = load_order(tree, camera, u[:, 0], u[:, 1:])
        wanted = BrickKeys(u[wo])  # tuples only if someone reads them: the frame reads the array
    else:
        wanted = BrickKeys(np.zeros((0, 4), dtype=np.int64))

    src_lv, src_idx = _resolve(t, data_lv, data_idx)
    drawn = src_lv >= 0
    t.counts["missing"] = int((~drawn).sum())
    fallback = drawn & ((src_lv != data_lv) | np.any(src_idx != data_idx, axis=1))
    t.counts["fallback"] = int(fallback.sum())
    src_lv, src_idx, reg_lv, reg_idx = _merge_fallback(tree, src_lv[drawn], src_idx[drawn], reg_lv[drawn],
                                                       reg_idx[drawn])
    # a cut of whole nodes (no ancestor drawn over part of its box) may skip the visibility order
    whole = not (t.counts["fallback"] or t.counts["missing"] or t.counts["outside_window"])
    ordered = ordered or not whole
    order = order_nodes(tree, camera, reg_lv, reg_idx) if ordered else depth_first(reg_lv, reg_idx)
    box_lo = np.empty((len(reg_lv), 3))
    box_hi = np.empty((len(reg_lv), 3))
    for L in np.unique(reg_lv):  # one vectorised call per level
        rows = reg_lv == L
        box_lo[rows], box_hi[rows] = tree.boxes(int(L), reg_idx[rows])
    items = DrawItems(np.concatenate([src_lv[order, None], src_idx[order]], axis=1), box_lo[order], box_hi[order])
    t.counts["texels"] = len(items) * tree.texels
    node_data = getattr(policy, "node_data", None)
    return Selection(items, wanted, t.counts, params.policy, dict(node_data) if node_data else {}, culled,
                     ordered=ordered)
