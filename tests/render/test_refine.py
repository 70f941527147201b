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
from clipvol.render.refine import COMPACT_BLOCK, COMPACT_MAX_BOXES, compact_order, compact_texels, refine_levels
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


# -- compaction: a masked pass's rays cast packed, scattered back ------------------------------------
def test_compact_order_lists_the_live_pixels_block_by_block():
    """Against a brute-force sort: block row, block column, then row and column inside the block."""
    rng = np.random.default_rng(7)
    live = rng.random((23, 37)) < 0.2  # sizes that are no multiple of the block
    xs, ys = compact_order(live)
    y, x = np.nonzero(live)
    B = COMPACT_BLOCK
    want = np.lexsort((x % B, y % B, x // B, y // B))
    assert np.array_equal(xs, x[want]) and np.array_equal(ys, y[want])
    assert compact_order(np.zeros((5, 9), dtype=bool))[0].size == 0


def test_compact_texels_pack_sixteen_entries_per_block_each_once():
    width = 16
    cx, cy = compact_texels(100, width)
    expect = []
    for i in range(100):  # entry i: block i // 16 of width / 4 per row, position i % 16 row by row
        b, j = divmod(i, 16)
        expect.append(((b % (width // 4)) * 4 + j % 4, (b // (width // 4)) * 4 + j // 4))
    assert list(zip(cx.tolist(), cy.tolist())) == expect
    assert len(set(expect)) == 100 and max(x for x, _ in expect) < width


def test_compacted_passes_draw_the_masked_passes_bit_for_bit(scene, draw_path, monkeypatch):
    """The same rays as the masked passes drawn in place (the images equal to the last bit), cast
    for exactly the pixels the mask leaves: the image pass's list is the reference refinement's
    pixels that are rays, not blends."""
    from clipvol.render import refine
    from clipvol.render.refine import Compaction

    vol, pyr, action = scene
    cam = camera()
    counts = []
    begin = Compaction.begin

    def counted(self, *args):
        out = begin(self, *args)
        counts.append(self.count)
        return out

    monkeypatch.setattr(Compaction, "begin", counted)
    monkeypatch.setattr(refine, "COMPACT", True)  # (off by default)
    kw = dict(path=draw_path, refine_tolerance=TOL, merge_boxes=draw_path == "bricks")
    img = action(**kw).render(cam, SHELL, wait=True)
    assert len(counts) == 2  # the 1/2 pass and the image pass, each compacted
    monkeypatch.setattr(refine, "COMPACT", False)
    in_place = action(**kw).render(cam, SHELL, wait=True)
    assert len(counts) == 2
    assert np.array_equal(img, in_place)
    _, blended = refined_reference(vol, pyr, cam, TOL, 2)
    rays = (1.0 - blended) * cam.size[0] * cam.size[1]
    assert abs(counts[1] - rays) <= 0.01 * cam.size[0] * cam.size[1], (counts, rays)


def test_a_pass_over_many_boxes_is_drawn_in_place(scene, monkeypatch):
    """Each box of a compacted pass runs over the whole list: a cut of more than COMPACT_MAX_BOXES
    boxes is drawn masked in place, and still refined like the reference."""
    from clipvol.render import refine
    from clipvol.render.refine import Compaction

    vol, pyr, action = scene
    calls = []
    monkeypatch.setattr(Compaction, "begin", lambda *a: calls.append(a))
    monkeypatch.setattr(refine, "COMPACT", True)
    cam = camera()
    a = action(path="bricks", refine_tolerance=TOL, merge_boxes=False)
    img = a.render(cam, SHELL, wait=True)
    assert a.boxes_drawn > COMPACT_MAX_BOXES and not calls
    want, _ = refined_reference(vol, pyr, cam, TOL, 2)
    d = np.abs(img.astype(np.int64) - ref.to_uint8(want).astype(np.int64)).max(axis=-1)
    assert (d > 2).mean() <= 0.01


def test_compacts_small_images_with_few_boxes_only(monkeypatch):
    from clipvol.render import refine

    small, large = camera((256, 256)), camera((257, 256))
    assert not refine.COMPACT and not refine.compacts(small, 1, True)  # off by default
    monkeypatch.setattr(refine, "COMPACT", True)
    assert refine.compacts(small, COMPACT_MAX_BOXES, False) and refine.compacts(small, 1000, True)
    assert not refine.compacts(small, COMPACT_MAX_BOXES + 1, False)
    assert not refine.compacts(large, 1, False) and not refine.compacts(large, 1, True)
    monkeypatch.setattr(refine, "COMPACT", False)
    assert not refine.compacts(small, 1, True)


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
