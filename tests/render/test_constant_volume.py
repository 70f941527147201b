"""A constant volume of every dtype draws as its constant (its value range is zero wide, so the
transfer function's window is a step at the value, which maps to the middle of the table).

Reference: the table's colour at ``t = 0.5`` written by hand (the table is flat over [0.2, 1], so
neither interpolation nor the step's exact position can move it), in the straight 8-bit RGBA
that the action returns; composite along 32 voxels of alpha 0.8 is opaque to within 1e-20.
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

COLOUR = (1.0, 0.5, 0.25, 0.8)
#: per dtype: a middle value and one at the edge of the type's range
VALUES = {
    "uint8": (100, 255), "int8": (-100, 127), "uint16": (1000, 65535), "int16": (-1000, 32767),
    "int32": (-70000, 2**31 - 1), "float32": (3.5, -1e20), "float64": (1e-3, 1e200),
}


@pytest.mark.parametrize("dtype", sorted(VALUES))
@pytest.mark.parametrize("mode", ["mip", "composite"])
def test_constant_volume_draws_its_constant(ctx, dtype, mode):
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.2, COLOUR), (1.0, COLOUR)])
    cam = Camera.orthographic((7.5, 7.5, 7.5), (0, 0, 1), (0, -1, 0), 12.0, 12.0, size=(24, 24))
    for value in VALUES[dtype]:
        vol = np.full((16, 16, 16), value, dtype=dtype)
        loader = NumpyLoader(vol, brick=8)
        assert loader.pyramid.value_range[0] == loader.pyramid.value_range[1]
        with ClipTexture(loader, "16MB", threads=1) as clip, ClipRenderAction(ctx, clip, mode=mode) as action:
            img = action.render(cam, tf, wait=True, timeout=30)
            assert action.last_frame_stats.converged
        rgb = np.round(np.array(COLOUR[:3]) * 255)
        alpha = 204 if mode == "mip" else 255
        expected = np.broadcast_to(np.array([*rgb, alpha]), img.shape)
        err = np.abs(img.astype(int) - expected).max()
        assert err <= 1, f"{dtype} {value} {mode}: pixel {img[12, 12]}, expected {expected[12, 12]}"


@pytest.mark.parametrize("dtype", ["uint16", "float32"])
def test_automatic_transfer_function_shows_a_constant_volume(dtype):
    """The automatic window of a constant volume is the step at its value: the value is visible."""
    from clipvol.scene.auto_tf import auto_transfer_function

    loader = NumpyLoader(np.full((16, 16, 16), 1000, dtype=dtype), brick=8)
    tf = auto_transfer_function(loader)
    assert tf.value_range == (1000.0, 1000.0)
    assert tf.lookup(np.array([1000.0]))[0, 3] > 0.0


@pytest.mark.parametrize("dtype", ["uint16", "int16"])
def test_sort_last_mip_of_a_constant_volume_draws_its_constant(ctx, tmp_path, dtype):
    """The sort-last compositor maps the groups' maximum texel back to a value as the action does."""
    from clipvol.app.sortlast import DistributedRenderer, release_worker_state
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.scene.params import RenderParams

    brick_volume(np.full((16, 16, 16), 1234, dtype=dtype), tmp_path / "c.zarr", brick=8, progress=False, workers=1,
                 summary=False)
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.2, COLOUR), (1.0, COLOUR)])
    cam = Camera.orthographic((7.5, 7.5, 7.5), (0, 0, 1), (0, -1, 0), 12.0, 12.0, size=(24, 24))
    try:
        with DistributedRenderer(tmp_path / "c.zarr", 2, RenderParams(mode="mip"), scheduler="inline",
                                 memory_budget="16MB") as dr:
            img = dr.render(cam, tf)
    finally:
        release_worker_state()
    expected = np.array([*np.round(np.array(COLOUR[:3]) * 255), 204])
    assert np.abs(img.astype(int) - expected).max() <= 1, img[12, 12]
