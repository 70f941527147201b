"""``ClipTexture(outside=...)`` / ``set_outside``: bricks outside a cut are never read, and a new cut
reads the bricks it brings back (counted at the loader, checked against the source array)."""

from __future__ import annotations

import numpy as np

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import BrickState, ClipTexture

from counting_loader import Counting


def test_outside_bricks_are_not_read_until_the_cut_lets_them_in(rng):
    vol = rng.random((32, 32, 32)).astype(np.float32)
    loader = Counting(NumpyLoader(vol, brick=8))
    left = lambda level, keys: keys[:, 2] >= 2 if level == 0 else np.zeros(len(keys), bool)  # noqa: E731
    with ClipTexture(loader, "64MB", threads=2, outside=left) as clip:
        assert clip.wait_until_idle(20)
        read0 = {ix for L, ix in loader.reads if L == 0}
        assert read0 == {(z, y, x) for z in range(4) for y in range(4) for x in range(2)}
        assert clip.set_outside(None) == 32  # the 32 bricks of x >= 2 come back and are read
        assert clip.wait_until_idle(20)
        assert {ix for L, ix in loader.reads if L == 0} == set(np.ndindex(4, 4, 4))
        for ix in [(0, 0, 3), (3, 2, 2)]:
            z, y, x = (8 * v for v in ix)
            assert clip.state(0, ix) == BrickState.RESIDENT
            assert np.array_equal(clip.get_brick(0, ix), vol[z:z + 8, y:y + 8, x:x + 8])
        n = len(loader.reads)
        assert clip.set_outside(left) == 0  # resident bricks stay; nothing new is read
        assert clip.wait_until_idle(20) and len(loader.reads) == n
