"""A cut on a time series (``SeriesSession``): no step's clip-texture reads a brick outside it - the
current step, the prefetched one and the steps loaded later - and a new cut reaches them all."""

from __future__ import annotations

import numpy as np
import pytest

from counting_loader import Counting

pytestmark = pytest.mark.gl


def test_every_step_leaves_the_bricks_outside_the_cut_unread(ctx, rng):
    from clipvol.app.timeseries import SeriesSession
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.scene.cut import cut_shape
    from clipvol.scene.params import RenderParams

    loaders = [Counting(NumpyLoader(rng.random((32, 32, 32)).astype(np.float32), brick=8)) for _ in range(3)]
    pyr = loaders[0].pyramid
    shape = cut_shape(pyr, None, crop_voxels=((0, 0, 0), (32, 32, 8)))  # x < 8: one column of bricks
    with SeriesSession(loaders, ctx, memory_budget="16MB", params=RenderParams(shape=shape), threads=1) as s:
        s.clip_texture.wait_until_idle(20)
        s.go_to(1)
        s.go_to(2)
        s.clip_texture.wait_until_idle(20)
        for ld in loaders:
            assert all(ix[2] <= 1 for L, ix in ld.reads if L == 0), sorted(ld.reads)[:5]  # x brick 0 (+ its neighbour)
        assert any(L == 0 for L, _ in loaders[2].reads)
        s.update(shape=None)  # the whole volume: the current step reads the rest
        s.clip_texture.wait_until_idle(20)
        assert {ix[2] for L, ix in loaders[2].reads if L == 0} == {0, 1, 2, 3}
