"""Coarse levels sit where level 0's voxels they average sit: no half-voxel offset between levels.

The image policy's remaining error on the benchmark head is a ring along the skin's silhouette
where a coarse level's blurred edge lands about a pixel away from level 0's. If a level's voxel
centres were placed half a voxel off the centres of the 2x2x2 blocks they average, every edge
would shift by that much. Here a store's level 1 and level 2, each drawn alone, are compared with
an independent numpy ray caster (``reference_raycast.py``) over a volume downsampled in numpy
(``floor((sum + 4) / 8)`` of each 2x2x2 block, the store's documented rounding for integers) and
placed at the centres of the blocks it averages (level-1 voxel ``i`` at ``2 i + 0.5`` level-0
voxels). The same reference shifted by half a coarse voxel must differ clearly, so the comparison
can see an offset of that size.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref

from clipvol.bricking.generators import ct_head
from clipvol.bricking.pipeline import brick_volume
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.open import open_store
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

N = 64


def _mean2(a: np.ndarray) -> np.ndarray:
    n = a.shape[0] // 2
    s = a.astype(np.int64).reshape(n, 2, n, 2, n, 2).sum(axis=(1, 3, 5))
    return ((s + 4) // 8).astype(np.uint8)


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    vol = ct_head((N, N, N), seed=0)
    path = tmp_path_factory.mktemp("place") / "h.zarr"
    brick_volume(vol, path, brick=16, progress=False, summary=False)
    return vol, path


@pytest.mark.parametrize("level", [1, 2])
def test_coarse_level_matches_numpy_downsample_at_block_centres(gl, head, level):
    vol, path = head
    loader = open_store(path)
    pyr = loader.pyramid
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    d = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    cam = Camera.perspective(tuple(c - d * 0.6 * np.linalg.norm(hi - lo)), tuple(c), up=(0, -1, 0), fov_y=40,
                             size=(96, 96))
    clip = ClipTexture(loader, "64MB", threads=2)
    # the reference classifies each coarse voxel's mean: so does classify="mean" (the placement is
    # what this test checks; tests/render/test_consistent_levels.py checks the distribution)
    action = ClipRenderAction(gl, clip, policy="fixed", level=level, classify="mean")
    try:
        img = action.render(cam, tf, wait=True, timeout=60)
    finally:
        action.close()
        clip.close()
    arr = vol
    for _ in range(level):
        arr = _mean2(arr)
    f = 2.0**level
    fc = cam.fit_depth(lo, hi)

    def reference(offset):
        levels = {level: (arr, np.full(3, f), np.full(3, offset))}
        return ref.to_uint8(ref.raycast_levels(levels, [(level, lo, hi)], fc, tf.table, tf.window(pyr.value_range),
                                               0.5, "composite", 1.0))

    centred = reference((f - 1.0) / 2.0)  # the centre of the 2^L block of level-0 voxels
    shifted = reference((f - 1.0) / 2.0 + f / 2.0)  # half a coarse voxel off
    diff = np.abs(img.astype(np.int64) - centred.astype(np.int64))
    off = np.abs(img.astype(np.int64) - shifted.astype(np.int64))
    assert (img[..., 3] > 0).mean() > 0.5  # the head fills the view
    assert np.percentile(diff, 99) <= 3 and diff.mean() < 0.5, (np.percentile(diff, 99), diff.mean())
    assert off.mean() > 10 * max(diff.mean(), 0.1) and off.max() > 40, (off.mean(), off.max())
