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
    lo = np.array([it.lo for it in items])
    hi = np.array([it.hi for it in items])
    rng = np.random.default_rng(1)
    vlo, vhi = pyr.volume_box()
    pts = vlo + rng.random((3000, 3)) * (vhi - vlo)
    nodes = item_nodes(items, pyr)
    covered = 0
    for p in pts:
        inside = np.nonzero(np.all((lo <= p) & (p < hi), axis=1))[0]
        kind, L, cell, Ld = walk(table, pyr, p)
        if len(inside) == 0:
            assert kind == EMPTY
            continue
        assert len(inside) == 1  # the items tile what they cover
        it = items[inside[0]]
        covered += 1
        assert kind == DRAWN
        assert (L, cell) == nodes[inside[0]]
        assert Ld == it.level
        assert tuple(np.array(cell) >> (Ld - L)) == tuple(it.index)  # the data brick the item samples
    assert covered > 500


def test_merged_items_are_refused():
    from clipvol.scene.selection import DrawItem

    pyr = Pyramid.build((32, 32, 32), (8, 8, 8))
    lo, hi = pyr.node_box(1, (0, 0, 0))
    merged = [DrawItem(0, (0, 0, 0), tuple(lo), tuple(hi), 2)]
    assert build_page_table(merged, pyr) is None
