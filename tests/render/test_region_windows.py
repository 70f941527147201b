"""Texture windows that follow a region: every region brick gets its own toroidal slot, the budget
holds, and a shape that already spans the region is kept (checked by enumerating slots)."""

from __future__ import annotations

import numpy as np

from clipvol.render.region_windows import region_extent, region_gpu_windows


def _box(lo, hi):
    """All brick indices (z, y, x) of the box [lo, hi)."""
    return np.argwhere(np.ones(tuple(h - l for l, h in zip(lo, hi)), dtype=bool)) + np.asarray(lo)


def _distinct_slots(bricks, w) -> bool:
    slots = {tuple(int(v) for v in np.asarray(b) % np.asarray(w)) for b in bricks}
    return len(slots) == len(bricks)


GRIDS = [(16, 16, 16), (8, 8, 8), (4, 4, 4), (2, 2, 2), (1, 1, 1)]
CUBE = [(6, 6, 6), (6, 6, 6), (4, 4, 4), (2, 2, 2), (1, 1, 1)]


def test_no_region_keeps_the_cubes():
    assert region_gpu_windows(GRIDS, CUBE, None, CUBE, 10_000) == CUBE
    assert region_gpu_windows(GRIDS, CUBE, [None] * 5, CUBE, 10_000) == CUBE


def test_a_slab_wider_than_the_cube_gets_every_brick_its_own_slot_within_the_budget():
    slots = sum(int(np.prod(c)) for c in CUBE)  # the cube windows' own budget: 505 bricks
    fine = _box((7, 4, 4), (9, 12, 12))  # 8 x 8 bricks of level 0, two layers thick
    mid = _box((3, 0, 0), (5, 8, 8))
    bricks = [fine, mid, _box((1, 0, 0), (3, 4, 4)), _box((0, 0, 0), (2, 2, 2)), _box((0, 0, 0), (1, 1, 1))]
    assert not _distinct_slots(fine, CUBE[0])  # the control: the 6-brick cube aliases
    w = region_gpu_windows(GRIDS, CUBE, bricks, CUBE, slots)
    assert sum(int(np.prod(s)) for s in w) <= slots
    for b, s in zip(bricks, w):
        assert _distinct_slots(b, s), (s, region_extent(b))
    assert w[0][0] >= 2 and w[0][1:] == (8, 8)  # thin across the plane, wide in it


def test_a_shape_that_spans_the_region_is_kept_while_the_plane_scrolls():
    fine = _box((7, 4, 4), (9, 12, 12))
    bricks = [fine, None, None, None, None]
    w1 = region_gpu_windows(GRIDS, CUBE, bricks, CUBE, 2000)
    moved = [fine + np.array([1, 0, 0]), None, None, None, None]
    assert region_gpu_windows(GRIDS, CUBE, moved, w1, 2000) == w1
    assert region_gpu_windows(GRIDS, CUBE, None, w1, 2000) == CUBE  # no region: back to cubes


def test_levels_with_an_empty_region_give_their_slots_first():
    empty = np.zeros((0, 3), dtype=np.int64)
    full = _box((7, 0, 0), (8, 16, 16))  # a full-resolution slab: 256 bricks of level 0
    bricks = [full, empty, empty, empty, _box((0, 0, 0), (1, 1, 1))]
    w = region_gpu_windows(GRIDS, CUBE, bricks, CUBE, 300)
    assert _distinct_slots(full, w[0])
    assert w[1] == w[2] == w[3] == (1, 1, 1)
    assert sum(int(np.prod(s)) for s in w) <= 300


def test_a_region_beyond_the_budget_shrinks_the_finest_level_and_holds_the_budget():
    full = _box((7, 0, 0), (8, 16, 16))
    bricks = [full, _box((3, 0, 0), (4, 8, 8)), None, None, None]
    w = region_gpu_windows(GRIDS, CUBE, bricks, CUBE, 200)
    assert sum(int(np.prod(s)) for s in w) <= 200
    assert _distinct_slots(bricks[1], w[1])  # the coarser level still whole
    assert not _distinct_slots(full, w[0])  # the finest gives way (drawn coarser there)
    assert w[2:] == CUBE[2:]


def test_texture_limits_per_axis_and_per_texture():
    full = _box((7, 0, 0), (8, 16, 16))
    w = region_gpu_windows(GRIDS, CUBE, [full, None, None, None, None], CUBE, 10_000, max_axis=(16, 10, 16))
    assert w[0][1] == 10
    w = region_gpu_windows(GRIDS, CUBE, [full, None, None, None, None], CUBE, 10_000, max_bricks=100)
    assert int(np.prod(w[0])) <= 100
