"""The GPU cache's textures follow the slice's region: a full-resolution slab wider than the cube
texture windows of the budget is drawn whole at level 0 (equal to numpy's slice), within the budget,
and a view without a region gets its cube windows back."""

from __future__ import annotations

import numpy as np

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.region import Region
from clipvol.render.gpu_cache import GpuBrickCache
from clipvol.render.slice_action import SliceAction
from clipvol.scene.plane import Plane


def test_a_slab_wider_than_the_cube_windows_is_drawn_whole_at_level0(gl, rng):
    vol = rng.integers(0, 256, size=(32, 128, 128), dtype=np.uint8)
    ld = NumpyLoader(vol, brick=8)
    pyr = ld.pyramid
    budget = 400 * pyr.brick_nbytes  # cube windows of 7 bricks a side: level 0 is 16 x 16 bricks
    pl = Plane.axis(pyr, "axial", 12)
    with ClipTexture(ld, "64MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
            SliceAction(gl, ct, level=0, texture_budget=budget) as sa:
        assert max(sa.cache.cube_windows[0]) < 16  # the control: a cube cannot hold the slab
        _, v = sa.render(pl, wait=True, timeout=60, return_values=True)
        st = sa.last_stats
        assert st.converged and set(st.tiles_per_level) == {0}
        np.testing.assert_array_equal(v, vol[12].astype(np.float32))
        assert sa.cache.windows[0][1:] == (16, 16)
        assert sa.cache.texture_bytes <= budget
        gl_bytes = sum(t.width * t.height * t.depth for t in sa.cache.textures if t is not None)
        assert gl_bytes == sa.cache.texture_bytes  # uint8: one byte a texel


def test_no_region_restores_the_cube_windows(gl, rng):
    vol = rng.integers(0, 256, size=(32, 128, 128), dtype=np.uint8)
    pyr = NumpyLoader(vol, brick=8).pyramid
    cache = GpuBrickCache(gl, pyr, 400 * pyr.brick_nbytes)
    try:
        cube = list(cache.windows)
        slab = np.argwhere(np.ones((1, 16, 16), dtype=bool)) + np.array([1, 0, 0])
        empty = np.zeros((0, 3), dtype=np.int64)
        region = Region((64.0, 64.0, 12.0), (slab, empty, empty, empty, np.zeros((1, 3), dtype=np.int64)))
        assert cache.follow_region(region)
        assert cache.windows != cube and cache.texture_bytes <= 400 * pyr.brick_nbytes
        assert cache.follow_region(region) == []  # the same region reallocates nothing
        assert cache.follow_region(None) and cache.windows == cube
        for t, w in zip(cache.textures, cube):
            assert (t.depth, t.height, t.width) == tuple(8 * v for v in w)
    finally:
        cache.release()
