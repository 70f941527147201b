"""Bricks sample exactly what one brick would: an opaque, high-contrast transfer function (bone)
over a store with per-brick statistics, so that air bricks are culled as transparent next to
bone bricks. Reference: the independent numpy ray caster over the whole array.

Before the fix, a culled air brick's box was not sampled at all, though samples within half a voxel
of its faces interpolate the visible neighbour's edge voxels (up to 44 LSB at those faces).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from render_helpers import every_draw_path
from scipy.ndimage import gaussian_filter

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

SHAPE = (45, 54, 45)  # odd axes: clipped edge bricks


def blob() -> np.ndarray:
    """An ellipsoid of bone-like noisy values in air (0)."""
    rng = np.random.default_rng(0)
    z, y, x = np.mgrid[0:SHAPE[0], 0:SHAPE[1], 0:SHAPE[2]]
    c = np.array(SHAPE)[:, None, None, None] / 2
    r = np.sqrt((((np.stack([z, y, x]) - c) / (np.array(SHAPE)[:, None, None, None] * 0.4)) ** 2).sum(0))
    v = np.where(r < 1, 0.3 + 2.1 * gaussian_filter(rng.random(SHAPE), 1.5), 0.0)
    return np.clip(v, 0, 1).astype(np.float32)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    vol = blob()
    out = {}
    for b in (8, 64):
        p = tmp_path_factory.mktemp("seams") / f"b{b}.zarr"
        brick_volume(vol, p, brick=b, progress=False, workers=1)
        out[b] = p
    return vol, out


@pytest.mark.parametrize("kw", [*(dict(path=p) for p in every_draw_path()),
                                pytest.param(dict(path="bricks", merge_boxes=False), marks=pytest.mark.slow)],
                         ids=[*every_draw_path(), "bricks-unmerged"])
def test_opaque_seams_match_one_brick_and_the_reference(ctx, stores, kw):
    vol, paths = stores
    tf = TransferFunction.preset("bone")
    n = max(SHAPE)
    c = [(s - 1) / 2 for s in SHAPE[::-1]]
    cam = Camera.perspective((c[0] + 1.3 * n, c[1] + 0.9 * n, c[2] - 1.1 * n), tuple(c), size=(96, 96), fov_y=35)
    imgs = {}
    for b in (8, 64):
        clip = ClipTexture(ZarrLoader(paths[b]), "64MB", threads=2)
        action = ClipRenderAction(ctx, clip, policy="fixed", level=0, **(kw if b == 8 else dict(path="bricks")))
        try:
            imgs[b] = action.render(cam, tf, wait=True, timeout=30)
            assert action.last_frame_stats.converged
            if b == 8:
                assert len(action.last_selection.items) > 100
        finally:
            action.close()
            clip.close()
    fc = cam.fit_depth(*ZarrLoader(paths[8]).pyramid.volume_box())
    r = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, tf.table, (float(vol.min()), float(vol.max())), 0.5))
    assert (r[..., 3] > 200).mean() > 0.2  # really opaque
    d_one = np.abs(imgs[8].astype(int) - imgs[64].astype(int))
    d_ref = np.abs(imgs[8].astype(int) - r.astype(int))
    assert d_one.max() <= 1, f"{int((d_one.max(axis=2) > 1).sum())} pixels differ from one brick"
    assert d_ref.max() <= 1, f"{int((d_ref.max(axis=2) > 1).sum())} pixels differ from the reference"


def test_culling_still_skips_air_far_from_the_object(ctx, tmp_path):
    """The footprint rule keeps culling what cannot be seen: a corner of air two bricks away from
    any non-zero voxel is culled."""
    vol = np.zeros((64, 64, 64), np.float32)
    vol[:16, :16, :16] = 1.0
    p = tmp_path / "corner.zarr"
    brick_volume(vol, p, brick=8, progress=False, workers=1)
    clip = ClipTexture(ZarrLoader(p), "64MB", threads=2)
    action = ClipRenderAction(ctx, clip, policy="fixed", level=0)
    try:
        cam = Camera.perspective((130.0, 110.0, -90.0), (31.5, 31.5, 31.5), size=(32, 32), fov_y=40)
        action.render(cam, TransferFunction.preset("bone"), wait=True, timeout=30)
        counts = action.last_frame_stats.counts
        assert counts["culled_transparent"] > 0
        drawn = {tuple(it.index) for it in action.last_selection.items if it.level == 0}
        assert drawn and all(max(i) <= 2 for i in drawn)  # only the object's bricks and their neighbours
    finally:
        action.close()
        clip.close()
