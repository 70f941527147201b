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

__all__ = ["PageTable", "DrawnNodes", "build_page_table", "update_page_table", "block_cells", "block_open_faces",
           "EMPTY", "REFINED", "DRAWN", "item_nodes", "item_keys"]

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
    #: the draw items and their nodes' entries (:class:`DrawnNodes`), and per entry the drawn nodes
    #: under it (``REFINED`` while above zero): what :func:`update_page_table` changes; None where
    #: not known
    drawn: "DrawnNodes | None" = None
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


@dataclass(frozen=True)
class DrawnNodes:
    """A table's draw items by :func:`item_keys` (sorted), each with its box's low corner (an item
    whose node is finer than its brick has the brick's key: the corner tells them apart), its
    node, its entry's position and value and its open faces: what an update reads of the table
    before instead of deriving it again from the items' world boxes."""

    keys: np.ndarray
    lo: np.ndarray
    node_lv: np.ndarray
    node_idx: np.ndarray
    pos: np.ndarray
    values: np.ndarray
    faces: np.ndarray


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
    their level's box. All levels at once (a handful of numpy calls however many levels: an
    updated table asks it every frame)."""
    big = np.iinfo(np.int64).max
    sh = np.arange(nlev)[None, :] - node_lv[:, None]  # (n, nlev): levels above each node, < 0 below
    up = sh >= 0
    anc = node_idx[:, None, :] >> np.maximum(sh, 0)[:, :, None]  # (n, nlev, 3)
    c0 = np.where(up[:, :, None], anc, big).min(axis=0, initial=big)
    top = np.where(up[:, :, None], anc, -1).max(axis=0, initial=-1)
    some = top[:, 0] >= 0
    c0 = np.where(some[:, None], c0, 0)
    size = np.where(some[:, None], top - c0 + 1, 0)
    counts = size.prod(axis=1)
    base = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    at = data_lv[:, None] == np.arange(nlev)[None, :]  # (n, nlev)
    d0 = np.where(at[:, :, None], data_idx[:, None, :], big).min(axis=0, initial=big)
    d0 = np.where(at.any(axis=0)[:, None], d0, c0)
    return c0, size, base, d0


def _flat(c0, size, base, levels, cells) -> np.ndarray:
    """The entries of cells ``(n, 3)`` of ``levels`` ``(n,)`` in a table of that layout."""
    c = cells - c0[levels]
    s = size[levels]
    return base[levels] + (c[:, 0] * s[:, 1] + c[:, 1]) * s[:, 2] + c[:, 2]


def _ancestors(c0, size, base, levels, cells) -> np.ndarray:
    """The entries of every strict ancestor of each node (one per node and coarser level)."""
    nlev = len(c0)
    sh = np.arange(nlev)[None, :] - levels[:, None]  # (n, nlev)
    n, L = np.nonzero(sh > 0)
    return _flat(c0, size, base, L, cells[n] >> sh[n, L][:, None])


def item_keys(arr: DrawItems) -> np.ndarray | None:
    """One int64 per draw item: its level, ``log2(span)`` and first brick (17 bits an axis), or
    None where an index does not fit or a span is not a power of two."""
    span = arr.span
    if np.any(span < 1) or np.any(span & (span - 1)) or (len(arr.rows) and (int(arr.rows[:, 1:].max()) >= 1 << 17
                                                                             or int(arr.rows[:, 1:].min()) < 0)):
        return None
    shift = np.round(np.log2(span)).astype(np.int64)
    r = arr.rows
    return ((((r[:, 0] << 5) | shift) << 17 | r[:, 1]) << 17 | r[:, 2]) << 17 | r[:, 3]


def _faces_of(pyramid, open_faces, node_lv, data_lv, data_idx, of, todo) -> None:
    """Ask ``open_faces`` the faces of the ``todo`` items into ``of`` (a block's face is open where it
    is for every brick on it)."""
    for Ld in np.unique(data_lv[todo]).tolist():
        rows = data_lv == Ld
        one = rows & (node_lv <= Ld) & todo
        merged = rows & (node_lv > Ld) & todo
        if one.any():
            of[one] = np.asarray(open_faces(Ld, data_idx[one]), dtype=bool)
        if merged.any():
            grid = np.asarray(pyramid.grid(Ld), dtype=np.int64)
            span = np.left_shift(1, node_lv[merged] - Ld)
            cnt = np.minimum(data_idx[merged] + span[:, None], grid) - data_idx[merged]
            of[merged] = block_open_faces(open_faces, Ld, data_idx[merged], cnt)


def _values(data_lv, of) -> np.ndarray:
    """The ``DRAWN`` entries of items of data levels ``data_lv`` with open faces ``of``."""
    bits = np.zeros(len(data_lv), dtype=np.uint32)
    for k, axis in enumerate((2, 1, 0)):  # x, y, z
        bits |= of[:, axis, 0].astype(np.uint32) << np.uint32(2 * k)
        bits |= of[:, axis, 1].astype(np.uint32) << np.uint32(2 * k + 1)
    return np.uint32(DRAWN) | (data_lv.astype(np.uint32) << np.uint32(2)) | (bits << np.uint32(8))


def _known(of, todo, keys, known_faces) -> None:
    """Take the faces of the ``todo`` items whose face ``keys`` ``known_faces`` holds (marking them done)."""
    if keys is None or known_faces is None or not len(known_faces[0]) or not todo.any():
        return
    known, known_of = known_faces
    w = np.nonzero(todo)[0]
    pos = np.minimum(np.searchsorted(known, keys[w]), len(known) - 1)
    hit = known[pos] == keys[w]
    of[w[hit]] = known_of[pos[hit]]
    todo[w[hit]] = False


def _sorted_faces(keys, of):
    """:attr:`PageTable.faces` of items with face ``keys`` and faces ``of`` (None: no keys)."""
    if keys is None:
        return None
    order = np.argsort(keys, kind="stable")
    return keys[order], of[order]


def _item_arrays(items) -> DrawItems:
    """The draw items as arrays (merge_items' output is one already: nothing made), none as empty ones."""
    return DrawItems.from_items(items) if len(items) else DrawItems(np.zeros((0, 4), dtype=np.int64), (), ())


def _drawn_entries(arr: DrawItems, pyramid, open_faces, known_faces):
    """The nodes of the draw items ``arr`` and their ``DRAWN`` entries: ``(node_lv, node_idx,
    data_lv, data_idx, values, faces, of)`` (``faces``: :attr:`PageTable.faces` of these items;
    ``of`` their open faces in item order), or None where the items are not node boxes."""
    nodes = _node_arrays(arr, pyramid)
    if nodes is None:
        return None
    node_lv, node_idx = nodes
    data_lv, data_idx = arr.rows[:, 0], arr.rows[:, 1:]
    of = np.zeros((len(data_lv), 3, 2), dtype=bool)  # (n, 3 zyx, 2): faces of each item's brick or block
    keys = face_keys(data_lv, data_idx, node_lv) if open_faces is not None else None
    todo = np.ones(len(data_lv), dtype=bool)  # items whose faces are still to be asked
    _known(of, todo, keys, known_faces)
    if open_faces is not None:
        _faces_of(pyramid, open_faces, node_lv, data_lv, data_idx, of, todo)
    return node_lv, node_idx, data_lv, data_idx, _values(data_lv, of), _sorted_faces(keys, of), of


def _drawn_nodes(arr, node_lv, node_idx, pos, values, of) -> DrawnNodes | None:
    """The :class:`DrawnNodes` of items ``arr`` (None where their keys do not fit)."""
    keys = item_keys(arr)
    if keys is None:
        return None
    o = np.argsort(keys, kind="stable")
    return DrawnNodes(keys[o], arr.lo[o], node_lv[o], node_idx[o], pos[o], values[o], of[o])


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
    arr = _item_arrays(items)
    drawn = _drawn_entries(arr, pyramid, open_faces, known_faces)
    if drawn is None:
        return None
    node_lv, node_idx, data_lv, data_idx, values, faces, of = drawn
    c0, size, base, d0 = _layout(node_lv, node_idx, data_lv, data_idx, pyramid.num_levels)
    n = int(size.prod(axis=1).sum())
    # refined: an ancestor of drawn nodes (counted, so that an update can take one away)
    refs = np.bincount(_ancestors(c0, size, base, node_lv, node_idx), minlength=n).astype(np.int32)
    entries = np.where(refs > 0, np.uint32(REFINED), np.uint32(EMPTY)).astype(np.uint32)
    pos = _flat(c0, size, base, node_lv, node_idx)
    entries[pos] = values
    return PageTable(entries, base, c0, size, d0, faces, _drawn_nodes(arr, node_lv, node_idx, pos, values, of), refs)


def update_page_table(old: PageTable | None, items, pyramid, open_faces=None, known_faces=None,
                      faces_hold: bool = False) -> tuple[PageTable | None, np.ndarray | None]:
    """The page table of ``items`` (:func:`build_page_table`'s, entry for entry) made from ``old``'s
    by what changed, and the entries that differ from ``old``'s (sorted; None: a table built
    from nothing, every entry new).

    ``faces_hold``: ``open_faces`` answers as it did for ``old`` (the same GPU slots): the items
    ``old`` held keep their faces and only new items are asked (else every item is;
    ``known_faces`` as for :func:`build_page_table`).

    Why: a kept cut changes by a few nodes a frame, and building its table from nothing cost
    ~3.5 ms of a 15 774-brick cut's frame (most of it finding each item's node from its world box
    and its faces), then a compare of the whole table for the GPU's sub-write. Items ``old``
    held (the same key and corner) keep their node, entry position and faces; only the new
    items' are found. While every level's box (and each data level's ``d0``: the shader's float32
    positions are relative to them, so the image is a fresh table's only with the same ones) is
    the same, only the entries of nodes that left, came or changed (their open faces) and of their
    ancestors are written: each ancestor keeps a count of the drawn nodes under it, REFINED while
    it is above zero. Another box builds the table from nothing.
    """
    def fresh():
        return build_page_table(items, pyramid, open_faces, known_faces), None

    if old is None or old.drawn is None or old.refs is None:
        return fresh()
    arr = _item_arrays(items)
    keys = item_keys(arr)
    if keys is None:
        return fresh()
    o = np.argsort(keys, kind="stable")
    keys, lo = keys[o], arr.lo[o]
    if len(keys) > 1 and np.any(keys[1:] == keys[:-1]):  # (two items of one key: what build does)
        return fresh()
    was = old.drawn
    k = np.minimum(np.searchsorted(was.keys, keys), max(len(was.keys) - 1, 0))
    held = np.zeros(len(keys), dtype=bool)
    if len(was.keys):
        held = (was.keys[k] == keys) & np.all(was.lo[k] == lo, axis=1)
    new = ~held
    rows = arr.rows[o]
    data_lv, data_idx = rows[:, 0], rows[:, 1:]
    node_lv = np.empty(len(keys), dtype=np.int64)
    node_idx = np.empty((len(keys), 3), dtype=np.int64)
    node_lv[held], node_idx[held] = was.node_lv[k[held]], was.node_idx[k[held]]
    if new.any():
        w = o[new]
        nodes = _node_arrays(DrawItems(arr.rows[w], arr.lo[w], arr.hi[w], arr.span[w]), pyramid)
        if nodes is None:
            return None, None
        node_lv[new], node_idx[new] = nodes
    c0, size, base, d0 = _layout(node_lv, node_idx, data_lv, data_idx, pyramid.num_levels)
    if not (np.array_equal(c0, old.c0) and np.array_equal(size, old.size) and np.array_equal(d0, old.d0)):
        return fresh()
    # faces: the held items' where the slots are the same, the others known or asked
    of = np.zeros((len(keys), 3, 2), dtype=bool)
    todo = np.ones(len(keys), dtype=bool)
    if faces_hold:
        of[held] = was.faces[k[held]]
        todo = new.copy()
    fkeys = face_keys(data_lv, data_idx, node_lv) if open_faces is not None else None
    _known(of, todo, fkeys, known_faces)
    if open_faces is not None and todo.any():
        _faces_of(pyramid, open_faces, node_lv, data_lv, data_idx, of, todo)
    values = _values(data_lv, of)
    pos = np.empty(len(keys), dtype=np.int64)
    pos[held] = was.pos[k[held]]
    pos[new] = _flat(c0, size, base, node_lv[new], node_idx[new])
    kept_old = np.zeros(len(was.keys), dtype=bool)
    kept_old[k[held]] = True
    gone = ~kept_old
    revalued = held & (values != was.values[k])
    refs = old.refs.copy()
    up = _ancestors(c0, size, base, node_lv[new], node_idx[new])
    down = _ancestors(c0, size, base, was.node_lv[gone], was.node_idx[gone])
    for cells, sign in ((up, 1), (down, -1)):
        if len(cells):
            u, c = np.unique(cells, return_counts=True)
            refs[u] += sign * c.astype(np.int32)
    touched = np.unique(np.concatenate([was.pos[gone], pos[new], pos[revalued], up, down]))
    entries = old.entries.copy()
    entries[touched] = np.where(refs[touched] > 0, np.uint32(REFINED), np.uint32(EMPTY))
    entries[pos[new]] = values[new]
    entries[pos[revalued]] = values[revalued]
    changed = touched[entries[touched] != old.entries[touched]]
    faces = _sorted_faces(fkeys, of)
    drawn = DrawnNodes(keys, lo, node_lv, node_idx, pos, values, of)
    return PageTable(entries, base, c0, size, d0, faces, drawn, refs), changed
