"""Odd axes: every level is drawn inside the level-0 world box ``[-s/2, (N - 1/2) s]`` (docs/format.md),
though the last coarse voxel of an odd axis has a cell that reaches past it.

Reference: the box itself, projected analytically (an orthographic axis-aligned view whose pixel
centres sit at known world positions).
"""

from __future__ import annotations

import numpy as np
import pytest
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl


def test_every_level_stays_inside_the_level0_box(ctx, draw_path):
    shape = (9, 11, 13)  # odd on every axis: levels 9x11x13 -> 5x6x7 -> 3x3x4 -> 2x2x2
    vol = np.ones(shape, np.float32)
    opaque = TransferFunction.from_points([(0.0, (1, 1, 1, 1)), (1.0, (1, 1, 1, 1))])
    loader = NumpyLoader(vol, brick=2, value_range=(0.0, 1.0))
    pyr = loader.pyramid
    assert pyr.num_levels >= 3
    px = 0.25  # world units per pixel; pixel centres at (i + 0.5) * px - 4
    size = (96, 96)
    cam = Camera.orthographic((12.0 - 4.0, 12.0 - 4.0, 4.0), (0, 0, 1), (0, -1, 0), size[0] * px, size[1] * px,
                              size=size)
    # analytic coverage: pixel centres inside [-0.5, n - 0.5] in x and y
    xs = (np.arange(size[0]) + 0.5) * px - 4.0
    ys = (np.arange(size[1]) + 0.5) * px - 4.0
    lo, hi = pyr.volume_box()
    inside = ((ys[:, None] > lo[1]) & (ys[:, None] < hi[1])) & ((xs[None] > lo[0]) & (xs[None] < hi[0]))
    with ClipTexture(loader, "16MB", threads=2) as clip:
        for level in range(pyr.num_levels):
            action = ClipRenderAction(ctx, clip, policy="fixed", level=level, path=draw_path)
            try:
                img = action.render(cam, opaque, wait=True, timeout=20)
                assert action.last_frame_stats.converged
            finally:
                action.close()
            drawn = img[..., 3] > 0
            # rows of the image run top to bottom, world y runs down the image (up = -y): row i <-> ys[i]
            assert np.array_equal(drawn, inside), f"level {level}: {int((drawn != inside).sum())} pixels off the box"
