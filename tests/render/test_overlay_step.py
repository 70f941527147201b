"""An overlay is sampled at its own step, not the primary's: a 1 mm primary drawn from a coarse level
(4 mm voxels, a 2 mm step) over a 3 mm map of a smooth saturated blob renders like the numpy
reference sampling the map every 1.5 mm or finer (``reference_raycast.raycast_overlays`` with a 1 mm
lattice), not like the same reference at the primary's 2 mm step, which shows the stair-step rings.
Sampled classified, the reference classifies the map's voxels (opacity for the 1 mm step) and
interpolates their colours (``reference_raycast.classified_overlay``): the shader corrects each
voxel's opacity for the sub-step before blending them.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.overlay import Overlay
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

P_SHAPE = (40, 40, 40)  # 1 mm; brick 16: level 2 is 10^3 voxels of 4 mm
M_SHAPE, M_SPACING = (14, 14, 14), (3.0, 3.0, 3.0)  # the map: 3 mm voxels over the same 42 mm


def _blob() -> np.ndarray:
    """A smooth blob in the middle of the map, clipped high (saturated)."""
    c = (np.arange(M_SHAPE[0]) * M_SPACING[0]) - 19.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    g = np.exp(-(x ** 2 + (y - 1.0) ** 2 + (z + 1.5) ** 2) / (2 * 6.0 ** 2))
    return np.minimum(1.4 * g, 1.0).astype(np.float32)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("overlay_step")
    p = np.zeros(P_SHAPE, dtype=np.float32)  # transparent under its table: only the map shows
    m = _blob()
    brick_volume(p, d / "p.zarr", brick=16, spacing=(1.0, 1.0, 1.0), progress=False, workers=1, summary=False)
    brick_volume(m, d / "m.zarr", brick=16, spacing=M_SPACING, progress=False, workers=1, summary=False)
    return p, m, d / "p.zarr", d / "m.zarr"


@pytest.mark.parametrize("sampling", ["interpolated", pytest.param("classified", marks=pytest.mark.slow)])
def test_coarse_primary_samples_the_map_at_its_own_step(ctx, stores, sampling):
    p, m, ppath, mpath = stores
    tf = TransferFunction.preset("grey", value_range=(0.5, 1.0))
    otf = TransferFunction.preset("inferno", value_range=(0.3, 1.0))
    cam = Camera.perspective((19.5 + 52.0, 19.5 - 38.0, 19.5 + 47.0), (19.5, 19.5, 19.5), up=(0, 0, 1),
                             fov_y=30, size=(96, 96))
    clip = ClipTexture(ZarrLoader(ppath), "64MB", threads=2)
    try:
        ov = Overlay(ZarrLoader(mpath), otf, sampling=sampling)
        with ClipRenderAction(ctx, clip, policy="fixed", level=2, overlays=(ov,)) as act:
            img = act.render(cam, tf, wait=True, timeout=30)
            assert act.last_frame_stats.converged
            assert act.last_frame_stats.bricks_drawn == {2: 1}  # drawn from 4 mm voxels: a 2 mm step
    finally:
        clip.close()
    fc = cam.fit_depth(*ZarrLoader(ppath).pyramid.volume_box())
    layer = (m, M_SPACING, (0.0, 0.0, 0.0), otf.table, (0.3, 1.0))
    layer = [ref.classified_overlay(*layer) if sampling == "classified" else layer]
    fine = ref.to_uint8(ref.raycast_overlays(p, (1, 1, 1), fc, tf.table, (0.5, 1.0), layer, step=1.0))
    coarse = ref.to_uint8(ref.raycast_overlays(p, (1, 1, 1), fc, tf.table, (0.5, 1.0), layer, step=2.0))
    assert (fine[..., 3] > 200).sum() > 300  # the blob is large and saturated in the picture
    # the primary's 2 mm step would show the rings: the two references differ much
    assert np.abs(fine.astype(int) - coarse.astype(int)).max() > 20
    diff = np.abs(img.astype(int) - fine.astype(int))
    assert diff.max() <= 3, (diff.max(), (diff > 1).mean())
    assert (diff > 1).mean() < 0.01
