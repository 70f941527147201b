"""The per-level page table of a selection's cut, for the single-pass ray-guided path (pure numpy).

Why a page table: the per-brick path draws one proxy box per draw item and composites boxes in
the selection's visibility order; a single-pass ray caster (after BigVolumeViewer and the
ray-guided renderers of the large-volume literature; references below)
instead marches each ray through the volume once and needs to answer, at any point, "which
brick, of which level, is drawn here?". The selection's cut answers it as a tree: this module
flattens it into one small integer table per level that the shader walks from the coarsest level
down. The selection, its policies and its budgets stay as they are; the table is their output.

Entry of node ``(L, cell)`` (``uint32``):

* bits 0-1, kind: ``EMPTY`` (0; nothing drawn in the node's box - culled, transparent, outside the
  window or the table: the ray skips the whole box in one step), ``REFINED`` (1; an ancestor of
  drawn nodes: look at level ``L - 1``), ``DRAWN`` (2; sample the node's box);
* bits 2-6, ``DRAWN`` only: the data level ``Ld`` - the node's own brick (``Ld == L``), the
  resident ancestor the selection drew over it (``Ld > L``: the brick ``cell >> (Ld - L)`` of
  level ``Ld``), or a **merged block** (``Ld < L``: the ``(2 ** (L - Ld))³`` bricks of level ``Ld``
  under the node, clipped to the level's grid, first brick ``cell << (L - Ld)``; see
  :func:`clipvol.scene.selection.merge_items`), sampled on one lattice with no face inside;
* bits 8-13, ``DRAWN`` only: which faces of the data brick (or block) filtering may read across
  (the neighbour is in texture memory), ``x-lo, x-hi, y-lo, y-hi, z-lo, z-hi`` - as the
  per-brick path clamps its sampling (a block's face is open only where it is for every brick).

Why merged blocks: a ray of the single pass restarts its march at every node face it crosses,
and on a SIMD rasteriser the pixels of one group cross faces at different samples, so each
crossing costs the group the longest of its segments. Where the per-brick path draws one box over
a complete sibling set, the table now holds one node as well: a full-resolution cut of a resident
volume becomes a handful of nodes, as it becomes a handful of boxes there.

Each level's table covers the bounding box (in cells) of the nodes of that level that are drawn
or refined; a cell outside it is ``EMPTY``. The tables are concatenated into one flat array.

References: M. Hadwiger, J. Beyer, W.-K. Jeong and H. Pfister, "Interactive Volume Exploration of
Petascale Microscopy Data Streams Using a Visualization-Driven Virtual Memory Approach", IEEE TVCG
2012; T. Fogal, A. Schiewe and J. Krüger, "An Analysis of Scalable GPU-Based Ray-Guided Volume
Rendering", IEEE LDAV 2013; E. LaMar, B. Hamann and K. I. Joy, "Multiresolution Techniques for
Interactive Texture-Based Volume Visualization", IEEE Visualization 1999 (the octree cut).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .selection.cut import DrawItems

__all__ = ["PageTable", "build_page_table", "update_page_table", "block_cells", "block_open_faces", "EMPTY", "REFINED", "DRAWN", "item_nodes"]

EMPTY, REFINED, DRAWN = 0, 1, 2


@dataclass(frozen=True)
class PageTable:
    """Flattened per-level tables of a cut.

    Attributes
    ----------
    entries : ndarray of uint32
        All levels' entries, level after level; each level's box in ``(z, y, x)`` C order.
    base : ndarray (num_levels,) of int64
        First entry of each level.
    c0, size : ndarray (num_levels, 3) of int64
        First cell ``(z, y, x)`` of each level's box and its extent in cells (0: empty level).
    d0 : ndarray (num_levels, 3) of int64
        A brick ``(z, y, x)`` of each level near the data it serves (the smallest index of the
        level's data bricks, else ``c0``): the shader places bricks relative to it, so positions
        stay small numbers in float32 however large the volume.
    """

    entries: np.ndarray
    base: np.ndarray
    c0: np.ndarray
    size: np.ndarray
    d0: np.ndarray | None = None
    #: the drawn items' open faces by item (:func:`build_page_table`'s ``known_faces`` for the next
    #: table over the same GPU slots): sorted :func:`face_keys` and their ``(n, 3, 2)`` faces; None
    #: where no ``open_faces`` was given or the keys do not fit
    faces: tuple[np.ndarray, np.ndarray] | None = None
    #: the drawn nodes' entries, sorted, and per entry the drawn nodes under it (``REFINED`` while
    #: above zero): what :func:`update_page_table` changes; None where not known
    drawn: np.ndarray | None = None
    refs: np.ndarray | None = None

    def lookup(self, level: int, cells) -> np.ndarray:
        """Entries of ``cells`` ``(n, 3)`` ``(z, y, x)`` of ``level`` (``EMPTY`` outside its box)."""
        c = np.asarray(cells, dtype=np.int64).reshape(-1, 3) - self.c0[level]
        s = self.size[level]
        inside = np.all((c >= 0) & (c < s), axis=1)
        out = np.zeros(len(c), dtype=np.uint32)
        ci = c[inside]
        flat = self.base[level] + (ci[:, 0] * s[1] + ci[:, 1]) * s[2] + ci[:, 2]
        out[inside] = self.entries[flat]
        return out


def item_nodes(items, pyramid) -> list[tuple[int, tuple[int, int, int]]] | None:
    """The octree node ``(level, index)`` whose box each draw item covers, or None if an item's box
    is not exactly one node's box (a cut this table cannot express). A merged item (``span > 1``,
    :func:`clipvol.scene.selection.merge_items`) covers the node of level ``level + log2(span)``
    over its bricks; any other item a node of its own level or finer (a fallback octant)."""
    nodes = _node_arrays(items, pyramid)
    if nodes is None:
        return None
    return [(int(L), (int(a), int(b), int(c))) for L, (a, b, c) in zip(*nodes)]


def _node_arrays(items, pyramid) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`item_nodes` as arrays: ``(levels (n,), indices (n, 3))``, or None."""
    if not len(items):
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64)
    arr = DrawItems.from_items(items)  # (merge_items' output is one already: no objects made)
    lo, hi = arr.lo, arr.hi
    vlo, _ = pyramid.volume_box()
    sp = np.array(pyramid.spacing[::-1], dtype=np.float64)
    B = np.array(pyramid.brick_shape[::-1], dtype=np.float64)
    out_level = np.full(len(items), -1)
    out_idx = np.zeros((len(items), 3), dtype=np.int64)
    spans = arr.span
    if np.any(spans < 1) or np.any(spans & (spans - 1)):
        return None
    shift = np.round(np.log2(spans)).astype(np.int64)
    top = arr.rows[:, 0] + shift
    bottom = np.where(spans > 1, top, 0)  # a merged item is its node's box, nothing finer
    first = arr.rows[:, 1:]
    for L in range(pyramid.num_levels - 1, -1, -1):
        cand = (out_level < 0) & (top >= L) & (bottom <= L)
        if not cand.any():
            continue
        ext = B * 2.0**L * sp
        idx_xyz = np.rint((lo[cand] - vlo) / ext).astype(np.int64)
        idx = idx_xyz[:, ::-1]
        g = np.array(pyramid.grid(L))
        ok = np.all((idx >= 0) & (idx < g), axis=1)
        nlo, nhi = pyramid.node_box(L, np.clip(idx, 0, g - 1))
        tol = 1e-9 * np.maximum(1.0, np.abs(ext).max())
        ok &= np.all(np.abs(nlo - lo[cand]) <= tol, axis=1) & np.all(np.abs(nhi - hi[cand]) <= tol, axis=1)
        sh = shift[cand][:, None]
        ok &= np.all(np.where(sh > 0, (idx << sh) == first[cand], True), axis=1)  # a block starts at its node
        w = np.nonzero(cand)[0][ok]
        out_level[w] = L
        out_idx[w] = idx[ok]
    if np.any(out_level < 0):
        return None
    return out_level.astype(np.int64), out_idx


def block_cells(count) -> tuple[np.ndarray, np.ndarray]:
    """Every cell of every block of ``count[i]`` cells per axis (``(n, 3)``): ``(block, local)``,
    the block of each cell and its ``(z, y, x)`` offset in it, blocks in order, cells in C order.
    Vectorised (one meshgrid per block cost ~0.1 ms each, hundreds a frame)."""
    count = np.asarray(count, dtype=np.int64).reshape(-1, 3)
    sizes = np.prod(count, axis=1)
    block = np.repeat(np.arange(len(count)), sizes)
    k = np.arange(int(sizes.sum())) - np.repeat(np.cumsum(sizes) - sizes, sizes)  # C-order rank in its block
    c = count[block]
    local = np.stack([k // (c[:, 1] * c[:, 2]), (k // c[:, 2]) % c[:, 1], k % c[:, 2]], axis=1)
    return block, local


def block_open_faces(open_faces, level: int, first, count) -> np.ndarray:
    """``(n, 3, 2)`` bool ``[axis (z, y, x), side (lo, hi)]``: may filtering read across that face
    of each block of bricks of ``level`` (first brick ``first[i]``, ``count[i]`` bricks per axis,
    ``(n, 3)``)? A block's face is open where it is open for every brick on it.

    ``open_faces(level, idx) -> (m, 3, 2) bool`` answers per brick (the GPU cache's
    :meth:`~clipvol.render.gpu_cache.GpuBrickCache.open_faces`); it is asked once for all bricks
    of all blocks (a frame's cut has hundreds of blocks: one call each cost 25 ms a frame).
    Shared by the page table and the per-brick path's clamps, so both paths filter alike.
    """
    first = np.asarray(first, dtype=np.int64).reshape(-1, 3)
    count = np.asarray(count, dtype=np.int64).reshape(-1, 3)
    n = len(first)
    out = np.zeros((n, 3, 2), dtype=bool)
    if n == 0:
        return out
    block, local = block_cells(count)
    surface = np.any((local == 0) | (local == count[block] - 1), axis=1)  # only these lie on a face
    block, local = block[surface], local[surface]
    of = np.asarray(open_faces(level, first[block] + local), dtype=bool)
    for axis in range(3):
        for side, edge in ((0, np.zeros(len(local), dtype=np.int64)), (1, count[block, axis] - 1)):
            on = local[:, axis] == edge  # the bricks on that face of their block
            shut = np.bincount(block[on], weights=~of[on, axis, side], minlength=n)
            out[:, axis, side] = shut == 0
    return out


#: bits of each brick index axis in a :func:`face_keys` key
FACE_KEY_AXIS_BITS = 17


def face_keys(data_lv: np.ndarray, data_idx: np.ndarray, node_lv: np.ndarray) -> np.ndarray | None:
    """One int64 per drawn item naming what its open faces depend on: the data level, the first
    brick and the block's depth (``node_lv - data_lv``, 0 for one brick); None where a brick index
    does not fit :data:`FACE_KEY_AXIS_BITS` bits."""
    if len(data_idx) and int(data_idx.max()) >= 1 << FACE_KEY_AXIS_BITS:
        return None
    b = FACE_KEY_AXIS_BITS
    depth = np.maximum(node_lv - data_lv, 0)
    return ((((data_lv << 6) | depth) << b | data_idx[:, 0]) << b | data_idx[:, 1]) << b | data_idx[:, 2]


def _layout(node_lv, node_idx, data_lv, data_idx, nlev: int):
    """Each level's box of cells ``(c0, size)``, the first entry of each level ``base`` and each
    level's data brick ``d0`` (:class:`PageTable`) of a cut's nodes: every node's ancestors span
    their level's box. Per node level first (a shift keeps the order of cells: the smallest
    ancestor is the smallest cell's), so no node's ancestors are listed."""
    c0 = np.zeros((nlev, 3), dtype=np.int64)
    size = np.zeros((nlev, 3), dtype=np.int64)
    lo = np.full((nlev, 3), np.iinfo(np.int64).max)
    hi = np.full((nlev, 3), -1, dtype=np.int64)
    present = np.zeros(nlev, dtype=bool)
    for l in np.unique(node_lv).tolist():
        cells = node_idx[node_lv == l]
        present[l] = True
        lo[l], hi[l] = cells.min(axis=0), cells.max(axis=0)
    for L in range(nlev):
        if not present[:L + 1].any():
            continue
        ls = np.nonzero(present[:L + 1])[0]
        sh = (L - ls)[:, None]
        c0[L] = (lo[ls] >> sh).min(axis=0)
        size[L] = (hi[ls] >> sh).max(axis=0) - c0[L] + 1
    counts = size.prod(axis=1)
    base = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    d0 = c0.copy()
    for Ld in np.unique(data_lv).tolist():
        d0[Ld] = data_idx[data_lv == Ld].min(axis=0)
    return c0, size, base, d0


def _flat(c0, size, base, levels, cells) -> np.ndarray:
    """The entries of cells ``(n, 3)`` of ``levels`` ``(n,)`` in a table of that layout."""
    c = cells - c0[levels]
    s = size[levels]
    return base[levels] + (c[:, 0] * s[:, 1] + c[:, 1]) * s[:, 2] + c[:, 2]


def _ancestors(c0, size, base, levels, cells) -> np.ndarray:
    """The entries of every strict ancestor of each node (one per node and coarser level)."""
    out = []
    for L in range(1, len(c0)):
        under = levels < L
        if under.any():
            out.append(_flat(c0, size, base, np.full(int(under.sum()), L), cells[under] >> (L - levels[under])[:, None]))
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def _drawn_entries(items, pyramid, open_faces, known_faces):
    """The nodes of the draw items and their ``DRAWN`` entries: ``(node_lv, node_idx, data_lv,
    data_idx, values, faces)`` (:attr:`PageTable.faces` of these items), or None where the items
    are not node boxes."""
    nodes = _node_arrays(items, pyramid)
    if nodes is None:
        return None
    node_lv, node_idx = nodes
    arr = DrawItems.from_items(items) if len(items) else DrawItems(np.zeros((0, 4), dtype=np.int64), (), ())
    data_lv, data_idx = arr.rows[:, 0], arr.rows[:, 1:]
    of = np.zeros((len(data_lv), 3, 2), dtype=bool)  # (n, 3 zyx, 2): faces of each item's brick or block
    keys = face_keys(data_lv, data_idx, node_lv) if open_faces is not None else None
    todo = np.ones(len(data_lv), dtype=bool)  # items whose faces are still to be asked
    if keys is not None and known_faces is not None and len(known_faces[0]) and len(keys):
        known, known_of = known_faces
        pos = np.minimum(np.searchsorted(known, keys), len(known) - 1)
        hit = known[pos] == keys
        of[hit] = known_of[pos[hit]]
        todo = ~hit
    if open_faces is not None:
        for Ld in np.unique(data_lv).tolist():
            rows = data_lv == Ld
            one = rows & (node_lv <= Ld) & todo
            merged = rows & (node_lv > Ld) & todo
            if one.any():
                of[one] = np.asarray(open_faces(Ld, data_idx[one]), dtype=bool)
            if merged.any():  # a block: a face is open where it is for every brick on it
                grid = np.asarray(pyramid.grid(Ld), dtype=np.int64)
                span = np.left_shift(1, node_lv[merged] - Ld)
                cnt = np.minimum(data_idx[merged] + span[:, None], grid) - data_idx[merged]
                of[merged] = block_open_faces(open_faces, Ld, data_idx[merged], cnt)
    bits = np.zeros(len(data_lv), dtype=np.uint32)
    for k, axis in enumerate((2, 1, 0)):  # x, y, z
        bits |= of[:, axis, 0].astype(np.uint32) << np.uint32(2 * k)
        bits |= of[:, axis, 1].astype(np.uint32) << np.uint32(2 * k + 1)
    values = np.uint32(DRAWN) | (data_lv.astype(np.uint32) << np.uint32(2)) | (bits << np.uint32(8))
    faces = None
    if keys is not None:
        order = np.argsort(keys, kind="stable")
        faces = (keys[order], of[order])
    return node_lv, node_idx, data_lv, data_idx, values, faces


def build_page_table(items, pyramid, open_faces=None, known_faces=None) -> PageTable | None:
    """The page table of a cut given as draw items (merged or not), or None if the items are not
    node boxes (see :func:`item_nodes`).

    ``open_faces(level, idx) -> (n, 3, 2) bool`` (axes ``z, y, x``; sides lo, hi): which faces of
    data bricks filtering may read across (the GPU cache's answer); None: none. A merged
    block's face is open where it is open for every brick on it.

    ``known_faces``: the :attr:`PageTable.faces` of an earlier table whose ``open_faces`` answered
    over the same GPU slots (the caller's to know): its items' faces are taken from it and only
    the other items are asked. A projected-size cut updated for a turning camera keeps most of
    its merged items; asking the faces of every block again cost ~12 ms a frame on a 13 742-brick cut.
    """
    drawn = _drawn_entries(items, pyramid, open_faces, known_faces)
    if drawn is None:
        return None
    node_lv, node_idx, data_lv, data_idx, values, faces = drawn
    c0, size, base, d0 = _layout(node_lv, node_idx, data_lv, data_idx, pyramid.num_levels)
    n = int(size.prod(axis=1).sum())
    # refined: an ancestor of drawn nodes (counted, so that an update can take one away)
    refs = np.bincount(_ancestors(c0, size, base, node_lv, node_idx), minlength=n).astype(np.int32)
    entries = np.where(refs > 0, np.uint32(REFINED), np.uint32(EMPTY)).astype(np.uint32)
    pos = _flat(c0, size, base, node_lv, node_idx)
    entries[pos] = values
    return PageTable(entries, base, c0, size, d0, faces, np.sort(pos), refs)


def update_page_table(old: PageTable | None, items, pyramid, open_faces=None,
                      known_faces=None) -> tuple[PageTable | None, np.ndarray | None]:
    """The page table of ``items`` (:func:`build_page_table`'s, entry for entry) made from ``old``'s
    by what changed, and the entries that differ from ``old``'s (sorted; None: a table built
    from nothing, every entry new).

    Why: a kept cut changes by a few nodes a frame, and building its table from nothing cost
    ~3.5 ms of a 15 774-brick cut's frame, then a compare of the whole table for the GPU's
    sub-write. While every level's box (and each data level's ``d0``: the shader's float32
    positions are relative to them, so the image is a fresh table's only with the same ones) is
    the same, only the entries of nodes that left, came or changed (their data level, their
    open faces) and of their ancestors are written: each ancestor keeps a count of the drawn
    nodes under it, REFINED while it is above zero. Another box builds the table from nothing.
    """
    if old is None or old.drawn is None or old.refs is None:
        return build_page_table(items, pyramid, open_faces, known_faces), None
    drawn = _drawn_entries(items, pyramid, open_faces, known_faces)
    if drawn is None:
        return None, None
    node_lv, node_idx, data_lv, data_idx, values, faces = drawn
    c0, size, base, d0 = _layout(node_lv, node_idx, data_lv, data_idx, pyramid.num_levels)
    if not (np.array_equal(c0, old.c0) and np.array_equal(size, old.size) and np.array_equal(d0, old.d0)):
        return build_page_table(items, pyramid, open_faces, known_faces), None
    pos = _flat(c0, size, base, node_lv, node_idx)
    order = np.argsort(pos)
    pos, lv, idx, values = pos[order], node_lv[order], node_idx[order], values[order]
    if len(pos) > 1 and np.any(pos[1:] == pos[:-1]):  # (two items of one node: what build does)
        return build_page_table(items, pyramid, open_faces, known_faces), None
    was = old.drawn
    k = np.minimum(np.searchsorted(was, pos), max(len(was) - 1, 0))
    kept = (was[k] == pos) if len(was) else np.zeros(len(pos), dtype=bool)
    k2 = np.minimum(np.searchsorted(pos, was), max(len(pos) - 1, 0))
    gone = was[(pos[k2] != was) if len(pos) else np.ones(len(was), dtype=bool)]
    came = ~kept
    revalued = pos[kept & (old.entries[pos] != values)]
    refs = old.refs.copy()
    up = _ancestors(c0, size, base, lv[came], idx[came])
    g_lv = np.searchsorted(base, gone, side="right") - 1  # (an empty level shares the next one's base)
    local = gone - base[g_lv]
    s = size[g_lv]
    g_idx = np.stack([local // (s[:, 1] * s[:, 2]), (local // s[:, 2]) % s[:, 1], local % s[:, 2]], axis=1) + c0[g_lv]
    down = _ancestors(c0, size, base, g_lv, g_idx)
    for cells, sign in ((up, 1), (down, -1)):
        if len(cells):
            u, c = np.unique(cells, return_counts=True)
            refs[u] += sign * c.astype(np.int32)
    touched = np.unique(np.concatenate([gone, pos[came], revalued, up, down]))
    entries = old.entries.copy()
    new = np.where(refs[touched] > 0, np.uint32(REFINED), np.uint32(EMPTY)).astype(np.uint32)
    j = np.minimum(np.searchsorted(pos, touched), max(len(pos) - 1, 0))
    on = (pos[j] == touched) if len(pos) else np.zeros(len(touched), dtype=bool)
    new[on] = values[j[on]]
    changed = touched[new != old.entries[touched]]
    entries[changed] = new[new != old.entries[touched]]
    return PageTable(entries, base, c0, size, d0, faces, pos, refs), changed
