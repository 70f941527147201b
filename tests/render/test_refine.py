"""Adaptive image sampling (RenderParams.refine_tolerance, clipvol.render.refine) draws what the
refinement of the numpy reference caster's own images draws, in both draw paths.

The reference is built here from the independent caster (tests/reference_raycast.py) and the
algorithm as its docstring states it, in float64 numpy: the image at 1/4, 1/2 and full resolution
(the rays of a camera of that size are the rays the coarse passes cast when the size divides), then
from the coarsest up, a pixel whose four surrounding coarser rays agree to within the tolerance in
every premultiplied channel is their bilinear blend, every other pixel is its own ray."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import reference_raycast as ref
from test_empty_skip import SHELL, scene  # noqa: F401  (scene: the shell volume's fixture)

from clipvol.errors import ParameterError
from clipvol.render.refine import refine_levels
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams

pytestmark = pytest.mark.gl

TOL = 0.05


def camera(size=(96, 80)):
    return Camera.perspective((95.0, 75.0, -40.0), (31.5, 31.5, 31.5), size=size, fov_y=40)


def refined_reference(vol, pyr, cam, tol: float, levels: int) -> tuple[np.ndarray, float]:
    """The refined image from the reference caster (premultiplied float, rows top first) and the
    share of its pixels that are blends rather than rays."""
    fc = cam.fit_depth(*pyr.volume_box())
    w, h = cam.size

    def cast(k):
        c = replace(fc, size=(w // 2**k, h // 2**k))
        return ref.raycast(vol, pyr.spacing, c, SHELL.table, SHELL.window(pyr.value_range), 0.5)[::-1]  # rows up

    img = cast(levels)
    blended = None
    for k in range(levels - 1, -1, -1):
        rays = cast(k)
        H, W = rays.shape[:2]
        y, x = np.mgrid[0:H, 0:W]
        cy, cx = (y + 0.5) / 2 - 0.5, (x + 0.5) / 2 - 0.5
        y0, x0 = np.floor(cy).astype(int), np.floor(cx).astype(int)
        fy, fx = (cy - y0)[..., None], (cx - x0)[..., None]

        def tap(dy, dx):
            return img[np.clip(y0 + dy, 0, img.shape[0] - 1), np.clip(x0 + dx, 0, img.shape[1] - 1)]

        a, b, d, e = tap(0, 0), tap(0, 1), tap(1, 0), tap(1, 1)
        taps = np.stack([a, b, d, e])
        smooth = (taps.max(axis=0) - taps.min(axis=0)).max(axis=-1) <= tol
        blend = (a * (1 - fx) + b * fx) * (1 - fy) + (d * (1 - fx) + e * fx) * fy
        img = np.where(smooth[..., None], blend, rays)
        blended = float(smooth.mean())
    return img[::-1], blended


def test_refined_frame_is_the_reference_refinement(scene, draw_path):
    vol, pyr, action = scene
    cam = camera()
    assert refine_levels(cam) == 2  # 96 x 80 -> 48 x 40 -> 24 x 20
    img = action(path=draw_path, refine_tolerance=TOL, merge_boxes=draw_path == "bricks").render(cam, SHELL, wait=True)
    want, blended = refined_reference(vol, pyr, cam, TOL, 2)
    assert blended > 0.5  # most pixels are blends: the test exercises the mask, not only the rays
    d = np.abs(img.astype(np.int64) - ref.to_uint8(want).astype(np.int64)).max(axis=-1)
    # a pixel whose spread lies within float32 rounding of the tolerance may go either way
    assert (d > 2).mean() <= 0.01, f"{(d > 2).sum()} pixels differ by more than 2 levels (max {d.max()})"
    plain = action(path=draw_path).render(cam, SHELL, wait=True)
    assert np.abs(plain.astype(np.int64) - img.astype(np.int64)).max() > 0  # refined, not the plain frame


def test_odd_sizes_keep_every_pixel_in_place(scene):
    """An image of odd size: the coarse passes have a column and row beyond it; the refined frame is
    the plain one wherever the tolerance is tiny (only exactly equal neighbours are blended)."""
    _, _, action = scene
    cam = camera((97, 79))
    plain = action().render(cam, SHELL, wait=True)
    img = action(refine_tolerance=1e-6).render(cam, SHELL, wait=True)
    d = np.abs(plain.astype(np.int64) - img.astype(np.int64)).max(axis=-1)
    assert (d > 1).mean() <= 0.01


def test_modes_other_than_composite_and_tiny_images_draw_every_pixel(scene):
    _, _, action = scene
    mip = action(mode="mip", refine_tolerance=0.5).render(camera(), SHELL, wait=True)
    assert np.array_equal(mip, action(mode="mip").render(camera(), SHELL, wait=True))
    small = camera((12, 12))
    assert refine_levels(small) == 0
    assert np.array_equal(action(refine_tolerance=0.5).render(small, SHELL, wait=True),
                          action().render(small, SHELL, wait=True))


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "x"])
def test_refine_tolerance_is_checked(bad):
    with pytest.raises(ParameterError, match="refine_tolerance"):
        RenderParams(refine_tolerance=bad)


@pytest.mark.parametrize("early_termination", [True, False])
def test_the_mask_drawn_only_over_the_volume_changes_no_pixel(scene, monkeypatch, early_termination):
    """The mask of a finer pass is drawn under the volume's scissor box: outside it the cleared pixel
    is what the blend of the coarse pass's cleared pixels gives (a background too, drawn back to
    front). Against the mask over the whole target, with the volume small in the image."""
    from clipvol.render.paths.setup import scissor_boxes
    from clipvol.render.refine import Refine

    vol, pyr, action = scene
    far = Camera.perspective((200.0, 150.0, -120.0), (31.5, 31.5, 31.5), size=(96, 80), fov_y=40)
    rect = scissor_boxes(far, *pyr.volume_box())[0]
    assert rect[2] * rect[3] < 0.5 * 96 * 80  # the volume covers under half the image
    kw = dict(refine_tolerance=TOL, early_termination=early_termination, background=(0.2, 0.3, 0.4, 1.0))
    img = action(**kw).render(far, SHELL, wait=True)
    mask = Refine.mask
    monkeypatch.setattr(Refine, "mask", lambda self, fbo, cam, k, tol, origin, rect=None: mask(self, fbo, cam, k, tol,
                                                                                              origin, None))
    whole = action(**kw).render(far, SHELL, wait=True)
    assert np.array_equal(img, whole)
    assert (img[..., 3] > 0).any() and (img[..., 3] == 255).any()  # the volume is drawn, on a background
