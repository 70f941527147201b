"""Which bricks a frame draws, at which level, and in which order (pure numpy, no GL).

After ``vzClipRenderAction`` (seed 001 §4.2) and LaMar, Hamann & Joy (seed 003 §3-4). The bricks of
a pyramid with one brick shape form an octree (brick ``(L+1, b)`` covers ``(L, 2b + {0,1}^3)``);
if the top level has more than one brick, virtual levels above it complete the tree (they are
only ever traversed, never drawn). A selection runs in four stages:

1. **Cut.** Traverse from the root, level by level (all nodes of a level in one numpy pass), culling
   nodes outside the camera frustum or wholly outside the :class:`~clipvol.scene.geometry.Shape`.
   A node is refined while one voxel of its level (the level's largest scale component) projects
   to more than ``lod_threshold`` pixels at the box's nearest depth (``Camera.projected_size``),
   and only into children inside the clip-texture's window (``in_window_mask``); a child outside
   the window is covered by its parent's data over the child's box. Leaves that the transfer
   function makes fully transparent are dropped (never requested, never drawn); a transparent
   node that must be refined is still refined, because a coarse brick's range does not bound
   its children's (a mean can hide a thin bright feature). The leaves' bricks are the ideal cut,
   :attr:`Selection.wanted`. Modes ``fixed`` (refine down to ``params.level``) and ``roaming``
   (one level for the whole frame, see :func:`select`) change the refinement rule; a
   ``max_texels_drawn`` budget switches to greedy refinement of the largest projected voxels first
   with a priority queue (seed 004), stopping when the next refinement would break the budget.
2. **Residency.** Each leaf is drawn with its own brick if resident, else with its nearest resident
   ancestor's brick over the leaf's box; if no ancestor is resident, the region is not drawn.
3. **Merge.** Sibling boxes all drawn from the same ancestor brick become one box (fewer draws).
4. **Order.** Exact back-to-front order (:func:`back_to_front`): the draw order of a depth-first
   traversal whose per-node child order comes from the eye (perspective: on each axis the child
   half on the far side of the node's split plane first; orthographic: by the sign of the view
   direction). Because every line crosses each split plane once, from the eye's side to the far
   side, octants are drawn in decreasing number of "far" axes, which never draws a box before one
   that occludes it. Sorting by centre distance is *not* a visibility order for mixed sizes.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from .camera import Camera
from ..errors import ParameterError
from .geometry import Shape
from ..bricking.pyramid import Pyramid

__all__ = ["MODES", "SelectionParams", "DrawItem", "Selection", "Residency", "select", "back_to_front"]

MODES = ("multiresolution", "roaming", "fixed")
#: roaming mode stops descending when a level's visible bricks exceed this count
ROAMING_MAX_BRICKS = 1 << 20

_OFFSETS = np.array([[dz, dy, dx] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], dtype=np.int64)
# octant rank by its "far" bits (x, y, z in bits 2, 1, 0): more far axes first, ties by code
_FAR_ORDER = sorted(range(8), key=lambda c: (-bin(c).count("1"), -c))
_RANK = np.empty(8, dtype=np.int64)
_RANK[_FAR_ORDER] = np.arange(8)


class Residency(Protocol):
    """What the selection asks of a clip-texture (or of a GPU-cache-aware wrapper around one)."""

    def in_window_mask(self, level: int, indices: np.ndarray) -> np.ndarray: ...

    def resident_mask(self, level: int, indices: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, slots=True)
class SelectionParams:
    """How to choose the cut.

    Parameters
    ----------
    mode : str
        ``"multiresolution"`` (per-region level from projected size), ``"roaming"`` (one level for
        the whole frame) or ``"fixed"`` (``level`` everywhere, ancestors as fallback).
    lod_threshold : float
        Refine while a voxel of the brick's level projects to more than this many pixels (> 0).
    level : int or None
        The level drawn in ``fixed`` mode.
    max_texels_drawn : int or None
        Upper bound on the texels of the drawn bricks (each drawn box counts a whole brick);
        the cut is coarsened until it holds (the top level is always allowed).
    """

    mode: str = "multiresolution"
    lod_threshold: float = 1.0
    level: int | None = None
    max_texels_drawn: int | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ParameterError(f"mode: expected one of {', '.join(MODES)}, got {self.mode!r}")
        try:
            thr = float(self.lod_threshold)
        except (TypeError, ValueError):
            raise ParameterError(f"lod_threshold: expected a number > 0, got {self.lod_threshold!r}") from None
        if not thr > 0:
            raise ParameterError(f"lod_threshold: expected a number > 0 (pixels), got {self.lod_threshold!r}")
        object.__setattr__(self, "lod_threshold", thr)
        if self.mode == "fixed" and self.level is None:
            raise ParameterError("level: expected a level for mode 'fixed', got None")
        if self.level is not None:
            if int(self.level) != self.level or self.level < 0:
                raise ParameterError(f"level: expected an integer >= 0, got {self.level!r}")
            object.__setattr__(self, "level", int(self.level))
        if self.max_texels_drawn is not None:
            if int(self.max_texels_drawn) != self.max_texels_drawn or self.max_texels_drawn < 1:
                raise ParameterError(f"max_texels_drawn: expected an integer >= 1 or None, got {self.max_texels_drawn!r}")
            object.__setattr__(self, "max_texels_drawn", int(self.max_texels_drawn))


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
    #: :func:`merge_items`), clipped to the level's grid
    span: int = 1


@dataclass
class Selection:
    """The result of :func:`select`.

    Attributes
    ----------
    items : list of DrawItem
        What to draw, in exact back-to-front order for the camera.
    wanted : list of (level, index)
        The ideal cut ignoring residency (inside the window), coarse levels first, then nearest
        first: the load priority and the target of ``wait``.
    counts : dict
        ``visited``, ``culled_frustum``, ``culled_shape``, ``culled_transparent``, ``refined``,
        ``outside_window`` (boxes drawn from the parent because the child is outside the window),
        ``fallback`` (items drawn from an ancestor because the ideal brick is not resident),
        ``missing`` (regions not drawn: nothing resident), ``texels`` (of the items' bricks),
        ``level`` (roaming / fixed: the level chosen, else -1).
    """

    items: list[DrawItem]
    wanted: list[tuple[int, tuple[int, int, int]]]
    counts: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------
class _Tree:
    """The octree of a pyramid, with virtual levels above its top until one node holds everything."""

    def __init__(self, pyramid: Pyramid) -> None:
        self.pyr = pyramid
        self.top = pyramid.num_levels - 1
        grids = [pyramid.grid(lv) for lv in range(pyramid.num_levels)]
        while grids[-1] != (1, 1, 1):
            grids.append(tuple((g + 1) // 2 for g in grids[-1]))
        self.grids = [np.array(g, dtype=np.int64) for g in grids]
        self.root = len(grids) - 1
        self.sp = np.array(pyramid.spacing[::-1], dtype=np.float64)  # (x, y, z)
        self.brick = np.array(pyramid.brick_shape[::-1], dtype=np.float64)
        self.texels = int(np.prod(pyramid.brick_shape))

    def boxes(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.pyr.node_box(level, idx.reshape(-1, 3))
        return np.atleast_2d(lo), np.atleast_2d(hi)

    def split(self, level: int, idx: np.ndarray) -> np.ndarray:
        """World ``(x, y, z)`` of the planes that split nodes ``idx`` of ``level`` into children."""
        ext = self.brick * 2.0**level
        return ((idx[:, ::-1] * 2 + 1) * ext * 0.5 - 0.5) * self.sp

    def children(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Existing children of nodes ``idx`` at ``level``: ``(child indices (m, 3), parent row (m,))``."""
        c = (2 * idx[:, None, :] + _OFFSETS[None]).reshape(-1, 3)
        parent = np.repeat(np.arange(len(idx)), 8)
        ok = np.all(c < self.grids[level - 1], axis=1)
        return c[ok], parent[ok]

    def n_children(self, level: int, idx: np.ndarray) -> np.ndarray:
        g = self.grids[level - 1]
        return np.prod(np.clip(g - 2 * idx, 0, 2), axis=1)

    def voxel(self, level: int) -> float:
        return max(self.pyr.levels[level].scale)


class _Ctx:
    """Per-call state shared by the stages."""

    def __init__(self, tree, camera, params, residency, shape, transparent) -> None:
        self.tree, self.cam, self.params = tree, camera, params
        self.residency, self.shape, self.transparent = residency, shape, transparent
        self.counts = dict(visited=0, culled_frustum=0, culled_shape=0, culled_transparent=0, refined=0,
                           outside_window=0, fallback=0, missing=0, texels=0, level=-1)
        # records: data node (level, idx) drawn over region node (level, idx)
        self.rec: list[tuple[int, np.ndarray, int, np.ndarray]] = []

    def cull(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Drop nodes outside the frustum or the shape; returns the kept ``(idx, lo, hi)``."""
        lo, hi = self.tree.boxes(level, idx)
        self.counts["visited"] += len(idx)
        keep = self.cam.boxes_in_frustum(lo, hi)
        self.counts["culled_frustum"] += int((~keep).sum())
        if self.shape is not None and not self.shape.is_everything:
            out = self.shape.boxes_outside(lo, hi) & keep
            self.counts["culled_shape"] += int(out.sum())
            keep &= ~out
        return idx[keep], lo[keep], hi[keep]

    def opaque(self, level: int, idx: np.ndarray) -> np.ndarray:
        """Mask of nodes not fully transparent (counts the others)."""
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

    def refinable(self, level: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(refine mask, projected voxel size)`` of real nodes under the mode's rule."""
        size = self.cam.projected_size(lo, hi, self.tree.voxel(level))
        if level == 0:
            return np.zeros(len(lo), dtype=bool), size
        if self.params.mode == "fixed":
            return np.full(len(lo), level > self.params.level), size
        return size > self.params.lod_threshold, size

    def leaves(self, level: int, idx: np.ndarray) -> None:
        idx = idx[self.opaque(level, idx)]
        if len(idx):
            self.rec.append((level, idx, level, idx))

    def expand(self, level: int, idx: np.ndarray) -> np.ndarray:
        """Children of ``idx`` that are inside the frustum and shape and in the window; children
        outside the window become records drawn from their parent."""
        c, parent = self.tree.children(level, idx)
        if level > self.tree.top:  # virtual parents have no data to fall back on
            return c
        win = self.in_window(level - 1, c)
        if not win.all():
            cout, pout = c[~win], parent[~win]
            cout, lo, hi = self._cull_rows(level - 1, cout, pout)
            if len(cout[0]):
                rows, pr = cout
                upr, inv = np.unique(pr, return_inverse=True)
                keep = self.opaque(level, idx[upr])[inv.reshape(-1)]
                self.counts["outside_window"] += int(keep.sum())
                if keep.any():
                    self.rec.append((level, idx[pr][keep], level - 1, rows[keep]))
        return c[win]

    def _cull_rows(self, level, c, parent):
        lo, hi = self.tree.boxes(level, c)
        keep = self.cam.boxes_in_frustum(lo, hi)
        if self.shape is not None and not self.shape.is_everything:
            keep &= ~self.shape.boxes_outside(lo, hi)
        return (c[keep], parent[keep]), lo[keep], hi[keep]


def _cut_traverse(ctx: _Ctx) -> None:
    """Level-by-level traversal (multiresolution and fixed modes without a texel budget)."""
    tree = ctx.tree
    level, idx = tree.root, np.zeros((1, 3), dtype=np.int64)
    while len(idx):
        idx, lo, hi = ctx.cull(level, idx)
        if not len(idx):
            break
        if level > tree.top:
            refine = np.ones(len(idx), dtype=bool)
        else:
            refine, _ = ctx.refinable(level, lo, hi)
            ctx.counts["refined"] += int(refine.sum())
            ctx.leaves(level, idx[~refine])
        idx = ctx.expand(level, idx[refine]) if refine.any() else idx[:0]
        level -= 1


def _cut_greedy(ctx: _Ctx, budget: int) -> None:
    """Refine the node with the largest projected voxel first while the texel budget holds."""
    tree = ctx.tree
    level, idx = tree.root, np.zeros((1, 3), dtype=np.int64)
    while level > tree.top and len(idx):
        idx, _, _ = ctx.cull(level, idx)
        idx = ctx.expand(level, idx)
        level -= 1
    idx, lo, hi = ctx.cull(level, idx)
    nodes: dict[tuple, tuple] = {}  # (level, index) of current leaves -> True
    heap: list = []
    counter = 0

    def push(lv: int, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        nonlocal counter
        ref, size = ctx.refinable(lv, lo, hi)
        for r, s, f in zip(rows, size, ref):
            key = (lv, tuple(int(v) for v in r))
            nodes[key] = True
            if f:
                heapq.heappush(heap, (-float(min(s, 1e300)), counter, key))
                counter += 1

    push(level, idx, lo, hi)
    cost = len(nodes) * tree.texels
    while heap:
        _, _, key = heap[0]
        lv, b = key
        one = np.array([b], dtype=np.int64)
        rec0, counts0 = len(ctx.rec), dict(ctx.counts)
        c = ctx.expand(lv, one)
        c, clo, chi = ctx.cull(lv - 1, c) if len(c) else (c, np.zeros((0, 3)), np.zeros((0, 3)))
        n_out = sum(len(r[1]) for r in ctx.rec[rec0:])
        delta = (len(c) + n_out - 1) * tree.texels
        if cost + delta > budget:
            del ctx.rec[rec0:]  # undo the out-of-window records and counts of this refusal
            ctx.counts.clear()
            ctx.counts.update(counts0)
            break
        heapq.heappop(heap)
        cost += delta
        ctx.counts["refined"] += 1
        del nodes[key]
        push(lv - 1, c, clo, chi)
    by_level: dict[int, list] = {}
    for lv, b in nodes:
        by_level.setdefault(lv, []).append(b)
    for lv, rows in by_level.items():
        ctx.leaves(lv, np.array(rows, dtype=np.int64))


def _cut_roaming(ctx: _Ctx) -> None:
    """One level for the frame: the finest whose visible bricks all lie in the window, within the
    texel budget, and no finer than needed (every visible voxel already <= ``lod_threshold`` px)."""
    tree, params = ctx.tree, ctx.params
    level, idx = tree.root, np.zeros((1, 3), dtype=np.int64)
    while level > tree.top and len(idx):
        idx, _, _ = ctx.cull(level, idx)
        idx = tree.children(level, idx)[0]
        level -= 1
    idx, lo, hi = ctx.cull(level, idx)
    chosen = (level, idx)
    while len(idx):
        opaque = ctx.opaque(level, idx)
        vis = idx[opaque]
        ok = bool(ctx.in_window(level, vis).all())
        if params.max_texels_drawn is not None and len(vis) * tree.texels > params.max_texels_drawn:
            ok = False
        if not ok and level != tree.top:
            break
        chosen = (level, idx)
        size = ctx.cam.projected_size(lo, hi, tree.voxel(level))
        if level == 0 or np.all(size <= params.lod_threshold) or len(idx) * 8 > ROAMING_MAX_BRICKS:
            break
        ctx.counts["refined"] += len(idx)
        idx = tree.children(level, idx)[0]
        idx, lo, hi = ctx.cull(level - 1, idx)
        level -= 1
    ctx.counts["level"] = chosen[0]
    ctx.leaves(*chosen)


def _resolve(ctx: _Ctx, data_lv, data_idx, reg_lv, reg_idx):
    """Replace non-resident data bricks by their nearest resident ancestor (-1: none)."""
    src_lv, src_idx = data_lv.copy(), data_idx.copy()
    done = np.zeros(len(src_lv), dtype=bool)
    for lv in range(int(src_lv.min()) if len(src_lv) else 0, ctx.tree.top + 1):
        rows = np.nonzero(~done & (src_lv == lv))[0]
        if not len(rows):
            continue
        # ask once per distinct brick (a wrapper may reserve GPU slots on each positive answer)
        uniq, inv = np.unique(src_idx[rows], axis=0, return_inverse=True)
        res = ctx.resident(lv, uniq)[inv.reshape(-1)]
        done[rows[res]] = True
        up = rows[~res]
        src_lv[up] += 1
        src_idx[up] //= 2
    src_lv[~done] = -1
    return src_lv, src_idx


def _merge(tree: _Tree, src_lv, src_idx, reg_lv, reg_idx):
    """Merge complete sibling groups drawn from one ancestor into their parent's box."""
    if not len(src_lv):
        return src_lv, src_idx, reg_lv, reg_idx
    for lv in range(int(reg_lv.min()), tree.top):
        sel = np.nonzero((reg_lv == lv) & (src_lv > lv))[0]
        if len(sel) < 2:
            continue
        parent = reg_idx[sel] // 2
        key = np.concatenate([parent, src_lv[sel, None], src_idx[sel]], axis=1)
        uniq, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        inv = inv.reshape(-1)
        full = cnt == tree.n_children(lv + 1, uniq[:, :3])
        if not full.any():
            continue
        merged = full[inv]
        drop = sel[merged]
        keep = np.ones(len(src_lv), dtype=bool)
        keep[drop] = False
        new = uniq[full]
        src_lv = np.concatenate([src_lv[keep], new[:, 3]])
        src_idx = np.concatenate([src_idx[keep], new[:, 4:]])
        reg_lv = np.concatenate([reg_lv[keep], np.full(len(new), lv + 1)])
        reg_idx = np.concatenate([reg_idx[keep], new[:, :3]])
    return src_lv, src_idx, reg_lv, reg_idx


def back_to_front(pyramid: Pyramid, camera: Camera, levels, indices) -> np.ndarray:
    """Permutation that puts non-nested octree nodes ``(levels[i], indices[i])`` in back-to-front order.

    The order is that of a depth-first traversal of the octree (virtual levels above the top
    included) whose children are visited far side first (see the module docstring): exact for any
    mix of levels, perspective or orthographic, with the eye anywhere (inside a node, on a split
    plane, exactly on an axis or diagonal).

    Parameters
    ----------
    levels : array_like of int, shape (n,)
    indices : array_like of int, shape (n, 3)
        Brick indices ``(bz, by, bx)``; no node may contain another.

    Returns
    -------
    numpy.ndarray
        ``(n,)`` indices into the inputs, the first to draw first.
    """
    return _order(_Tree(pyramid), camera, np.asarray(levels, dtype=np.int64).reshape(-1),
                  np.asarray(indices, dtype=np.int64).reshape(-1, 3))


def _order(tree: _Tree, camera: Camera, levels: np.ndarray, idx: np.ndarray) -> np.ndarray:
    n = len(levels)
    if n < 2:
        return np.arange(n)
    depth = tree.root - int(levels.min())
    ranks = np.zeros((n, max(depth, 1)), dtype=np.int64)
    eye = camera.eye
    fwd = camera.forward
    for k in range(depth):
        plv = tree.root - k  # parent level of this step
        rows = np.nonzero(levels < plv)[0]
        if not len(rows):
            continue
        shift = (plv - levels[rows])[:, None]
        anc = idx[rows] >> shift  # ancestor at plv, (z, y, x)
        bit = ((idx[rows] >> (shift - 1)) & 1)[:, ::-1]  # child half per axis, (x, y, z)
        if camera.orthographic:
            far_high = np.broadcast_to(fwd >= 0, bit.shape)
        else:
            far_high = eye[None, :] <= tree.split(plv, anc)
        far = np.where(far_high, bit == 1, bit == 0)
        code = far[:, 0] * 4 + far[:, 1] * 2 + far[:, 2]
        ranks[rows, k] = _RANK[code]
    return np.lexsort(ranks.T[::-1])


def _wanted_order(tree: _Tree, camera: Camera, lv: np.ndarray, idx: np.ndarray) -> np.ndarray:
    if not len(lv):
        return np.arange(0)
    dist = np.empty(len(lv))
    for L in np.unique(lv):
        rows = np.nonzero(lv == L)[0]
        lo, hi = tree.boxes(int(L), idx[rows])
        near = np.clip(camera.eye, lo, hi)
        dist[rows] = np.linalg.norm(near - camera.eye, axis=1)
    return np.lexsort((dist, -lv))


def select(pyramid: Pyramid, camera: Camera, params: SelectionParams = SelectionParams(), *,
           residency: Residency | None = None, shape: Shape | None = None,
           transparent: Callable[[int, np.ndarray], np.ndarray] | None = None) -> Selection:
    """Choose the bricks to draw for ``camera`` and their back-to-front order.

    Parameters
    ----------
    pyramid : Pyramid
        The data's pyramid (``loader.pyramid``).
    camera : Camera
        The view.
    params : SelectionParams
        Mode, LOD threshold, fixed level, texel budget.
    residency : object, optional
        Has ``in_window_mask(level, idx)`` and ``resident_mask(level, idx)`` (``idx`` ``(n, 3)``
        ``(bz, by, bx)``), e.g. a ``ClipTexture``; None treats every brick as resident.
    shape : Shape, optional
        Region of interest; bricks wholly outside it are culled.
    transparent : callable, optional
        ``transparent(level, idx) -> (n,) bool``, True for bricks the transfer function makes
        fully transparent; they are neither requested nor drawn.

    Returns
    -------
    Selection
        Items in back-to-front order, the ideal cut (``wanted``) and counts.

    Notes
    -----
    ``roaming`` picks, from the top down, the finest level whose visible (non-transparent) bricks
    are all in the residency window and whose bricks fit ``max_texels_drawn``; it stops early at
    the first level whose voxels all project to at most ``lod_threshold`` pixels (finer levels
    would not be seen) or whose visible bricks would exceed ``ROAMING_MAX_BRICKS``.
    """
    if not isinstance(params, SelectionParams):
        raise ParameterError(f"params: expected a SelectionParams, got {type(params).__name__}")
    tree = _Tree(pyramid)
    if params.level is not None and params.level > tree.top:
        raise ParameterError(f"level: expected 0..{tree.top} for this pyramid, got {params.level}")
    ctx = _Ctx(tree, camera, params, residency, shape, transparent)
    if params.mode == "roaming":
        _cut_roaming(ctx)
    elif params.max_texels_drawn is not None:
        _cut_greedy(ctx, params.max_texels_drawn)
    else:
        _cut_traverse(ctx)
    if params.mode == "fixed":
        ctx.counts["level"] = params.level

    if ctx.rec:
        data_lv = np.concatenate([np.full(len(r[1]), r[0], dtype=np.int64) for r in ctx.rec])
        data_idx = np.concatenate([r[1] for r in ctx.rec]).astype(np.int64)
        reg_lv = np.concatenate([np.full(len(r[3]), r[2], dtype=np.int64) for r in ctx.rec])
        reg_idx = np.concatenate([r[3] for r in ctx.rec]).astype(np.int64)
    else:
        data_lv = reg_lv = np.zeros(0, dtype=np.int64)
        data_idx = reg_idx = np.zeros((0, 3), dtype=np.int64)

    # the ideal cut: unique data bricks, coarse first, then nearest first
    if len(data_lv):
        u = np.unique(np.concatenate([data_lv[:, None], data_idx], axis=1), axis=0)
        wo = _wanted_order(tree, camera, u[:, 0], u[:, 1:])
        wanted = [(int(u[i, 0]), (int(u[i, 1]), int(u[i, 2]), int(u[i, 3]))) for i in wo]
    else:
        wanted = []

    src_lv, src_idx = _resolve(ctx, data_lv, data_idx, reg_lv, reg_idx)
    drawn = src_lv >= 0
    ctx.counts["missing"] = int((~drawn).sum())
    fallback = drawn & ((src_lv != data_lv) | np.any(src_idx != data_idx, axis=1))
    ctx.counts["fallback"] = int(fallback.sum())
    src_lv, src_idx, reg_lv, reg_idx = _merge(tree, src_lv[drawn], src_idx[drawn], reg_lv[drawn], reg_idx[drawn])
    order = _order(tree, camera, reg_lv, reg_idx)
    box_lo = np.empty((len(reg_lv), 3))
    box_hi = np.empty((len(reg_lv), 3))
    for L in np.unique(reg_lv):  # one vectorised call per level
        rows = reg_lv == L
        box_lo[rows], box_hi[rows] = tree.boxes(int(L), reg_idx[rows])
    items = [DrawItem(int(src_lv[i]), (int(src_idx[i, 0]), int(src_idx[i, 1]), int(src_idx[i, 2])),
                      tuple(box_lo[i].tolist()), tuple(box_hi[i].tolist())) for i in order]
    ctx.counts["texels"] = len(items) * tree.texels
    return Selection(items, wanted, ctx.counts)


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
            touched.update((n, (int(a), int(b), int(c))) for a, b, c in np.unique(idx >> (n - int(L)), axis=0))
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

    stack: list[tuple[DrawItem, tuple[int, tuple[int, int, int]] | None]] = []
    for it, f in zip(items, full):
        stack.append((it, (it.level, tuple(it.index)) if f else None))
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
