"""The GL pass that turns the float target into the 8-bit image (render/resolve.py), against the
straight-alpha arithmetic written out here in numpy float64 (background under, un-premultiply where
the 8-bit alpha is not 0, clamp, round half to even), and the action's frames against it."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.render.resolve import Resolve


def _reference(prem: np.ndarray, background) -> np.ndarray:
    p = prem.astype(np.float64)
    r, g, b, a = background
    p = p + (1.0 - p[..., 3:4]) * np.array([r * a, g * a, b * a, a])
    alpha = np.clip(p[..., 3:4], 0.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.where(np.rint(alpha * 255.0) > 0, p[..., :3] / alpha, 0.0)
    return np.rint(np.clip(np.concatenate([rgb, alpha], -1), 0.0, 1.0) * 255.0).astype(np.uint8)


def _target(rng, h: int, w: int) -> np.ndarray:
    alpha = rng.random((h, w, 1)).astype(np.float32)
    alpha[:8] = 0.0  # nothing drawn
    alpha[8:16] = rng.random((8, w, 1)) * (1.5 / 255.0)  # around the first 8-bit step
    alpha[16:20] = 1.0 + rng.random((4, w, 1)) * 0.01  # a little over 1 (accumulated rounding)
    colour = rng.random((h, w, 3)).astype(np.float32) * alpha
    return np.concatenate([colour, alpha], -1).astype(np.float32)


@pytest.mark.parametrize("background", [(0.0, 0.0, 0.0, 0.0), (0.2, 0.4, 0.6, 1.0), (1.0, 1.0, 1.0, 0.5)])
def test_resolve_matches_numpy(ctx, background):
    rng = np.random.default_rng(7)
    h, w = 64, 48
    prem = _target(rng, h, w)
    tex = ctx.texture((w, h), 4, prem[::-1].tobytes(), dtype="f4")  # GL rows run bottom-up
    resolve = Resolve(ctx)
    try:
        out = resolve(tex, background)
    finally:
        ctx.detect_framebuffer(0).use()  # leave no framebuffer bound that is about to be released
        resolve.release()
        tex.release()
    ref = _reference(prem, background)
    assert out.shape == (h, w, 4) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[..., 3], ref[..., 3])
    assert (out[ref[..., 3] == 0][:, :3] == 0).all()  # black where nothing shows
    diff = np.abs(out.astype(int) - ref.astype(int))
    # float32 on the GL against float64 here: a value within an ulp of a rounding tie may go either way
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3


def test_frame_equals_numpy_resolve_of_its_target(ctx):
    """A composite frame is the numpy arithmetic applied to the float target it drew."""
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    rng = np.random.default_rng(3)
    vol = rng.random((32, 32, 32)).astype(np.float32)
    loader = NumpyLoader(vol, brick=16)
    background = (0.1, 0.2, 0.3, 1.0)
    with ClipTexture(loader, 64 << 20, threads=1) as clip, \
            ClipRenderAction(ctx, clip, policy="fixed", level=0, background=background) as action:
        cam = Camera.perspective((70.0, 50.0, -40.0), (16.0, 16.0, 16.0), size=(64, 48))
        image = action.render(cam, TransferFunction.preset("bone", value_range=(0.0, 1.0)), wait=True, timeout=60)
        raw = np.array(action.last_raw)
    assert raw[..., 3].max() > 0.5 and raw[..., 3].min() == 0.0  # the volume and empty space are both in view
    ref = _reference(raw, background)
    diff = np.abs(image.astype(int) - ref.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
