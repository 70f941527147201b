"""The scissor rectangles that restrict each box's one screen triangle (``render.paths.setup.scissor_boxes``)
must hold every pixel whose ray meets the box - a pixel left out would silently lose that box's
samples. Checked against rays built here with plain numpy (not the camera's own ray code) and a
slab test per pixel centre."""

import numpy as np
import pytest

from clipvol.render.paths.setup import scissor_boxes
from clipvol.scene.camera import Camera


def _hit_pixels(eye, target, up, fov_y, size, lo, hi):
    """Bool ``(h, w)`` (row 0 at the bottom, as GL counts): the ray through the pixel centre meets the box."""
    w, h = size
    f = np.subtract(target, eye).astype(float)
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = np.tan(np.radians(fov_y) / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * ty * w / h
    ys = ((np.arange(h) + 0.5) / h * 2.0 - 1.0) * ty  # bottom row first
    gx, gy = np.meshgrid(xs, ys)
    d = f + gx[..., None] * r + gy[..., None] * u
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (np.asarray(lo) - eye) / d
        tb = (np.asarray(hi) - eye) / d
    t0 = np.nanmax(np.minimum(ta, tb), axis=-1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=-1)
    return t1 > np.maximum(t0, 0.0)


@pytest.mark.parametrize("seed", range(6))
def test_scissor_boxes_hold_every_pixel_a_box_covers(seed):
    rng = np.random.default_rng(seed)
    size = (96, 64)
    eye = rng.uniform(-40, 40, 3)
    target = rng.uniform(-5, 5, 3)
    up = np.array([0.0, 0.0, 1.0]) if seed % 2 else np.array([0.0, 1.0, 0.0])
    cam = Camera.perspective(eye, target, up=tuple(up), fov_y=50.0, size=size)
    lo = rng.uniform(-20, 15, (40, 3))
    hi = lo + rng.uniform(0.5, 12, (40, 3))
    rects = scissor_boxes(cam, lo, hi)
    f = (target - eye) / np.linalg.norm(target - eye)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = np.tan(np.radians(50.0) / 2.0)
    seen = 0
    for k in range(len(lo)):
        hit = _hit_pixels(eye, target, up, 50.0, size, lo[k], hi[k])
        x, y, w, h = rects[k]
        inside = np.zeros_like(hit)
        inside[y:y + h, x:x + w] = True
        assert not np.any(hit & ~inside), f"box {k}: pixels its rays meet lie outside its scissor box {rects[k]}"
        corners = np.array([[(lo[k], hi[k])[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
        depth = (corners - eye) @ f
        if np.all(depth > 0):
            # and not much more (the per-brick path's speed): within 2 pixels of the bounding box
            # of the corners' pinhole projections (a box reaching the eye plane gets the whole image)
            px = ((corners - eye) @ r / depth / (ty * size[0] / size[1]) + 1.0) * 0.5 * size[0]
            py = ((corners - eye) @ u / depth / ty + 1.0) * 0.5 * size[1]
            assert x >= min(max(px.min(), 0), size[0]) - 2 and x + w <= max(min(px.max(), size[0]), 0) + 2
            assert y >= min(max(py.min(), 0), size[1]) - 2 and y + h <= max(min(py.max(), size[1]), 0) + 2
        seen += bool(hit.any())
    assert seen >= 5  # the random scene does put boxes in view


def test_box_around_the_eye_gets_the_whole_image_and_one_behind_none():
    cam = Camera.perspective((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), size=(80, 60))
    rects = scissor_boxes(cam, [(-1, -1, 9), (-1, -1, 20)], [(1, 1, 11), (1, 1, 22)])
    assert tuple(rects[0]) == (0, 0, 80, 60)
    assert rects[1, 2] == 0 or rects[1, 3] == 0
