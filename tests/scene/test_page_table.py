"""The page table of a cut (clipvol.scene.page_table) against brute-force box containment.

The reference: for a random point, the one draw item whose world box holds it (numpy, from the
items' boxes alone). The page table, walked from the coarsest level down as the shader walks it,
must name the same node and data brick - or EMPTY where no item covers the point.
"""

from __future__ import annotations

import numpy as np

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.camera import Camera
from clipvol.scene.page_table import DRAWN, EMPTY, REFINED, build_page_table, item_nodes
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import select


def probes(table, pyr, items, rng, n):
    """For ``n`` random points of the volume: the indices of the items whose boxes hold the point
    (the reference) and the table's walk there, for points some item holds; a point no item
    holds must walk to EMPTY."""
    lo = np.array([it.lo for it in items])
    hi = np.array([it.hi for it in items])
    vlo, vhi = pyr.volume_box()
    for p in vlo + rng.random((n, 3)) * (vhi - vlo):
        inside = np.nonzero(np.all((lo <= p) & (p < hi), axis=1))[0]
        found = walk(table, pyr, p)
        if len(inside) == 0:
            assert found[0] == EMPTY
            continue
        yield inside, found


class HalfResident:
    """Residency: level 0 bricks with an even x index and every coarser brick are resident, so the
    cut holds fallback items (ancestors drawn over the missing children's boxes)."""

    def in_window_mask(self, level, idx):
        return np.ones(len(np.asarray(idx).reshape(-1, 3)), dtype=bool)

    def resident_mask(self, level, idx):
        idx = np.asarray(idx).reshape(-1, 3)
        return np.ones(len(idx), dtype=bool) if level > 0 else (idx[:, 2] % 2 == 0)


def walk(table, pyr, p):
    """The shader's lookup, in numpy: ``(kind, node level, node cell (z, y, x), data level)``."""
    vlo, _ = pyr.volume_box()
    sp = np.array(pyr.spacing[::-1])
    B = np.array(pyr.brick_shape[::-1], dtype=np.float64)
    L = pyr.num_levels - 1
    while True:
        cell = np.floor((p - vlo) / (B * 2.0**L * sp)).astype(np.int64)[::-1]
        e = int(table.lookup(L, cell[None])[0])
        if (e & 3) == REFINED and L > 0:
            L -= 1
            continue
        return e & 3, L, tuple(int(c) for c in cell), (e >> 2) & 31


def test_page_table_names_the_item_holding_each_point():
    pyr = Pyramid.build((70, 64, 90), (8, 8, 8))  # odd sizes: clipped edge nodes
    cam = Camera.perspective((30.0, 20.0, -25.0), (45.0, 32.0, 35.0), size=(48, 40), fov_y=50)
    sel = select(pyr, cam, RenderParams(lod_threshold=3.0), residency=HalfResident())
    items = sel.items
    assert len({it.level for it in items}) >= 2 and sel.counts["fallback"] > 0
    table = build_page_table(items, pyr)
    assert table is not None
    nodes = item_nodes(items, pyr)
    covered = 0
    for inside, (kind, L, cell, Ld) in probes(table, pyr, items, np.random.default_rng(1), 3000):
        assert len(inside) == 1  # the items tile what they cover
        it = items[inside[0]]
        covered += 1
        assert kind == DRAWN
        assert (L, cell) == nodes[inside[0]]
        assert Ld == it.level
        assert tuple(np.array(cell) >> (Ld - L)) == tuple(it.index)  # the data brick the item samples
    assert covered > 500


class AllResident(HalfResident):
    def resident_mask(self, level, idx):
        return np.ones(len(np.asarray(idx).reshape(-1, 3)), dtype=bool)


def test_merged_items_are_nodes_over_blocks_of_bricks():
    """merge_items' boxes over complete sibling sets are table nodes of the coarser level whose data
    is the block of finer bricks under them; a block face is open only where every brick on it is
    (reference: the items' boxes and a per-brick loop over a random open-face answer)."""
    from clipvol.scene.selection import merge_items

    pyr = Pyramid.build((70, 64, 90), (8, 8, 8))
    cam = Camera.perspective((30.0, 20.0, -25.0), (45.0, 32.0, 35.0), size=(48, 40), fov_y=50)
    sel = select(pyr, cam, RenderParams(policy="fixed", level=0), residency=AllResident())
    windows = [tuple(pyr.grid(L)) for L in range(pyr.num_levels)]
    items = merge_items(list(sel.items), pyr, windows)
    assert any(it.span > 1 for it in items) and len(items) < len(sel.items)
    rng = np.random.default_rng(3)
    open_bits = {}  # a random open/closed answer per (brick, axis, side), fixed for the test

    def open_faces(level, idx):
        idx = np.asarray(idx).reshape(-1, 3)
        out = np.zeros((len(idx), 3, 2), dtype=bool)
        for n, b in enumerate(idx):
            key = (level, tuple(int(v) for v in b))
            if key not in open_bits:
                open_bits[key] = rng.random((3, 2)) < 0.8
            out[n] = open_bits[key]
        return out

    table = build_page_table(items, pyr, open_faces)
    assert table is not None
    seen_merged = 0
    for inside, (kind, L, cell, Ld) in probes(table, pyr, items, rng, 2000):
        it = items[inside[0]]
        assert kind == DRAWN and Ld == it.level
        assert 2 ** (L - Ld) == it.span  # the node over the block
        assert tuple(np.array(cell) << (L - Ld)) == tuple(it.index)  # the block's first brick
        if it.span > 1:
            seen_merged += 1
        # faces: open where open for every brick of the block on that face (loops, per brick)
        e = int(table.lookup(L, np.array(cell)[None])[0])
        grid = pyr.grid(Ld)
        first = it.index
        stop = [min(f + it.span, g) for f, g in zip(first, grid)]
        for k, axis in enumerate((2, 1, 0)):
            for side in (0, 1):
                want = True
                for bz in range(first[0], stop[0]):
                    for by in range(first[1], stop[1]):
                        for bx in range(first[2], stop[2]):
                            b = (bz, by, bx)
                            on_face = b[axis] == (first[axis] if side == 0 else stop[axis] - 1)
                            if on_face and not open_bits[(Ld, b)][axis, side]:
                                want = False
                got = bool((e >> (8 + 2 * k + side)) & 1)
                assert got == want, (it, axis, side)
    assert seen_merged > 100


def test_a_block_not_on_its_node_is_refused():
    from clipvol.scene.selection import DrawItem

    pyr = Pyramid.build((32, 32, 32), (8, 8, 8))
    lo, hi = pyr.node_box(1, (0, 0, 0))
    shifted = [DrawItem(0, (0, 0, 1), tuple(lo), tuple(hi), 2)]  # its bricks do not start at the node
    assert build_page_table(shifted, pyr) is None
    assert build_page_table([DrawItem(0, (0, 0, 0), tuple(lo), tuple(hi), 3)], pyr) is None  # span not 2^k


def test_block_open_faces_is_open_only_where_every_brick_on_the_face_is():
    """Against a plain loop over each block's face bricks, with a random per-brick answer."""
    import numpy as np

    from clipvol.scene.page_table import block_open_faces

    rng = np.random.default_rng(3)
    per_brick = rng.random((12, 10, 14, 3, 2)) < 0.9  # mostly open: whole faces open often enough
    calls = []

    def open_faces(level, idx):
        calls.append(len(idx))
        return per_brick[idx[:, 0], idx[:, 1], idx[:, 2]]

    first = np.stack([rng.integers(0, 8, 40), rng.integers(0, 6, 40), rng.integers(0, 10, 40)], axis=1)
    count = rng.integers(1, 5, (40, 3))
    got = block_open_faces(open_faces, 0, first, count)
    assert len(calls) == 1  # one question for all blocks
    seen_open = 0
    for (z, y, x), (cz, cy, cx), g in zip(first, count, got):
        blk = per_brick[z:z + cz, y:y + cy, x:x + cx]
        want = np.array([[blk[0, :, :, 0, 0].all(), blk[-1, :, :, 0, 1].all()],
                         [blk[:, 0, :, 1, 0].all(), blk[:, -1, :, 1, 1].all()],
                         [blk[:, :, 0, 2, 0].all(), blk[:, :, -1, 2, 1].all()]])
        np.testing.assert_array_equal(g, want)
        seen_open += int(want.sum())
    assert 0 < seen_open < got.size  # both answers occur
    assert block_open_faces(open_faces, 0, np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3, 2)


def test_block_cells_lists_every_cell_of_every_block_in_c_order(rng):
    from clipvol.scene.page_table import block_cells

    count = rng.integers(1, 4, size=(9, 3))
    count[3] = (1, 1, 1)
    block, local = block_cells(count)
    want_block, want_local = [], []
    for b, (cz, cy, cx) in enumerate(count):  # the plain loop
        for z in range(cz):
            for y in range(cy):
                for x in range(cx):
                    want_block.append(b)
                    want_local.append((z, y, x))
    np.testing.assert_array_equal(block, want_block)
    np.testing.assert_array_equal(local, np.array(want_local).reshape(-1, 3))
    b0, l0 = block_cells(np.zeros((0, 3), np.int64))
    assert len(b0) == 0 and l0.shape == (0, 3)


def test_known_faces_of_an_earlier_table_give_the_table_built_afresh():
    """A table built with ``known_faces`` of the frame before (a turned camera: most merged items
    kept) equals the table built asking every face, and asks only about items the earlier cut did
    not hold (reference: the same build without ``known_faces``, and the earlier items' keys)."""
    from clipvol.scene.selection import merge_items

    pyr = Pyramid.build((70, 64, 90), (8, 8, 8))
    windows = [tuple(pyr.grid(L)) for L in range(pyr.num_levels)]
    params = RenderParams(policy="projected-size", lod_threshold=2.0)
    rng = np.random.default_rng(5)
    bits = {L: rng.random(tuple(pyr.grid(L)) + (3, 2)) < 0.7 for L in range(pyr.num_levels)}
    asked = []

    def open_faces(level, idx):
        idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
        asked.extend((level, *map(int, b)) for b in idx)
        return bits[level][idx[:, 0], idx[:, 1], idx[:, 2]]

    def cut(deg):
        th = np.radians(deg)
        eye = (45.0 + 80.0 * np.sin(th), 32.0 - 30.0, 35.0 - 80.0 * np.cos(th))
        cam = Camera.perspective(eye, (45.0, 32.0, 35.0), size=(48, 40), fov_y=50)
        return merge_items(select(pyr, cam, params, residency=AllResident()).items, pyr, windows)

    a, b = cut(0.0), cut(6.0)
    # the same cut unmerged: single bricks where the merged one held blocks starting at them
    plain = [it for it in select(pyr, Camera.perspective((45.0, 2.0, -45.0), (45.0, 32.0, 35.0), size=(48, 40),
                                                         fov_y=50), params, residency=AllResident()).items]
    first = build_page_table(a, pyr, open_faces)
    np.testing.assert_array_equal(build_page_table(plain, pyr, open_faces, known_faces=first.faces).entries,
                                  build_page_table(plain, pyr, open_faces).entries)
    keys = lambda items: {(it.level, tuple(it.index), it.span) for it in items}  # noqa: E731
    assert keys(a) & keys(b) and keys(b) - keys(a) and len({it.level for it in b}) > 1
    first = build_page_table(a, pyr, open_faces)
    asked.clear()
    again = build_page_table(b, pyr, open_faces, known_faces=first.faces)
    asked_again = set(asked)
    fresh = build_page_table(b, pyr, open_faces)
    np.testing.assert_array_equal(again.entries, fresh.entries)
    for name in ("base", "c0", "size", "d0"):
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name))
    new = [it for it in b if (it.level, tuple(it.index), it.span) not in keys(a)]
    bricks_new = set()  # every brick of every new item (a block: its bricks inside the grid)
    for it in new:
        count = [min(it.span, g - i) for i, g in zip(it.index, pyr.grid(it.level))]
        bricks_new |= {(it.level, *(int(v) + d for v, d in zip(it.index, off))) for off in np.ndindex(*count)}
    assert asked_again and asked_again <= bricks_new  # only what the earlier cut did not hold
