"""A page table updated by what changed (clipvol.scene.page_table.update_page_table) against a table
derived by brute force from the draw items' world boxes.

The reference (numpy, none of the page table's code): every cell of every level is compared with
every item's box. A cell whose box is an item's box is DRAWN from that item's level, with the faces
open where every brick of the item on that face is open (asked brick by brick); a cell holding an
item's box strictly inside it is REFINED; any other cell is EMPTY. Along random camera paths, with
bricks evicted and arriving (fallback items drawn from a coarser brick, other open faces), each
updated table must hold exactly that, equal the table built from nothing, and name as changed
exactly the entries that differ from the table before.
"""

from __future__ import annotations

import numpy as np

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.camera import Camera
from clipvol.scene.page_table import DRAWN, EMPTY, REFINED, build_page_table, update_page_table
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import DrawItems, merge_items, select

PYR = Pyramid.build((70, 64, 90), (8, 8, 8))  # odd sizes: clipped edge nodes


class Residency:
    """Every brick resident but those of ``missing`` (level, z, y, x); all in the window."""

    def __init__(self, missing=()) -> None:
        self.missing = set(missing)

    def in_window_mask(self, level, idx):
        return np.ones(len(np.asarray(idx).reshape(-1, 3)), dtype=bool)

    def resident_mask(self, level, idx):
        idx = np.asarray(idx).reshape(-1, 3)
        return np.array([(level, *map(int, b)) not in self.missing for b in idx], dtype=bool)


def reference(items, open_bits) -> dict:
    """``{level: (kind, data level, faces bits)}`` per cell of the level's whole grid, by brute force."""
    arr = DrawItems.from_items(items)
    vlo, _ = PYR.volume_box()
    out = {}
    for L in range(PYR.num_levels):
        g = PYR.grid(L)
        cells = np.argwhere(np.ones(g, dtype=bool))  # (z, y, x)
        clo, chi = PYR.node_box(L, cells)  # world (x, y, z)
        tol = 1e-6
        same = np.all(np.abs(clo[:, None] - arr.lo[None]) <= tol, axis=2) & \
            np.all(np.abs(chi[:, None] - arr.hi[None]) <= tol, axis=2)
        inside = np.all(clo[:, None] <= arr.lo[None] + tol, axis=2) & np.all(arr.hi[None] <= chi[:, None] + tol, axis=2)
        kind = np.where(same.any(axis=1), DRAWN, np.where((inside & ~same).any(axis=1), REFINED, EMPTY))
        data = np.zeros(len(cells), dtype=np.int64)
        faces = np.zeros(len(cells), dtype=np.int64)
        for c in np.nonzero(kind == DRAWN)[0]:
            i = int(np.nonzero(same[c])[0][0])
            Ld, first, span = int(arr.rows[i, 0]), arr.rows[i, 1:], int(arr.span[i])
            data[c] = Ld
            gd = np.array(PYR.grid(Ld))
            count = np.minimum(first + span, gd) - first
            bricks = first + np.argwhere(np.ones(tuple(count), dtype=bool))
            bits = 0
            for k, axis in enumerate((2, 1, 0)):  # x, y, z: lo then hi
                for side, edge in ((0, first[axis]), (1, first[axis] + count[axis] - 1)):
                    on = bricks[bricks[:, axis] == edge]
                    if all(open_bits[Ld][tuple(b)][axis, side] for b in on):
                        bits |= 1 << (2 * k + side)
            faces[c] = bits
        out[L] = (cells, kind, data, faces)
    return out


def assert_table_is(table, items, open_bits) -> None:
    for L, (cells, kind, data, faces) in reference(items, open_bits).items():
        e = table.lookup(L, cells).astype(np.int64)
        np.testing.assert_array_equal(e & 3, kind, err_msg=f"level {L}: kinds")
        drawn = kind == DRAWN
        np.testing.assert_array_equal((e >> 2)[drawn] & 31, data[drawn], err_msg=f"level {L}: data levels")
        np.testing.assert_array_equal((e >> 8)[drawn], faces[drawn], err_msg=f"level {L}: open faces")


def camera(rng, k: int) -> Camera:
    """A slow orbit at a distance that keeps most of the volume in view, the distance wandering
    (the levels' boundaries move through the cut)."""
    th = np.radians(3.0 * k)
    d = 95.0 + 6.0 * np.sin(0.4 * k) + rng.normal() * 1.0
    eye = (45.0 + d * np.sin(th), 32.0 - 0.4 * d, 35.0 - d * np.cos(th))
    return Camera.perspective(eye, (45.0, 32.0, 35.0), size=(48, 40), fov_y=55)


def test_updated_table_equals_the_brute_force_table_along_random_paths():
    rng = np.random.default_rng(7)
    bits = {L: rng.random(tuple(PYR.grid(L)) + (3, 2)) < 0.7 for L in range(PYR.num_levels)}
    windows = [tuple(PYR.grid(L)) for L in range(PYR.num_levels)]

    def open_faces(level, idx):
        idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
        return bits[level][idx[:, 0], idx[:, 1], idx[:, 2]]

    params = RenderParams(policy="projected-size", lod_threshold=2.0)
    prev, in_place, rebuilt, changed_total = None, 0, 0, 0
    missing: set = set()
    for k in range(40):
        faces_hold = True
        if k % 7 == 3:  # bricks evicted: fallback items, drawn from a coarser brick
            g0 = PYR.grid(0)
            missing = {(0, *map(int, rng.integers(0, g0))) for _ in range(6)}
        elif k % 7 == 5:  # they arrive again; other slots: other open faces
            missing = set()
            bits = {L: rng.random(tuple(PYR.grid(L)) + (3, 2)) < 0.7 for L in range(PYR.num_levels)}
            faces_hold = False
        sel = select(PYR, camera(rng, k), params, residency=Residency(missing))
        items = sel.items if k == 20 else merge_items(sel.items, PYR, windows)
        table, changed = update_page_table(prev, items, PYR, open_faces,
                                           known_faces=prev.faces if prev is not None and faces_hold else None,
                                           faces_hold=faces_hold)
        assert_table_is(table, items, bits)
        fresh = build_page_table(items, PYR, open_faces)
        for name in ("entries", "base", "c0", "size", "d0"):
            np.testing.assert_array_equal(getattr(table, name), getattr(fresh, name), err_msg=name)
        if changed is None:
            rebuilt += 1
        else:  # exactly the entries that differ from the table before
            np.testing.assert_array_equal(changed, np.nonzero(table.entries != prev.entries)[0])
            in_place += 1
            changed_total += len(changed)
        prev = table
    assert in_place >= 10 and rebuilt >= 2 and changed_total >= 30, (in_place, rebuilt, changed_total)


def test_an_update_that_takes_nodes_away_and_back_restores_the_table():
    """Items removed (a hole in the cut: REFINED ancestors must turn EMPTY where nothing is left
    under them) and put back: each step equals the brute-force table."""
    cam = Camera.perspective((45.0, -10.0, -60.0), (45.0, 32.0, 35.0), size=(48, 40), fov_y=55)
    sel = select(PYR, cam, RenderParams(policy="fixed", level=0), residency=Residency())
    arr = DrawItems.from_items(sel.items)
    g = np.array(PYR.grid(0))
    inner = np.nonzero(np.all((arr.rows[:, 1:] > 0) & (arr.rows[:, 1:] < g - 1), axis=1))[0]
    assert len(inner) > 16
    parent = arr.rows[inner[len(inner) // 2], 1:] >> 1  # every child of one level-1 node inside the box
    hole = ~np.all((arr.rows[:, 1:] >> 1) == parent, axis=1)
    hole[inner[:4]] = False  # and a few more level-0 items: the layout holds
    holed = DrawItems(arr.rows[hole], arr.lo[hole], arr.hi[hole], arr.span[hole])
    bits = {L: np.ones(tuple(PYR.grid(L)) + (3, 2), dtype=bool) for L in range(PYR.num_levels)}
    of = lambda level, idx: bits[level][tuple(np.asarray(idx).reshape(-1, 3).T)]  # noqa: E731
    first = build_page_table(arr, PYR, of)
    table, changed = update_page_table(first, holed, PYR, of, known_faces=first.faces, faces_hold=True)
    assert changed is not None and len(changed) >= 8
    assert_table_is(table, holed, bits)
    assert table.lookup(1, parent[None])[0] == EMPTY and first.lookup(1, parent[None])[0] == REFINED
    again, changed2 = update_page_table(table, arr, PYR, of, known_faces=table.faces, faces_hold=True)
    np.testing.assert_array_equal(again.entries, first.entries)
    np.testing.assert_array_equal(changed2, changed)
    np.testing.assert_array_equal(again.refs, first.refs)
