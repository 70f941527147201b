"""Regions of interest: the clip-texture pages only the bricks an action hands it, nearest first,
within its slots; window fitting checked against brute force."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.errors import ParameterError
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import BrickState, ClipTexture
from clipvol.paging.region import Region
from clipvol.paging.toroidal import region_window


class Recording:
    """A loader that records every brick it is asked for."""

    def __init__(self, shape=(64, 64, 64), brick=8):
        vol = np.arange(math.prod(shape), dtype=np.float32).reshape(shape)
        self.base = NumpyLoader(vol, brick=brick)
        self.pyramid = self.base.pyramid
        self.calls: list = []
        self._lock = threading.Lock()

    def read_brick(self, level, index):
        with self._lock:
            self.calls.append((int(level), tuple(int(i) for i in index)))
        return self.base.read_brick(level, index)


def _keys(arr) -> set:
    return {tuple(int(v) for v in k) for k in np.asarray(arr).reshape(-1, 3)}


def _region(pyr, per_level: dict, center) -> Region:
    return Region(center, tuple(np.array(per_level.get(L, []), dtype=np.int64).reshape(-1, 3)
                                for L in range(pyr.num_levels)))


def test_only_the_region_is_read_and_all_of_it():
    ld = Recording()
    pyr = ld.pyramid  # grid 8^3 at level 0
    slab = [(3, y, x) for y in range(8) for x in range(8)]  # one layer of level 0
    region = _region(pyr, {0: slab, 3: [(0, 0, 0)]}, (31.5, 31.5, 27.5))
    with ClipTexture(ld, "2MB", 1, region=region) as ct:  # 2 MB: 128 slots of 16 KiB, level 0 windowed
        assert ct.wait_until_idle(30)
        assert set(ld.calls) == {(0, k) for k in slab} | {(3, (0, 0, 0))}
        assert len(ld.calls) == len(set(ld.calls))  # none twice
        start, stop = ct.window(0)
        assert all(b - a <= g for a, b, g in zip(start, stop, pyr.grid(0)))
        assert ct.stats.pool_bytes <= ct.memory_budget
        assert _keys([k for L, k in ct.resident_bricks() if L == 0]) == set(slab)


def test_region_larger_than_the_slots_reads_the_part_nearest_the_centre():
    ld = Recording()
    pyr = ld.pyramid
    everything = [tuple(k) for k in np.ndindex(pyr.grid(0))]  # 512 bricks, far more than the slots
    center = (10.0, 50.0, 20.0)
    with ClipTexture(ld, "2MB", 1, region=_region(pyr, {0: everything}, center)) as ct:
        assert ct.wait_until_idle(30)
        got = [k for L, k in ld.calls if L == 0]
        cap = len(ct._levels[0].state)
        assert 0 < len(got) <= cap
        assert pyr.world_to_brick(0, center) in got
        # read nearest first: distances from the centre to the bricks' boxes never decrease (1 thread)
        c = np.array(center)
        lo = np.array([[k[2], k[1], k[0]] for k in got], float) * 8 - 0.5
        d = np.linalg.norm(np.maximum(np.maximum(lo - c, c - (lo + 8)), 0), axis=1)
        assert np.all(np.diff(d) >= -1e-9)


def test_a_brick_outside_the_region_is_read_when_a_frame_waits_for_it():
    ld = Recording()
    pyr = ld.pyramid
    region = _region(pyr, {0: [(3, 3, 3)]}, (27.5, 27.5, 27.5))
    with ClipTexture(ld, "8MB", 1, region=region) as ct:
        assert ct.wait_until_idle(30)
        assert ld.calls == [(0, (3, 3, 3))]
        assert ct.state(0, (3, 3, 4)) == BrickState.ABSENT and ct.in_window_mask(0, np.array([(3, 3, 4)]))[0]
        assert ct.wait_for([(0, (3, 3, 4))], timeout=30)
        assert ct.state(0, (3, 3, 4)) == BrickState.RESIDENT
        assert ld.calls == [(0, (3, 3, 3)), (0, (3, 3, 4))]


def test_empty_region_reads_nothing_and_none_restores_cubes():
    ld = Recording((32, 32, 32), 8)
    pyr = ld.pyramid
    with ClipTexture(ld, "8MB", 1, region=Region.empty(pyr.num_levels)) as ct:
        assert ct.wait_until_idle(30)
        assert ld.calls == []
        ct.set_region(None)
        assert ct.wait_until_idle(30)
        assert set(ld.calls) == {(L, tuple(k)) for L in range(pyr.num_levels) for k in np.ndindex(pyr.grid(L))}


def test_bad_regions_are_named():
    ld = Recording((32, 32, 32), 8)
    with ClipTexture(ld, "8MB", 1) as ct:
        with pytest.raises(ParameterError, match="region"):
            ct.set_region(Region((0, 0, 0), (None,)))
        with pytest.raises(ParameterError, match="level 0"):
            ct.set_region(_region(ld.pyramid, {0: [(4, 0, 0)]}, (0, 0, 0)))
        with pytest.raises(ParameterError, match="region"):
            ct.set_region("slab")
    with pytest.raises(ParameterError, match="center"):
        Region((0, float("nan"), 0), ())


@settings(max_examples=200, deadline=None)
@given(grid=st.tuples(*[st.integers(1, 12)] * 3), cube=st.integers(2, 6), lo=st.tuples(*[st.integers(0, 11)] * 3),
       ext=st.tuples(*[st.integers(1, 12)] * 3), c=st.tuples(*[st.integers(0, 11)] * 3))
def test_region_window_fits_the_slots_and_holds_what_it_can(grid, cube, lo, ext, c):
    lo = tuple(min(a, g - 1) for a, g in zip(lo, grid))
    hi = tuple(min(a + e, g) for a, e, g in zip(lo, ext, grid))
    cube3 = tuple(min(cube, g) for g in grid)
    cap = math.prod(cube3)  # the slots a cube window of the level has
    center = tuple(min(max(v, a), b - 1) for v, a, b in zip(c, lo, hi))  # a brick of the region
    start, stop = region_window(grid, cube3, cap, lo, hi, center)
    shape = [b - a for a, b in zip(start, stop)]
    assert all(0 <= a < b <= g for a, b, g in zip(start, stop, grid))
    assert math.prod(shape) <= cap
    if math.prod([b - a for a, b in zip(lo, hi)]) <= cap:
        # a region that fits the slots is held whole
        assert all(a <= l and h <= b for a, b, l, h in zip(start, stop, lo, hi))
    else:
        # else the window holds the centre's brick and reaches no further than the region where it is short
        assert all(a <= v < b for a, b, v in zip(start, stop, center))


def test_random_regions_keep_every_resident_brick_exact_and_the_pool_in_budget():
    ld = Recording((48, 64, 80), 8)
    pyr = ld.pyramid
    rng = np.random.default_rng(5)
    # 400 kB: 195 slots; level 0 windowed in 64 slots (a cube of 4), the region boxes up to 5 a side
    with ClipTexture(ld, 400_000, 2) as ct:
        assert ct.whole_levels == (4, 3, 2, 1)
        for step in range(25):
            if step % 6 == 5:
                region = None
            else:
                per = {}
                for L in range(pyr.num_levels):
                    g = np.array(pyr.grid(L))
                    lo = rng.integers(0, g)
                    hi = np.minimum(lo + rng.integers(1, 6, 3), g)
                    box = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi)], indexing="ij"), -1)
                    per[L] = box.reshape(-1, 3)
                c = rng.uniform(0, 1, 3) * (np.array(pyr.shape[::-1]) - 1)
                region = _region(pyr, per, tuple(c))
            ct.set_region(region)
            assert ct.wait_until_idle(30)
            assert ct.stats.pool_bytes <= ct.memory_budget
            for L, idx in ct.resident_bricks():
                got = ct.get_brick(L, idx)
                assert got is not None
                np.testing.assert_array_equal(got, ld.base.read_brick(L, idx), err_msg=f"step {step} {L} {idx}")
            if region is not None:
                for L, b in enumerate(region.bricks):
                    # every region brick its window holds was read
                    held = b[ct.in_window_mask(L, b)]
                    assert ct.resident_mask(L, held).all()
