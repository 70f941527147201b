"""The converged picture (level 0, a fine step, supersampled and box-filtered) that the report and the
benchmarks measure error against: nearer an independent numpy ray cast of the limit (a finer step,
more rays per pixel) than the plain full-resolution frame is, and its box filter against a loop."""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref

pytest.importorskip("moderngl")


def _shells(n: int = 24) -> np.ndarray:
    """Thin bright shells around the centre (a skull-like membrane, 1-2 voxels thick) over a dim
    interior: what a half-voxel step and one ray per pixel draw worst under a sharp table."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    r = np.sqrt((x - n / 2 + 0.3) ** 2 + (y - n / 2 - 0.2) ** 2 + (z - n / 2 + 0.1) ** 2)
    v = 0.25 * (r < 0.42 * n) + 0.75 * np.exp(-((r - 0.35 * n) / 0.8) ** 2) + 0.7 * np.exp(-((r - 0.2 * n) / 0.6) ** 2)
    return np.clip(v, 0.0, 1.0).astype(np.float32)


def test_box_filter_is_the_premultiplied_block_mean():
    from clipvol.app.converged import box_filter

    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, size=(6, 9, 4)).astype(np.uint8)
    img[:3, :3, 3] = 0  # a transparent block
    out = box_filter(img, 3)
    assert out.shape == (2, 3, 4) and out.dtype == np.uint8
    for i in range(2):
        for j in range(3):
            blk = img[3 * i:3 * i + 3, 3 * j:3 * j + 3].reshape(-1, 4).astype(np.float64) / 255.0
            a = blk[:, 3].mean()
            want_rgb = (blk[:, :3] * blk[:, 3:4]).sum(axis=0) / blk[:, 3].sum() if a > 0 else np.zeros(3)
            np.testing.assert_allclose(out[i, j, 3] / 255.0, a, atol=0.5 / 255 + 1e-9)
            np.testing.assert_allclose(out[i, j, :3] / 255.0, want_rgb, atol=0.5 / 255 + 1e-9)
    assert not out[0, 0].any()


def test_box_filter_names_a_bad_size():
    from clipvol.app.converged import box_filter
    from clipvol.errors import ParameterError

    with pytest.raises(ParameterError, match="not a multiple of the factor 2"):
        box_filter(np.zeros((5, 4, 4), np.uint8), 2)
    with pytest.raises(ParameterError, match="supersample"):
        box_filter(np.zeros((4, 4, 4), np.uint8), 0)


@pytest.mark.gl
def test_converged_picture_is_nearer_the_limit_than_the_plain_frame(ctx):
    """The converged picture of a volume of thin shells under a sharp table, drawn by the GL renderer
    (step 0.25, 2x2 rays per pixel), is nearer the numpy ray cast of the limit (step 0.125, 3x3 rays
    per pixel, averaged) than the plain full-resolution frame (step 0.5, one ray per pixel) is."""
    from clipvol.app.converged import ConvergedPictures
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.metrics import percent_delta_e, rmse
    from clipvol.scene.params import RenderParams
    from clipvol.scene.transfer import TransferFunction

    vol = _shells()
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0.0)), (0.55, (0, 0, 0, 0.0)), (0.6, (1, 0.9, 0.7, 0.9)),
                                       (1.0, (1, 1, 1, 1.0))])
    loader = NumpyLoader(vol, brick=8)
    pyr = loader.pyramid
    w = 32
    cam = Camera.perspective((30.0, 22.0, -26.0), (11.5, 11.5, 11.5), up=(0, 1, 0), fov_y=40, size=(w, w))
    clip = ClipTexture(loader, "64MB", threads=2)
    base = RenderParams(policy="fixed", level=0, step=0.5)
    action = ClipRenderAction(ctx, clip, base)
    try:
        def render(c, params):
            action.set_params(params)
            return action.render(c, tf, wait=True, timeout=30)

        plain = render(cam, base)
        conv = ConvergedPictures(render, base, supersample=2, step=0.25).get(cam)
        assert conv.shape == plain.shape
        # the limit, in numpy: 3x3 rays per pixel at step 0.125, premultiplied colours averaged
        k = 3
        big = Camera.perspective((30.0, 22.0, -26.0), (11.5, 11.5, 11.5), up=(0, 1, 0), fov_y=40, size=(w * k, w * k))
        prem = ref.raycast(vol, pyr.spacing, big.fit_depth(*pyr.volume_box()), tf.table, tf.window(pyr.value_range),
                           0.125)
        truth = ref.to_uint8(prem.reshape(w, k, w, k, 4).mean(axis=(1, 3)))
    finally:
        action.close()
        clip.close()
    e_plain = rmse(plain, truth, premultiplied=False)
    e_conv = rmse(conv, truth, premultiplied=False)
    p_plain = percent_delta_e(plain, truth, premultiplied=False)
    p_conv = percent_delta_e(conv, truth, premultiplied=False)
    assert p_plain > 2.0  # the plain frame is visibly off the limit on this volume
    assert e_conv < 0.6 * e_plain and p_conv < 0.5 * p_plain, (e_conv, e_plain, p_conv, p_plain)
